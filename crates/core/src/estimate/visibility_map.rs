//! HPR visibility of a shape precomputed over view directions, so that estimators can ask
//! "which points does the camera see at this rotation?" in O(1) instead of running HPR.
//!
//! Under orthographic projection visibility depends only on the viewing direction in the model
//! frame, `d = Rᵀ e_z` (the third row of `R`), not on the rotation about it. The map is indexed
//! by the yaw and pitch of the roll-free rotation with the same `d`:
//! `pitch = -asin(d_y)`, `yaw = atan2(d_x, d_z)`.

use nalgebra::{Rotation3, Vector3};

use crate::error::{Error, Result};
use crate::geometry::EulerAngles;
use crate::hpr::{HprScratch, PaperHpr};
use crate::parallel;
use crate::synth::AngleRange;

/// Visibility bitmaps over a yaw x pitch grid (roll 0).
#[derive(Debug, Clone)]
pub struct VisibilityMap {
    yaw: AngleRange,
    pitch: AngleRange,
    n_points: usize,
    /// `bits[(iy * n_pitch + ip) * n_points + i]`.
    bits: Vec<bool>,
}

impl VisibilityMap {
    /// Runs HPR over the grid for `shape` (frontal, model frame), on the machine's cores.
    pub fn build(
        shape: &[Vector3<f64>],
        hpr: &PaperHpr,
        yaw: AngleRange,
        pitch: AngleRange,
    ) -> Result<Self> {
        let n = shape.len();
        if hpr.triangulation().n_points() != n {
            return Err(Error::PointCount {
                what: "HPR triangulation".into(),
                expected: n,
                got: hpr.triangulation().n_points(),
            });
        }
        let cells: Vec<(f64, f64)> = yaw
            .values()
            .flat_map(|y| pitch.values().map(move |p| (y, p)))
            .collect();
        let init = || (HprScratch::default(), vec![Vector3::zeros(); n]);
        let one = |(scratch, rotated): &mut (HprScratch, Vec<Vector3<f64>>),
                   &(y, p): &(f64, f64)| {
            let r = EulerAngles::new(y, p, 0.0)?.to_rotation();
            for (dst, x) in rotated.iter_mut().zip(shape) {
                *dst = r * x;
            }
            let mut out = vec![false; n];
            hpr.visibility_into(rotated, scratch, &mut out)?;
            Ok::<_, crate::Error>(out)
        };
        let mut bits = Vec::with_capacity(cells.len() * n);
        for cell in parallel::map_with(&cells, init, one) {
            bits.extend_from_slice(&cell?);
        }
        Ok(VisibilityMap {
            yaw,
            pitch,
            n_points: n,
            bits,
        })
    }

    /// The default grid: yaw and pitch within ±90° in 3° steps.
    pub fn build_default(shape: &[Vector3<f64>], hpr: &PaperHpr) -> Result<Self> {
        let g = AngleRange {
            min: -90.0,
            max: 90.0,
            step: 3.0,
        };
        Self::build(shape, hpr, g, g)
    }

    /// A map from stored bitmaps (`bits` as [`VisibilityMap::bits`] gives them), checked for
    /// size only: whether they are HPR's for a shape is for the caller to know.
    pub fn from_bits(
        yaw: AngleRange,
        pitch: AngleRange,
        n_points: usize,
        bits: Vec<bool>,
    ) -> Result<Self> {
        let cells = yaw.len() * pitch.len();
        if bits.len() != cells * n_points {
            return Err(Error::PointCount {
                what: format!("visibility map of {cells} directions x {n_points} points"),
                expected: cells * n_points,
                got: bits.len(),
            });
        }
        Ok(VisibilityMap {
            yaw,
            pitch,
            n_points,
            bits,
        })
    }

    /// The yaw and pitch of the grid's directions.
    pub fn grid(&self) -> (AngleRange, AngleRange) {
        (self.yaw, self.pitch)
    }

    /// Every direction's bitmap, yaw outermost then pitch, `n_points` flags each.
    pub fn bits(&self) -> &[bool] {
        &self.bits
    }

    /// Number of points per bitmap.
    pub fn n_points(&self) -> usize {
        self.n_points
    }

    /// The visibility at rotation `r` (nearest grid direction; directions beyond the grid use
    /// its edge).
    pub fn lookup(&self, r: &Rotation3<f64>) -> &[bool] {
        let m = r.matrix();
        let (dx, dy, dz) = (m[(2, 0)], m[(2, 1)], m[(2, 2)]);
        let pitch = -dy.clamp(-1.0, 1.0).asin().to_degrees();
        let yaw = dx.atan2(dz).to_degrees();
        self.lookup_yaw_pitch(yaw, pitch)
    }

    /// The visibility at the roll-free pose (yaw, pitch) in degrees (any roll sees the same).
    pub fn lookup_yaw_pitch(&self, yaw: f64, pitch: f64) -> &[bool] {
        let index = |v: f64, r: &AngleRange| {
            (((v - r.min) / r.step).round().max(0.0) as usize).min(r.len() - 1)
        };
        let cell = index(yaw, &self.yaw) * self.pitch.len() + index(pitch, &self.pitch);
        &self.bits[cell * self.n_points..(cell + 1) * self.n_points]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_matches_hpr_and_ignores_roll() {
        // A pyramid with a point tucked behind the apex's left face.
        let shape = vec![
            Vector3::new(-10.0, -10.0, 0.0),
            Vector3::new(10.0, -10.0, 0.0),
            Vector3::new(10.0, 10.0, 0.0),
            Vector3::new(-10.0, 10.0, 0.0),
            Vector3::new(0.0, 0.0, 10.0),
            Vector3::new(-4.0, 0.0, 1.0),
        ];
        let hpr = PaperHpr::from_frontal(&shape).unwrap();
        let map = VisibilityMap::build_default(&shape, &hpr).unwrap();
        for (yaw, pitch) in [(0.0, 0.0), (60.0, 0.0), (-75.0, 12.0), (30.0, -45.0)] {
            let r0 = EulerAngles::new(yaw, pitch, 0.0).unwrap().to_rotation();
            let rotated: Vec<_> = shape.iter().map(|p| r0 * p).collect();
            let direct = hpr.visibility(&rotated).unwrap();
            assert_eq!(map.lookup(&r0), &direct[..], "yaw {yaw} pitch {pitch}");
            // A roll about the viewing axis (applied after, in the camera frame) changes nothing.
            let spun = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.7) * r0;
            assert_eq!(map.lookup(&spun), &direct[..]);
        }
    }
}
