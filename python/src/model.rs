//! `Model`: a pose model (the embedded default, a bundle folder, or trained from shapes) and the
//! estimates made with it, one face or a batch (the GIL released, the batch split over threads).

use std::num::NonZeroUsize;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use facepose_core::geometry::rotation_rows;
use facepose_core::model::bundle::{Bundle, Provenance};
use facepose_core::model::{
    BasisSource, PoseModel, RegressionParams, TrainOptions, default_model, train_from_population,
};
use facepose_core::pose::Estimate;
use facepose_core::shape::{MAX_POINTS, Scheme};
use nalgebra::Vector3;
use numpy::ndarray::{Array1, Array2, Array3, ArrayView2};
use numpy::{IntoPyArray, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyString, PyTuple};

use crate::errors::{FaceError, InvalidParameterError, ModelError, core_err};
use crate::face::{FacePose, Options, estimate_all, estimate_face};

struct Inner {
    model: PoseModel,
    bundle: Bundle,
}

/// A pose model. `Model.default()` (the embedded one, built by `facepose train`), `Model.load(path)`
/// (a bundle folder or its model.json) or `facepose.train(shapes)`.
#[pyclass(frozen, module = "facepose._facepose")]
#[derive(Clone)]
pub struct Model {
    inner: Arc<Inner>,
}

static DEFAULT: OnceLock<Arc<Inner>> = OnceLock::new();

fn model_err(e: impl std::fmt::Display) -> PyErr {
    ModelError::new_err(e.to_string())
}

/// The landmarks of one face from an (N, 2) array: a row of two NaN is a missing point; any
/// other row goes to the core as it is (a lone NaN or an infinity is refused there, naming the
/// landmark).
fn points_of(a: ArrayView2<'_, f64>) -> PyResult<Vec<Option<[f64; 2]>>> {
    let (n, d) = a.dim();
    if d != 2 {
        return Err(InvalidParameterError::new_err(format!(
            "landmarks must be an (N, 2) array of x, y pixels, got shape ({n}, {d})"
        )));
    }
    if n > MAX_POINTS {
        return Err(InvalidParameterError::new_err(format!(
            "landmarks: more than {MAX_POINTS} landmarks, the most a scheme may have"
        )));
    }
    Ok(a.rows()
        .into_iter()
        .map(|r| {
            let (x, y) = (r[0], r[1]);
            if x.is_nan() && y.is_nan() {
                None
            } else {
                Some([x, y])
            }
        })
        .collect())
}

fn threads_of(threads: Option<usize>) -> usize {
    match threads {
        Some(t) if t > 0 => t,
        _ => std::thread::available_parallelism().map_or(1, NonZeroUsize::get),
    }
}

/// One pose as a dict of `Pose`'s fields.
fn pose_dict<'py>(py: Python<'py>, m: &Inner, p: FacePose<'_>) -> PyResult<Bound<'py, PyDict>> {
    let e: Estimate = p.estimate;
    // What the stream's Kalman filter weighs the frame by (the method's filter trust applied),
    // so that the Python tracker smooths as the stream does.
    let filter_cov = e.filter_cov();
    let d = PyDict::new(py);
    d.set_item("yaw", e.angles.yaw)?;
    d.set_item("pitch", e.angles.pitch)?;
    d.set_item("roll", e.angles.roll)?;
    let rows = rotation_rows(&e.rotation);
    let rot = Array2::from_shape_fn((3, 3), |(i, j)| rows[i][j]);
    d.set_item("rotation", rot.into_pyarray(py))?;
    d.set_item("visible", Array1::from(e.visible).into_pyarray(py))?;
    d.set_item("residual", e.residual)?;
    d.set_item("method", e.method.name())?;
    let mut warnings: Vec<String> = e.warnings.iter().map(ToString::to_string).collect();
    warnings.extend(p.extra_warnings.iter().cloned());
    d.set_item("warnings", warnings)?;
    d.set_item("conventions", p.conventions.as_deref())?;
    match &e.uncertainty {
        Some(u) => {
            // The core's order is pitch, yaw, roll; the answer's yaw, pitch, roll.
            // Tuples: Python's AngleUncertainty takes them as they are.
            let iv = |k: usize| (u.interval90[k][0], u.interval90[k][1]);
            let sd = (u.sd[1], u.sd[0], u.sd[2]);
            d.set_item("uncertainty", (sd, (iv(1), iv(0), iv(2))))?;
            let c = filter_cov.unwrap_or(u.turn_cov);
            let cov = Array2::from_shape_fn((3, 3), |(i, j)| c[(i, j)]);
            d.set_item("turn_cov", cov.into_pyarray(py))?;
        }
        None => {
            d.set_item("uncertainty", py.None())?;
            d.set_item("turn_cov", py.None())?;
        }
    }
    match e.translation {
        Some(t) => d.set_item(
            "translation",
            Array1::from(vec![t.x, t.y, t.z]).into_pyarray(py),
        )?,
        None => d.set_item("translation", py.None())?,
    }
    d.set_item("scheme", p.scheme)?;
    d.set_item("model", &m.bundle.name)?;
    d.set_item("model_version", &m.bundle.version)?;
    Ok(d)
}

