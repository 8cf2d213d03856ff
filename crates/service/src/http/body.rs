//! Request bodies: the JSON check of `Content-Type`, reading a body up to its limit (an
//! over-limit body is drained within bounds so that the client reads the 413, not a reset),
//! and parsing JSON with the error classes of the API (syntax: 400; values: 422 with the path
//! to the bad value). Response bodies serialized in one allocation.

use axum::body::{Body, Bytes};
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use facepose_app::error::ServiceError;
use http_body_util::BodyExt;
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::error::HttpError;
use super::pose_body::PoseBody;

/// Refuses (415) a request whose `Content-Type` is not JSON.
pub fn require_json(headers: &HeaderMap) -> Result<(), HttpError> {
    let Some(ct) = headers.get(header::CONTENT_TYPE) else {
        return Err(HttpError::UnsupportedMediaType(
            "missing Content-Type: send the body as JSON with Content-Type: application/json"
                .into(),
        ));
    };
    let ct = ct.to_str().unwrap_or("");
    let mime = ct.split(';').next().unwrap_or("").trim();
    let ends = |suffix: &str| {
        mime.len() >= suffix.len()
            && mime.as_bytes()[mime.len() - suffix.len()..].eq_ignore_ascii_case(suffix.as_bytes())
    };
    let starts = |prefix: &str| {
        mime.as_bytes()
            .get(..prefix.len())
            .is_some_and(|p| p.eq_ignore_ascii_case(prefix.as_bytes()))
    };
    if mime.eq_ignore_ascii_case("application/json") || (starts("application/") && ends("+json")) {
        Ok(())
    } else {
        Err(HttpError::UnsupportedMediaType(format!(
            "Content-Type {ct:?} is not JSON: send Content-Type: application/json"
        )))
    }
}

/// A pose body's breach of its limits is answered from this many bytes on: a shorter body's
/// errors come from the parser, which names them precisely (the reader checks every byte, but
/// whatever a body this short holds costs little: the worst, empty faces, under 2 MB parsed).
const GUARD_FROM: usize = 16 * 1024;

/// How much of an over-limit body is read and thrown away before the 413 goes out. Most
/// clients send the whole body before reading the answer (few use `Expect: 100-continue`); a
/// server that answers and closes early makes them see a reset connection instead of the 413.
const DRAIN_LIMIT: u64 = 4 << 20;
/// How long draining an over-limit body may take before the connection is dropped.
const DRAIN_TIME: std::time::Duration = std::time::Duration::from_secs(2);

/// The body, up to `--max-body` bytes (see [`read_body_limited`]).
pub async fn read_body(headers: &HeaderMap, body: Body, limit: usize) -> Result<Bytes, HttpError> {
    read_body_limited(headers, body, limit, "--max-body", "split the batch").await
}

/// The body, up to `limit` bytes: 413 above, its message naming `flag` and saying what to do
/// (`hint`); an over-limit body of up to [`DRAIN_LIMIT`] is drained first so the client reads
/// the answer.
pub async fn read_body_limited(
    headers: &HeaderMap,
    body: Body,
    limit: usize,
    flag: &'static str,
    hint: &'static str,
) -> Result<Bytes, HttpError> {
    read_chunks(headers, body, limit, flag, hint, None).await
}

/// [`read_body`] for a pose body, read by `reader` as it arrives (checked and parsed in one
/// pass): a body that crosses one of its limits is refused there (drained within bounds, as an
/// over-limit body), not read whole.
pub async fn read_pose_body(
    headers: &HeaderMap,
    body: Body,
    limit: usize,
    reader: &mut PoseBody,
) -> Result<Bytes, HttpError> {
    read_chunks(
        headers,
        body,
        limit,
        "--max-body",
        "split the batch",
        Some(reader),
    )
    .await
}

