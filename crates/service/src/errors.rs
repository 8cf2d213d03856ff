//! The one mapping of everything that can go wrong with a request to an HTTP status, a gRPC
//! code and a message saying what to fix. Both transports send the same message.
//!
//! | kind | HTTP | gRPC |
//! |---|---|---|
//! | `malformed_json` | 400 | (n/a) |
//! | `unsupported_media_type` | 415 | (n/a) |
//! | `invalid_argument` | 422 | INVALID_ARGUMENT |
//! | `unauthenticated` | 401 | UNAUTHENTICATED |
//! | `forbidden` | 403 | PERMISSION_DENIED |
//! | `not_found` | 404 | NOT_FOUND |
//! | `conflict` | 409 | FAILED_PRECONDITION |
//! | `method_not_allowed` | 405 | (n/a) |
//! | `payload_too_large` | 413 | RESOURCE_EXHAUSTED |
//! | `overloaded` | 429 | UNAVAILABLE |
//! | `timeout` | 503 | DEADLINE_EXCEEDED |
//! | `unavailable` | 503 | UNAVAILABLE |
//! | `internal` | 500 | INTERNAL |

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

/// What kind of error; fixes the status on both transports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ErrorKind {
    /// The body is not JSON (HTTP only).
    MalformedJson,
    /// The body is not declared as JSON (HTTP only).
    UnsupportedMediaType,
    /// The request is well-formed but its values are unusable: landmarks, scheme, method,
    /// camera, unknown fields.
    InvalidArgument,
    /// An admin route without a valid bearer token.
    Unauthenticated,
    /// An admin route on a server with no admin token configured (admin routes disabled).
    Forbidden,
    /// No such model, version, job or route.
    NotFound,
    /// The registry's state forbids it: deleting the active version, retraining without a
    /// models folder, activating a version that does not load.
    Conflict,
    /// Wrong HTTP method for the route.
    MethodNotAllowed,
    /// Body, message or batch over the configured limit.
    PayloadTooLarge,
    /// Too many requests in progress: retry with backoff.
    Overloaded,
    /// The request took longer than the configured limit.
    Timeout,
    /// Not ready or shutting down: retry, possibly on another replica.
    Unavailable,
    /// A bug: the message is logged with the request id.
    Internal,
}

impl ErrorKind {
    pub fn http_status(self) -> StatusCode {
        match self {
            ErrorKind::MalformedJson => StatusCode::BAD_REQUEST,
            ErrorKind::UnsupportedMediaType => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ErrorKind::InvalidArgument => StatusCode::UNPROCESSABLE_ENTITY,
            ErrorKind::Unauthenticated => StatusCode::UNAUTHORIZED,
            ErrorKind::Forbidden => StatusCode::FORBIDDEN,
            ErrorKind::NotFound => StatusCode::NOT_FOUND,
            ErrorKind::Conflict => StatusCode::CONFLICT,
            ErrorKind::MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            ErrorKind::PayloadTooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            ErrorKind::Overloaded => StatusCode::TOO_MANY_REQUESTS,
            ErrorKind::Timeout | ErrorKind::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
            ErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    pub fn grpc_code(self) -> tonic::Code {
        match self {
            ErrorKind::MalformedJson
            | ErrorKind::UnsupportedMediaType
            | ErrorKind::InvalidArgument => tonic::Code::InvalidArgument,
            ErrorKind::Unauthenticated => tonic::Code::Unauthenticated,
            ErrorKind::Forbidden => tonic::Code::PermissionDenied,
            ErrorKind::NotFound => tonic::Code::NotFound,
            ErrorKind::Conflict => tonic::Code::FailedPrecondition,
            ErrorKind::MethodNotAllowed => tonic::Code::Unimplemented,
            ErrorKind::PayloadTooLarge => tonic::Code::ResourceExhausted,
            ErrorKind::Overloaded | ErrorKind::Unavailable => tonic::Code::Unavailable,
            ErrorKind::Timeout => tonic::Code::DeadlineExceeded,
            ErrorKind::Internal => tonic::Code::Internal,
        }
    }

    /// The snake_case name used in JSON bodies and metrics labels.
    pub fn name(self) -> &'static str {
        match self {
            ErrorKind::MalformedJson => "malformed_json",
            ErrorKind::UnsupportedMediaType => "unsupported_media_type",
            ErrorKind::InvalidArgument => "invalid_argument",
            ErrorKind::Unauthenticated => "unauthenticated",
            ErrorKind::Forbidden => "forbidden",
            ErrorKind::NotFound => "not_found",
            ErrorKind::Conflict => "conflict",
            ErrorKind::MethodNotAllowed => "method_not_allowed",
            ErrorKind::PayloadTooLarge => "payload_too_large",
            ErrorKind::Overloaded => "overloaded",
            ErrorKind::Timeout => "timeout",
            ErrorKind::Unavailable => "unavailable",
            ErrorKind::Internal => "internal",
        }
    }
}

/// A request error: its kind and what to fix.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct ApiError {
    #[serde(rename = "code")]
    pub kind: ErrorKind,
    pub message: String,
    /// Structured details where a list says more than the message (HTTP only): the validation
    /// report of a rejected upload.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub details: Option<Box<serde_json::Value>>,
}

