//! CORS (`--cors-origins`): which `/v1` routes a page of another origin may call from a browser,
//! answered by tower-http's [`CorsLayer`].
//!
//! Routes are opened per operation, from the OpenAPI document (the list that also gives the
//! routes, [`super::api`]): an operation without a security requirement (pose, the models, the
//! versions, a job) is open to the configured origins, `*` included; an admin operation (it
//! requires `admin_token`: upload, activate, delete, cancel) is open only to origins listed by
//! name, never to `*`, with `authorization` among its allowed headers. No route allows
//! credentials (cookies): the admin token is a header the page itself sets, never ambient.
//! The operational routes (`/healthz`, `/metrics`, ...) and gRPC are not opened.
//!
//! A preflight (`OPTIONS` with `Origin` and `Access-Control-Request-Method`) on a route is
//! answered here, 200, before the limits, the handlers and their admin check; one for an
//! operation that is not opened (or a method the route lacks) gets the same 200 without
//! `access-control-allow-origin`, so the browser refuses the call. A path with no route gets
//! the fallback's 404. Any other `OPTIONS` is the 405 it always was.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::{MatchedPath, Request, State};
use axum::http::header::{
    ACCESS_CONTROL_REQUEST_METHOD, AUTHORIZATION, CONTENT_TYPE, LOCATION, ORIGIN, RETRY_AFTER,
};
use axum::http::{HeaderName, HeaderValue, Method};
use axum::middleware::Next;
use axum::response::Response;
use tower::{Layer, ServiceExt};
use tower_http::cors::{AllowMethods, AllowOrigin, CorsLayer};

use super::middleware::REQUEST_ID;

/// How long a browser may keep a preflight's answer (`access-control-max-age`).
pub const MAX_AGE: Duration = Duration::from_secs(600);

/// The origins of `--cors-origins`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CorsOrigins {
    /// `*`: every origin, on the routes that need no admin token.
    Any,
    /// These origins (as browsers send them: `scheme://host[:port]`), on every `/v1` route.
    List(Vec<HeaderValue>),
}

impl CorsOrigins {
    /// `*`, or origins separated by commas. `None` for an empty text: CORS off.
    pub fn parse(text: &str) -> Result<Option<CorsOrigins>, String> {
        let text = text.trim();
        if text.is_empty() {
            return Ok(None);
        }
        if text == "*" {
            return Ok(Some(CorsOrigins::Any));
        }
        let origins = text
            .split(',')
            .map(|o| parse_origin(o.trim()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Some(CorsOrigins::List(origins)))
    }
}

/// One origin, checked to be what a browser sends in `Origin`, so that it can match one.
fn parse_origin(o: &str) -> Result<HeaderValue, String> {
    if o.is_empty() {
        return Err("an empty origin in the list (a stray comma?)".into());
    }
    if o == "*" {
        return Err(
            "\"*\" stands alone: give either \"*\" (every origin, routes without the admin \
             token) or a list of origins"
                .into(),
        );
    }
    let form = "write scheme://host[:port], e.g. https://app.example.com";
    let Some((scheme, rest)) = o.split_once("://") else {
        return Err(format!("{o:?} is not an origin: {form}"));
    };
    let scheme_ok = scheme.starts_with(|c: char| c.is_ascii_lowercase())
        && scheme
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || "+-.".contains(c));
    if !scheme_ok {
        return Err(format!(
            "{o:?}: the scheme {scheme:?} is not a lower-case URL scheme (browsers send \
             e.g. https): {form}"
        ));
    }
    if let Some(i) = rest.find(['/', '?', '#']) {
        return Err(format!(
            "{o:?}: an origin has no path, query or fragment: write \"{scheme}://{}\"",
            &rest[..i]
        ));
    }
    if rest.contains('@') {
        return Err(format!("{o:?}: an origin has no user name: {form}"));
    }
    let (host, port) = match rest.strip_prefix('[') {
        Some(v6) => {
            let (addr, after) = v6
                .split_once(']')
                .ok_or_else(|| format!("{o:?}: an IPv6 host without its closing ]"))?;
            if addr.parse::<std::net::Ipv6Addr>().is_err() {
                return Err(format!("{o:?}: [{addr}] is not an IPv6 address"));
            }
            match after {
                "" => (&rest[..addr.len() + 2], None),
                p => match p.strip_prefix(':') {
                    Some(p) => (&rest[..addr.len() + 2], Some(p)),
                    None => return Err(format!("{o:?}: {p:?} after the IPv6 host: {form}")),
                },
            }
        }
        None => match rest.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (rest, None),
        },
    };
    if !host.starts_with('[') {
        let host_ok = !host.is_empty()
            && !host.starts_with(['.', '-'])
            && host
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-' || c == '.');
        if !host_ok {
            let hint = if host.chars().any(|c| c.is_ascii_uppercase()) {
                " (browsers send host names in lower case)"
            } else {
                ""
            };
            return Err(format!("{o:?}: {host:?} is not a host name{hint}: {form}"));
        }
    }
    if let Some(p) = port {
        let n = p
            .parse::<u16>()
            .ok()
            .filter(|&n| n > 0 && p.bytes().all(|b| b.is_ascii_digit()))
            .ok_or_else(|| format!("{o:?}: the port {p:?} is not a number from 1 to 65535"))?;
        if (scheme, n) == ("http", 80) || (scheme, n) == ("https", 443) {
            return Err(format!(
                "{o:?}: browsers leave the default port out of an origin: write \
                 \"{scheme}://{host}\""
            ));
        }
    }
    HeaderValue::from_str(o).map_err(|_| format!("{o:?} is not a header value"))
}