async fn read_chunks(
    headers: &HeaderMap,
    body: Body,
    limit: usize,
    flag: &'static str,
    hint: &'static str,
    mut reader: Option<&mut PoseBody>,
) -> Result<Bytes, HttpError> {
    let too_large = |size: Option<u64>| {
        HttpError::Service(ServiceError::TooLarge {
            what: "request body",
            size,
            limit,
            flag,
            hint,
        })
    };
    let unreadable =
        |e: axum::Error| HttpError::MalformedJson(format!("could not read the request body: {e}"));
    let declared = declared_length(headers);
    if let Some(n) = declared.filter(|&n| n > limit as u64) {
        discard_body(headers, body).await;
        return Err(too_large(Some(n)));
    }
    let mut first: Option<Bytes> = None;
    let mut rest: Vec<u8> = Vec::new();
    let mut body = body;
    while let Some(frame) = body.frame().await {
        let Ok(data) = frame.map_err(unreadable)?.into_data() else {
            continue; // trailers
        };
        // Once a second chunk came, `rest` holds the first one too.
        let before = if rest.is_empty() {
            first.as_ref().map_or(0, Bytes::len)
        } else {
            rest.len()
        };
        let seen = before + data.len();
        if seen > limit {
            drain(body, seen as u64).await;
            return Err(too_large(None));
        }
        if let Some(r) = reader.as_deref_mut()
            && let Err(breach) = r.feed(&data)
            && seen > GUARD_FROM
        {
            // Thrown away unparsed, up to the body limit (what a client sends before it
            // reads the answer), so that it reads the answer rather than a reset.
            drain_up_to(body, seen as u64, DRAIN_LIMIT.max(limit as u64)).await;
            return Err(r.breach_error(breach));
        }
        match &first {
            None => first = Some(data),
            Some(f) => {
                if rest.is_empty() {
                    // What the client declares, within reason: the pages are touched only
                    // as the body arrives, but a guarded body may stop long before.
                    rest.reserve(declared.map_or(2 * f.len(), |n| (n as usize).min(1 << 20)));
                    rest.extend_from_slice(f);
                }
                rest.extend_from_slice(&data);
            }
        }
    }
    Ok(if rest.is_empty() {
        first.unwrap_or_default()
    } else {
        Bytes::from(rest)
    })
}

/// Throws away the body of a request refused before reading it (an admin route without the
/// token, say), within the same bounds as an over-limit body, so that the client reads the
/// answer rather than a reset connection.
pub async fn discard_body(headers: &HeaderMap, body: Body) {
    // A client waiting for `100 Continue` reads the answer without sending the body.
    let waits = headers
        .get(header::EXPECT)
        .is_some_and(|v| v.as_bytes().eq_ignore_ascii_case(b"100-continue"));
    if !waits && declared_length(headers).is_none_or(|n| n <= DRAIN_LIMIT) {
        drain(body, 0).await;
    }
}

/// The body length the request declares (`Content-Length`), if any.
fn declared_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}

/// Reads and discards the rest of a body, up to [`DRAIN_LIMIT`] bytes in all (counting `seen`)
/// and [`DRAIN_TIME`].
async fn drain(body: Body, seen: u64) {
    drain_up_to(body, seen, DRAIN_LIMIT).await;
}

/// [`drain`] up to `max` bytes.
async fn drain_up_to(mut body: Body, mut seen: u64, max: u64) {
    let _ = tokio::time::timeout(DRAIN_TIME, async {
        while seen <= max {
            match body.frame().await {
                Some(Ok(frame)) => {
                    seen += frame.data_ref().map_or(0, |d| d.len() as u64);
                }
                _ => break,
            }
        }
    })
    .await;
}

/// Parses a JSON body. Syntax errors are 400; well-formed JSON with unusable values (wrong
/// types, unknown or missing fields, NaN or infinite numbers) is 422, with the path to the bad
/// value.
pub fn parse_json<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, HttpError> {
    match bytes.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') => {}
        None => return Err(empty_body()),
        // Not an object: say so if it is valid JSON (serde would read an array as a struct).
        Some(_) => {
            if let Err(e) = serde_json::from_slice::<serde::de::IgnoredAny>(bytes) {
                return Err(json_error::<T>(bytes, e));
            }
            return Err(HttpError::invalid(
                "the body must be a JSON object, e.g. {\"landmarks\": [[x, y], ...]}",
            ));
        }
    }
    match serde_json::from_slice::<T>(bytes) {
        Ok(v) => Ok(v),
        Err(e) => Err(json_error::<T>(bytes, e)),
    }
}

