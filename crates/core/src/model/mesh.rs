//! A dense face mesh served beside a model's own scheme: MediaPipe's Face Mesh, whose landmarks
//! web apps have in hand (MediaPipe Face Landmarker: 468 mesh vertices, then 10 iris points).
//!
//! The mesh comes from MediaPipe's canonical face (`canonical_face_468.json`), moved into the
//! model's frame and scale by a similarity fit of its ibug68 correspondence to the model's mean
//! (inner points only: the correspondence's jaw is its weakest part). It serves two schemes:
//! `mediapipe468` (the mesh) and `mediapipe478` (the mesh and the iris points, which move with
//! the gaze and so take no part in the fits' pose, though the detector regression trained on
//! them reads them; each reports the visibility of its eye).
//!
//! How the methods use it (`pose.rs`): the rigid fit fits the mesh's own points; the shape fit,
//! the regression and the geometric method run on the model's own scheme, with each model point
//! the mean of its corresponding mesh landmarks (the model's contour points left out). The
//! visibility is HPR's over the mesh's own triangles, precomputed over view directions.

use nalgebra::Vector3;

use crate::error::{Error, Result};
use crate::estimate::visibility_map::VisibilityMap;
use crate::geometry::procrustes::{Scaling, align3};
use crate::hpr::{PaperHpr, Triangulation};
use crate::shape::{Anchors, Scheme, Shape2};

/// The 468-point scheme: MediaPipe Face Mesh vertices in its landmark order.
pub const MEDIAPIPE468: &str = "mediapipe468";
/// The 478-point scheme: the mesh, then MediaPipe's 10 iris points.
pub const MEDIAPIPE478: &str = "mediapipe478";
/// Vertices of MediaPipe's face mesh.
pub const MESH_VERTICES: usize = 468;
/// Iris points of the 478-point form: 468-472 the subject's right iris (image-left for a
/// frontal face; centre first), 473-477 the left.
pub const IRIS_POINTS: usize = 10;

/// MediaPipe's eye contours (`FACEMESH_RIGHT_EYE` / `FACEMESH_LEFT_EYE`: right = the subject's
/// right), whose mean places an iris point for its visibility.
const RIGHT_EYE: [usize; 16] = [
    33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173,
];
const LEFT_EYE: [usize; 16] = [
    263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398,
];

/// The source of a mesh: vertices (mm, model-frame axes), triangles and the correspondence to the
/// model's scheme (`to_model[k]`: the vertices whose mean is the model's point `k`).
#[derive(Debug, Clone, PartialEq)]
pub struct MeshSource {
    /// Vertices, model frame, mm.
    pub vertices: Vec<Vector3<f64>>,
    /// Triangles, as vertex indices.
    pub triangles: Vec<[usize; 3]>,
    /// Per model point, the vertices whose mean is that point.
    pub to_model: Vec<Vec<usize>>,
}

/// One scheme of the mesh.
#[derive(Debug, Clone)]
pub struct MeshScheme {
    /// The scheme.
    pub scheme: Scheme,
    /// The scheme's points in the model frame (an iris point at its eye's centre).
    pub points: Vec<Vector3<f64>>,
    /// The points that take part in the pose: the first `pose_points` (the mesh vertices).
    pub pose_points: usize,
    /// Per point, the mesh vertex whose visibility it reports.
    vertex_of: Vec<usize>,
}

/// The served mesh: its source aligned to the model, the visibility of its vertices over view
/// directions, and its two schemes.
#[derive(Debug, Clone)]
pub struct FaceMesh {
    source: MeshSource,
    visibility: VisibilityMap,
    schemes: [MeshScheme; 2],
}

impl MeshSource {
    /// Checks sizes and indices against a model scheme of `n_model` points.
    pub fn validate(&self, n_model: usize) -> Result<()> {
        let n = self.vertices.len();
        let bad = |reason: String| Error::param("mesh", reason);
        if n != MESH_VERTICES {
            return Err(bad(format!(
                "{n} vertices; MediaPipe's face mesh has {MESH_VERTICES}"
            )));
        }
        if let Some(i) = self
            .vertices
            .iter()
            .position(|v| !v.iter().all(|c| c.is_finite()))
        {
            return Err(bad(format!("vertex {i} is not finite")));
        }
        if self.to_model.len() != n_model {
            return Err(bad(format!(
                "the correspondence has {} entries for the model's {n_model} points",
                self.to_model.len()
            )));
        }
        if let Some(k) = self
            .to_model
            .iter()
            .position(|v| v.is_empty() || v.iter().any(|&i| i >= n))
        {
            return Err(bad(format!(
                "the correspondence of model point {k} names no vertex or one out of range"
            )));
        }
        Ok(())
    }

