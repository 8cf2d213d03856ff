//! What can go wrong with a request, as a type the callers match on: [`ServiceError`]. Each
//! variant carries what a message needs; [`ServiceError::kind`] is its class, which the
//! transports map to an HTTP status and a gRPC code. `Display` is the transport-neutral
//! message; where a message would point the client at a route or an RPC, the transports say it
//! in their own words (`facepose_service::http::error`, `facepose_service::grpc::error`).
//!
//! | kind | HTTP | gRPC |
//! |---|---|---|
//! | `invalid_argument` | 422 | INVALID_ARGUMENT |
//! | `unauthenticated` | 401 | UNAUTHENTICATED |
//! | `forbidden` | 403 | PERMISSION_DENIED |
//! | `not_found` | 404 | NOT_FOUND |
//! | `conflict` | 409 | FAILED_PRECONDITION |
//! | `payload_too_large` | 413 | RESOURCE_EXHAUSTED |
//! | `overloaded` | 429 | UNAVAILABLE |
//! | `timeout` | 503 | DEADLINE_EXCEEDED |
//! | `unavailable` | 503 | UNAVAILABLE |
//! | `internal` | 500 | INTERNAL |

use std::time::Duration;

/// The longest name (model, scheme, method, landmark style) a request may give: every valid
/// one is shorter (model names have at most 64 characters).
pub const MAX_NAME: usize = 64;

/// The longest error message sent to a client, bytes: what a message echoes of a request stays
/// within it, so that a gRPC status fits in a header block any client accepts.
pub const MAX_MESSAGE: usize = 1024;

/// `message` cut to [`MAX_MESSAGE`] bytes (at a character boundary), saying so.
pub fn bounded_message(message: String) -> String {
    if message.len() <= MAX_MESSAGE {
        return message;
    }
    let mut end = MAX_MESSAGE - 40;
    while !message.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}... ({} bytes cut)", &message[..end], message.len() - end)
}

use facepose_core::model::validate::ValidationReport;

use crate::job_state::{JobStage, JobState};

/// The class of an error: fixes the status on both transports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// The request is well-formed but its values are unusable: landmarks, scheme, method,
    /// camera, an upload's fields.
    InvalidArgument,
    /// An admin call without a valid bearer token.
    Unauthenticated,
    /// An admin call on a server with no admin token configured (admin calls disabled).
    Forbidden,
    /// No such model, version or job.
    NotFound,
    /// The registry's state forbids it: deleting the active version, retraining without a
    /// models folder, activating a version that does not load, cancelling a job that ended.
    Conflict,
    /// A body, message or batch over the configured limit.
    PayloadTooLarge,
    /// Too many requests in progress: retry with backoff.
    Overloaded,
    /// The request took longer than the configured limit.
    Timeout,
    /// Not ready or shutting down: retry, possibly on another replica.
    Unavailable,
    /// A bug or a broken volume: the message is logged with the request id.
    Internal,
}

impl ErrorKind {
    /// The snake_case name, in JSON bodies and metrics labels.
    pub fn name(self) -> &'static str {
        match self {
            ErrorKind::InvalidArgument => "invalid_argument",
            ErrorKind::Unauthenticated => "unauthenticated",
            ErrorKind::Forbidden => "forbidden",
            ErrorKind::NotFound => "not_found",
            ErrorKind::Conflict => "conflict",
            ErrorKind::PayloadTooLarge => "payload_too_large",
            ErrorKind::Overloaded => "overloaded",
            ErrorKind::Timeout => "timeout",
            ErrorKind::Unavailable => "unavailable",
            ErrorKind::Internal => "internal",
        }
    }

    /// Whether a client may simply retry (with backoff, possibly elsewhere).
    pub fn is_retryable(self) -> bool {
        matches!(
            self,
            ErrorKind::Overloaded | ErrorKind::Unavailable | ErrorKind::Timeout
        )
    }
}

/// Why an admin call was not authenticated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unauthenticated {
    /// No credentials at all.
    Missing,
    /// Credentials that are not `Bearer <token>`.
    NotBearer,
    /// A bearer token that is not the configured one.
    WrongToken,
    /// More than one `Authorization` header.
    Repeated,
}

