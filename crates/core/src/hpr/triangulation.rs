//! The triangulation HPR works on: Delaunay triangulation (spade) of the frontal shape's
//! projection onto the image plane, with every triangle counter-clockwise seen from the camera
//! (+z), so that its normal points to the camera while the face is frontal.

use nalgebra::Vector3;
use spade::{DelaunayTriangulation, Point2, Triangulation as _};

use crate::error::{Error, Result};

/// Triangles over the points of a shape (indices into it), counter-clockwise from +z.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Triangulation {
    n_points: usize,
    triangles: Vec<[usize; 3]>,
}

impl Triangulation {
    /// Delaunay triangulation of the (x, y) projection of a frontal 3D shape. Fails on
    /// non-finite points, fewer than 3 points, two points at the same (x, y) or all collinear.
    pub fn delaunay_frontal(frontal: &[Vector3<f64>]) -> Result<Self> {
        if frontal.len() < 3 {
            return Err(Error::too_few("triangulation", 3, frontal.len()));
        }
        if frontal.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::non_finite("triangulation points"));
        }
        let pts: Vec<Point2<f64>> = frontal.iter().map(|p| Point2::new(p.x, p.y)).collect();
        let dt = DelaunayTriangulation::<Point2<f64>>::bulk_load_stable(pts).map_err(|e| {
            Error::Degenerate(format!("cannot triangulate the frontal shape: {e:?}"))
        })?;
        if dt.num_vertices() != frontal.len() {
            return Err(Error::Degenerate(
                "two points of the frontal shape have the same (x, y) position".into(),
            ));
        }
        let triangles: Vec<[usize; 3]> = dt
            .inner_faces()
            .map(|f| f.vertices().map(|v| v.fix().index()))
            .collect();
        if triangles.is_empty() {
            return Err(Error::Degenerate(
                "the frontal shape's points are collinear".into(),
            ));
        }
        Self::new(frontal, triangles)
    }

    /// Triangles given explicitly (for instance a mesh's own); each is re-oriented to be
    /// counter-clockwise from +z in `frontal`. Fails on an index out of range or a triangle
    /// with a repeated vertex.
    pub fn new(frontal: &[Vector3<f64>], triangles: Vec<[usize; 3]>) -> Result<Self> {
        let n = frontal.len();
        let mut out = Vec::with_capacity(triangles.len());
        for (k, t) in triangles.into_iter().enumerate() {
            if t.iter().any(|&i| i >= n) || t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                return Err(Error::param(
                    "triangles",
                    format!("triangle {k} {t:?} is not 3 distinct points of {n}"),
                ));
            }
            let (a, b, c) = (frontal[t[0]], frontal[t[1]], frontal[t[2]]);
            let z = (b - a).cross(&(c - a)).z;
            out.push(if z < 0.0 { [t[0], t[2], t[1]] } else { t });
        }
        Ok(Triangulation {
            n_points: n,
            triangles: out,
        })
    }

    /// The triangles, counter-clockwise from +z in the frontal shape.
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    /// Number of points the triangulation is over.
    pub fn n_points(&self) -> usize {
        self.n_points
    }

    /// For each point, the triangles it belongs to.
    pub fn incidence(&self) -> Vec<Vec<usize>> {
        let mut inc = vec![Vec::new(); self.n_points];
        for (k, t) in self.triangles.iter().enumerate() {
            for &i in t {
                inc[i].push(k);
            }
        }
        inc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_with_centre_gives_four_ccw_triangles() {
        let pts = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(2.0, 0.0, 0.0),
            Vector3::new(2.0, 2.0, 0.0),
            Vector3::new(0.0, 2.0, 0.0),
            Vector3::new(1.0, 1.0, 1.0),
        ];
        let t = Triangulation::delaunay_frontal(&pts).unwrap();
        assert_eq!(t.triangles().len(), 4);
        for tri in t.triangles() {
            assert!(tri.contains(&4));
            let (a, b, c) = (pts[tri[0]], pts[tri[1]], pts[tri[2]]);
            assert!((b - a).cross(&(c - a)).z > 0.0);
        }
        assert!(t.incidence()[4].len() == 4);
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let line: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(Triangulation::delaunay_frontal(&line).is_err());
        let dup = vec![
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        assert!(Triangulation::delaunay_frontal(&dup).is_err());
        assert!(Triangulation::delaunay_frontal(&dup[..2]).is_err());
        assert!(Triangulation::new(&dup, vec![[0, 0, 1]]).is_err());
    }
}
