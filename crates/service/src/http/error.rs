//! HTTP's errors: the application's [`ServiceError`] and the errors only HTTP has (a body that
//! is not JSON, an unknown route), each with its status and the JSON body
//! `{"error": {"code": "...", "message": "..."}}`. Messages that point the client somewhere
//! name HTTP routes here; gRPC names its RPCs in its own module.
//!
//! | code | status |
//! |---|---|
//! | `malformed_json` | 400 |
//! | `malformed_path` | 400 |
//! | `unsupported_media_type` | 415 |
//! | `invalid_argument` | 422 |
//! | `unauthenticated` | 401 (with `WWW-Authenticate: Bearer`) |
//! | `forbidden` | 403 |
//! | `not_found` | 404 |
//! | `conflict` | 409 |
//! | `method_not_allowed` | 405 |
//! | `payload_too_large` | 413 |
//! | `overloaded` | 429 (with `Retry-After`) |
//! | `timeout` | 503 (with `Retry-After`) |
//! | `unavailable` | 503 (with `Retry-After`) |
//! | `internal` | 500 |

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use facepose_app::error::{ErrorKind, NotCancellable, ServiceError};
use serde::Serialize;

/// The `code` of an error body.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
#[schema(as = ErrorKind)]
pub enum ErrorCode {
    /// The body is not JSON.
    MalformedJson,
    /// A path segment is not UTF-8 once percent-decoded.
    MalformedPath,
    /// The body is not declared as JSON.
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
    /// Body or batch over the configured limit.
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

impl ErrorCode {
    /// The HTTP status of the code.
    pub fn status(self) -> StatusCode {
        match self {
            ErrorCode::MalformedJson | ErrorCode::MalformedPath => StatusCode::BAD_REQUEST,
            ErrorCode::UnsupportedMediaType => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ErrorCode::InvalidArgument => StatusCode::UNPROCESSABLE_ENTITY,
            ErrorCode::Unauthenticated => StatusCode::UNAUTHORIZED,
            ErrorCode::Forbidden => StatusCode::FORBIDDEN,
            ErrorCode::NotFound => StatusCode::NOT_FOUND,
            ErrorCode::Conflict => StatusCode::CONFLICT,
            ErrorCode::MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            ErrorCode::PayloadTooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            ErrorCode::Overloaded => StatusCode::TOO_MANY_REQUESTS,
            ErrorCode::Timeout | ErrorCode::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
            ErrorCode::Internal => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    fn of(kind: ErrorKind) -> ErrorCode {
        match kind {
            ErrorKind::InvalidArgument => ErrorCode::InvalidArgument,
            ErrorKind::Unauthenticated => ErrorCode::Unauthenticated,
            ErrorKind::Forbidden => ErrorCode::Forbidden,
            ErrorKind::NotFound => ErrorCode::NotFound,
            ErrorKind::Conflict => ErrorCode::Conflict,
            ErrorKind::PayloadTooLarge => ErrorCode::PayloadTooLarge,
            ErrorKind::Overloaded => ErrorCode::Overloaded,
            ErrorKind::Timeout => ErrorCode::Timeout,
            ErrorKind::Unavailable => ErrorCode::Unavailable,
            ErrorKind::Internal => ErrorCode::Internal,
        }
    }
}

/// An error of an HTTP request.
#[derive(Debug, Clone, PartialEq)]
pub enum HttpError {
    /// What the application refused.
    Service(ServiceError),
    /// The body is not JSON (400).
    MalformedJson(String),
    /// The path does not decode (400).
    MalformedPath(String),
    /// The body is not declared as JSON (415).
    UnsupportedMediaType(String),
    /// No route, or no such action on a route (404).
    NotFound(String),
    /// A route without that method (405).
    MethodNotAllowed(String),
}

impl From<ServiceError> for HttpError {
    fn from(e: ServiceError) -> Self {
        HttpError::Service(e)
    }
}

impl From<facepose_core::Error> for HttpError {
    fn from(e: facepose_core::Error) -> Self {
        HttpError::Service(e.into())
    }
}

impl HttpError {
    /// A value the client must fix (422).
    pub fn invalid(message: impl Into<String>) -> Self {
        HttpError::Service(ServiceError::invalid(message))
    }

    /// The error's `code`.
    pub fn code(&self) -> ErrorCode {
        match self {
            HttpError::Service(e) => ErrorCode::of(e.kind()),
            HttpError::MalformedJson(_) => ErrorCode::MalformedJson,
            HttpError::MalformedPath(_) => ErrorCode::MalformedPath,
            HttpError::UnsupportedMediaType(_) => ErrorCode::UnsupportedMediaType,
            HttpError::NotFound(_) => ErrorCode::NotFound,
            HttpError::MethodNotAllowed(_) => ErrorCode::MethodNotAllowed,
        }
    }

    /// The message, in HTTP's words, within
    /// [`MAX_MESSAGE`](facepose_app::error::MAX_MESSAGE).
    pub fn message(&self) -> String {
        facepose_app::error::bounded_message(match self {
            HttpError::Service(e) => message(e),
            HttpError::MalformedJson(m)
            | HttpError::MalformedPath(m)
            | HttpError::UnsupportedMediaType(m)
            | HttpError::NotFound(m)
            | HttpError::MethodNotAllowed(m) => m.clone(),
        })
    }

    /// The error as sent: code, message and details.
    pub fn object(&self) -> ErrorObject {
        ErrorObject {
            code: self.code(),
            message: self.message(),
            details: match self {
                HttpError::Service(ServiceError::TooFewShapes { report, .. }) => {
                    Some(Box::new(serde_json::json!({ "validation": report })))
                }
                _ => None,
            },
        }
    }
}

impl std::fmt::Display for HttpError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.code().name(), self.message())
    }
}