/// Why a job cannot be cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotCancellable {
    /// It has ended (in this state).
    Ended(JobState),
    /// It is writing or activating its version.
    Late(JobStage),
}

/// A request's error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ServiceError {
    /// The request's values are unusable; the message names the value and what to fix.
    #[error("{0}")]
    Invalid(String),
    /// An upload with fewer usable shapes than it needs; the report gives the reason of every
    /// drop.
    #[error("{message}")]
    TooFewShapes {
        /// What is wrong, for the caller.
        message: String,
        /// Every shape's fate.
        report: Box<ValidationReport>,
    },
    #[error("unknown model {name:?}; loaded models: {}", loaded.join(", "))]
    /// No loaded model has this name.
    UnknownModel {
        /// The name asked for.
        name: String,
        /// The loaded models' names.
        loaded: Vec<String>,
    },
    /// A scheme the model does not serve, asked for by name as a resource
    /// (`/v1/models/{name}/schemes/{scheme}`); in a pose request an unknown scheme is a value,
    /// `Invalid`.
    #[error(
        "model {model:?} serves no scheme {scheme:?}; it serves {}",
        served.join(", ")
    )]
    UnknownScheme {
        /// The model asked for.
        model: String,
        /// The scheme asked for.
        scheme: String,
        /// The schemes the model serves.
        served: Vec<String>,
    },
    /// No such model folder entry.
    #[error(
        "no model {name:?} in the models folder{}",
        if *has_folder { "" } else { " (the server has no models folder)" }
    )]
    /// The models folder has no model of this name.
    NotInFolder {
        /// The name asked for.
        name: String,
        /// Whether the server has a models folder at all.
        has_folder: bool,
    },
    /// No such version; the message lists the versions there are.
    #[error("{0}")]
    UnknownVersion(String),
    #[error(
        "unknown job {id:?}: no replica sharing this models folder has it (jobs are kept for an \
         hour after they end)"
    )]
    /// No replica knows this job.
    UnknownJob {
        /// The job id asked for.
        id: String,
    },
    /// The job cannot be cancelled any more.
    #[error("{}", not_cancellable(id, why))]
    NotCancellable {
        /// The job's id.
        id: String,
        /// The job's model, whose versions say what a late job wrote.
        model: String,
        /// Why it cannot be cancelled.
        why: NotCancellable,
    },
    /// The models folder's state forbids the change; the message says what to do.
    #[error("{0}")]
    Conflict(String),
    #[error(
        "this server has no models folder, so it cannot store versions: start it with --models \
         DIR (a folder shared by every replica)"
    )]
    /// A change to the models folder on a server without one.
    NoModelsFolder,
    #[error("{faces} faces in one request; the limit is {limit} (--max-batch): split the batch")]
    /// More faces in one request than `--max-batch`.
    BatchTooLarge {
        /// Faces in the request.
        faces: usize,
        /// The limit.
        limit: usize,
    },
    /// A batch refused as it arrived, at face `at_least` (the rest was not read whole).
    #[error(
        "at least {at_least} faces in one request; the limit is {limit} (--max-batch): split the \
         batch"
    )]
    /// More faces than `--max-batch`, found before the whole request was read.
    BatchOverLimit {
        /// Faces counted so far.
        at_least: usize,
        /// The limit.
        limit: usize,
    },
    /// A request body, message or upload over its limit.
    #[error("{}", too_large(what, *size, *limit, flag, hint))]
    TooLarge {
        /// What is too large ("request body", "the upload").
        what: &'static str,
        /// Its size when known.
        size: Option<u64>,
        /// The limit, bytes.
        limit: usize,
        /// The flag that sets the limit.
        flag: &'static str,
        /// What to do.
        hint: &'static str,
    },
    #[error("server busy: {limit} requests already in progress; retry with backoff")]
    /// Every request slot (`--max-concurrency`) is taken.
    Overloaded {
        /// Requests in progress at most.
        limit: usize,
    },
    #[error("server busy: {limit} streams already open (--max-streams); retry with backoff")]
    /// Every stream slot (`--max-streams`) is taken.
    StreamsBusy {
        /// Streams open at most.
        limit: usize,
    },
    #[error(
        "{} retraining jobs are queued or running (--max-queued-jobs {max_queued}); retry later",
        max_queued.saturating_add(1)
    )]
    /// The retraining queue is full.
    QueueFull {
        /// `--max-queued-jobs`.
        max_queued: usize,
    },
    #[error("request took longer than {limit:?} (--request-timeout); send smaller batches")]
    /// The request outran `--request-timeout`.
    Timeout {
        /// The timeout.
        limit: Duration,
    },
    #[error(
        "the upload took longer than {limit:?} to arrive and be checked (--upload-timeout); send \
         fewer shapes per upload or from closer to the server"
    )]
    /// The upload outran `--upload-timeout`.
    UploadTimeout {
        /// The timeout.
        limit: Duration,
    },
    /// A change of the models folder that outlived the request; it completes in the background.
    #[error(
        "the change took longer than {limit:?} (--request-timeout) and goes on in the background"
    )]
    /// A change outran `--request-timeout`; it goes on in the background.
    ChangeTimedOut {
        /// The timeout.
        limit: Duration,
    },
    #[error("server shutting down; retry, possibly on another replica")]
    /// The server is draining.
    ShuttingDown,
    #[error(
        "admin routes are disabled on this server: start it with FACEPOSE_ADMIN_TOKEN or \
         --admin-token-file to enable retraining, activation and deletion"
    )]
    /// An admin route on a server without an admin token.
    AdminDisabled,
    #[error("{}", match .0 {
        Unauthenticated::Missing => "missing admin token: send Authorization: Bearer <token>",
        Unauthenticated::NotBearer => "the Authorization header must be \"Bearer <token>\"",
        Unauthenticated::WrongToken => "invalid admin token",
        Unauthenticated::Repeated => "send one Authorization header: this request has several",
    })]
    /// An admin route without the right token.
    Unauthenticated(Unauthenticated),
    #[error("{0}")]
    /// A failure of the server itself (the message says what).
    Internal(String),
}

