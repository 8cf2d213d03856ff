//! 2D and 3D landmark shapes with per-point presence.
//!
//! [`Shape2`] holds image pixels (origin top-left, x right, y down) as clients send them, and as
//! the synthetic projections are written. [`Shape3`] holds model-frame points (x towards the
//! subject's left, y up, z towards the camera, mm).

use nalgebra::{Rotation3, Unit, Vector2, Vector3};

use super::scheme::Scheme;
use crate::error::{Error, Result};
use crate::geometry::procrustes::{centre3, centroid_size3};

/// A 2D shape in image pixels; a missing point has `present[i] == false` and its coordinates
/// are ignored (stored as zero).
#[derive(Debug, Clone, PartialEq)]
pub struct Shape2 {
    points: Vec<Vector2<f64>>,
    present: Vec<bool>,
}

/// A 3D shape in the model frame, with per-point presence.
#[derive(Debug, Clone, PartialEq)]
pub struct Shape3 {
    points: Vec<Vector3<f64>>,
    present: Vec<bool>,
}

macro_rules! shape_common {
    ($ty:ident, $vec:ty, $dim:literal) => {
        impl $ty {
            /// A shape from points and a presence mask of the same length. Present points must
            /// be finite; missing points are zeroed.
            pub fn new(mut points: Vec<$vec>, present: Vec<bool>) -> Result<Self> {
                if points.len() != present.len() {
                    return Err(Error::PointCount {
                        what: "presence mask".into(),
                        expected: points.len(),
                        got: present.len(),
                    });
                }
                for (i, (p, &on)) in points.iter_mut().zip(&present).enumerate() {
                    if !on {
                        *p = <$vec>::zeros();
                    } else if !p.iter().all(|v| v.is_finite()) {
                        return Err(Error::non_finite(format!("point {i}")));
                    }
                }
                Ok($ty { points, present })
            }

            /// A shape whose points are all present.
            pub fn full(points: Vec<$vec>) -> Result<Self> {
                let n = points.len();
                Self::new(points, vec![true; n])
            }

            /// A shape from optional coordinates (`None` = missing).
            pub fn from_options(points: &[Option<[f64; $dim]>]) -> Result<Self> {
                let present = points.iter().map(Option::is_some).collect();
                let pts = points
                    .iter()
                    .map(|p| p.map(|a| <$vec>::from(a)).unwrap_or_else(<$vec>::zeros))
                    .collect();
                Self::new(pts, present)
            }

            /// Number of points, present or not.
            pub fn len(&self) -> usize {
                self.points.len()
            }

            /// Whether the shape has no points at all.
            pub fn is_empty(&self) -> bool {
                self.points.is_empty()
            }

            /// Number of present points.
            pub fn n_present(&self) -> usize {
                self.present.iter().filter(|&&p| p).count()
            }

            /// The point `i` if present.
            pub fn get(&self, i: usize) -> Option<&$vec> {
                self.present
                    .get(i)
                    .copied()
                    .unwrap_or(false)
                    .then(|| &self.points[i])
            }

            /// All coordinates (missing points are zero).
            pub fn points(&self) -> &[$vec] {
                &self.points
            }

            /// The presence mask.
            pub fn present(&self) -> &[bool] {
                &self.present
            }

            /// Centroid of the present points.
            pub fn centroid(&self) -> Result<$vec> {
                let n = self.n_present();
                if n == 0 {
                    return Err(Error::too_few("centroid", 1, 0));
                }
                let sum: $vec = self.iter_present().map(|(_, p)| *p).sum();
                Ok(sum / n as f64)
            }

            /// `(index, point)` of the present points.
            pub fn iter_present(&self) -> impl Iterator<Item = (usize, &$vec)> {
                self.points
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| self.present[*i])
            }

            /// The same shape with the given points marked missing as well.
            pub fn with_missing(&self, missing: impl IntoIterator<Item = usize>) -> Self {
                let mut s = self.clone();
                for i in missing {
                    if i < s.len() {
                        s.present[i] = false;
                        s.points[i] = <$vec>::zeros();
                    }
                }
                s
            }

            /// The shape restricted to `indices` (in that order).
            pub fn select(&self, indices: &[usize]) -> Result<Self> {
                let mut pts = Vec::with_capacity(indices.len());
                let mut present = Vec::with_capacity(indices.len());
                for &i in indices {
                    if i >= self.len() {
                        return Err(Error::param(
                            "indices",
                            format!("point {i} of {}", self.len()),
                        ));
                    }
                    pts.push(self.points[i]);
                    present.push(self.present[i]);
                }
                Ok($ty {
                    points: pts,
                    present,
                })
            }

            /// The mean of the present points among `indices`, if any is present.
            pub fn anchor(&self, indices: &[usize]) -> Option<$vec> {
                let mut sum = <$vec>::zeros();
                let mut n = 0;
                for &i in indices {
                    if let Some(p) = self.get(i) {
                        sum += p;
                        n += 1;
                    }
                }
                (n > 0).then(|| sum / n as f64)
            }

            /// The five-point shape (scheme `five`) of this shape under `scheme`: each anchor is
            /// the mean of its present points; an anchor with none present is missing. Fails
            /// for a scheme that names no nose tip and mouth corners (`dlib5`).
            pub fn to_five(&self, scheme: &Scheme) -> Result<Self> {
                if !scheme.anchors.has_nose_and_mouth() {
                    return Err(Error::param(
                        "scheme",
                        format!(
                            "{} names no nose tip and mouth corners, which the five anchor \
                             points (and the geometric method) need; use fit, fit-shape or \
                             regression",
                            scheme.name
                        ),
                    ));
                }
                if scheme.len() != self.len() {
                    return Err(Error::PointCount {
                        what: format!("shape for scheme {}", scheme.name),
                        expected: scheme.len(),
                        got: self.len(),
                    });
                }
                let pts: Vec<Option<$vec>> = scheme
                    .anchors
                    .as_array()
                    .iter()
                    .map(|a| self.anchor(a))
                    .collect();
                let present = pts.iter().map(Option::is_some).collect();
                Self::new(
                    pts.into_iter()
                        .map(|p| p.unwrap_or_else(<$vec>::zeros))
                        .collect(),
                    present,
                )
            }
        }
    };
}

