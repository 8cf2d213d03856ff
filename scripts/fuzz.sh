#!/usr/bin/env bash
# Runs every fuzz target (fuzz/, cargo fuzz with libFuzzer) for a bounded time and reports
# executions and crashes per target.
#
#   scripts/fuzz.sh                # 60 s per target
#   SECONDS_PER_TARGET=600 scripts/fuzz.sh landmarks proto_face
#
# Installs the nightly toolchain and cargo-fuzz if missing. The seeds in fuzz/seeds/<target>
# are read, never written: new inputs go to a temporary corpus. A crash leaves its input in
# fuzz/artifacts/<target>/ (reproduce: cargo +nightly fuzz run <target> <file>). Built without
# a sanitizer (-s none): the targets are safe Rust, so the checks are the code's own panics and
# the targets' assertions, at several times the executions per second of AddressSanitizer.
# Exits 1 if any target crashed (after the table). Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
SECONDS_PER_TARGET=${SECONDS_PER_TARGET:-60}
TARGETS=("$@")
[ ${#TARGETS[@]} -eq 0 ] && TARGETS=(landmarks pose_body proto_face bundle upload ws_frame)
rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked
cargo +nightly fuzz build -s none 2>&1 | tail -1
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
printf '| target | seconds | executions | crashes |\n|---|---|---|---|\n'
total=0 crashed=0
for t in "${TARGETS[@]}"; do
    mkdir -p "$WORK/$t" "artifacts/$t"
    before=$(find "artifacts/$t" -type f | wc -l)
    cargo +nightly fuzz run -s none "$t" "$WORK/$t" "seeds/$t" -- \
        -max_total_time="$SECONDS_PER_TARGET" -print_final_stats=1 -max_len=65536 \
        -rss_limit_mb=2048 > "$WORK/$t.log" 2>&1 || true
    runs=$(awk '/stat::number_of_executed_units/ {print $2}' "$WORK/$t.log" | tail -1)
    crashes=$(( $(find "artifacts/$t" -type f | wc -l) - before ))
    total=$(( total + ${runs:-0} ))
    printf '| `%s` | %s | %s | %s |\n' "$t" "$SECONDS_PER_TARGET" "${runs:-?}" "$crashes"
    if [ "$crashes" -gt 0 ]; then
        crashed=1
        grep -m3 -E "panicked|ERROR" "$WORK/$t.log" >&2 || true
    fi
done
printf '| all | | %s | |\n' "$total"
exit "$crashed"
