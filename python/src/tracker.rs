//! The stream trackers: per track, the core's Kalman filter on rotations (weighing each frame
//! by its uncertainty) or its One Euro filter. Unlike the service's stream session
//! (`crates/app/src/tracking.rs`), each track's time step is the time since that track's own
//! last update, so a face that skips frames is not stepped by the stream's frame interval.

use std::collections::HashMap;

use facepose_core::geometry::EulerAngles;
use facepose_core::geometry::rotation_kalman::{KalmanParams, RotationKalman};
use facepose_core::geometry::smoothing::{OneEuroParams, RotationOneEuro};
use nalgebra::{Matrix3, Rotation3};
use numpy::IntoPyArray;
use numpy::PyReadonlyArray2;
use numpy::ndarray::Array2;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::errors::{InvalidParameterError, core_err};

/// The time step assumed without timestamps, or when they do not increase, seconds.
pub const DEFAULT_DT: f64 = 1.0 / 30.0;

#[derive(Debug, Clone)]
enum Filter {
    Kalman(Box<RotationKalman>),
    OneEuro(RotationOneEuro),
}

struct Track {
    filter: Filter,
    last_t: Option<f64>,
}

/// Smoothing of head rotations over time, one filter state per track.
#[pyclass(module = "facepose._facepose")]
pub struct _Tracker {
    template: Filter,
    kind: &'static str,
    max_gap: f64,
    tracks: HashMap<String, Track>,
}

fn rotation_of(a: &PyReadonlyArray2<'_, f64>, what: &str) -> PyResult<Matrix3<f64>> {
    let v = a.as_array();
    if v.dim() != (3, 3) {
        return Err(InvalidParameterError::new_err(format!(
            "{what} must be a 3 x 3 array, got shape {:?}",
            v.dim()
        )));
    }
    Ok(Matrix3::from_fn(|i, j| v[(i, j)]))
}

#[pymethods]
impl _Tracker {
    #[new]
    #[pyo3(signature = (kind, params, max_gap))]
    fn new(kind: &str, params: &Bound<'_, PyDict>, max_gap: f64) -> PyResult<Self> {
        let get = |key: &str, default: f64| -> PyResult<f64> {
            match params.get_item(key)? {
                Some(v) => v.extract::<f64>(),
                None => Ok(default),
            }
        };
        let known: &[&str];
        let (template, kind) = match kind {
            "kalman" => {
                known = &[
                    "acceleration_deg_s2",
                    "gate",
                    "max_rejected",
                    "default_sd_deg",
                ];
                let d = KalmanParams::default();
                let max_rejected = match params.get_item("max_rejected")? {
                    Some(v) => v.extract::<u32>()?,
                    None => d.max_rejected,
                };
                let p = KalmanParams {
                    acceleration_deg_s2: get("acceleration_deg_s2", d.acceleration_deg_s2)?,
                    gate: get("gate", d.gate)?,
                    max_rejected,
                    default_sd_deg: get("default_sd_deg", d.default_sd_deg)?,
                };
                (
                    Filter::Kalman(Box::new(RotationKalman::new(p).map_err(core_err)?)),
                    "kalman",
                )
            }
            "one-euro" | "one_euro" => {
                known = &["min_cutoff_hz", "beta", "d_cutoff_hz"];
                let d = OneEuroParams::default();
                let p = OneEuroParams {
                    min_cutoff_hz: get("min_cutoff_hz", d.min_cutoff_hz)?,
                    beta: get("beta", d.beta)?,
                    d_cutoff_hz: get("d_cutoff_hz", d.d_cutoff_hz)?,
                };
                (
                    Filter::OneEuro(RotationOneEuro::new(p).map_err(core_err)?),
                    "one-euro",
                )
            }
            other => {
                return Err(InvalidParameterError::new_err(format!(
                    "invalid parameter smoothing: unknown filter {other:?} (known: kalman, one-euro)"
                )));
            }
        };
        for k in params.keys() {
            let k: String = k.extract()?;
            if !known.contains(&k.as_str()) {
                return Err(InvalidParameterError::new_err(format!(
                    "invalid parameter smoothing: {kind} has no parameter {k:?} (its parameters: {})",
                    known.join(", ")
                )));
            }
        }
        if !(max_gap.is_finite() && max_gap > 0.0) {
            return Err(InvalidParameterError::new_err(format!(
                "invalid parameter max_gap: must be a positive number of seconds, got {max_gap}"
            )));
        }
        Ok(_Tracker {
            template,
            kind,
            max_gap,
            tracks: HashMap::new(),
        })
    }

    #[getter]
    fn kind(&self) -> &'static str {
        self.kind
    }

    /// Filters one rotation of track `key` taken at `t` seconds (None: one frame, 1/30 s, after
    /// the track's last one), with the covariance of its turn (radians², None: the filter's
    /// default). Returns (rotation, yaw, pitch, roll, accepted).
    #[pyo3(signature = (key, rotation, turn_cov, t))]
    fn filter<'py>(
        &mut self,
        py: Python<'py>,
        key: String,
        rotation: PyReadonlyArray2<'py, f64>,
        turn_cov: Option<PyReadonlyArray2<'py, f64>>,
        t: Option<f64>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let r = Rotation3::from_matrix_unchecked(rotation_of(&rotation, "rotation")?);
        let cov = turn_cov
            .as_ref()
            .map(|c| rotation_of(c, "turn_cov"))
            .transpose()?;
        if let Some(t) = t.filter(|t| !t.is_finite()) {
            return Err(InvalidParameterError::new_err(format!(
                "invalid parameter timestamp: {t} is not a finite number of seconds"
            )));
        }
        let template = &self.template;
        let track = self.tracks.entry(key).or_insert_with(|| Track {
            filter: template.clone(),
            last_t: None,
        });
        let dt = match (track.last_t, t) {
            (Some(prev), Some(now)) if now > prev => now - prev,
            _ => DEFAULT_DT,
        };
        if dt > self.max_gap {
            // Unseen for too long: start again at this frame.
            match &mut track.filter {
                Filter::Kalman(k) => k.reset(),
                Filter::OneEuro(e) => e.reset(),
            }
        }
        if t.is_some() {
            track.last_t = t;
        }
        let (out, accepted) = match &mut track.filter {
            Filter::Kalman(k) => {
                let f = k.filter(&r, cov.as_ref(), dt);
                (f.rotation, f.accepted)
            }
            Filter::OneEuro(e) => (e.filter(&r, dt), true),
        };
        let a = EulerAngles::from_rotation(&out);
        let m = Array2::from_shape_fn((3, 3), |(i, j)| out[(i, j)]);
        PyTuple::new(
            py,
            [
                m.into_pyarray(py).into_any(),
                a.yaw.into_pyobject(py)?.into_any(),
                a.pitch.into_pyobject(py)?.into_any(),
                a.roll.into_pyobject(py)?.into_any(),
                pyo3::types::PyBool::new(py, accepted).to_owned().into_any(),
            ],
        )
    }

    /// Forgets one track (False when there was none).
    fn forget(&mut self, key: &str) -> bool {
        self.tracks.remove(key).is_some()
    }

    /// Forgets every track.
    fn reset(&mut self) {
        self.tracks.clear();
    }

    /// The keys of the tracks held.
    fn tracks(&self) -> Vec<String> {
        let mut k: Vec<String> = self.tracks.keys().cloned().collect();
        k.sort();
        k
    }
}
