//! Synthesis of 2D views (paper §3.2): rotate a 3D shape over a yaw x pitch (x roll) grid at any
//! interval, project it, and attach per-point visibility from HPR.

use nalgebra::{Rotation3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::geometry::EulerAngles;
use crate::hpr::{HprScratch, PaperHpr};
use crate::shape::Shape2;

/// Angles `min, min + step, ..., max` in degrees (max included when it falls on the grid).
/// Read from JSON through [`AngleRange::new`]'s checks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "AngleRangeFields")]
pub struct AngleRange {
    /// First angle, degrees.
    pub min: f64,
    /// Last angle, degrees (included when on the grid).
    pub max: f64,
    /// Step, degrees.
    pub step: f64,
}

#[derive(Deserialize)]
struct AngleRangeFields {
    min: f64,
    max: f64,
    step: f64,
}

impl TryFrom<AngleRangeFields> for AngleRange {
    type Error = Error;
    fn try_from(f: AngleRangeFields) -> Result<Self> {
        AngleRange::new(f.min, f.max, f.step)
    }
}

impl AngleRange {
    /// The most values a range may hold.
    pub const MAX_VALUES: usize = 10_000;

    /// A validated range: finite, `min <= max`, `step > 0`, at most [`Self::MAX_VALUES`] values.
    pub fn new(min: f64, max: f64, step: f64) -> Result<Self> {
        if !(min.is_finite() && max.is_finite() && step.is_finite()) {
            return Err(Error::non_finite("angle range"));
        }
        if min > max || step <= 0.0 {
            return Err(Error::param(
                "angle range",
                format!("needs min <= max and step > 0, got {min}..{max} step {step}"),
            ));
        }
        if (max - min) / step >= Self::MAX_VALUES as f64 {
            return Err(Error::param(
                "angle range",
                format!(
                    "{min}..{max} at step {step} is over {} angles: use a larger step",
                    Self::MAX_VALUES
                ),
            ));
        }
        Ok(AngleRange { min, max, step })
    }

    /// A single angle.
    pub fn fixed(v: f64) -> Self {
        AngleRange {
            min: v,
            max: v,
            step: 1.0,
        }
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        ((self.max - self.min) / self.step + 1e-9).floor() as usize + 1
    }

    /// Whether the range is empty (never, for a validated range).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The values, computed as `min + k · step` (no accumulated rounding).
    pub fn values(&self) -> impl Iterator<Item = f64> + '_ {
        (0..self.len()).map(move |k| self.min + k as f64 * self.step)
    }
}

/// The grid of poses to synthesize.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseGrid {
    /// Yaw angles, degrees.
    pub yaw: AngleRange,
    /// Pitch angles, degrees.
    pub pitch: AngleRange,
    /// Roll angles, degrees.
    pub roll: AngleRange,
}

impl PoseGrid {
    /// The paper's grid: yaw and pitch within ±40° at 2°, no roll.
    pub fn paper() -> Self {
        PoseGrid {
            yaw: AngleRange {
                min: -40.0,
                max: 40.0,
                step: 2.0,
            },
            pitch: AngleRange {
                min: -40.0,
                max: 40.0,
                step: 2.0,
            },
            roll: AngleRange::fixed(0.0),
        }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.yaw.len() * self.pitch.len() * self.roll.len()
    }

    /// Whether the grid is empty (never, for validated ranges).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every pose, yaw outermost, roll innermost.
    pub fn poses(&self) -> impl Iterator<Item = EulerAngles> + '_ {
        self.yaw.values().flat_map(move |y| {
            self.pitch.values().flat_map(move |p| {
                self.roll.values().map(move |r| EulerAngles {
                    pitch: p,
                    yaw: y,
                    roll: r,
                })
            })
        })
    }
}

/// One synthesized view: the pose, the projected shape in image coordinates (unit scale, no
/// translation: `u = (R X)_x`, `v = -(R X)_y`) and which points HPR finds visible.
#[derive(Debug, Clone)]
pub struct SyntheticView {
    /// The view's pose, degrees (Pose_Para).
    pub angles: EulerAngles,
    /// The view's rotation.
    pub rotation: Rotation3<f64>,
    /// Projected points, image frame (y down).
    pub projected: Vec<Vector2<f64>>,
    /// Per point, whether HPR finds it visible.
    pub visible: Vec<bool>,
}

impl SyntheticView {
    /// The projection as a [`Shape2`] with hidden points marked missing.
    pub fn visible_shape(&self) -> Result<Shape2> {
        Shape2::new(self.projected.clone(), self.visible.clone())
    }
}

