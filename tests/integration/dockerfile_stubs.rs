//! The Dockerfile builds the dependencies first from the workspace's manifests with empty
//! targets: every bench a crate's Cargo.toml declares needs its stub there, or the image's
//! build fails on a file it cannot find (as it did when `real_faces` was added).

#[test]
fn the_dockerfile_stubs_every_declared_bench() {
    let root = env!("CARGO_MANIFEST_DIR");
    let dockerfile = std::fs::read_to_string(format!("{root}/Dockerfile")).unwrap();
    for krate in ["core", "service"] {
        let manifest =
            std::fs::read_to_string(format!("{root}/crates/{krate}/Cargo.toml")).unwrap();
        let benches = manifest
            .split("[[bench]]")
            .skip(1)
            .filter_map(|s| s.lines().find_map(|l| l.trim().strip_prefix("name = ")))
            .map(|n| n.trim_matches('"').to_string());
        for bench in benches {
            let stubbed = dockerfile.lines().any(|l| {
                (l.contains(&format!("crates/{krate}/benches/{bench}.rs")))
                    || (l.contains(&format!("crates/{krate}/benches/$b.rs"))
                        && l.split(" do ").next().is_some_and(|head| {
                            head.split_whitespace()
                                .any(|w| w.trim_end_matches(';') == bench)
                        }))
            });
            assert!(
                stubbed,
                "Dockerfile: no stub for crates/{krate}/benches/{bench}.rs"
            );
        }
    }
}

/// Every crate of the workspace's default build has its manifest copied and an empty library
/// made in the dependency layer, or the image's first `cargo build` cannot read the workspace
/// (as would have happened when the evaluation and the records left the core).
#[test]
fn the_dockerfile_copies_every_member_manifest() {
    let root = env!("CARGO_MANIFEST_DIR");
    let dockerfile = std::fs::read_to_string(format!("{root}/Dockerfile")).unwrap();
    let workspace = std::fs::read_to_string(format!("{root}/Cargo.toml")).unwrap();
    let members = workspace
        .split("members = [")
        .nth(1)
        .and_then(|s| s.split(']').next())
        .unwrap();
    let stubbed_libs = dockerfile
        .lines()
        .find(|l| l.contains("touch crates/$c/src/lib.rs"))
        .expect("a loop that makes the libraries' stubs");
    for member in members.split(',').map(|m| m.trim().trim_matches('"')) {
        let Some(name) = member.strip_prefix("crates/") else {
            continue;
        };
        assert!(
            dockerfile.contains(&format!("COPY crates/{name}/Cargo.toml crates/{name}/")),
            "Dockerfile: crates/{name}/Cargo.toml is not copied before the dependency build"
        );
        let lib = std::path::Path::new(root).join(member).join("src/lib.rs");
        if lib.exists() {
            assert!(
                stubbed_libs
                    .split_whitespace()
                    .any(|w| w.trim_end_matches(';') == name),
                "Dockerfile: no stub lib.rs for crates/{name}"
            );
        }
    }
}