impl ApiError {
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        ApiError {
            kind,
            message: message.into(),
            details: None,
        }
    }

    /// The same error with structured details (sent in HTTP bodies).
    pub fn with_details(mut self, details: serde_json::Value) -> Self {
        self.details = Some(Box::new(details));
        self
    }

    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::InvalidArgument, message)
    }

    /// A batch (or stream frame) with more faces than `--max-batch`.
    pub fn batch_too_large(n: usize, limit: usize) -> Self {
        Self::new(
            ErrorKind::PayloadTooLarge,
            format!(
                "{n} faces in one request; the limit is {limit} (--max-batch): split the batch"
            ),
        )
    }

    pub fn overloaded(limit: usize) -> Self {
        Self::new(
            ErrorKind::Overloaded,
            format!("server busy: {limit} requests already in progress; retry with backoff"),
        )
    }

    pub fn timeout(limit: std::time::Duration) -> Self {
        Self::new(
            ErrorKind::Timeout,
            format!("request took longer than {limit:?} (--request-timeout); send smaller batches"),
        )
    }

    /// A retraining upload over `--upload-timeout`.
    pub fn upload_timeout(limit: std::time::Duration) -> Self {
        Self::new(
            ErrorKind::Timeout,
            format!(
                "the upload took longer than {limit:?} to arrive and be checked (--upload-timeout); \
                 send fewer shapes per upload or from closer to the server"
            ),
        )
    }

    /// A change to the models folder (activation, deletion) that outlived the request's time:
    /// it still completes in the background.
    pub fn change_timeout(limit: std::time::Duration) -> Self {
        Self::new(
            ErrorKind::Timeout,
            format!(
                "the change took longer than {limit:?} (--request-timeout) and goes on in the \
                 background; see GET /v1/models/{{name}}/versions for the outcome"
            ),
        )
    }

    pub fn shutting_down() -> Self {
        Self::new(
            ErrorKind::Unavailable,
            "server shutting down; retry, possibly on another replica",
        )
    }

    pub fn internal(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Internal, message)
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.kind.name(), self.message)
    }
}

/// Every core error is caused by the request's values (the core never fails on its own state):
/// 422 / INVALID_ARGUMENT, with the core's message.
impl From<facepose_core::Error> for ApiError {
    fn from(e: facepose_core::Error) -> Self {
        use facepose_core::Error as E;
        let message = match &e {
            E::Numerical(_) => format!("could not estimate a pose from these landmarks: {e}"),
            E::NonFinite { .. }
            | E::TooFewPoints { .. }
            | E::PointCount { .. }
            | E::Degenerate(_)
            | E::InvalidParameter { .. }
            | E::InvalidScheme { .. } => e.to_string(),
        };
        ApiError::invalid(message)
    }
}

impl From<ApiError> for tonic::Status {
    fn from(e: ApiError) -> Self {
        tonic::Status::new(e.kind.grpc_code(), e.message)
    }
}

/// The JSON body of every HTTP error: `{"error": {"code": "...", "message": "..."}}`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    pub error: ApiError,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.kind.http_status();
        let retry = matches!(
            self.kind,
            ErrorKind::Overloaded | ErrorKind::Unavailable | ErrorKind::Timeout
        );
        let body = serde_json::to_vec(&ErrorBody { error: self }).unwrap_or_default();
        let mut resp = (
            status,
            [(
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            )],
            body,
        )
            .into_response();
        if retry {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from_static("1"));
        }
        if status == StatusCode::UNAUTHORIZED {
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"facepose admin\""),
            );
        }
        resp
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn core_errors_are_invalid_arguments_with_the_core_message() {
        let e: ApiError = facepose_core::Error::Degenerate("all points are equal".into()).into();
        assert_eq!(e.kind.http_status(), StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(e.kind.grpc_code(), tonic::Code::InvalidArgument);
        assert!(e.message.contains("all points are equal"));
        let s: tonic::Status = e.into();
        assert_eq!(s.code(), tonic::Code::InvalidArgument);
        assert!(s.message().contains("all points are equal"));
    }

    #[test]
    fn the_json_body_has_code_and_message() {
        let body = serde_json::to_value(ErrorBody {
            error: ApiError::batch_too_large(5, 2),
        })
        .unwrap();
        assert_eq!(body["error"]["code"], "payload_too_large");
        assert!(
            body["error"]["message"]
                .as_str()
                .unwrap()
                .contains("limit is 2")
        );
    }
}
