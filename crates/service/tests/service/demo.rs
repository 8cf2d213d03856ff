//! The demo page (`GET /demo`, `--demo`): served as HTML under its Content-Security-Policy,
//! self-contained, and gone with `--demo false`. What it does in a browser is checked by
//! scripts/browser-test.sh (headless Chromium).

use facepose_testkit::Endpoint;
use facepose_testkit::server::Server;
use reqwest::StatusCode;
use serde_json::Value;

fn header<'a>(r: &'a reqwest::Response, name: &str) -> &'a str {
    r.headers()
        .get(name)
        .unwrap_or_else(|| panic!("no {name} header: {r:?}"))
        .to_str()
        .unwrap()
}

/// The directives of a Content-Security-Policy: name -> sources.
fn directives(csp: &str) -> std::collections::BTreeMap<&str, Vec<&str>> {
    csp.split(';')
        .filter_map(|d| {
            let mut words = d.split_whitespace();
            Some((words.next()?, words.collect()))
        })
        .collect()
}

#[tokio::test]
async fn the_demo_page_is_html_under_a_strict_policy() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let r = c.get(server.url("/demo")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, "content-type"), "text/html; charset=utf-8");
    assert_eq!(header(&r, "x-content-type-options"), "nosniff");
    assert_eq!(header(&r, "x-frame-options"), "DENY");
    assert_eq!(header(&r, "referrer-policy"), "no-referrer");
    let csp = header(&r, "content-security-policy").to_string();
    let d = directives(&csp);
    assert_eq!(d["default-src"], ["'none'"], "{csp}");
    assert_eq!(d["connect-src"], ["'self'"], "{csp}");
    assert_eq!(d["frame-ancestors"], ["'none'"], "{csp}");
    assert_eq!(d["base-uri"], ["'none'"], "{csp}");
    assert_eq!(d["img-src"], ["data:"], "{csp}");
    for directive in ["script-src", "style-src"] {
        let sources = &d[directive];
        assert_eq!(sources.len(), 1, "{directive}: {csp}");
        assert!(sources[0].starts_with("'sha256-"), "{directive}: {csp}");
    }
    assert!(!csp.contains("unsafe"), "{csp}");
    let html = r.text().await.unwrap();
    assert!(html.starts_with("<!doctype html>"));
    // Self-contained: no URL of another origin, nothing loaded by the markup.
    let lower = html.to_ascii_lowercase();
    for external in ["http://", "https://", " src=", "@import", "url("] {
        assert!(!lower.contains(external), "the page has {external:?}");
    }
    assert_eq!(lower.matches("<script").count(), 1);
    assert_eq!(lower.matches("<style").count(), 1);
    // It calls this server's routes, relative to its own origin.
    for route in [
        "\"/v1/pose\"",
        "\"/v1/models\"",
        "/schemes/",
        "/v1/pose:stream",
    ] {
        assert!(html.contains(route), "{route}");
    }
    // HEAD answers too (a link checker, a proxy's probe), and the page is no API operation.
    let r = c.head(server.url("/demo")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, "content-type"), "text/html; charset=utf-8");
    let doc: Value = c
        .get(server.url("/openapi.json"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert!(doc["paths"].get("/demo").is_none());
    let r = c.post(server.url("/demo")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
}

#[tokio::test]
async fn demo_false_leaves_no_page() {
    let server = Server::start(&["--demo", "false"]);
    let c = reqwest::Client::new();
    let r = c.get(server.url("/demo")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["error"]["code"], "not_found");
    // The API itself is unchanged.
    let r = c
        .get(server.url("/v1/models/default/schemes/five"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
}