fn empty_body() -> HttpError {
    HttpError::MalformedJson(
        "empty request body: send a JSON object, e.g. {\"landmarks\": [[x, y], ...]}".into(),
    )
}

fn json_error<T: DeserializeOwned>(bytes: &[u8], e: serde_json::Error) -> HttpError {
    use serde_json::error::Category;
    match e.classify() {
        Category::Data => HttpError::invalid(format!("{}{e}", error_path::<T>(bytes))),
        Category::Syntax | Category::Eof | Category::Io => {
            let msg = e.to_string();
            if bytes.iter().all(u8::is_ascii_whitespace) {
                empty_body()
            } else if msg.starts_with("number out of range") {
                HttpError::invalid(format!("a number is too large for a 64-bit float ({msg})"))
            } else if non_finite_literal_at(bytes, e.line(), e.column()) {
                HttpError::invalid(format!(
                    "{}NaN and Infinity are not JSON numbers ({msg}): coordinates must be finite; \
                     send null for a missing landmark (and leave out a 3D shape with a point you \
                     do not have)",
                    error_path::<T>(bytes)
                ))
            } else {
                HttpError::MalformedJson(format!("malformed JSON: {msg}"))
            }
        }
    }
}

/// `"path.to[3].value: "` where parsing `bytes` as `T` fails (empty at the top level). Parses
/// again, tracking the path, only on this error path.
fn error_path<T: DeserializeOwned>(bytes: &[u8]) -> String {
    let de = &mut serde_json::Deserializer::from_slice(bytes);
    match serde_path_to_error::deserialize::<_, T>(de) {
        Err(pe) if pe.path().to_string() != "." => format!("{}: ", pe.path()),
        _ => String::new(),
    }
}

/// Whether the text at a 1-based (line, column) error position is a NaN or Infinity literal
/// (as Python's `json.dumps` writes them).
fn non_finite_literal_at(bytes: &[u8], line: usize, column: usize) -> bool {
    let Some(start) = bytes
        .split(|&b| b == b'\n')
        .take(line.saturating_sub(1))
        .map(|l| l.len() + 1)
        .sum::<usize>()
        .checked_add(column.saturating_sub(1))
    else {
        return false;
    };
    let from = start.saturating_sub(1).min(bytes.len());
    let to = (start + 10).min(bytes.len());
    let window = String::from_utf8_lossy(&bytes[from..to]).to_ascii_lowercase();
    window.contains("nan") || window.contains("inf")
}

/// A JSON response (200) from bytes serialized elsewhere.
pub fn json_bytes(body: Vec<u8>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}

/// Room for one pose's JSON: with 68 points and the uncertainty it is about 1,000-1,100 bytes,
/// so one allocation rather than a regrowth and a copy.
pub const ONE_POSE_JSON: usize = 1536;

/// Room for one face's error in a batch's answer (its code, a message of a line and the id).
pub const ONE_ERROR_JSON: usize = 384;