impl ErrorCode {
    /// The snake_case name of the JSON body.
    pub fn name(self) -> &'static str {
        match self {
            ErrorCode::MalformedJson => "malformed_json",
            ErrorCode::MalformedPath => "malformed_path",
            ErrorCode::UnsupportedMediaType => "unsupported_media_type",
            ErrorCode::MethodNotAllowed => "method_not_allowed",
            ErrorCode::InvalidArgument => ErrorKind::InvalidArgument.name(),
            ErrorCode::Unauthenticated => ErrorKind::Unauthenticated.name(),
            ErrorCode::Forbidden => ErrorKind::Forbidden.name(),
            ErrorCode::NotFound => ErrorKind::NotFound.name(),
            ErrorCode::Conflict => ErrorKind::Conflict.name(),
            ErrorCode::PayloadTooLarge => ErrorKind::PayloadTooLarge.name(),
            ErrorCode::Overloaded => ErrorKind::Overloaded.name(),
            ErrorCode::Timeout => ErrorKind::Timeout.name(),
            ErrorCode::Unavailable => ErrorKind::Unavailable.name(),
            ErrorCode::Internal => ErrorKind::Internal.name(),
        }
    }
}

/// An application error in HTTP's words: where a message points the client at a route, it is
/// this API's route.
pub fn message(e: &ServiceError) -> String {
    match e {
        ServiceError::UnknownJob { .. } => {
            format!("{e}; GET /v1/models/{{name}}/versions lists the versions every replica sees")
        }
        ServiceError::NotCancellable {
            model,
            why: NotCancellable::Late(_),
            ..
        } => format!("{e} (/v1/models/{model}/versions)"),
        ServiceError::ChangeTimedOut { .. } => {
            format!("{e}; see GET /v1/models/{{name}}/versions for the outcome")
        }
        _ => e.to_string(),
    }
}

/// One error as sent, in a body or in a batch's result.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
#[schema(as = ApiError)]
pub struct ErrorObject {
    /// The error's kind.
    pub code: ErrorCode,
    /// What went wrong and what to do, for people.
    pub message: String,
    /// Structured details where a list says more than the message: the validation report of
    /// a rejected upload.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub details: Option<Box<serde_json::Value>>,
}

/// The JSON body of every HTTP error: `{"error": {"code": "...", "message": "..."}}`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// The error.
    pub error: ErrorObject,
}

impl IntoResponse for HttpError {
    fn into_response(self) -> Response {
        let code = self.code();
        let status = code.status();
        let body = serde_json::to_vec(&ErrorBody {
            error: self.object(),
        })
        .unwrap_or_default();
        let mut resp = (
            status,
            [(
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            )],
            body,
        )
            .into_response();
        if matches!(
            code,
            ErrorCode::Overloaded | ErrorCode::Unavailable | ErrorCode::Timeout
        ) {
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
    fn the_json_body_has_code_and_message() {
        let e: HttpError = ServiceError::BatchTooLarge { faces: 5, limit: 2 }.into();
        let body = serde_json::to_value(ErrorBody { error: e.object() }).unwrap();
        assert_eq!(body["error"]["code"], "payload_too_large");
        assert_eq!(e.code().status(), StatusCode::PAYLOAD_TOO_LARGE);
        assert!(
            body["error"]["message"]
                .as_str()
                .unwrap()
                .contains("limit is 2")
        );
    }

    #[test]
    fn messages_point_at_http_routes() {
        let e = message(&ServiceError::UnknownJob { id: "x".into() });
        assert!(e.contains("GET /v1/models/{name}/versions"), "{e}");
        let e: HttpError = facepose_core::Error::Degenerate("all points are equal".into()).into();
        assert_eq!(e.code().status(), StatusCode::UNPROCESSABLE_ENTITY);
        assert!(e.message().contains("all points are equal"));
        let e = message(&ServiceError::TooLarge {
            what: "request body",
            size: Some(10),
            limit: 5,
            flag: "--max-body",
            hint: "split the batch",
        });
        assert_eq!(
            e,
            "request body of 10 bytes is over the limit of 5 bytes (--max-body); split the batch"
        );
    }
}