shape_common!(Shape2, Vector2<f64>, 2);
shape_common!(Shape3, Vector3<f64>, 3);

/// A centred, energy-normalized 2D shape as a `2n` vector `(x0, y0, x1, y1, ...)` (paper
/// eq. 17): the centroid of the present points is subtracted, missing points are zero, and the
/// vector has unit Euclidean norm. Also returns the norm before scaling (the shape's size).
pub fn normalized_vector(shape: &Shape2) -> Result<(Vec<f64>, f64)> {
    if shape.n_present() < 2 {
        return Err(Error::too_few("normalized shape", 2, shape.n_present()));
    }
    let c = shape.centroid()?;
    let mut v = vec![0.0; 2 * shape.len()];
    for (i, p) in shape.iter_present() {
        v[2 * i] = p.x - c.x;
        v[2 * i + 1] = p.y - c.y;
    }
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm.is_nan() || norm <= 1e-12 * (1.0 + c.norm()) {
        return Err(Error::Degenerate(
            "all present points are at the same place".into(),
        ));
    }
    v.iter_mut().for_each(|x| *x /= norm);
    Ok((v, norm))
}

impl Shape3 {
    /// Every point rotated by `r` (missing points stay missing).
    pub fn rotated(&self, r: &Rotation3<f64>) -> Shape3 {
        let points = self
            .points
            .iter()
            .zip(&self.present)
            .map(|(p, &on)| if on { r * p } else { Vector3::zeros() })
            .collect();
        Shape3 {
            points,
            present: self.present.clone(),
        }
    }

    /// The shape centred on its present points.
    pub fn centred(&self) -> Result<Shape3> {
        let c = self.centroid()?;
        Shape3::new(
            self.points.iter().map(|p| p - c).collect(),
            self.present.clone(),
        )
    }