/// `v` as JSON in a buffer made with room for `capacity` bytes (a batch's answer: its faces
/// times [`ONE_POSE_JSON`], rather than a dozen regrowths and copies of up to a megabyte).
pub fn to_json_sized<T: Serialize>(v: &T, capacity: usize) -> Result<Vec<u8>, HttpError> {
    let mut out = Vec::with_capacity(capacity);
    serde_json::to_writer(&mut out, v)
        .map_err(|e| ServiceError::internal(format!("response serialization: {e}")))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::http::error::ErrorCode;
    use crate::http::wire::{BatchRequest, PoseRequest};

    /// A body sent in `chunks` of the given sizes, with its length declared.
    fn chunked(sizes: &[usize]) -> (HeaderMap, Body) {
        let total: usize = sizes.iter().sum();
        let mut headers = HeaderMap::new();
        headers.insert(header::CONTENT_LENGTH, total.into());
        let chunks: Vec<Result<Bytes, std::convert::Infallible>> = sizes
            .iter()
            .map(|&n| Ok(Bytes::from(vec![b' '; n])))
            .collect();
        (
            headers,
            Body::from_stream(futures_util::stream::iter(chunks)),
        )
    }

    #[tokio::test]
    async fn a_body_of_many_chunks_is_held_to_its_length_not_more() {
        // A large first chunk was counted twice once a second one came: a body 100 bytes
        // under the limit was refused.
        for sizes in [&[600, 300][..], &[600, 200, 100], &[900], &[1, 1, 898]] {
            let (headers, body) = chunked(sizes);
            let bytes = read_body(&headers, body, 900).await.unwrap();
            assert_eq!(bytes.len(), 900, "{sizes:?}");
        }
        let (headers, body) = chunked(&[600, 200]);
        assert_eq!(read_body(&headers, body, 1000).await.unwrap().len(), 800);
        let mut headers = HeaderMap::new();
        headers.insert(header::TRANSFER_ENCODING, "chunked".parse().unwrap());
        let chunks: Vec<Result<Bytes, std::convert::Infallible>> = vec![
            Ok(Bytes::from(vec![b' '; 600])),
            Ok(Bytes::from(vec![b' '; 301])),
        ];
        let body = Body::from_stream(futures_util::stream::iter(chunks));
        assert!(read_body(&headers, body, 900).await.is_err());
    }

    #[test]
    fn json_content_types_are_recognized() {
        let with = |ct: &str| {
            let mut h = HeaderMap::new();
            h.insert(header::CONTENT_TYPE, HeaderValue::from_str(ct).unwrap());
            require_json(&h).is_ok()
        };
        for ok in [
            "application/json",
            "Application/JSON; charset=utf-8",
            " application/json ;x=y",
            "application/problem+json",
            "APPLICATION/VND.API+JSON",
        ] {
            assert!(with(ok), "{ok}");
        }
        for bad in [
            "text/plain",
            "application/jsonx",
            "+json",
            "application/",
            "json",
            "",
        ] {
            assert!(!with(bad), "{bad}");
        }
        assert!(require_json(&HeaderMap::new()).is_err());
    }

    #[test]
    fn json_errors_are_classified() {
        let cases: [(&[u8], ErrorCode, &str); 9] = [
            (b"", ErrorCode::MalformedJson, "empty request body"),
            (b"  \n", ErrorCode::MalformedJson, "empty request body"),
            (
                b"{\"landmarks\": [",
                ErrorCode::MalformedJson,
                "malformed JSON",
            ),
            (
                b"{\"landmarks\": [[1, NaN]]}",
                ErrorCode::InvalidArgument,
                "NaN and Infinity",
            ),
            (
                b"{\"landmarks\": [[1, -Infinity]]}",
                ErrorCode::InvalidArgument,
                "NaN and Infinity",
            ),
            (
                b"{\"landmarks\": [[1, 1e999]]}",
                ErrorCode::InvalidArgument,
                "out of range",
            ),
            (
                b"{\"landmarks\": 5}",
                ErrorCode::InvalidArgument,
                "landmarks: expected an array",
            ),
            (
                b"{\"landmarks\": [], \"methd\": 1}",
                ErrorCode::InvalidArgument,
                "unknown field `methd`",
            ),
            (
                b"[1, 2]",
                ErrorCode::InvalidArgument,
                "must be a JSON object",
            ),
        ];
        for (body, kind, want) in cases {
            let e = parse_json::<PoseRequest>(body).unwrap_err();
            assert_eq!(e.code(), kind, "{}: {e}", String::from_utf8_lossy(body));
            assert!(
                e.message().contains(want),
                "{}: {e}",
                String::from_utf8_lossy(body)
            );
        }
        let e = parse_json::<BatchRequest>(b"{\"faces\": [{\"landmarks\": [[1, 2], [3, \"x\"]]}]}")
            .unwrap_err();
        assert!(e.message().starts_with("faces[0].landmarks"), "{e}");
        assert!(e.message().contains("landmark 1 y"), "{e}");
    }
}