    /// The model's points by the correspondence.
    fn model_points(&self) -> Vec<Vector3<f64>> {
        self.to_model
            .iter()
            .map(|v| v.iter().map(|&i| self.vertices[i]).sum::<Vector3<f64>>() / v.len() as f64)
            .collect()
    }

    /// The source moved into the frame and scale of a model whose scheme is `scheme` and frontal
    /// mean `mean`: the similarity that best maps the corresponding points onto the mean, over
    /// the points off the scheme's contour.
    pub fn aligned_to(&self, scheme: &Scheme, mean: &[Vector3<f64>]) -> Result<MeshSource> {
        self.validate(mean.len())?;
        let keep: Vec<usize> = (0..mean.len())
            .filter(|k| !scheme.contour.contains(k))
            .collect();
        let src = self.model_points();
        let a: Vec<Vector3<f64>> = keep.iter().map(|&k| src[k]).collect();
        let b: Vec<Vector3<f64>> = keep.iter().map(|&k| mean[k]).collect();
        let sim = align3(&a, &b, Scaling::Similarity)?;
        Ok(MeshSource {
            vertices: self.vertices.iter().map(|v| sim.apply(v)).collect(),
            triangles: self.triangles.clone(),
            to_model: self.to_model.clone(),
        })
    }
}

impl FaceMesh {
    /// The mesh of a model, from an aligned source ([`MeshSource::aligned_to`]) and, when the
    /// bundle stores it, its vertices' visibility (else HPR computes it over the default grid).
    pub fn new(
        source: MeshSource,
        model_scheme: &Scheme,
        visibility: Option<VisibilityMap>,
    ) -> Result<FaceMesh> {
        source.validate(model_scheme.len())?;
        let visibility = match visibility {
            Some(v) => {
                if v.n_points() != MESH_VERTICES {
                    return Err(Error::PointCount {
                        what: "mesh visibility map".into(),
                        expected: MESH_VERTICES,
                        got: v.n_points(),
                    });
                }
                v
            }
            None => {
                let tri = Triangulation::new(&source.vertices, source.triangles.clone())?;
                VisibilityMap::build_default(&source.vertices, &PaperHpr::new(tri))?
            }
        };
        let schemes = schemes(&source, model_scheme)?;
        Ok(FaceMesh {
            source,
            visibility,
            schemes,
        })
    }

    /// The aligned source (what a bundle stores).
    pub fn source(&self) -> &MeshSource {
        &self.source
    }

    /// The vertices' visibility over view directions.
    pub fn visibility(&self) -> &VisibilityMap {
        &self.visibility
    }

    /// The two schemes, `mediapipe468` first.
    pub fn schemes(&self) -> &[MeshScheme] {
        &self.schemes
    }

    /// The scheme called `name`, if the mesh serves it.
    pub fn scheme(&self, name: &str) -> Option<&MeshScheme> {
        self.schemes.iter().find(|s| s.scheme.name == name)
    }

    /// The model's landmarks from a mesh scheme's: each model point the mean of its
    /// corresponding landmarks that are present (missing when none is), the model's contour
    /// points left out (the correspondence is weakest there, and a mesh vertex is not the
    /// outline point a contour landmark is).
    pub fn to_model(&self, landmarks: &Shape2, model_scheme: &Scheme) -> Result<Shape2> {
        let pts: Vec<Option<[f64; 2]>> = self
            .source
            .to_model
            .iter()
            .enumerate()
            .map(|(k, verts)| {
                if model_scheme.contour.contains(&k) {
                    return None;
                }
                let (mut sum, mut n) = ([0.0, 0.0], 0.0);
                for p in verts.iter().filter_map(|&i| landmarks.get(i)) {
                    sum[0] += p.x;
                    sum[1] += p.y;
                    n += 1.0;
                }
                (n > 0.0).then(|| [sum[0] / n, sum[1] / n])
            })
            .collect();
        Shape2::from_options(&pts)
    }
}

impl MeshScheme {
    /// The per-point visibility at rotation `r` from the mesh's map.
    pub fn visible(&self, mesh: &FaceMesh, r: &nalgebra::Rotation3<f64>) -> Vec<bool> {
        let vis = mesh.visibility.lookup(r);
        self.vertex_of.iter().map(|&v| vis[v]).collect()
    }

