//! The exceptions: `FaceposeError(ValueError)` and one subclass per kind of core error, each
//! with the message the service's 422 answer carries for the same input
//! (`crates/app/src/error.rs`, `impl From<facepose_core::Error> for ServiceError`).

use facepose_core::Error;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::{PyErr, create_exception};

create_exception!(
    facepose,
    FaceposeError,
    PyValueError,
    "What facepose refuses: the input or an option is unusable. The message is the one the service's 422 answer gives for the same input."
);
create_exception!(
    facepose,
    NonFiniteError,
    FaceposeError,
    "A coordinate or parameter is NaN or infinite."
);
create_exception!(
    facepose,
    TooFewPointsError,
    FaceposeError,
    "Fewer points present than the method needs."
);
create_exception!(
    facepose,
    PointCountError,
    FaceposeError,
    "The number of landmarks does not match the scheme."
);
create_exception!(
    facepose,
    DegenerateError,
    FaceposeError,
    "The points are degenerate: all at one place, or on one line."
);
create_exception!(
    facepose,
    InvalidParameterError,
    FaceposeError,
    "An option or a value is outside its valid range (method, camera, image_size, landmarks ...)."
);
create_exception!(
    facepose,
    InvalidSchemeError,
    FaceposeError,
    "An unknown or inconsistent landmark scheme."
);
create_exception!(
    facepose,
    NotAFaceError,
    FaceposeError,
    "The landmarks do not look like a face in their scheme."
);
create_exception!(
    facepose,
    ConventionError,
    FaceposeError,
    "A convention that cannot be answered as asked."
);
create_exception!(
    facepose,
    NumericalError,
    FaceposeError,
    "The estimator could not converge."
);
create_exception!(
    facepose,
    ModelError,
    FaceposeError,
    "A model bundle that cannot be read, validated or written."
);

/// A face's failure: a core error, or a check of the service's own (its message as is).
#[derive(Debug, Clone)]
pub enum FaceError {
    Core(Error),
    /// The service's own checks (name lengths, a method the model lacks, a result that is not
    /// finite): `InvalidParameterError` with this message.
    Invalid(String),
}

impl From<Error> for FaceError {
    fn from(e: Error) -> Self {
        FaceError::Core(e)
    }
}

impl FaceError {
    /// The message of the service's 422 answer.
    pub fn message(&self) -> String {
        match self {
            FaceError::Core(e @ Error::Numerical(_)) => {
                format!("could not estimate a pose from these landmarks: {e}")
            }
            FaceError::Core(e) => e.to_string(),
            FaceError::Invalid(m) => m.clone(),
        }
    }

    pub fn to_pyerr(&self) -> PyErr {
        let m = self.message();
        match self {
            FaceError::Invalid(_) => InvalidParameterError::new_err(m),
            FaceError::Core(e) => match e {
                Error::NonFinite { .. } => NonFiniteError::new_err(m),
                Error::TooFewPoints { .. } => TooFewPointsError::new_err(m),
                Error::PointCount { .. } => PointCountError::new_err(m),
                Error::Degenerate(_) => DegenerateError::new_err(m),
                Error::InvalidParameter { .. } => InvalidParameterError::new_err(m),
                Error::InvalidScheme { .. } => InvalidSchemeError::new_err(m),
                Error::NotAFace { .. } => NotAFaceError::new_err(m),
                Error::Convention(_) => ConventionError::new_err(m),
                Error::Numerical(_) => NumericalError::new_err(m),
            },
        }
    }
}

impl From<FaceError> for PyErr {
    fn from(e: FaceError) -> Self {
        e.to_pyerr()
    }
}

/// A core error as a Python exception.
pub fn core_err(e: Error) -> PyErr {
    FaceError::Core(e).to_pyerr()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("FaceposeError", py.get_type::<FaceposeError>())?;
    m.add("NonFiniteError", py.get_type::<NonFiniteError>())?;
    m.add("TooFewPointsError", py.get_type::<TooFewPointsError>())?;
    m.add("PointCountError", py.get_type::<PointCountError>())?;
    m.add("DegenerateError", py.get_type::<DegenerateError>())?;
    m.add(
        "InvalidParameterError",
        py.get_type::<InvalidParameterError>(),
    )?;
    m.add("InvalidSchemeError", py.get_type::<InvalidSchemeError>())?;
    m.add("NotAFaceError", py.get_type::<NotAFaceError>())?;
    m.add("NumericalError", py.get_type::<NumericalError>())?;
    m.add("ConventionError", py.get_type::<ConventionError>())?;
    m.add("ModelError", py.get_type::<ModelError>())?;
    Ok(())
}