/// A batch's answers as columns: NaN (and empty strings) where a face failed.
fn batch_dict<'py, 'm>(
    py: Python<'py>,
    m: &Inner,
    results: Vec<Result<FacePose<'m>, FaceError>>,
    counts: &[usize],
    camera: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let b = results.len();
    let nan = f64::NAN;
    let mut angles = Array2::from_elem((b, 3), nan);
    let mut rotation = Array3::from_elem((b, 3, 3), nan);
    let mut residual = Array1::from_elem(b, nan);
    let mut sd = Array2::from_elem((b, 3), nan);
    let mut interval = Array3::from_elem((b, 3, 2), nan);
    let mut turn_cov = Array3::from_elem((b, 3, 3), nan);
    let mut translation = Array2::from_elem((b, 3), nan);
    let uniform = counts.windows(2).all(|w| w[0] == w[1]);
    let n = counts.first().copied().unwrap_or(0);
    let mut visible_grid = Array2::from_elem((if uniform { b } else { 0 }, n), false);
    let visible_list = PyList::empty(py);
    let methods = PyList::empty(py);
    let schemes = PyList::empty(py);
    let warnings = PyList::empty(py);
    let errors = PyList::empty(py);
    let conventions = PyList::empty(py);
    // One Python string per distinct method and scheme, and one empty tuple for the faces
    // without warnings: a batch's faces share them (strings and tuples are immutable).
    let mut names: Vec<(&'m str, Bound<'py, PyString>)> = Vec::new();
    let mut name = |s: &'m str| -> Bound<'py, PyString> {
        match names.iter().find(|(k, _)| *k == s) {
            Some((_, v)) => v.clone(),
            None => {
                let v = PyString::new(py, s);
                names.push((s, v.clone()));
                v
            }
        }
    };
    let no_warnings = PyTuple::empty(py);
    let empty = PyString::new(py, "");
    for (i, r) in results.into_iter().enumerate() {
        match r {
            Ok(p) => {
                let e = &p.estimate;
                angles[(i, 0)] = e.angles.yaw;
                angles[(i, 1)] = e.angles.pitch;
                angles[(i, 2)] = e.angles.roll;
                let rows = rotation_rows(&e.rotation);
                for (j, row) in rows.iter().enumerate() {
                    for (k, v) in row.iter().enumerate() {
                        rotation[(i, j, k)] = *v;
                    }
                }
                residual[i] = e.residual;
                if let (Some(u), Some(cov)) = (&e.uncertainty, e.filter_cov()) {
                    for (k, c) in [1, 0, 2].into_iter().enumerate() {
                        sd[(i, k)] = u.sd[c];
                        interval[(i, k, 0)] = u.interval90[c][0];
                        interval[(i, k, 1)] = u.interval90[c][1];
                    }
                    for j in 0..3 {
                        for k in 0..3 {
                            turn_cov[(i, j, k)] = cov[(j, k)];
                        }
                    }
                }
                if let Some(t) = e.translation {
                    for k in 0..3 {
                        translation[(i, k)] = t[k];
                    }
                }
                if uniform {
                    for (k, v) in e.visible.iter().enumerate() {
                        visible_grid[(i, k)] = *v;
                    }
                } else {
                    visible_list.append(Array1::from(e.visible.clone()).into_pyarray(py))?;
                }
                methods.append(name(e.method.name()))?;
                if e.warnings.is_empty() && p.extra_warnings.is_empty() {
                    warnings.append(&no_warnings)?;
                } else {
                    let mut w: Vec<String> = e.warnings.iter().map(ToString::to_string).collect();
                    w.extend(p.extra_warnings.iter().cloned());
                    warnings.append(PyTuple::new(py, w)?)?;
                }
                conventions.append(p.conventions.as_deref())?;
                schemes.append(name(p.scheme))?;
                errors.append(py.None())?;
            }
            Err(err) => {
                if !uniform {
                    visible_list.append(Array1::from_elem(counts[i], false).into_pyarray(py))?;
                }
                methods.append(&empty)?;
                conventions.append(py.None())?;
                schemes.append(&empty)?;
                warnings.append(&no_warnings)?;
                errors.append(err.to_pyerr().into_value(py))?;
            }
        }
    }
    let d = PyDict::new(py);
    d.set_item("angles", angles.into_pyarray(py))?;
    d.set_item("rotation", rotation.into_pyarray(py))?;
    d.set_item("residual", residual.into_pyarray(py))?;
    d.set_item("sd", sd.into_pyarray(py))?;
    d.set_item("interval90", interval.into_pyarray(py))?;
    d.set_item("turn_cov", turn_cov.into_pyarray(py))?;
    if camera {
        d.set_item("translation", translation.into_pyarray(py))?;
    } else {
        d.set_item("translation", py.None())?;
    }
    if uniform {
        d.set_item("visible", visible_grid.into_pyarray(py))?;
    } else {
        d.set_item("visible", visible_list)?;
    }
    d.set_item("method", methods)?;
    d.set_item("scheme", schemes)?;
    d.set_item("warnings", warnings)?;
    d.set_item("errors", errors)?;
    d.set_item("conventions", conventions)?;
    d.set_item("model", &m.bundle.name)?;
    d.set_item("model_version", &m.bundle.version)?;
    Ok(d)
}