    /// `landmarks` with the points that take no part in the pose (the iris) marked missing.
    pub fn pose_landmarks(&self, landmarks: &Shape2) -> Shape2 {
        if self.pose_points == landmarks.len() {
            return landmarks.clone();
        }
        landmarks.with_missing(self.pose_points..landmarks.len())
    }
}

/// The mean of some vertices.
fn centre(v: &[Vector3<f64>], idx: &[usize]) -> Vector3<f64> {
    idx.iter().map(|&i| v[i]).sum::<Vector3<f64>>() / idx.len() as f64
}

/// The vertex nearest to a point.
fn nearest(v: &[Vector3<f64>], p: &Vector3<f64>) -> usize {
    (0..v.len())
        .min_by(|&a, &b| {
            (v[a] - p)
                .norm_squared()
                .total_cmp(&(v[b] - p).norm_squared())
        })
        .unwrap_or(0)
}

/// The left-right pairing of the vertices: each vertex's nearest to its mirror image, kept when
/// it is a pairing (the canonical mesh is symmetric) and `None` otherwise.
fn mirror_of(v: &[Vector3<f64>]) -> Option<Vec<usize>> {
    let m: Vec<usize> = v
        .iter()
        .map(|p| nearest(v, &Vector3::new(-p.x, p.y, p.z)))
        .collect();
    (0..m.len()).all(|i| m[m[i]] == i).then_some(m)
}

/// `mediapipe468` and `mediapipe478` of a mesh whose correspondence is to `model_scheme`: the
/// anchors are the vertices of the model's anchors.
fn schemes(source: &MeshSource, model_scheme: &Scheme) -> Result<[MeshScheme; 2]> {
    let verts_of = |idx: &[usize]| -> Vec<usize> {
        let mut out: Vec<usize> = idx
            .iter()
            .flat_map(|&k| source.to_model[k].iter().copied())
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    };
    let a = &model_scheme.anchors;
    let anchors = Anchors {
        eye_left: verts_of(&a.eye_left),
        eye_right: verts_of(&a.eye_right),
        nose_tip: verts_of(&a.nose_tip),
        mouth_left: verts_of(&a.mouth_left),
        mouth_right: verts_of(&a.mouth_right),
    };
    let v = &source.vertices;
    let mirror = mirror_of(v);
    let names: Vec<String> = (0..MESH_VERTICES).map(|i| format!("mesh_{i}")).collect();
    let s468 = Scheme::new(
        MEDIAPIPE468,
        names.clone(),
        anchors.clone(),
        mirror.clone(),
        vec![],
    )?;
    // The iris points: 468-472 the subject's right eye, 473-477 the left.
    let (right, left) = (centre(v, &RIGHT_EYE), centre(v, &LEFT_EYE));
    let (right_v, left_v) = (nearest(v, &right), nearest(v, &left));
    let mut names478 = names;
    let mut points478 = v.clone();
    let mut vertex_of: Vec<usize> = (0..MESH_VERTICES).collect();
    for (side, c, vert) in [("right", right, right_v), ("left", left, left_v)] {
        for k in 0..IRIS_POINTS / 2 {
            names478.push(format!("iris_{side}_{k}"));
            points478.push(c);
            vertex_of.push(vert);
        }
    }
    let mirror478 = mirror.map(|mut m| {
        m.extend((0..IRIS_POINTS).map(|k| MESH_VERTICES + (k + IRIS_POINTS / 2) % IRIS_POINTS));
        m
    });
    let s478 = Scheme::new(MEDIAPIPE478, names478, anchors, mirror478, vec![])?;
    Ok([
        MeshScheme {
            scheme: s468,
            points: v.clone(),
            pose_points: MESH_VERTICES,
            vertex_of: (0..MESH_VERTICES).collect(),
        },
        MeshScheme {
            scheme: s478,
            points: points478,
            pose_points: MESH_VERTICES,
            vertex_of,
        },
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric toy "mesh" is not 468 points: the size check says so.
    #[test]
    fn a_mesh_of_the_wrong_size_is_refused() {
        let s = MeshSource {
            vertices: vec![Vector3::zeros(); 10],
            triangles: vec![],
            to_model: vec![vec![0]; 68],
        };
        let e = s.validate(68).unwrap_err().to_string();
        assert!(e.contains("468"), "{e}");
    }
}
