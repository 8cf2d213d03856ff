//! Typed errors of the numeric core. Every public function of the core returns these instead of
//! panicking; the service maps each variant to a precise HTTP / gRPC status.

use thiserror::Error;

/// What went wrong in the numeric core. Messages say what the caller should fix.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Error {
    /// A coordinate or parameter is NaN or infinite.
    #[error("{what} is not a finite number (NaN or infinity)")]
    NonFinite {
        /// What was not finite.
        what: String,
    },

    /// Fewer usable points than the operation needs.
    #[error("{what}: needs at least {needed} points present, got {got}")]
    TooFewPoints {
        /// What the points are for.
        what: String,
        /// Points needed at least.
        needed: usize,
        /// Points present.
        got: usize,
    },

    /// The number of points does not match the scheme or the other operand.
    #[error("{what}: expected {expected} points, got {got}")]
    PointCount {
        /// What the points are for.
        what: String,
        /// Points expected.
        expected: usize,
        /// Points given.
        got: usize,
    },

    /// The points are degenerate for the operation (all equal, collinear, zero spread ...).
    #[error("degenerate input: {0}")]
    Degenerate(String),

    /// A parameter is outside its valid range.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// The parameter's name.
        name: String,
        /// Why it is invalid.
        reason: String,
    },

    /// A landmark scheme definition is inconsistent.
    #[error("invalid landmark scheme {scheme:?}: {reason}")]
    InvalidScheme {
        /// The scheme's name.
        scheme: String,
        /// What is inconsistent.
        reason: String,
    },

    /// The landmarks do not look like a face in their scheme: the best fit of the face leaves
    /// most of their spread unexplained (a wrong scheme, a wrong point order, or not a face).
    #[error(
        "the landmarks do not look like a face in scheme {scheme}: the best fit of the face \
         leaves {pct:.0}% of their spread unexplained (real faces stay below 25%; the limit is \
         {limit:.0}%); check the scheme and the order of the points (MediaPipe's are \
         mediapipe468 or mediapipe478, not ibug68), and that x, y are the pixels of one face",
        pct = misfit * 100.0,
        limit = limit * 100.0
    )]
    NotAFace {
        /// The landmarks' scheme.
        scheme: String,
        /// The share of the landmarks' spread the fit leaves unexplained (0 to 1).
        misfit: f64,
        /// The share refused above (0 to 1).
        limit: f64,
    },

    /// A requested answer convention cannot be given (`geometry::convention`). Boxed: its
    /// messages' parts would double the size of every `Result` of the core.
    #[error(transparent)]
    Convention(Box<crate::geometry::convention::ConventionError>),

    /// An iterative solver failed to converge or a decomposition failed.
    #[error("numerical failure: {0}")]
    Numerical(String),
}

impl From<crate::geometry::convention::ConventionError> for Error {
    fn from(e: crate::geometry::convention::ConventionError) -> Self {
        Error::Convention(Box::new(e))
    }
}

impl Error {
    /// [`Error::NonFinite`] for `what`.
    pub fn non_finite(what: impl Into<String>) -> Self {
        Error::NonFinite { what: what.into() }
    }

    /// [`Error::TooFewPoints`]: `what` needs `needed` and has `got`.
    pub fn too_few(what: impl Into<String>, needed: usize, got: usize) -> Self {
        Error::TooFewPoints {
            what: what.into(),
            needed,
            got,
        }
    }

    /// [`Error::InvalidParameter`]: parameter `name` is wrong for `reason`.
    pub fn param(name: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::InvalidParameter {
            name: name.into(),
            reason: reason.into(),
        }
    }
}

/// Result with the core's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Fails with [`Error::NonFinite`] unless every value is finite.
pub(crate) fn ensure_finite<'a>(
    what: &str,
    values: impl IntoIterator<Item = &'a f64>,
) -> Result<()> {
    if values.into_iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::non_finite(what))
    }
}
