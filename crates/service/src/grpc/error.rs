//! gRPC's statuses: the application's [`ServiceError`] as a [`Status`] with the code of its
//! class and a message in gRPC's words (where a message points the client somewhere, it names
//! an RPC or metadata, not an HTTP route), and tonic's own size errors mapped like the rest.

use facepose_app::error::{
    ErrorKind, NotCancellable, ServiceError, Unauthenticated, bounded_message,
};
use tonic::{Code, Status};

/// The code of an error class.
pub fn code(kind: ErrorKind) -> Code {
    match kind {
        ErrorKind::InvalidArgument => Code::InvalidArgument,
        ErrorKind::Unauthenticated => Code::Unauthenticated,
        ErrorKind::Forbidden => Code::PermissionDenied,
        ErrorKind::NotFound => Code::NotFound,
        ErrorKind::Conflict => Code::FailedPrecondition,
        ErrorKind::PayloadTooLarge => Code::ResourceExhausted,
        ErrorKind::Overloaded | ErrorKind::Unavailable => Code::Unavailable,
        ErrorKind::Timeout => Code::DeadlineExceeded,
        ErrorKind::Internal => Code::Internal,
    }
}

/// An application error in gRPC's words, within [`MAX_MESSAGE`](facepose_app::error::MAX_MESSAGE).
pub fn message(e: &ServiceError) -> String {
    bounded_message(words(e))
}

fn words(e: &ServiceError) -> String {
    match e {
        ServiceError::UnknownJob { .. } => {
            format!("{e}; ListVersions lists the versions every replica sees")
        }
        ServiceError::NotCancellable {
            model,
            why: NotCancellable::Late(_),
            ..
        } => format!("{e} (ListVersions of model {model:?})"),
        ServiceError::ChangeTimedOut { .. } => format!("{e}; ListVersions shows the outcome"),
        ServiceError::Unauthenticated(Unauthenticated::Missing) => {
            "missing admin token: send the metadata authorization: Bearer <token>".into()
        }
        ServiceError::Unauthenticated(Unauthenticated::NotBearer) => {
            "the authorization metadata must be \"Bearer <token>\"".into()
        }
        _ => e.to_string(),
    }
}

/// The status of an application error.
pub fn status(e: &ServiceError) -> Status {
    Status::new(code(e.kind()), message(e))
}

/// The standard upper-case name of a code (metrics labels, per-face errors).
pub fn code_name(code: Code) -> &'static str {
    use tonic::Code as C;
    match code {
        C::Ok => "OK",
        C::Cancelled => "CANCELLED",
        C::Unknown => "UNKNOWN",
        C::InvalidArgument => "INVALID_ARGUMENT",
        C::DeadlineExceeded => "DEADLINE_EXCEEDED",
        C::NotFound => "NOT_FOUND",
        C::AlreadyExists => "ALREADY_EXISTS",
        C::PermissionDenied => "PERMISSION_DENIED",
        C::ResourceExhausted => "RESOURCE_EXHAUSTED",
        C::FailedPrecondition => "FAILED_PRECONDITION",
        C::Aborted => "ABORTED",
        C::OutOfRange => "OUT_OF_RANGE",
        C::Unimplemented => "UNIMPLEMENTED",
        C::Internal => "INTERNAL",
        C::Unavailable => "UNAVAILABLE",
        C::DataLoss => "DATA_LOSS",
        C::Unauthenticated => "UNAUTHENTICATED",
    }
}

/// A client-side stream error as the status to end the stream with: tonic's "message too
/// large" (OUT_OF_RANGE) is RESOURCE_EXHAUSTED with the limit, like every other size limit; the
/// codec's statuses lose their mark (`codec::REFUSED_BEFORE_DECODING`).
pub fn inbound_error(status: Status, max_body: usize) -> Status {
    if is_too_large(&status) {
        Status::resource_exhausted(too_large_message(max_body, status.message()))
    } else {
        Status::new(status.code(), bounded_message(status.message().to_string()))
    }
}

/// Whether `status` is tonic's decode-size error.
pub fn is_too_large(status: &Status) -> bool {
    status.code() == Code::OutOfRange && status.message().contains("too large")
}

/// The message of a message over `--max-body` (`max_body` bytes), with tonic's detail.
pub fn too_large_message(max_body: usize, detail: &str) -> String {
    format!("message over the limit of {max_body} bytes (--max-body); split it: {detail}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_point_at_rpcs_not_routes() {
        let s = status(&ServiceError::UnknownJob { id: "x".into() });
        assert_eq!(s.code(), Code::NotFound);
        assert!(s.message().contains("ListVersions"), "{s:?}");
        assert!(!s.message().contains("/v1/"), "{s:?}");
        let s = status(&ServiceError::ChangeTimedOut {
            limit: std::time::Duration::from_secs(1),
        });
        assert_eq!(s.code(), Code::DeadlineExceeded);
        assert!(!s.message().contains("/v1/"), "{s:?}");
        let s = status(&ServiceError::Unauthenticated(Unauthenticated::Missing));
        assert_eq!(s.code(), Code::Unauthenticated);
        assert!(s.message().contains("metadata"), "{s:?}");
        let s = status(&facepose_core::Error::Degenerate("all points are equal".into()).into());
        assert_eq!(s.code(), Code::InvalidArgument);
        assert!(s.message().contains("all points are equal"));
    }
}