/// The image of a rotated model-frame point at unit scale and no translation:
/// `u = (R X)_x`, `v = -(R X)_y`.
pub fn image_of(rotated: &Vector3<f64>) -> Vector2<f64> {
    Vector2::new(rotated.x, -rotated.y)
}

/// Synthesizes views of a frontal 3D shape over a grid, lazily (memory stays flat in the grid
/// size). `hpr` must have been built on the same shape. A clone has its own work space, for
/// another thread.
#[derive(Clone)]
pub struct ViewSynthesizer<'a> {
    shape: &'a [Vector3<f64>],
    hpr: &'a PaperHpr,
    scratch: HprScratch,
    rotated: Vec<Vector3<f64>>,
}

impl<'a> ViewSynthesizer<'a> {
    /// Fails when the HPR operator is over another number of points.
    pub fn new(shape: &'a [Vector3<f64>], hpr: &'a PaperHpr) -> Result<Self> {
        if hpr.triangulation().n_points() != shape.len() {
            return Err(Error::PointCount {
                what: "HPR triangulation".into(),
                expected: shape.len(),
                got: hpr.triangulation().n_points(),
            });
        }
        Ok(ViewSynthesizer {
            shape,
            hpr,
            scratch: HprScratch::default(),
            rotated: Vec::with_capacity(shape.len()),
        })
    }

    /// The view at one pose.
    pub fn view(&mut self, angles: EulerAngles) -> Result<SyntheticView> {
        let rotation = angles.to_rotation();
        self.rotated.clear();
        self.rotated.extend(self.shape.iter().map(|p| rotation * p));
        let mut visible = vec![false; self.shape.len()];
        self.hpr
            .visibility_into(&self.rotated, &mut self.scratch, &mut visible)?;
        let projected = self.rotated.iter().map(image_of).collect();
        Ok(SyntheticView {
            angles,
            rotation,
            projected,
            visible,
        })
    }

    /// Every view of the grid, lazily.
    pub fn views<'g>(
        &'g mut self,
        grid: &'g PoseGrid,
    ) -> impl Iterator<Item = Result<SyntheticView>> + 'g {
        grid.poses().map(move |a| self.view(a))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_ranges_go_through_the_checks() {
        let ok: AngleRange = serde_json::from_str(r#"{"min": -4, "max": 4, "step": 2}"#).unwrap();
        assert_eq!(ok.values().collect::<Vec<_>>(), [-4.0, -2.0, 0.0, 2.0, 4.0]);
        for bad in [
            r#"{"min": 0, "max": 10, "step": 0}"#,
            r#"{"min": 0, "max": 10, "step": -1}"#,
            r#"{"min": 10, "max": 0, "step": 1}"#,
            r#"{"min": -90, "max": 90, "step": 1e-6}"#,
        ] {
            let e = serde_json::from_str::<AngleRange>(bad)
                .unwrap_err()
                .to_string();
            assert!(e.contains("angle range"), "{bad}: {e}");
        }
    }
    use approx::assert_relative_eq;

    #[test]
    fn ranges_include_both_ends() {
        let r = AngleRange::new(-40.0, 40.0, 2.0).unwrap();
        assert_eq!(r.len(), 41);
        let v: Vec<_> = r.values().collect();
        assert_eq!((v[0], v[20], v[40]), (-40.0, 0.0, 40.0));
        assert_eq!(PoseGrid::paper().len(), 41 * 41);
        assert!(AngleRange::new(1.0, 0.0, 1.0).is_err());
        assert!(AngleRange::new(0.0, 1.0, 0.0).is_err());
        assert!(AngleRange::new(0.0, f64::NAN, 1.0).is_err());
    }

    #[test]
    fn a_view_is_the_projection_at_its_pose() {
        let shape = vec![
            Vector3::new(-30.0, 30.0, 0.0),
            Vector3::new(30.0, 30.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-25.0, -30.0, 5.0),
            Vector3::new(25.0, -30.0, 5.0),
        ];
        let hpr = PaperHpr::from_frontal(&shape).unwrap();
        let mut synth = ViewSynthesizer::new(&shape, &hpr).unwrap();
        let v = synth
            .view(EulerAngles::new(30.0, 0.0, 0.0).unwrap())
            .unwrap();
        // Nose (0, 0, 40) at yaw 30: x = -40 sin 30 = -20, image v = 0.
        assert_relative_eq!(v.projected[2], Vector2::new(-20.0, 0.0), epsilon = 1e-12);
        // Eye (-30, 30, 0): y up 30 -> image v = -30.
        assert_relative_eq!(v.projected[0].y, -30.0, epsilon = 1e-12);
        assert!(v.visible.iter().all(|&b| b));
    }
}