/// Who may call an operation from another origin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Access {
    /// No admin token: the configured origins, `*` included.
    Public,
    /// The admin token: origins listed by name only.
    Admin,
}

/// The CORS answers of the HTTP routes: the operations of each `/v1` route template and the
/// layer that answers for each [`Access`].
pub struct CorsPolicy {
    routes: HashMap<String, Vec<(Method, Access)>>,
    /// The origins listed by name; `None` for `*`.
    listed: Option<Vec<HeaderValue>>,
    public: CorsLayer,
    /// `None` with `*`: the admin routes are then answered by `closed`.
    admin: Option<CorsLayer>,
    /// Allows no origin: the answer to a preflight for an operation that is not opened.
    closed: CorsLayer,
}

impl CorsPolicy {
    /// The policy of `origins` over the operations of `doc` (the HTTP router's own document).
    pub fn new(doc: &utoipa::openapi::OpenApi, origins: &CorsOrigins) -> CorsPolicy {
        let mut routes: HashMap<String, Vec<(Method, Access)>> = HashMap::new();
        for (path, item) in doc.paths.paths.iter() {
            if !path.starts_with("/v1/") {
                continue;
            }
            let ops = [
                (Method::GET, &item.get),
                (Method::POST, &item.post),
                (Method::PUT, &item.put),
                (Method::PATCH, &item.patch),
                (Method::DELETE, &item.delete),
            ];
            for (method, op) in ops {
                let Some(op) = op else { continue };
                let admin = op.security.as_ref().is_some_and(|s| !s.is_empty());
                let access = if admin { Access::Admin } else { Access::Public };
                routes
                    .entry(path.clone())
                    .or_default()
                    .push((method, access));
            }
        }
        let request_id = HeaderName::from_static(REQUEST_ID);
        let base = CorsLayer::new()
            // The requested method, once it is known to be an operation of the route.
            .allow_methods(AllowMethods::mirror_request())
            .max_age(MAX_AGE);
        let public = base
            .clone()
            .allow_headers([CONTENT_TYPE, request_id.clone()])
            .expose_headers([request_id.clone(), RETRY_AFTER]);
        let (public, admin) = match origins {
            CorsOrigins::Any => (public.allow_origin(AllowOrigin::any()), None),
            CorsOrigins::List(list) => (
                public.allow_origin(AllowOrigin::list(list.iter().cloned())),
                Some(
                    base.allow_origin(AllowOrigin::list(list.iter().cloned()))
                        .allow_headers([AUTHORIZATION, CONTENT_TYPE, request_id.clone()])
                        .expose_headers([request_id, RETRY_AFTER, LOCATION]),
                ),
            ),
        };
        CorsPolicy {
            routes,
            listed: match origins {
                CorsOrigins::Any => None,
                CorsOrigins::List(list) => Some(list.clone()),
            },
            public,
            admin,
            // Its answers too depend on the origin and the method asked for (for caches).
            closed: CorsLayer::new().vary([ORIGIN, ACCESS_CONTROL_REQUEST_METHOD]),
        }
    }

    /// The layer that answers `req`, or `None` when CORS has nothing to do with it (a route
    /// not opened, an `OPTIONS` that is not a preflight, a method the route does not have).
    fn layer_for(&self, req: &Request) -> Option<&CorsLayer> {
        let ops = self
            .routes
            .get(req.extensions().get::<MatchedPath>()?.as_str())?;
        let headers = req.headers();
        let preflight = req.method() == Method::OPTIONS;
        let method = if preflight {
            if !headers.contains_key(ORIGIN) {
                return None;
            }
            let requested = headers.get(ACCESS_CONTROL_REQUEST_METHOD)?;
            Method::from_bytes(requested.as_bytes()).ok()
        } else {
            Some(req.method().clone())
        };
        // HEAD is answered by the GET routes.
        let method = method.map(|m| if m == Method::HEAD { Method::GET } else { m });
        let access = ops
            .iter()
            .find(|(m, _)| Some(m) == method.as_ref())
            .map(|&(_, a)| a);
        // An origin not listed learns nothing, not even the headers the route would allow.
        let listed = match (&self.listed, headers.get(ORIGIN)) {
            (Some(list), Some(origin)) => list.contains(origin),
            _ => true,
        };
        match access {
            Some(_) if !listed => Some(&self.closed),
            Some(Access::Public) => Some(&self.public),
            Some(Access::Admin) => Some(self.admin.as_ref().unwrap_or(&self.closed)),
            None if preflight => Some(&self.closed),
            None => None,
        }
    }
}

