//! The paper's hidden-point removal (Heo & Savvides 2011, §3.3), for a camera on the +z axis at
//! infinity (weak perspective):
//!
//! 1. triangulate the shape (Delaunay of the frontal shape, [`Triangulation`]);
//! 2. compute each triangle's normal `(S2 - S1) × (S3 - S1)` in the rotated shape;
//! 3. a triangle whose normal makes 90° or more with the viewing direction faces backwards; a
//!    point all of whose triangles face backwards is hidden;
//! 4. a remaining point that projects inside a triangle it does not belong to, and lies behind
//!    that triangle's centre of gravity as seen from the camera, is occluded by it.

use nalgebra::Vector3;

use super::triangulation::Triangulation;
use crate::error::{Error, Result};

/// How step 4 decides that a point is behind a triangle it projects into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthTest {
    /// The paper's rule: compare with the depth of the triangle's centre of gravity.
    Centroid,
    /// Compare with the triangle's own depth at the point (its plane, interpolated).
    Plane,
}

/// A reusable HPR operator for one shape's triangulation.
#[derive(Debug, Clone)]
pub struct PaperHpr {
    tri: Triangulation,
    depth_test: DepthTest,
    /// Tolerance of step 4, relative to the shape's size.
    rel_eps: f64,
}

/// Per-call work space of [`PaperHpr::visibility_into`], to keep the hot path free of
/// allocation.
#[derive(Debug, Default, Clone)]
pub struct HprScratch {
    front: Vec<bool>,
    boxes: Vec<[f64; 5]>,
}

impl PaperHpr {
    /// HPR over a triangulation with the paper's centroid depth test.
    pub fn new(tri: Triangulation) -> Self {
        PaperHpr {
            tri,
            depth_test: DepthTest::Centroid,
            rel_eps: 1e-9,
        }
    }

    /// HPR over the Delaunay triangulation of a frontal shape.
    pub fn from_frontal(frontal: &[Vector3<f64>]) -> Result<Self> {
        Ok(Self::new(Triangulation::delaunay_frontal(frontal)?))
    }

    /// The same operator with another depth test in step 4.
    pub fn with_depth_test(mut self, depth_test: DepthTest) -> Self {
        self.depth_test = depth_test;
        self
    }

    /// The triangulation it works on.
    pub fn triangulation(&self) -> &Triangulation {
        &self.tri
    }

    /// Visibility of each point of `rotated` (the shape already rotated into the camera frame).
    pub fn visibility(&self, rotated: &[Vector3<f64>]) -> Result<Vec<bool>> {
        let mut out = vec![false; rotated.len()];
        self.visibility_into(rotated, &mut HprScratch::default(), &mut out)?;
        Ok(out)
    }

    /// [`PaperHpr::visibility`] into `out`, reusing `scratch`.
    pub fn visibility_into(
        &self,
        rotated: &[Vector3<f64>],
        scratch: &mut HprScratch,
        out: &mut [bool],
    ) -> Result<()> {
        let n = self.tri.n_points();
        if rotated.len() != n || out.len() != n {
            return Err(Error::PointCount {
                what: "HPR shape".into(),
                expected: n,
                got: rotated.len().min(out.len()),
            });
        }
        if rotated.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::non_finite("HPR points"));
        }
        let tris = self.tri.triangles();
        scratch.front.clear();
        scratch.boxes.clear();
        // Steps 2-3: normals and back-facing test; a point is visible if any of its
        // triangles faces the camera.
        out.fill(false);
        let mut extent = 0.0f64;
        for t in tris {
            let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
            let nz = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
            let front = nz > 0.0;
            scratch.front.push(front);
            if front {
                for &i in t {
                    out[i] = true;
                }
            }
            let (x0, x1) = (a.x.min(b.x).min(c.x), a.x.max(b.x).max(c.x));
            let (y0, y1) = (a.y.min(b.y).min(c.y), a.y.max(b.y).max(c.y));
            extent = extent.max(x1 - x0).max(y1 - y0);
            scratch
                .boxes
                .push([x0, x1, y0, y1, (a.z + b.z + c.z) / 3.0]);
        }
        // Step 4: depth test of the remaining points against triangles they project into.
        let eps = self.rel_eps * extent.max(1e-300);
        for (i, p) in rotated.iter().enumerate() {
            if !out[i] {
                continue;
            }
            for (k, t) in tris.iter().enumerate() {
                let [x0, x1, y0, y1, zc] = scratch.boxes[k];
                if p.x < x0 || p.x > x1 || p.y < y0 || p.y > y1 || t.contains(&i) {
                    continue;
                }
                let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
                let Some((wa, wb, wc)) = barycentric(p, &a, &b, &c, eps) else {
                    continue;
                };
                let depth = match self.depth_test {
                    DepthTest::Centroid => zc,
                    DepthTest::Plane => wa * a.z + wb * b.z + wc * c.z,
                };
                if depth > p.z + eps {
                    out[i] = false;
                    break;
                }
            }
        }
        Ok(())
    }
}

