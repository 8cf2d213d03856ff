//! The JSON records of one face, shared by `facepose estimate` (JSON Lines) and the service's
//! HTTP API: the landmark list a client sends and the pose it gets back. Parsing and formatting
//! only: no I/O, no async.
//!
//! Landmarks are image pixels (origin top-left, x right, y down), `[x, y]` per point or `null`
//! for a point the client could not find. Angles are degrees (`Pose_Para` convention, see
//! [`crate::geometry::convention`]) and `rotation` is `R` as row-major nested arrays.

use std::fmt;

use serde::de::{self, DeserializeSeed, IgnoredAny, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};

use crate::error::{Error, Result};
use crate::estimate::{Estimate, Method};
use crate::geometry::rotation_rows;
use crate::shape::Shape2;

/// Landmarks as sent: `[[x, y] | null, ...]`. Deserializing names the first bad landmark by
/// its index ("landmark 3 ...") and says what is expected; the point count is checked against
/// the scheme by the estimator.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Landmarks(pub Vec<Option<[f64; 2]>>);

/// The largest coordinate accepted, pixels: beyond it a value is not a pixel position and the
/// arithmetic of the estimators would overflow.
pub const MAX_COORDINATE: f64 = 1e9;

/// The shape of optional points (`None` = missing), after checking that every coordinate is
/// finite and within ±[`MAX_COORDINATE`]; errors name the landmark.
pub fn shape_from_points(points: &[Option<[f64; 2]>]) -> Result<Shape2> {
    for (i, p) in points.iter().enumerate() {
        for (c, v) in ["x", "y"].iter().zip(p.iter().flatten()) {
            if !v.is_finite() {
                return Err(Error::NonFinite {
                    what: format!("landmark {i} {c}"),
                });
            }
            if v.abs() > MAX_COORDINATE {
                return Err(Error::InvalidParameter {
                    name: "landmarks".into(),
                    reason: format!(
                        "landmark {i} {c} = {v:e} is out of range: pixel coordinates must be within ±{MAX_COORDINATE:e}"
                    ),
                });
            }
        }
    }
    Shape2::from_options(points)
}

impl Landmarks {
    /// The shape, with missing points for `null` (see [`shape_from_points`]).
    pub fn to_shape(&self) -> Result<Shape2> {
        shape_from_points(&self.0)
    }

    /// Number of landmarks, present or not.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether there are no landmarks at all.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl Serialize for Landmarks {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        self.0.serialize(s)
    }
}

impl<'de> Deserialize<'de> for Landmarks {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_seq(LandmarksVisitor)
    }
}

struct LandmarksVisitor;

impl<'de> Visitor<'de> for LandmarksVisitor {
    type Value = Landmarks;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("an array of landmarks, each [x, y] (pixels) or null")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Landmarks, A::Error> {
        let mut points = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(1024));
        while let Some(p) = seq.next_element_seed(PointSeed(points.len()))? {
            points.push(p);
        }
        Ok(Landmarks(points))
    }
}

/// Landmark `.0`: `[x, y]` or `null`.
struct PointSeed(usize);

impl<'de> DeserializeSeed<'de> for PointSeed {
    type Value = Option<[f64; 2]>;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> std::result::Result<Self::Value, D::Error> {
        d.deserialize_any(PointVisitor(self.0))
    }
}

struct PointVisitor(usize);

impl<'de> Visitor<'de> for PointVisitor {
    type Value = Option<[f64; 2]>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "landmark {} as [x, y] numbers or null", self.0)
    }

    fn visit_unit<E: de::Error>(self) -> std::result::Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_none<E: de::Error>(self) -> std::result::Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_seq<A: SeqAccess<'de>>(
        self,
        mut seq: A,
    ) -> std::result::Result<Self::Value, A::Error> {
        let i = self.0;
        let short = || {
            de::Error::custom(format_args!(
                "landmark {i} must be [x, y] numbers or null: it has fewer than 2 values"
            ))
        };
        let x = seq
            .next_element_seed(CoordSeed(i, "x"))?
            .ok_or_else(short)?;
        let y = seq
            .next_element_seed(CoordSeed(i, "y"))?
            .ok_or_else(short)?;
        if seq.next_element::<IgnoredAny>()?.is_some() {
            return Err(de::Error::custom(format_args!(
                "landmark {i} must be [x, y] numbers or null: it has more than 2 values"
            )));
        }
        Ok(Some([x, y]))
    }
}