    /// The shape rotated and centred so that the eye line (image-left eye centre to image-right
    /// eye centre) lies along +x, by the smallest rotation that does so; the facing direction is
    /// otherwise kept, and the nose tip must then point to the camera (+z relative to the
    /// centroid). Needs every point present.
    pub fn frontalized(&self, scheme: &Scheme) -> Result<Shape3> {
        if self.n_present() != self.len() {
            return Err(Error::too_few(
                "frontalization (all points)",
                self.len(),
                self.n_present(),
            ));
        }
        let c = self.centred()?;
        let a = &scheme.anchors;
        let (el, er, nose) = match (
            c.anchor(&a.eye_left),
            c.anchor(&a.eye_right),
            c.anchor(&a.nose_tip),
        ) {
            (Some(l), Some(r), Some(n)) => (l, r, n),
            _ => return Err(Error::too_few("frontalization anchors", 3, 0)),
        };
        let eye = Unit::try_new(er - el, 1e-9)
            .ok_or_else(|| Error::Degenerate("the two eye centres coincide".into()))?;
        let r =
            Rotation3::rotation_between(&eye.into_inner(), &Vector3::x()).unwrap_or_else(|| {
                Rotation3::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI)
            });
        let out = c.rotated(&r);
        if (r * nose).z <= 0.0 {
            return Err(Error::Degenerate(
                "the nose tip does not point to the camera: the shape is mirrored or faces away"
                    .into(),
            ));
        }
        Ok(out)
    }

    /// Root of the summed squared distances of the present points to their centroid.
    pub fn centroid_size(&self) -> Result<f64> {
        let c = self.centroid()?;
        let pts: Vec<_> = self.iter_present().map(|(_, p)| p - c).collect();
        Ok(centroid_size3(&pts))
    }

    /// Centred copy of the points, for callers that need plain vectors (all present).
    pub fn centred_points(&self) -> Vec<Vector3<f64>> {
        centre3(&self.points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;
    use crate::shape::scheme::{five, ibug68};
    use approx::assert_relative_eq;

    #[test]
    fn missing_points_are_zeroed_and_skipped() {
        let s = Shape2::from_options(&[Some([1.0, 2.0]), None, Some([3.0, 4.0])]).unwrap();
        assert_eq!(s.n_present(), 2);
        assert_eq!(s.get(1), None);
        assert_relative_eq!(s.centroid().unwrap(), Vector2::new(2.0, 3.0));
        assert!(Shape2::from_options(&[Some([f64::NAN, 0.0])]).is_err());
        assert!(Shape2::new(vec![Vector2::zeros()], vec![true, false]).is_err());
    }

    #[test]
    fn normalized_vector_is_centred_unit_and_zero_where_missing() {
        let s = Shape2::from_options(&[Some([0.0, 0.0]), Some([4.0, 0.0]), None, Some([2.0, 6.0])])
            .unwrap();
        let (v, size) = normalized_vector(&s).unwrap();
        assert_relative_eq!(v.iter().map(|x| x * x).sum::<f64>(), 1.0, epsilon = 1e-12);
        assert_eq!((v[4], v[5]), (0.0, 0.0));
        assert_relative_eq!(v[0] + v[2] + v[6], 0.0, epsilon = 1e-12);
        // Centred coordinates: (-2,-2), (2,-2), (0,4): size sqrt(8+8+16).
        assert_relative_eq!(size, 32f64.sqrt(), epsilon = 1e-12);
        let same = Shape2::full(vec![Vector2::new(1.0, 1.0); 3]).unwrap();
        assert!(matches!(
            normalized_vector(&same),
            Err(Error::Degenerate(_))
        ));
        let one = Shape2::from_options(&[Some([1.0, 1.0]), None]).unwrap();
        assert!(matches!(
            normalized_vector(&one),
            Err(Error::TooFewPoints { .. })
        ));
    }

    #[test]
    fn five_points_are_the_anchor_means() {
        let scheme = ibug68();
        let pts: Vec<_> = (0..68)
            .map(|i| Vector2::new(i as f64, 2.0 * i as f64))
            .collect();
        let s = Shape2::full(pts).unwrap().with_missing([36]);
        let f = s.to_five(&scheme).unwrap();
        assert_eq!(f.len(), five().len());
        assert_relative_eq!(f.get(0).unwrap().x, (37 + 38 + 39 + 40 + 41) as f64 / 5.0);
        assert_relative_eq!(f.get(1).unwrap().x, (42..48).sum::<usize>() as f64 / 6.0);
        assert_relative_eq!(f.get(2).unwrap().x, 30.0);
        assert_relative_eq!(f.get(4).unwrap().x, 54.0);
        let short = Shape2::full(vec![Vector2::zeros(); 10]).unwrap();
        assert!(short.to_five(&scheme).is_err());
    }

    #[test]
    fn frontalization_undoes_roll_and_yaw() {
        let scheme = five();
        let face = vec![
            Vector3::new(-32.0, 35.0, 0.0),
            Vector3::new(32.0, 35.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-25.0, -30.0, 5.0),
            Vector3::new(25.0, -30.0, 5.0),
        ];
        let reference = Shape3::full(face.clone()).unwrap().centred().unwrap();
        // A pure yaw or a pure roll is undone exactly.
        for (yaw, roll) in [(25.0, 0.0), (0.0, -15.0)] {
            let r = EulerAngles::new(yaw, 0.0, roll).unwrap().to_rotation();
            let f = Shape3::full(face.clone())
                .unwrap()
                .rotated(&r)
                .frontalized(&scheme)
                .unwrap();
            for (a, b) in f.points().iter().zip(reference.points()) {
                assert_relative_eq!(a, b, epsilon = 1e-9);
            }
        }
        // Any turn: the eye line ends on +x and the nose in front.
        let r = EulerAngles::new(20.0, 10.0, 15.0).unwrap().to_rotation();
        let f = Shape3::full(face.clone())
            .unwrap()
            .rotated(&r)
            .frontalized(&scheme)
            .unwrap();
        let eye = f.get(1).unwrap() - f.get(0).unwrap();
        assert_relative_eq!(eye.normalize(), Vector3::x(), epsilon = 1e-12);
        assert!(f.get(2).unwrap().z > 0.0);
        let mirrored = Shape3::full(
            reference
                .points()
                .iter()
                .map(|p| Vector3::new(p.x, p.y, -p.z))
                .collect(),
        )
        .unwrap();
        assert!(mirrored.frontalized(&scheme).is_err());
    }
}