/// `router` (the HTTP routes, before the gRPC ones join them) with `policy` on its routes. The
/// layer sits inside the routing, where the route template is known, and outside each route's
/// limits and handler, so a preflight takes no permit and never meets the admin check.
pub fn layer(router: Router, policy: CorsPolicy) -> Router {
    router.layer(axum::middleware::from_fn_with_state(
        Arc::new(policy),
        answer,
    ))
}

async fn answer(State(policy): State<Arc<CorsPolicy>>, req: Request, next: Next) -> Response {
    match policy.layer_for(&req) {
        Some(cors) => match cors.layer(next).oneshot(req).await {
            Ok(resp) => resp,
            Err(never) => match never {},
        },
        None => next.run(req).await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn origins(text: &str) -> Result<Option<CorsOrigins>, String> {
        CorsOrigins::parse(text)
    }

    #[test]
    fn origins_parse() {
        assert_eq!(origins("").unwrap(), None);
        assert_eq!(origins(" * ").unwrap(), Some(CorsOrigins::Any));
        let list = [
            "https://app.example.com",
            "http://localhost:3000",
            "http://127.0.0.1:8080",
            "http://[::1]:5173",
            "https://[2001:db8::1]",
            "chrome-extension://abcdefghijklmnop",
        ];
        let Some(CorsOrigins::List(got)) = origins(&list.join(" , ")).unwrap() else {
            panic!("not a list")
        };
        assert_eq!(got, list.map(HeaderValue::from_static));
    }

    #[test]
    fn bad_origins_say_what_to_write() {
        for (text, want) in [
            (
                "https://app.example.com/",
                "write \"https://app.example.com\"",
            ),
            ("https://a.example/x?y", "write \"https://a.example\""),
            (
                "app.example.com",
                "is not an origin: write scheme://host[:port]",
            ),
            ("https://a.example,", "an empty origin in the list"),
            ("*,https://a.example", "\"*\" stands alone"),
            ("https://a.example, *", "\"*\" stands alone"),
            (
                "https://App.example",
                "browsers send host names in lower case",
            ),
            ("HTTPS://a.example", "is not a lower-case URL scheme"),
            ("https://a.example:443", "write \"https://a.example\""),
            ("http://localhost:80", "write \"http://localhost\""),
            (
                "http://localhost:0",
                "the port \"0\" is not a number from 1 to 65535",
            ),
            ("http://localhost:99999", "is not a number from 1 to 65535"),
            ("http://localhost:", "the port \"\""),
            ("https://user@a.example", "no user name"),
            ("http://[::1", "without its closing ]"),
            ("http://[nope]:80", "is not an IPv6 address"),
            ("https://", "\"\" is not a host name"),
            ("https://a_b.example", "is not a host name"),
            ("null", "is not an origin"),
        ] {
            let e = origins(text).unwrap_err();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    /// The operations each `/v1` route opens, from the served document, against the API's
    /// list of admin routes (docs/API.md).
    #[test]
    fn admin_operations_are_the_ones_with_the_token() {
        let doc = super::super::tests::document_of();
        let policy = CorsPolicy::new(&doc, &CorsOrigins::Any);
        let mut admin: Vec<String> = Vec::new();
        let mut public: Vec<String> = Vec::new();
        for (path, ops) in &policy.routes {
            for (m, a) in ops {
                let op = format!("{m} {path}");
                match a {
                    Access::Admin => admin.push(op),
                    Access::Public => public.push(op),
                }
            }
        }
        admin.sort();
        public.sort();
        assert_eq!(
            admin,
            [
                "DELETE /v1/models/{name}/versions/{version}",
                "POST /v1/models",
                "POST /v1/models/jobs/{id}",
                "POST /v1/models/{name}/versions/{version}",
            ]
        );
        assert_eq!(
            public,
            [
                "GET /v1/models",
                "GET /v1/models/jobs/{id}",
                "GET /v1/models/{name}",
                "GET /v1/models/{name}/schemes/{scheme}",
                "GET /v1/models/{name}/versions",
                "POST /v1/pose",
                "POST /v1/pose:batch",
            ]
        );
        assert!(policy.admin.is_none());
    }
}