fn not_cancellable(id: &str, why: &NotCancellable) -> String {
    match why {
        NotCancellable::Ended(s) => format!(
            "job {id} has already {}; there is nothing to cancel",
            match s {
                JobState::Cancelled => "been cancelled",
                other => other.name(),
            }
        ),
        NotCancellable::Late(stage) => format!(
            "job {id} is {} its version: too late to cancel; once it ends, activate another \
             version or delete this one",
            stage.name()
        ),
    }
}

fn too_large(what: &str, size: Option<u64>, limit: usize, flag: &str, hint: &str) -> String {
    match size {
        Some(n) => {
            format!("{what} of {n} bytes is over the limit of {limit} bytes ({flag}); {hint}")
        }
        None => format!("{what} is over the limit of {limit} bytes ({flag}); {hint}"),
    }
}

impl ServiceError {
    /// An unusable value: 422 / INVALID_ARGUMENT with `message`.
    pub fn invalid(message: impl Into<String>) -> Self {
        ServiceError::Invalid(message.into())
    }

    /// A name a client sent (`what`: "model", "scheme", "method", "landmark style") that is
    /// longer than any valid one: refused without echoing it.
    pub fn check_name_length(what: &str, name: &str) -> Result<(), ServiceError> {
        if name.len() <= MAX_NAME {
            return Ok(());
        }
        Err(ServiceError::Invalid(format!(
            "{what} names have at most {MAX_NAME} characters; this one has {}",
            name.len()
        )))
    }

    /// A bug or a broken volume: 500 / INTERNAL.
    pub fn internal(message: impl Into<String>) -> Self {
        ServiceError::Internal(message.into())
    }

