//! facepose for Python: the numeric core (`facepose-core`) behind a small extension module,
//! `facepose._facepose`; the typed API (`Pose`, `PoseBatch`, `estimate`, `Tracker`) is the
//! Python package around it (python/facepose/__init__.py).

// A program around the library: the core's no-I/O rule (clippy.toml) is the core's.
#![allow(clippy::disallowed_methods, clippy::disallowed_types)]

mod errors;
mod face;
mod model;
mod tracker;

use pyo3::prelude::*;

#[pymodule]
fn _facepose(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::register(m)?;
    m.add_class::<model::Model>()?;
    m.add_class::<tracker::_Tracker>()?;
    m.add_function(wrap_pyfunction!(model::_train, m)?)?;
    m.add("DEFAULT_DT", tracker::DEFAULT_DT)?;
    m.add("MAX_NAME", face::MAX_NAME)?;
    Ok(())
}
