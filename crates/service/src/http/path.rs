//! Path parameters whose failures answer with the JSON error body, as every other error: axum's
//! own `Path` answers a segment that is not UTF-8 once percent-decoded (`/v1/models/%c0%ae`)
//! with plain text.

use axum::extract::rejection::PathRejection;
use axum::extract::{FromRequestParts, Path};
use axum::http::request::Parts;
use facepose_app::error::ServiceError;
use serde::de::DeserializeOwned;

use super::error::HttpError;

/// A route's path parameters (`Segments(name)`, `Segments((name, version))`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Segments<T>(pub T);

impl<S, T> FromRequestParts<S> for Segments<T>
where
    S: Send + Sync,
    T: DeserializeOwned + Send,
{
    type Rejection = HttpError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, HttpError> {
        match Path::<T>::from_request_parts(parts, state).await {
            Ok(Path(t)) => Ok(Segments(t)),
            Err(PathRejection::FailedToDeserializePathParams(e)) => {
                Err(HttpError::MalformedPath(format!(
                    "{}: percent-encode the UTF-8 bytes of model names, versions and job ids",
                    e.body_text()
                )))
            }
            Err(e) => Err(ServiceError::internal(e.body_text()).into()),
        }
    }
}