/// Coordinate `.1` of landmark `.0`: a JSON number.
struct CoordSeed(usize, &'static str);

impl<'de> DeserializeSeed<'de> for CoordSeed {
    type Value = f64;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> std::result::Result<f64, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for CoordSeed {
    type Value = f64;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "landmark {} {} as a number", self.0, self.1)
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<f64, E> {
        Ok(v)
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<f64, E> {
        Ok(v as f64)
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<f64, E> {
        Ok(v as f64)
    }

    fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<f64, E> {
        let (i, c) = (self.0, self.1);
        let t = v.trim().trim_start_matches(['+', '-']).to_ascii_lowercase();
        if t == "nan" || t.starts_with("inf") {
            Err(E::custom(format_args!(
                "landmark {i} {c} is {v:?}: not a finite number (send null for a missing point)"
            )))
        } else {
            Err(E::custom(format_args!(
                "landmark {i} {c} is the string {v:?}: send a JSON number"
            )))
        }
    }
}

/// One pose as JSON: what `facepose estimate` prints per face and the core of every pose the
/// service returns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PoseRecord {
    /// Degrees; > 0 the nose turns towards image-left.
    pub yaw: f64,
    /// Degrees; > 0 chin up.
    pub pitch: f64,
    /// Degrees; > 0 the face turns clockwise on screen.
    pub roll: f64,
    /// `R = Rx(pitch) · Ry(yaw) · Rz(roll)`, row-major: `rotation[i][j]` is row `i`, column `j`.
    pub rotation: [[f64; 3]; 3],
    /// Per input landmark: visible at the estimated pose.
    pub visible: Vec<bool>,
    /// RMS reprojection error over the present landmarks divided by the projected inter-ocular
    /// distance (unitless; below ~0.05 for a good fit).
    pub residual: f64,
    /// The method that produced the estimate (never `auto`).
    #[schema(value_type = String, example = "fit")]
    pub method: Method,
    /// With camera intrinsics only: the model origin in the camera frame, mm (x right, y up,
    /// z towards the viewer; the face is at negative z).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<[f64; 3]>,
}

impl PoseRecord {
    /// Whether every number is finite (JSON has no NaN or infinity).
    pub fn is_finite(&self) -> bool {
        [self.yaw, self.pitch, self.roll, self.residual]
            .iter()
            .chain(self.rotation.iter().flatten())
            .chain(self.translation.iter().flatten())
            .all(|v| v.is_finite())
    }
}

impl From<&Estimate> for PoseRecord {
    fn from(e: &Estimate) -> Self {
        PoseRecord {
            yaw: e.angles.yaw,
            pitch: e.angles.pitch,
            roll: e.angles.roll,
            rotation: rotation_rows(&e.rotation),
            visible: e.visible.clone(),
            residual: e.residual,
            method: e.method,
            translation: e.translation.map(|t| [t.x, t.y, t.z]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> std::result::Result<Landmarks, String> {
        serde_json::from_str(s).map_err(|e| e.to_string())
    }

    #[test]
    fn points_and_nulls() {
        let l = parse("[[1, 2.5], null, [-0.0, 1e3]]").unwrap();
        assert_eq!(l.0, vec![Some([1.0, 2.5]), None, Some([-0.0, 1000.0])]);
        let s = l.to_shape().unwrap();
        assert_eq!(s.len(), 3);
        assert_eq!(s.n_present(), 2);
    }

    #[test]
    fn messages_name_the_landmark() {
        let cases = [
            (
                "[[1, 2], [3]]",
                "landmark 1 must be [x, y] numbers or null: it has fewer",
            ),
            (
                "[[1, 2, 3]]",
                "landmark 0 must be [x, y] numbers or null: it has more",
            ),
            (
                "[[1, 2], 5]",
                "expected landmark 1 as [x, y] numbers or null",
            ),
            ("[[1, \"a\"]]", "landmark 0 y is the string \"a\""),
            (
                "[[\"NaN\", 1]]",
                "landmark 0 x is \"NaN\": not a finite number",
            ),
            ("[[1, \"-Infinity\"]]", "not a finite number"),
            ("[[1, [2]]]", "expected landmark 0 y as a number"),
            ("{\"a\": 1}", "an array of landmarks"),
            ("[[1, 1e400]]", "number out of range"),
        ];
        for (input, want) in cases {
            let err = parse(input).unwrap_err();
            assert!(err.contains(want), "{input}: {err}");
        }
    }

    #[test]
    fn coordinates_must_be_finite_pixels() {
        let err = shape_from_points(&[Some([1.0, 2.0]), Some([3.0, f64::NAN])]).unwrap_err();
        assert!(err.to_string().contains("landmark 1 y"), "{err}");
        let err = shape_from_points(&[None, Some([1e308, 2.0])]).unwrap_err();
        assert!(
            err.to_string()
                .contains("landmark 1 x = 1e308 is out of range"),
            "{err}"
        );
        assert!(shape_from_points(&[Some([-1e9, 1e9]), None]).is_ok());
    }

    #[test]
    fn works_from_a_json_value_too() {
        let v = serde_json::json!([[1, 2], null]);
        let l = Landmarks::deserialize(&v).unwrap();
        assert_eq!(l.len(), 2);
        let v = serde_json::json!([[1, true]]);
        let err = Landmarks::deserialize(&v).unwrap_err().to_string();
        assert!(err.contains("landmark 0 y"), "{err}");
    }
}
