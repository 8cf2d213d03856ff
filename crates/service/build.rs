//! Compiles `proto/facepose/v1/*.proto` with protox (pure Rust: no system protoc) into the
//! tonic/prost code of `facepose_service::proto`, and keeps the encoded file descriptor set
//! (`$OUT_DIR/facepose_descriptor.bin`) for gRPC server reflection.
//!
//! `Face` and `Pose` are not generated: `src/proto/hand_coded.rs` codes them by hand
//! for speed. prost's derived code for every message, those two included, is also written to
//! `$OUT_DIR/reference/` for the tests that hold the hand-coded pair to it.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=../../proto");
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    let mut protos: Vec<PathBuf> = std::fs::read_dir("../../proto/facepose/v1")?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "proto"))
        .collect();
    protos.sort();
    let mut compiler = protox::Compiler::new(["../../proto"])?;
    compiler.include_source_info(true).include_imports(true);
    for p in &protos {
        compiler.open_file(p)?;
    }
    std::fs::write(
        out.join("facepose_descriptor.bin"),
        compiler.encode_file_descriptor_set(),
    )?;
    tonic_prost_build::configure()
        .build_client(true)
        .build_server(true)
        .extern_path(".facepose.v1.Face", "crate::proto::Face")
        .extern_path(".facepose.v1.Pose", "crate::proto::Pose")
        .compile_fds(compiler.file_descriptor_set())?;
    let reference = out.join("reference");
    std::fs::create_dir_all(&reference)?;
    tonic_prost_build::configure()
        .build_client(false)
        .build_server(false)
        .out_dir(&reference)
        .compile_fds(compiler.file_descriptor_set())?;
    Ok(())
}
