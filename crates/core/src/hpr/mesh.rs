//! Ground-truth visibility on a dense triangle mesh, for scoring HPR: a vertex (or a point on the
//! surface) is hidden when every mesh triangle around it faces away from the camera, or when a
//! ray from it towards the camera (+z) crosses another triangle of the mesh.

use nalgebra::Vector3;

use super::triangulation::Triangulation;
use crate::error::{Error, Result};

/// A surface point to test: its position is the mean of the listed mesh vertices, and the
/// triangles around those vertices are its own surface (they neither hide nor reveal it).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SurfacePoint {
    /// Indices of the mesh vertices the point stands on.
    pub vertices: Vec<usize>,
}

/// Ray-casting visibility against a mesh.
#[derive(Debug, Clone)]
pub struct MeshVisibility {
    mesh: Triangulation,
    incidence: Vec<Vec<usize>>,
    depth_tolerance: f64,
    back_face_rule: bool,
}

impl MeshVisibility {
    /// A mesh over `frontal` vertices with its own triangles.
    pub fn new(frontal: &[Vector3<f64>], triangles: Vec<[usize; 3]>) -> Result<Self> {
        let mesh = Triangulation::new(frontal, triangles)?;
        let incidence = mesh.incidence();
        Ok(MeshVisibility {
            mesh,
            incidence,
            depth_tolerance: 0.0,
            back_face_rule: true,
        })
    }

    /// The same truth with a depth tolerance (model units, mm): an occluder must be in front of
    /// the point by more than this, as with the depth bias of a z-buffer. Creases shallower than
    /// the tolerance (a lip over the mouth corner) then do not hide a point.
    pub fn with_depth_tolerance(mut self, tolerance: f64) -> Self {
        self.depth_tolerance = tolerance.max(0.0);
        self
    }

    /// Whether a point all of whose own triangles face away counts as hidden (on by default:
    /// the surface stands for a closed head; off gives a pure ray cast, as a z-buffer of the
    /// open mesh sees it).
    pub fn with_back_face_rule(mut self, on: bool) -> Self {
        self.back_face_rule = on;
        self
    }

    /// Visibility of each point in `points` on the mesh posed as `rotated` (its vertices in the
    /// camera frame).
    pub fn visibility(
        &self,
        rotated: &[Vector3<f64>],
        points: &[SurfacePoint],
    ) -> Result<Vec<bool>> {
        let n = self.mesh.n_points();
        if rotated.len() != n {
            return Err(Error::PointCount {
                what: "mesh vertices".into(),
                expected: n,
                got: rotated.len(),
            });
        }
        let tris = self.mesh.triangles();
        let front: Vec<bool> = tris
            .iter()
            .map(|t| {
                let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
                (b - a).cross(&(c - a)).z > 0.0
            })
            .collect();
        let extent = rotated
            .iter()
            .map(|p| p.x.abs().max(p.y.abs()))
            .fold(0.0, f64::max);
        let eps = 1e-9 * extent.max(1e-300) + self.depth_tolerance;
        let mut out = Vec::with_capacity(points.len());
        let mut own = Vec::new();
        for sp in points {
            if sp.vertices.is_empty() || sp.vertices.iter().any(|&v| v >= n) {
                return Err(Error::param(
                    "surface point",
                    format!("vertices {:?} of {n}", sp.vertices),
                ));
            }
            own.clear();
            own.extend(
                sp.vertices
                    .iter()
                    .flat_map(|&v| self.incidence[v].iter().copied()),
            );
            let p = sp
                .vertices
                .iter()
                .map(|&v| rotated[v])
                .sum::<Vector3<f64>>()
                / sp.vertices.len() as f64;
            let faces_camera = !self.back_face_rule || own.iter().any(|&k| front[k]);
            let occluded = faces_camera
                && tris.iter().enumerate().any(|(k, t)| {
                    !own.contains(&k) && {
                        let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
                        depth_at(&p, &a, &b, &c).is_some_and(|z| z > p.z + eps)
                    }
                });
            out.push(faces_camera && !occluded);
        }
        Ok(out)
    }

    /// Visibility of every mesh vertex.
    pub fn vertex_visibility(&self, rotated: &[Vector3<f64>]) -> Result<Vec<bool>> {
        let pts: Vec<SurfacePoint> = (0..self.mesh.n_points())
            .map(|v| SurfacePoint { vertices: vec![v] })
            .collect();
        self.visibility(rotated, &pts)
    }
}

/// Depth of the triangle at `p`'s (x, y), if `p` projects inside it (edges included).
fn depth_at(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> Option<f64> {
    if p.x < a.x.min(b.x).min(c.x)
        || p.x > a.x.max(b.x).max(c.x)
        || p.y < a.y.min(b.y).min(c.y)
        || p.y > a.y.max(b.y).max(c.y)
    {
        return None;
    }
    let det = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    if det.abs() < 1e-300 {
        return None;
    }
    let wb = ((p.x - a.x) * (c.y - a.y) - (p.y - a.y) * (c.x - a.x)) / det;
    let wc = ((b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)) / det;
    let wa = 1.0 - wb - wc;
    (wa >= 0.0 && wb >= 0.0 && wc >= 0.0).then(|| wa * a.z + wb * b.z + wc * c.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vertex_under_a_flap_is_hidden() {
        // A big triangle at z = 10 above a small one at z = 0 (sharing no vertex).
        let v = vec![
            Vector3::new(-10.0, -10.0, 10.0),
            Vector3::new(10.0, -10.0, 10.0),
            Vector3::new(0.0, 10.0, 10.0),
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        let m = MeshVisibility::new(&v, vec![[0, 1, 2], [3, 4, 5]]).unwrap();
        assert_eq!(
            m.vertex_visibility(&v).unwrap(),
            vec![true, true, true, false, false, false]
        );
        // Turned away (yaw 180): everything faces backwards; a pure ray cast finds nothing in
        // front of anything (the flap is now behind).
        let back: Vec<_> = v.iter().map(|p| Vector3::new(-p.x, p.y, -p.z)).collect();
        assert_eq!(m.vertex_visibility(&back).unwrap(), vec![false; 6]);
        let ray = m.clone().with_back_face_rule(false);
        assert_eq!(ray.vertex_visibility(&back).unwrap(), vec![true; 6]);
    }
}