    /// The class of the error.
    pub fn kind(&self) -> ErrorKind {
        use ServiceError as E;
        match self {
            E::Invalid(_) | E::TooFewShapes { .. } => ErrorKind::InvalidArgument,
            E::UnknownModel { .. }
            | E::UnknownScheme { .. }
            | E::NotInFolder { .. }
            | E::UnknownVersion(_)
            | E::UnknownJob { .. } => ErrorKind::NotFound,
            E::NotCancellable { .. } | E::Conflict(_) | E::NoModelsFolder => ErrorKind::Conflict,
            E::BatchTooLarge { .. } | E::BatchOverLimit { .. } | E::TooLarge { .. } => {
                ErrorKind::PayloadTooLarge
            }
            E::Overloaded { .. } | E::QueueFull { .. } => ErrorKind::Overloaded,
            E::Timeout { .. } | E::UploadTimeout { .. } | E::ChangeTimedOut { .. } => {
                ErrorKind::Timeout
            }
            E::ShuttingDown | E::StreamsBusy { .. } => ErrorKind::Unavailable,
            E::AdminDisabled => ErrorKind::Forbidden,
            E::Unauthenticated(_) => ErrorKind::Unauthenticated,
            E::Internal(_) => ErrorKind::Internal,
        }
    }
}

/// Every core error is caused by the request's values (the core never fails on its own
/// state): 422 / INVALID_ARGUMENT, with the core's message.
impl From<facepose_core::Error> for ServiceError {
    fn from(e: facepose_core::Error) -> Self {
        use facepose_core::Error as E;
        ServiceError::Invalid(match &e {
            E::Numerical(_) => format!("could not estimate a pose from these landmarks: {e}"),
            E::NonFinite { .. }
            | E::TooFewPoints { .. }
            | E::PointCount { .. }
            | E::Degenerate(_)
            | E::InvalidParameter { .. }
            | E::InvalidScheme { .. }
            | E::NotAFace { .. }
            | E::Convention(_) => e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_cut_at_a_character_boundary_and_say_so() {
        assert_eq!(bounded_message("short".into()), "short");
        let exact = "x".repeat(MAX_MESSAGE);
        assert_eq!(bounded_message(exact.clone()), exact);
        // Two-byte characters around the cut.
        let long = format!("unknown scheme {:?}", "é".repeat(20_000));
        let cut = bounded_message(long.clone());
        assert!(cut.len() <= MAX_MESSAGE, "{}", cut.len());
        assert!(cut.starts_with("unknown scheme \"éé"));
        assert!(cut.ends_with(&format!(
            "({} bytes cut)",
            long.len() - cut.find("...").unwrap()
        )));
    }

    #[test]
    fn names_longer_than_any_valid_one_are_refused_without_an_echo() {
        assert!(ServiceError::check_name_length("model", &"m".repeat(MAX_NAME)).is_ok());
        let e = ServiceError::check_name_length("scheme", &"s".repeat(20_000)).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::InvalidArgument);
        assert_eq!(
            e.to_string(),
            "scheme names have at most 64 characters; this one has 20000"
        );
    }

    #[test]
    fn core_errors_are_invalid_arguments_with_the_core_message() {
        let e: ServiceError =
            facepose_core::Error::Degenerate("all points are equal".into()).into();
        assert_eq!(e.kind(), ErrorKind::InvalidArgument);
        assert!(e.to_string().contains("all points are equal"), "{e}");
    }

    #[test]
    fn messages_name_the_limit_and_what_to_do() {
        let e = ServiceError::BatchTooLarge { faces: 5, limit: 2 };
        assert_eq!(e.kind(), ErrorKind::PayloadTooLarge);
        assert!(e.to_string().contains("limit is 2"), "{e}");
        let e = ServiceError::QueueFull { max_queued: 1 };
        assert_eq!(e.kind(), ErrorKind::Overloaded);
        assert!(e.to_string().contains("--max-queued-jobs 1"), "{e}");
        assert!(ErrorKind::Overloaded.is_retryable());
        assert!(!ErrorKind::Conflict.is_retryable());
        let late = ServiceError::NotCancellable {
            id: "j".into(),
            model: "m".into(),
            why: NotCancellable::Late(JobStage::Writing),
        };
        assert_eq!(late.kind(), ErrorKind::Conflict);
        assert!(
            late.to_string().contains("is writing its version"),
            "{late}"
        );
    }
}
