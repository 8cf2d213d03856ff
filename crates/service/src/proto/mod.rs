//! The gRPC code of `proto/facepose/v1/pose.proto` (package `facepose.v1`, server and client):
//! generated into `generated/` by `cargo run -p facepose-protogen`, except [`Face`] and [`Pose`],
//! which are coded by hand ([`hand_coded`]) because every estimate decodes one and encodes the
//! other. The generated code is checked in, so that builds need no protobuf compiler; a test
//! fails when `proto/` no longer matches the digest the generator recorded.

#[allow(clippy::all, missing_docs)]
mod generated {
    include!("generated/facepose.v1.rs");
}

pub mod hand_coded;

pub use generated::*;
pub use hand_coded::{Face, Pose};

/// The encoded file descriptor set, for server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!("generated/facepose_descriptor.bin");

#[cfg(test)]
mod tests {
    use std::path::Path;

    use sha2::{Digest, Sha256};

    /// The `.proto` files as they are now, in the form of `generated/SOURCES.sha256`.
    fn digest_of_sources() -> String {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../proto");
        let mut files: Vec<_> = std::fs::read_dir(root.join("facepose/v1"))
            .expect("proto/facepose/v1 is readable")
            .map(|e| e.expect("a directory entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "proto"))
            .collect();
        files.sort();
        files
            .iter()
            .map(|p| {
                let bytes = std::fs::read(p).expect("a .proto file is readable");
                let hex: String = Sha256::digest(bytes)
                    .iter()
                    .map(|b| format!("{b:02x}"))
                    .collect();
                let name = p.strip_prefix(&root).expect("under proto/").display();
                format!("{hex}  {name}\n")
            })
            .collect()
    }

    #[test]
    fn generated_code_matches_the_proto_files() {
        assert_eq!(
            include_str!("generated/SOURCES.sha256"),
            digest_of_sources(),
            "proto/ changed since crates/service/src/proto/generated/ was made: \
             run `cargo run -p facepose-protogen` and commit the result"
        );
    }
}
