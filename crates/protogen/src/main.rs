//! Regenerates `crates/service/src/proto/generated/` from `proto/facepose/v1/*.proto`:
//!
//! - `facepose.v1.rs`: tonic's server and client and prost's messages, except `Face` and `Pose`,
//!   which the service codes by hand (`hand_coded.rs`), over the service's codec
//!   (`grpc/codec.rs`: prost's, with limits checked before decoding);
//! - `reference/facepose.v1.rs`: prost's derived code for every message, those two included, for
//!   the tests that hold the hand-coded pair to it;
//! - `facepose_descriptor.bin`: the encoded file descriptor set, for gRPC server reflection;
//! - maps (`Convention.params`) are `BTreeMap`s, so that a message encodes to the same bytes
//!   every time (the hand-coded pair's tests compare bytes);
//! - `SOURCES.sha256`: the digest of the `.proto` files it was made from, which a service test
//!   compares with the files in `proto/`, so that an edit without a regeneration fails CI.
//!
//! Run `cargo run -p facepose-protogen` from anywhere in the workspace. protox compiles the
//! `.proto` files in Rust: no system `protoc` is needed.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()?;
    let proto_root = root.join("proto");
    let out = root.join("crates/service/src/proto/generated");
    let protos = proto_files(&proto_root.join("facepose/v1"))?;

    let mut compiler = protox::Compiler::new([&proto_root])?;
    compiler.include_source_info(true).include_imports(true);
    for p in &protos {
        compiler.open_file(p)?;
    }
    std::fs::create_dir_all(out.join("reference"))?;
    std::fs::write(
        out.join("facepose_descriptor.bin"),
        compiler.encode_file_descriptor_set(),
    )?;
    tonic_prost_build::configure()
        .build_client(true)
        .build_server(true)
        .btree_map(".")
        .extern_path(".facepose.v1.Face", "crate::proto::Face")
        .extern_path(".facepose.v1.Pose", "crate::proto::Pose")
        .codec_path("crate::grpc::codec::FaceposeCodec")
        .out_dir(&out)
        .compile_fds(compiler.file_descriptor_set())?;
    tonic_prost_build::configure()
        .build_client(false)
        .build_server(false)
        .btree_map(".")
        .out_dir(out.join("reference"))
        .compile_fds(compiler.file_descriptor_set())?;
    std::fs::write(
        out.join("SOURCES.sha256"),
        sources_digest(&proto_root, &protos)?,
    )?;
    println!("regenerated {}", out.display());
    Ok(())
}

/// The `.proto` files of one folder, sorted.
fn proto_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut protos = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "proto") {
            protos.push(path);
        }
    }
    protos.sort();
    Ok(protos)
}

/// One line per file, `sha256  path` (as `sha256sum` writes it), paths relative to `proto/`.
fn sources_digest(root: &Path, protos: &[PathBuf]) -> std::io::Result<String> {
    let mut text = String::new();
    for p in protos {
        let digest = Sha256::digest(std::fs::read(p)?);
        let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
        let name = p.strip_prefix(root).unwrap_or(p).display();
        text.push_str(&format!("{hex}  {name}\n"));
    }
    Ok(text)
}