type Camera = Option<[f64; 4]>;
type Size = Option<[f64; 2]>;

impl Model {
    fn options(
        &self,
        scheme: Option<&str>,
        method: Option<&str>,
        style: Option<&str>,
        camera: Camera,
        image_size: Size,
        conventions: Option<&str>,
    ) -> PyResult<Options> {
        let m = &self.inner;
        Ok(Options::parse(
            &m.model,
            &m.bundle.name,
            scheme,
            method,
            style,
            camera,
            image_size,
            conventions,
        )?)
    }

    fn run_batch<'py>(
        &self,
        py: Python<'py>,
        faces: Vec<Vec<Option<[f64; 2]>>>,
        o: Options,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let counts: Vec<usize> = faces.iter().map(Vec::len).collect();
        let threads = threads_of(threads);
        let inner = Arc::clone(&self.inner);
        let camera = o.opts.camera.is_some();
        let results = py.detach(|| estimate_all(&inner.model, &o, &faces, threads));
        batch_dict(py, &self.inner, results, &counts, camera)
    }
}

#[pymethods]
impl Model {
    /// The embedded default model (parsed once per process).
    #[staticmethod]
    fn default(py: Python<'_>) -> PyResult<Model> {
        if let Some(inner) = DEFAULT.get() {
            return Ok(Model {
                inner: Arc::clone(inner),
            });
        }
        let (bundle, model) = py.detach(default_model).map_err(model_err)?;
        let inner = DEFAULT.get_or_init(|| Arc::new(Inner { model, bundle }));
        Ok(Model {
            inner: Arc::clone(inner),
        })
    }

