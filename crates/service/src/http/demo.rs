//! `GET /demo` (`--demo`, on by default): a page for developers, served by the service itself.
//! A pose explorer (the served model's mean shape projected at a pose the user picks, with
//! noise and missing points, sent to `POST /v1/pose` and drawn against the truth), a box for
//! pasting a face's landmarks, and the request, the response and the `fetch()` code to copy.
//!
//! The page is one HTML file (`crates/service/assets/demo.html`) with its style and script
//! inline, compiled into the binary: no build step, no external assets, so it works offline
//! and can change no other origin's state. It calls only the public read routes and the pose
//! route, on its own origin, as any client could. Its answer carries a Content-Security-Policy
//! that allows exactly that page's one script and one style block (by their SHA-256, computed
//! here once), connections to its own origin only, and no framing.
//!
//! It is outside the OpenAPI document: it is a page, not an operation a client generator
//! should offer.

use std::sync::LazyLock;

use axum::Router;
use axum::http::{HeaderName, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use sha2::{Digest, Sha256};

/// Where the page is served.
pub const PATH: &str = "/demo";

/// The page, as served.
pub const PAGE: &str = include_str!("../../assets/demo.html");

/// The text between the only `<open>` and `</close>` of `html`, or `None` unless there is
/// exactly one such block.
fn only_block<'a>(html: &'a str, open: &str, close: &str) -> Option<&'a str> {
    let mut blocks = html.match_indices(open);
    let (start, _) = blocks.next()?;
    if blocks.next().is_some() {
        return None;
    }
    let body = &html[start + open.len()..];
    let end = body.find(close)?;
    Some(&body[..end])
}

/// Standard base64 with padding (RFC 4648), as CSP hash sources are written.
fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= chunk.len() {
                out.push(char::from(ALPHABET[(n >> shift) as usize & 63]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A CSP hash source for an inline block.
fn sha256_source(text: &str) -> String {
    format!("'sha256-{}'", base64(&Sha256::digest(text.as_bytes())))
}

/// The Content-Security-Policy of `html`: its one inline script and its one inline style by
/// hash, nothing else loaded (images only as `data:` URLs: the page's icon), connections to
/// the page's own origin, no plugins, no framing, no forms, no `<base>`. `None` when the page
/// has not exactly one script and one style block.
pub fn content_security_policy(html: &str) -> Option<String> {
    let script = only_block(html, "<script>", "</script>")?;
    let style = only_block(html, "<style>", "</style>")?;
    Some(format!(
        "default-src 'none'; script-src {}; style-src {}; img-src data:; connect-src 'self'; \
         base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
        sha256_source(script),
        sha256_source(style)
    ))
}

/// The page's CSP, computed once.
static CSP: LazyLock<HeaderValue> = LazyLock::new(|| {
    content_security_policy(PAGE)
        .and_then(|csp| HeaderValue::from_str(&csp).ok())
        // Unreachable with the page compiled in (a unit test checks it); a page that would
        // run nothing is still safer than one without a policy.
        .unwrap_or_else(|| HeaderValue::from_static("default-src 'none'"))
});

/// The demo page.
pub async fn page() -> Response {
    (
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("text/html; charset=utf-8"),
            ),
            (header::CONTENT_SECURITY_POLICY, CSP.clone()),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
            (header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY")),
            (
                header::REFERRER_POLICY,
                HeaderValue::from_static("no-referrer"),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            (
                HeaderName::from_static("cross-origin-opener-policy"),
                HeaderValue::from_static("same-origin"),
            ),
        ],
        PAGE,
    )
        .into_response()
}

/// The page's route, for the HTTP router (stateless: it reads nothing of the server).
pub fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    Router::new().route(PATH, get(page))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_is_rfc_4648() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(input.as_bytes()), want, "{input:?}");
        }
        // The CSP hash of an empty block, as browsers print it in their CSP messages.
        assert_eq!(
            sha256_source(""),
            "'sha256-47DEQpj8HBSa+/TImW+5JCeuQeRkm5NMpJWZG3hSuFU='"
        );
    }

    #[test]
    fn the_policy_hashes_the_pages_one_script_and_one_style() {
        let csp = content_security_policy(PAGE).expect("one <script> and one <style>");
        let script = only_block(PAGE, "<script>", "</script>").unwrap();
        let style = only_block(PAGE, "<style>", "</style>").unwrap();
        assert!(csp.contains(&format!("script-src {};", sha256_source(script))));
        assert!(csp.contains(&format!("style-src {};", sha256_source(style))));
        assert!(csp.starts_with("default-src 'none';"));
        assert!(HeaderValue::from_str(&csp).is_ok());
        // Two scripts, or none, and there is no policy to give.
        assert_eq!(
            content_security_policy("<style></style><script></script><script></script>"),
            None
        );
        assert_eq!(content_security_policy("<style></style>"), None);
        assert_eq!(
            content_security_policy("<style>a</style><script>b</script>").unwrap(),
            format!(
                "default-src 'none'; script-src {}; style-src {}; img-src data:; connect-src \
                 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
                sha256_source("b"),
                sha256_source("a")
            )
        );
    }

    /// What a hash-based policy would block, or what would load from elsewhere: the page must
    /// have none of it (the browser test also watches the console and the requests).
    #[test]
    fn the_page_loads_nothing_from_elsewhere_and_has_no_inline_handlers() {
        let lower = PAGE.to_ascii_lowercase();
        for bad in [
            "http://",
            "https://",
            "//cdn",
            " src=",
            "@import",
            "url(",
            " style=",
            " onclick",
            " onload",
            " oninput",
            " onchange",
            "javascript:",
        ] {
            assert!(!lower.contains(bad), "the page contains {bad:?}");
        }
    }
}