/// Barycentric coordinates of `p`'s projection in the triangle's projection, if it lies
/// strictly inside (by more than `eps`); `None` outside or for a degenerate projection.
fn barycentric(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
    eps: f64,
) -> Option<(f64, f64, f64)> {
    let det = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    if det.abs() < eps * eps {
        return None;
    }
    let wb = ((p.x - a.x) * (c.y - a.y) - (p.y - a.y) * (c.x - a.x)) / det;
    let wc = ((b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)) / det;
    let wa = 1.0 - wb - wc;
    let tol = 1e-12;
    (wa > tol && wb > tol && wc > tol).then_some((wa, wb, wc))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;

    /// A pyramid: a square base at z = 0 and an apex at z = 10 in front of it.
    fn pyramid() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(-10.0, -10.0, 0.0),
            Vector3::new(10.0, -10.0, 0.0),
            Vector3::new(10.0, 10.0, 0.0),
            Vector3::new(-10.0, 10.0, 0.0),
            Vector3::new(0.0, 0.0, 10.0),
        ]
    }

    #[test]
    fn frontal_view_sees_everything() {
        let hpr = PaperHpr::from_frontal(&pyramid()).unwrap();
        assert_eq!(hpr.visibility(&pyramid()).unwrap(), vec![true; 5]);
    }

    #[test]
    fn turned_away_hides_everything() {
        let hpr = PaperHpr::from_frontal(&pyramid()).unwrap();
        let r = EulerAngles::new(0.0, 180.0, 0.0).unwrap().to_rotation();
        let rotated: Vec<_> = pyramid().iter().map(|p| r * p).collect();
        assert_eq!(hpr.visibility(&rotated).unwrap(), vec![false; 5]);
    }

    #[test]
    fn a_point_behind_a_facing_triangle_is_occluded() {
        // Three points in front (z = 10) around a fourth far behind them (z = -50).
        let frontal = vec![
            Vector3::new(-10.0, -10.0, 10.0),
            Vector3::new(10.0, -10.0, 10.0),
            Vector3::new(0.0, 10.0, 10.0),
            Vector3::new(30.0, 0.0, -50.0),
        ];
        let hpr = PaperHpr::from_frontal(&frontal).unwrap();
        // Slide point 3 behind the big triangle (as a rotation would) and test.
        let mut moved = frontal.clone();
        moved[3] = Vector3::new(0.0, -2.0, -50.0);
        for test in [DepthTest::Centroid, DepthTest::Plane] {
            let v = hpr
                .clone()
                .with_depth_test(test)
                .visibility(&moved)
                .unwrap();
            assert!(!v[3], "{test:?}");
            assert!(v[0] && v[1] && v[2]);
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let hpr = PaperHpr::from_frontal(&pyramid()).unwrap();
        assert!(hpr.visibility(&pyramid()[..4]).is_err());
        let mut nan = pyramid();
        nan[0].x = f64::NAN;
        assert!(hpr.visibility(&nan).is_err());
    }
}