    /// A model bundle: a folder with model.json (as `facepose train --out` writes it), or the file.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Model> {
        let (bundle, model) = py
            .detach(|| facepose_files::store::load_model(&path).map_err(|e| e.to_string()))
            .map_err(ModelError::new_err)?;
        Ok(Model {
            inner: Arc::new(Inner { model, bundle }),
        })
    }

    /// Writes the model's bundle to the folder `path` (which must not exist), atomically.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let b = &self.inner.bundle;
        py.detach(|| facepose_files::store::write_bundle_dir(&path, b).map_err(|e| e.to_string()))
            .map_err(ModelError::new_err)
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.bundle.name.clone()
    }

    #[getter]
    fn version(&self) -> String {
        self.inner.bundle.version.clone()
    }

    /// The schemes served, name -> number of points, the model's own first.
    #[getter]
    fn schemes(&self) -> Vec<(String, usize)> {
        self.inner
            .model
            .schemes()
            .map(|s| (s.name.clone(), s.len()))
            .collect()
    }

    /// The point names of a scheme.
    fn scheme_points(&self, scheme: &str) -> PyResult<Vec<String>> {
        let s = self.inner.model.scheme(scheme).map_err(core_err)?;
        Ok(s.points.clone())
    }

    /// The model's mean 3D shape in a scheme it serves: (N, 3) mm, model frame (x towards the
    /// subject's left, y up, z towards the camera): a generic face for other solvers
    /// (`cv2.solvePnP`). For the MediaPipe schemes, the face mesh's points aligned to the mean.
    fn mean_shape<'py>(
        &self,
        py: Python<'py>,
        scheme: &str,
    ) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let m = &self.inner.model;
        let pts: &[Vector3<f64>] = match m.mesh_scheme(scheme) {
            Some((_, ms)) => &ms.points,
            None => &m.subset(scheme).map_err(core_err)?.mean,
        };
        Ok(Array2::from_shape_fn((pts.len(), 3), |(i, j)| pts[i][j]).into_pyarray(py))
    }

    /// Whether the model has a shape basis (the `fit-shape` method) and an uncertainty calibration.
    #[getter]
    fn has_shape_basis(&self) -> bool {
        self.inner.model.morph.is_some()
    }

    #[getter]
    fn has_calibration(&self) -> bool {
        self.inner.model.calibration.is_some()
    }

    /// The bundle as JSON text (what `save` writes).
    fn to_json(&self) -> String {
        self.inner.bundle.to_json()
    }

    fn __repr__(&self) -> String {
        format!(
            "Model(name={:?}, version={:?}, schemes=[{}])",
            self.inner.bundle.name,
            self.inner.bundle.version,
            self.schemes()
                .iter()
                .map(|(s, _)| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )
    }

    /// One face: a float64 (N, 2) array. Returns the fields of `Pose` as a dict.
    #[pyo3(signature = (landmarks, scheme=None, method=None, landmark_style=None, camera=None, image_size=None, conventions=None))]
    #[allow(clippy::too_many_arguments)]
    fn _estimate_one<'py>(
        &self,
        py: Python<'py>,
        landmarks: PyReadonlyArray2<'py, f64>,
        scheme: Option<&str>,
        method: Option<&str>,
        landmark_style: Option<&str>,
        camera: Camera,
        image_size: Size,
        conventions: Option<&str>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let o = self.options(
            scheme,
            method,
            landmark_style,
            camera,
            image_size,
            conventions,
        )?;
        let points = points_of(landmarks.as_array())?;
        let inner = Arc::clone(&self.inner);
        let p = py.detach(|| estimate_face(&inner.model, &o, &points))?;
        pose_dict(py, &self.inner, p)
    }

    /// A batch as a float64 (B, N, 2) array. Returns the columns of `PoseBatch` as a dict.
    #[pyo3(signature = (landmarks, scheme=None, method=None, landmark_style=None, camera=None, image_size=None, conventions=None, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn _estimate_array<'py>(
        &self,
        py: Python<'py>,
        landmarks: PyReadonlyArray3<'py, f64>,
        scheme: Option<&str>,
        method: Option<&str>,
        landmark_style: Option<&str>,
        camera: Camera,
        image_size: Size,
        conventions: Option<&str>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let o = self.options(
            scheme,
            method,
            landmark_style,
            camera,
            image_size,
            conventions,
        )?;
        let a = landmarks.as_array();
        let faces = a
            .outer_iter()
            .map(|f| points_of(f))
            .collect::<PyResult<Vec<_>>>()?;
        self.run_batch(py, faces, o, threads)
    }

    /// A batch as a list of float64 (N_i, 2) arrays.
    #[pyo3(signature = (landmarks, scheme=None, method=None, landmark_style=None, camera=None, image_size=None, conventions=None, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn _estimate_list<'py>(
        &self,
        py: Python<'py>,
        landmarks: Vec<PyReadonlyArray2<'py, f64>>,
        scheme: Option<&str>,
        method: Option<&str>,
        landmark_style: Option<&str>,
        camera: Camera,
        image_size: Size,
        conventions: Option<&str>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let o = self.options(
            scheme,
            method,
            landmark_style,
            camera,
            image_size,
            conventions,
        )?;
        let faces = landmarks
            .iter()
            .enumerate()
            .map(|(i, f)| {
                points_of(f.as_array()).map_err(|e| {
                    InvalidParameterError::new_err(format!("faces[{i}]: {}", e.value(py)))
                })
            })
            .collect::<PyResult<Vec<_>>>()?;
        self.run_batch(py, faces, o, threads)
    }
}

