#!/usr/bin/env bash
# Instructions per parse of one 68-point `/v1/pose` body (callgrind): the service's one-pass
# reader against serde's derived reader on serde_json (with and without its `float_roundtrip`
# feature, which the model bundles need) and on simd-json. The alternatives are built as
# throwaway crates in a temporary folder (one each: a Cargo feature applies to a whole build),
# around the same request type with the landmarks as `Vec<Option<[f64; 2]>>`. Each figure is
# (CALLS parses - no parse) / CALLS; for the throwaway crates both runs copy the body once per
# call (simd-json parses in place), so the copy cancels out.
#
#   scripts/json-compare.sh          # CALLS=2000
#
# Installs valgrind if missing. Not part of CI. The figures that kept the hand-written reader are
# in docs/performance-notes.md.
set -euo pipefail
cd "$(dirname "$0")/.."
CALLS=${CALLS:-2000}
if ! command -v valgrind >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get install -y valgrind >/dev/null 2>&1 ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y valgrind >/dev/null; }
fi
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
count() {
    valgrind --tool=callgrind --callgrind-out-file="$WORK/cg.out" "$@" 2>&1 |
        awk '/Collected/ {print $4}'
}
# The body: 68 points at full precision (17 significant digits), as a client computing in
# doubles sends them.
python3 - "$WORK/body68.json" <<'EOF'
import json, random, sys
random.seed(1)
pts = [[random.uniform(120, 340) + random.random() * 1e-9, random.uniform(150, 380)] for _ in range(68)]
open(sys.argv[1], "w").write(json.dumps({"landmarks": pts, "scheme": "ibug68", "method": "fit"}, separators=(",", ":")))
EOF
main_rs() {  # $1: the parse call
    cat <<EOF
use serde::Deserialize;
use std::hint::black_box;

#[derive(Debug, Deserialize)]
#[serde(untagged)]
#[allow(dead_code)]
enum FaceId { Text(String), Integer(i64), Number(f64) }

#[derive(Debug, Deserialize)]
#[allow(dead_code)]
struct Camera { fx: f64, fy: f64, cx: f64, cy: f64 }

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
struct PoseRequest {
    landmarks: Vec<Option<[f64; 2]>>,
    #[serde(default)] scheme: Option<String>,
    #[serde(default)] method: Option<String>,
    #[serde(default)] model: Option<String>,
    #[serde(default)] camera: Option<Camera>,
    #[serde(default)] landmark_style: Option<String>,
    #[serde(default)] id: Option<FaceId>,
}

fn main() {
    let mut args = std::env::args().skip(1);
    let body = std::fs::read(args.next().unwrap()).unwrap();
    let calls: usize = args.next().unwrap().parse().unwrap();
    let parse = args.next().is_none();
    for _ in 0..calls {
        let mut copy = body.clone();
        if parse {
            let r: PoseRequest = $1;
            black_box(r);
        }
        black_box(&mut copy);
    }
}
EOF
}
crate() {  # $1: name, $2: dependency line, $3: parse call
    mkdir -p "$WORK/$1/src"
    printf '[package]\nname = "%s"\nversion = "0.1.0"\nedition = "2024"\n[dependencies]\nserde = { version = "1", features = ["derive"] }\n%s\n[profile.release]\nlto = "thin"\ncodegen-units = 4\n' \
        "$1" "$2" > "$WORK/$1/Cargo.toml"
    main_rs "$3" > "$WORK/$1/src/main.rs"
    (cd "$WORK/$1" && cargo build --release --quiet)
}
crate serde-json 'serde_json = "1.0.154"' 'serde_json::from_slice(black_box(&copy)).unwrap()'
crate serde-json-roundtrip 'serde_json = { version = "1.0.154", features = ["float_roundtrip"] }' \
    'serde_json::from_slice(black_box(&copy)).unwrap()'
crate simd-json 'simd-json = "0.17"' 'simd_json::serde::from_slice(black_box(&mut copy)).unwrap()'
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
release_build --no-bin --example instructions
BIN=$EXAMPLES/instructions
base=$(count "$BIN" none 0 "$WORK/body68.json")
ours=$(count "$BIN" parse-pose-body "$CALLS" "$WORK/body68.json")
printf '| reader | instructions per parse |\n|---|---|\n'
printf '| facepose one-pass reader (`parse_pose_request`) | %s |\n' "$(( (ours - base) / CALLS ))"
for c in serde-json serde-json-roundtrip simd-json; do
    b="$WORK/$c/target/release/$c"
    z=$(count "$b" "$WORK/body68.json" "$CALLS" copy-only)
    p=$(count "$b" "$WORK/body68.json" "$CALLS")
    printf '| serde derive on %s | %s |\n' "$c" "$(( (p - z) / CALLS ))"
done
