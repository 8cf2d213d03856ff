//! The layering of docs/ARCHITECTURE.md, checked: which crate may depend on which, what the
//! core and the service must not link, that the two transports never name each other, and
//! that the application's modules have no import cycles. Each rule here is one a review used
//! to check by reading.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn cargo(args: &[&str]) -> String {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(args)
        .current_dir(root())
        .output()
        .expect("run cargo");
    assert!(
        out.status.success(),
        "cargo {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Each workspace package's normal (not dev, not build) dependencies, by name.
fn normal_dependencies() -> BTreeMap<String, BTreeSet<String>> {
    let meta: Value = serde_json::from_str(&cargo(&[
        "metadata",
        "--no-deps",
        "--format-version",
        "1",
        "--offline",
    ]))
    .unwrap();
    meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["kind"].is_null())
                .map(|d| d["name"].as_str().unwrap().to_string())
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

#[test]
fn crates_depend_only_downwards() {
    let deps = normal_dependencies();
    // Who may use whom among the workspace's crates: the layers of docs/ARCHITECTURE.md.
    let allowed: BTreeMap<&str, &[&str]> = BTreeMap::from([
        ("facepose-core", &[][..]),
        ("facepose-eval", &["facepose-core"][..]),
        ("facepose-files", &["facepose-core"][..]),
        ("facepose-records", &["facepose-core"][..]),
        (
            "facepose-app",
            &["facepose-core", "facepose-files", "facepose-records"][..],
        ),
        (
            "facepose-service",
            &["facepose-core", "facepose-app", "facepose-records"][..],
        ),
        (
            "facepose-testkit",
            &["facepose-core", "facepose-files", "facepose-service"][..],
        ),
        ("facepose-protogen", &[][..]),
        // The Python package: numbers in, poses out, like the CLI's estimate, with no service.
        (
            "facepose-python",
            &["facepose-core", "facepose-files", "facepose-records"][..],
        ),
        (
            "facepose",
            &[
                "facepose-core",
                "facepose-eval",
                "facepose-files",
                "facepose-records",
                "facepose-service",
            ][..],
        ),
    ]);
    assert_eq!(
        deps.keys().map(String::as_str).collect::<BTreeSet<_>>(),
        allowed.keys().copied().collect::<BTreeSet<_>>(),
        "a crate was added or removed: give it its place in the layers here and in ARCHITECTURE.md"
    );
    for (krate, uses) in &deps {
        for dep in uses.iter().filter(|d| d.starts_with("facepose")) {
            assert!(
                allowed[krate.as_str()].contains(&dep.as_str()),
                "{krate} depends on {dep}, which its layer may not use"
            );
        }
    }
    // What a layer must not link, whatever it is for.
    let forbidden: [(&str, &[&str]); 5] = [
        (
            "facepose-core",
            &[
                "tokio", "axum", "hyper", "tonic", "prost", "utoipa", "plotters", "png",
            ],
        ),
        ("facepose-eval", &["tokio", "axum", "hyper", "tonic"]),
        (
            "facepose-app",
            &["axum", "hyper", "tonic", "prost", "nalgebra"],
        ),
        ("facepose-service", &["nalgebra", "plotters", "png"]),
        (
            "facepose-python",
            &["tokio", "axum", "hyper", "tonic", "facepose-service"],
        ),
    ];
    for (krate, bad) in forbidden {
        for b in bad {
            assert!(
                !deps[krate].contains(*b),
                "{krate} depends on {b} (docs/ARCHITECTURE.md says why it must not)"
            );
        }
    }
}

/// `facepose serve` links the service, whose whole dependency tree has no plotting.
#[test]
fn the_service_links_no_plotting() {
    let tree = cargo(&[
        "tree",
        "-p",
        "facepose-service",
        "-e",
        "normal",
        "--prefix",
        "none",
        "--offline",
    ]);
    for line in tree.lines() {
        let name = line.split_whitespace().next().unwrap_or_default();
        assert!(
            !["plotters", "png", "facepose-eval"].contains(&name),
            "facepose-service's tree has {line}"
        );
    }
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(rust_files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out.sort();
    out
}

/// A file's code: comments removed, and its unit tests (a trailing `#[cfg(test)] mod`), which
/// may reach anywhere in their crate.
fn code(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let text = match text.find("#[cfg(test)]\nmod ") {
        Some(i) => &text[..i],
        None => &text[..],
    };
    text.lines()
        .map(|l| l.split("//").next().unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn http_and_grpc_never_name_each_other() {
    let src = root().join("crates/service/src");
    for (dir, other) in [("http", "grpc"), ("grpc", "http")] {
        for file in rust_files(&src.join(dir)) {
            let code = code(&file);
            for path in [
                format!("crate::{other}"),
                format!("super::{other}"),
                format!("super::super::{other}"),
            ] {
                assert!(
                    !code.contains(&path),
                    "{} names {path}: the transports are siblings over the application",
                    file.display()
                );
            }
        }
    }
}

/// The modules a file's code names by path: `crate::m` (for a top-level module) or `super::m`
/// (a sibling), as (level, name).
fn named_modules(code: &str) -> BTreeSet<(&'static str, String)> {
    let mut out = BTreeSet::new();
    for (prefix, level) in [("crate::", "crate"), ("super::", "super")] {
        for piece in code.split(prefix).skip(1) {
            let name: String = piece
                .chars()
                .take_while(|c| c.is_ascii_lowercase() || *c == '_' || c.is_ascii_digit())
                .collect();
            if !name.is_empty() && name != "super" {
                out.insert((level, name));
            }
        }
        // `use crate::{a, b::c}` groups.
        for group in code.split(&format!("{prefix}{{")).skip(1) {
            let inner = group.split('}').next().unwrap_or_default();
            for item in inner.split(',') {
                let name: String = item
                    .trim()
                    .chars()
                    .take_while(|c| c.is_ascii_lowercase() || *c == '_')
                    .collect();
                if !name.is_empty() && name != "self" {
                    out.insert((level, name));
                }
            }
        }
    }
    out
}

/// A cycle in `graph`, if any (depth-first search).
fn cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == node) {
            let mut c = path[i..].to_vec();
            c.push(node.to_string());
            return Some(c);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(c) = visit(next, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|n| visit(n, graph, &mut Vec::new(), &mut done))
}

#[test]
fn the_application_has_no_import_cycles() {
    let src = root().join("crates/app/src");
    // Top-level modules, and the submodules of each folder among themselves.
    let mut graphs: BTreeMap<PathBuf, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for file in rust_files(&src) {
        let rel = file.strip_prefix(&src).unwrap();
        let parts: Vec<String> = rel
            .with_extension("")
            .iter()
            .map(|p| p.to_string_lossy().into_owned())
            .collect();
        // `registry/mod.rs` is module `registry` at the top; `registry/watch.rs` is `watch`
        // inside `registry`.
        let (top, inner) = match parts.as_slice() {
            [m] if m == "lib" => continue,
            [m] => (m.clone(), None),
            [m, sub] if sub == "mod" => (m.clone(), None),
            [m, sub] => (m.clone(), Some(sub.clone())),
            _ => continue,
        };
        for (level, name) in named_modules(&code(&file)) {
            match (level, &inner) {
                ("crate", _) if name != top => {
                    graphs
                        .entry(PathBuf::new())
                        .or_default()
                        .entry(top.clone())
                        .or_default()
                        .insert(name);
                }
                ("super", Some(me)) if name != *me => {
                    graphs
                        .entry(PathBuf::from(&top))
                        .or_default()
                        .entry(me.clone())
                        .or_default()
                        .insert(name);
                }
                _ => {}
            }
        }
    }
    assert!(graphs.contains_key(&PathBuf::new()), "no module read");
    for (folder, graph) in &graphs {
        if let Some(c) = cycle(graph) {
            panic!(
                "import cycle among the app's modules in {}: {}",
                if folder.as_os_str().is_empty() {
                    "crates/app/src".into()
                } else {
                    format!("crates/app/src/{}", folder.display())
                },
                c.join(" -> ")
            );
        }
    }
}