/// Trains a model from 3D shapes (S, N, 3), mm, model frame (x towards the subject's left, y up,
/// z towards the camera), every point present, in a built-in scheme: the mean by generalized
/// Procrustes analysis, a shape basis of up to `components` principal components (0: none, no
/// `fit-shape`), the regression over `grid`'s views. Like `facepose train --shapes` (without the
/// MediaPipe mesh and the uncertainty calibration).
#[pyfunction]
#[pyo3(signature = (shapes, created, scheme="ibug68", components=40, grid="wide", subsets=None, seed=2011, name="trained", version="1"))]
#[allow(clippy::too_many_arguments)]
pub fn _train(
    py: Python<'_>,
    shapes: PyReadonlyArray3<'_, f64>,
    created: &str,
    scheme: &str,
    components: usize,
    grid: &str,
    subsets: Option<Vec<String>>,
    seed: u64,
    name: &str,
    version: &str,
) -> PyResult<Model> {
    let scheme_def = Scheme::builtin(scheme).ok_or_else(|| {
        core_err(facepose_core::Error::InvalidScheme {
            scheme: scheme.into(),
            reason: format!("built-in schemes: {}", Scheme::builtin_names().join(", ")),
        })
    })?;
    let a = shapes.as_array();
    let (s, n, d) = a.dim();
    if d != 3 || n != scheme_def.len() {
        return Err(InvalidParameterError::new_err(format!(
            "shapes must be an (S, {}, 3) array of 3D points in scheme {scheme}, got shape ({s}, {n}, {d})",
            scheme_def.len()
        )));
    }
    if let Some(((k, i, _), _)) = a.indexed_iter().find(|(_, v)| !v.is_finite()) {
        return Err(core_err(facepose_core::Error::NonFinite {
            what: format!("shape {k} point {i}"),
        }));
    }
    let pop: Vec<Vec<Vector3<f64>>> = a
        .outer_iter()
        .map(|sh| {
            sh.rows()
                .into_iter()
                .map(|r| Vector3::new(r[0], r[1], r[2]))
                .collect()
        })
        .collect();
    let regression = match grid {
        "wide" => RegressionParams::wide(),
        "paper" => RegressionParams::paper(),
        g => {
            return Err(InvalidParameterError::new_err(format!(
                "unknown grid {g:?} (known: wide, paper)"
            )));
        }
    };
    let mut opts = TrainOptions {
        regression,
        seed,
        ..TrainOptions::default()
    };
    if let Some(sub) = subsets {
        opts.subsets = sub;
    }
    let basis = BasisSource::Pca(components);
    let model = py
        .detach(|| train_from_population(&scheme_def, &pop, basis, &opts))
        .map_err(core_err)?;
    let provenance = Provenance {
        sources: vec![],
        command: "facepose.train (Python)".into(),
        notes: format!(
            "{s} shapes given as an array; mean by generalized Procrustes analysis; shape basis: up to {components} principal components of the shapes"
        ),
    };
    let bundle =
        Bundle::from_model(&model, &opts, name, version, created, provenance).map_err(model_err)?;
    Ok(Model {
        inner: Arc::new(Inner { model, bundle }),
    })
}
