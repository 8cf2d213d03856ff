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
