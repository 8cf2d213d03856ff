//! Admin authentication: retraining, activation and deletion need `Authorization: Bearer
//! <token>` (HTTP header or gRPC metadata) with the token configured by `FACEPOSE_ADMIN_TOKEN`
//! or `--admin-token-file`. Read-only routes need nothing.
//!
//! | configured | request | HTTP | gRPC |
//! |---|---|---|---|
//! | no token | any | 403 `forbidden` | PERMISSION_DENIED |
//! | token | no `Authorization`, more than one, not `Bearer`, or a wrong token | 401 `unauthenticated` (`WWW-Authenticate: Bearer`) | UNAUTHENTICATED |
//! | token | the token | the route's answer | |
//!
//! The scheme name is matched without regard to case (`Bearer`, `bearer`, `BEARER`: RFC 9110
//! §11.1), and a request with two `Authorization` headers is refused rather than judged by
//! one of them. The comparison is in constant time: both sides are hashed (SHA-256, so their lengths do not
//! matter either) and the digests compared with `subtle`. The token is never logged, never put
//! in a message, and its `Debug` form is redacted.

use sha2::{Digest, Sha256};
use subtle::ConstantTimeEq;

use crate::error::{ServiceError, Unauthenticated};

/// The shortest token accepted at start.
pub const MIN_TOKEN_LEN: usize = 16;

/// The configured admin token, if any (only its digest is kept).
#[derive(Clone, Default)]
pub struct AdminToken {
    digest: Option<[u8; 32]>,
}

impl std::fmt::Debug for AdminToken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.digest.is_some() {
            "AdminToken(<redacted>)"
        } else {
            "AdminToken(disabled)"
        })
    }
}

impl AdminToken {
    /// No token: admin routes are disabled.
    pub fn disabled() -> Self {
        AdminToken { digest: None }
    }

    /// A token (already checked for length and characters by the configuration).
    pub fn new(token: &str) -> Self {
        AdminToken {
            digest: Some(Sha256::digest(token.as_bytes()).into()),
        }
    }

    /// Whether a token is configured (admin routes enabled).
    pub fn is_enabled(&self) -> bool {
        self.digest.is_some()
    }

    /// Checks the values of a request's `Authorization` headers (or gRPC `authorization`
    /// metadata): exactly one, `Bearer <token>`.
    pub fn check<'a>(
        &self,
        authorization: impl IntoIterator<Item = &'a [u8]>,
    ) -> Result<(), ServiceError> {
        let Some(expected) = &self.digest else {
            return Err(ServiceError::AdminDisabled);
        };
        let mut values = authorization.into_iter();
        let Some(value) = values.next() else {
            return Err(ServiceError::Unauthenticated(Unauthenticated::Missing));
        };
        if values.next().is_some() {
            return Err(ServiceError::Unauthenticated(Unauthenticated::Repeated));
        }
        let token =
            bearer_token(value).ok_or(ServiceError::Unauthenticated(Unauthenticated::NotBearer))?;
        let given: [u8; 32] = Sha256::digest(token).into();
        if bool::from(given.ct_eq(expected)) {
            Ok(())
        } else {
            Err(ServiceError::Unauthenticated(Unauthenticated::WrongToken))
        }
    }
}

/// The credentials of `<scheme> <token>` if the scheme is `Bearer` in any case, trimmed.
fn bearer_token(value: &[u8]) -> Option<&[u8]> {
    let value = value.trim_ascii_start();
    let space = value.iter().position(|&b| b == b' ')?;
    let (scheme, rest) = value.split_at(space);
    scheme
        .eq_ignore_ascii_case(b"bearer")
        .then(|| rest.trim_ascii())
}

/// Checks a token read from the environment or a file: at least [`MIN_TOKEN_LEN`] visible
/// ASCII characters (what fits in a header without escaping).
pub fn check_token(token: &str) -> Result<(), String> {
    if token.len() < MIN_TOKEN_LEN {
        return Err(format!(
            "the admin token has {} characters; use at least {MIN_TOKEN_LEN} (e.g. openssl rand -hex 32)",
            token.len()
        ));
    }
    if !token.bytes().all(|b| b.is_ascii_graphic()) {
        return Err("the admin token must be visible ASCII characters without spaces".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::ErrorKind;

    const TOKEN: &str = "0123456789abcdef-secret";

    #[test]
    fn the_matrix() {
        let off = AdminToken::disabled();
        let on = AdminToken::new(TOKEN);
        let bearer = format!("Bearer {TOKEN}");
        let e = off.check([bearer.as_bytes()]).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Forbidden);
        assert_eq!(on.check([]).unwrap_err().kind(), ErrorKind::Unauthenticated);
        for wrong in [
            "Bearer nope".to_string(),
            format!("Basic {TOKEN}"),
            TOKEN.to_string(),
            format!("Bearer {TOKEN}x"),
            format!("Bearer {}", &TOKEN[1..]),
            "Bearer ".to_string(),
            format!("Bearer{TOKEN}"),
            format!("Bearerx {TOKEN}"),
        ] {
            let e = on.check([wrong.as_bytes()]).unwrap_err();
            assert_eq!(e.kind(), ErrorKind::Unauthenticated, "{wrong}");
            assert!(!e.to_string().contains(TOKEN), "{e}");
        }
        for scheme in ["Bearer", "bearer", "BEARER", "bEaReR"] {
            on.check([format!("{scheme} {TOKEN}").as_bytes()]).unwrap();
        }
        on.check([format!("  Bearer   {TOKEN} ").as_bytes()])
            .unwrap();
        // Two headers are refused, even when one of them is right.
        for pair in [
            [bearer.as_str(), "Bearer nope"],
            ["Bearer nope", bearer.as_str()],
        ] {
            let e = on.check(pair.map(str::as_bytes)).unwrap_err();
            assert_eq!(e, ServiceError::Unauthenticated(Unauthenticated::Repeated));
            assert!(e.to_string().contains("one Authorization header"), "{e}");
        }
        assert!(!format!("{on:?}").contains(TOKEN));
    }

    #[test]
    fn token_rules() {
        assert!(check_token(TOKEN).is_ok());
        assert!(check_token("short").unwrap_err().contains("at least 16"));
        assert!(check_token("with a space in it ok").is_err());
    }
}
