//! The method table (`facepose_core::pose::METHODS`) and the scheme table
//! (`facepose_core::shape::BUILTIN_SCHEMES`) are the one place each method and scheme is
//! written; code reads them. What cannot read them (prose, the .proto comments, the CLI's
//! defaults) is held to them here, so that a row added to a table without its docs fails.

use std::process::Command;

use facepose_core::model::mesh::{MEDIAPIPE468, MEDIAPIPE478};
use facepose_core::pose::{METHODS, Method};
use facepose_core::shape::builtin::{BUILTIN_SCHEMES, Served};

fn text(rel: &str) -> String {
    std::fs::read_to_string(format!("{}/{rel}", env!("CARGO_MANIFEST_DIR")))
        .unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_facepose"))
        .args(args)
        .output()
        .expect("run facepose");
    String::from_utf8(out.stdout).unwrap()
}

/// The part of `doc` from `heading` to the next heading of the same level.
fn section<'a>(doc: &'a str, heading: &str) -> &'a str {
    let start = doc
        .find(heading)
        .unwrap_or_else(|| panic!("no section {heading:?}"));
    let level = heading.split(' ').next().unwrap();
    let rest = &doc[start + heading.len()..];
    let end = rest
        .find(&format!("\n{level} "))
        .map_or(rest.len(), |e| e + 1);
    &rest[..end]
}

#[test]
fn every_method_is_documented_where_the_table_cannot_reach() {
    let readme = text("README.md");
    let methods_section = section(&readme, "## Methods");
    let api = text("docs/API.md");
    let proto = text("proto/facepose/v1/pose.proto");
    let estimate_help = help(&["estimate", "-h"]);
    let eval_help = help(&["eval", "--help"]);
    let proto_list = Method::NAMES.join(" | ");
    assert!(
        proto.contains(&format!("// {proto_list}; empty: auto.")),
        "pose.proto's method comment is not `{proto_list}; empty: auto.`"
    );
    for m in &METHODS {
        let quoted = format!("`{}`", m.name);
        if m.method != Method::Auto {
            assert!(
                methods_section.contains(&format!("- {quoted}")),
                "README's Methods section has no item for {quoted}"
            );
        }
        assert!(api.contains(&quoted), "docs/API.md never names {quoted}");
        assert!(
            estimate_help.contains(m.name),
            "`facepose estimate -h` does not list {}",
            m.name
        );
        // `eval` evaluates every method unless told otherwise.
        let default = eval_help
            .split("--methods")
            .nth(1)
            .and_then(|s| s.split("[default: ").nth(1))
            .and_then(|s| s.split(']').next())
            .unwrap_or_default();
        assert!(
            default.split(',').any(|d| d == m.name),
            "`facepose eval --methods` does not default to every method: {default}"
        );
    }
}

#[test]
fn every_builtin_scheme_is_documented_where_the_table_cannot_reach() {
    let readme = text("README.md");
    let api = text("docs/API.md");
    let formats = text("docs/FORMATS.md");
    let proto = text("proto/facepose/v1/pose.proto");
    let estimate_help = help(&["estimate", "--help"]);
    let wire = text("crates/service/src/http/wire.rs");
    let readme_usage = format!(
        "[--scheme {}]",
        BUILTIN_SCHEMES
            .iter()
            .map(|b| b.name)
            .collect::<Vec<_>>()
            .join("|")
    );
    assert!(
        readme.contains(&readme_usage),
        "README's estimate usage does not read {readme_usage}"
    );
    for b in &BUILTIN_SCHEMES {
        for (what, doc) in [
            ("docs/API.md", &api),
            ("docs/FORMATS.md", &formats),
            ("pose.proto", &proto),
            ("`facepose estimate --help`", &estimate_help),
            ("the HTTP request's scheme field (wire.rs)", &wire),
        ] {
            assert!(doc.contains(b.name), "{what} never names scheme {}", b.name);
        }
        if b.served == Served::Mesh {
            assert!(
                [MEDIAPIPE468, MEDIAPIPE478].contains(&b.name),
                "{} is served by the mesh, which builds only {MEDIAPIPE468} and {MEDIAPIPE478}",
                b.name
            );
        }
    }
}
