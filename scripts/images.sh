#!/usr/bin/env bash
# Builds the facepose image (facepose:dev) on a machine whose Docker Engine can pull nothing (no
# registry), then runs its smoke test (scripts/image-smoke.sh) and prints its size.
#
#   scripts/images.sh            # as root (debootstrap and apt-get need it)
#
# The Dockerfile stays the one a machine with a registry builds as it is: this script only
# makes, locally, the base image its build stage names (`FROM rust:<version>-slim-bookworm`),
# so that `docker build` finds it and pulls nothing. The runtime stage is `FROM scratch`, which
# Docker provides without a registry.
#
# How the Rust toolchain and the crates get into the build, and why this way:
# - the toolchain is the host's (rustup cannot download inside the engine), its cargo, rustc and
#   standard library only (about 560 MB of the 1.4 GB folder: no docs, clippy, rustfmt), copied
#   into a Debian rootfs that debootstrap made with gcc, libc6-dev and make: the contents of the
#   official rust:*-slim-bookworm image, at the same paths (/usr/local/cargo, /usr/local/rustup);
# - the crates come from `cargo vendor` on the host, in a layer above with a source replacement
#   in $CARGO_HOME/config.toml and CARGO_NET_OFFLINE=true: the build runs offline. A container
#   here reaches the network (TCP), but HTTPS goes through an egress proxy whose certificate a
#   fresh rootfs does not trust, and nothing says a build machine has the network at all;
# - not a binary built on the host and copied in: the Dockerfile would need a second way in (a
#   build argument or a named context; this engine has no buildx for named contexts), and the
#   binary would be linked against the host's libraries instead of the build stage's.
# The vendored crates are keyed by Cargo.lock's hash (an image label): a lock change rebuilds
# that layer only. Each step is skipped when its result exists, so a re-run is quick; the
# folders are cached under target/images/ (remove it, and the images, to start over).
#
# The figures of the steps that ran (their times, the image's size) are written into the
# generated block "images" of docs/DEPLOY.md (scripts/lib/docblock.sh; IMAGES_DOC=0: not).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
work=target/images
mkdir -p "$work"
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
t_all=$(date +%s)
# shellcheck source=scripts/lib/docblock.sh
. scripts/lib/docblock.sh
figures=$work/figures.tsv # "figure<TAB>value" of this run, for docs/DEPLOY.md
: >"$figures"
figure() { printf '%s\t%s\n' "$1" "$2" >>"$figures"; }
built=0 # something was made (not a re-run with everything in place)

step() { echo "== $*"; }
elapsed() { echo "   ($(($(date +%s) - $1)) s)"; }
has_image() { docker image inspect "$1" >/dev/null 2>&1; }

if ! docker info >/dev/null 2>&1; then
  echo "images: no Docker engine answers (docker info failed): nothing built"
  exit 1
fi

# The build stage's base image, as the Dockerfile names it, and the Rust version in that name.
build_base=$(sed -n 's/^FROM \(rust:[^ ]*\) AS build$/\1/p' Dockerfile)
rust_minor=$(echo "$build_base" | sed -n 's/^rust:\([0-9]*\.[0-9]*\).*/\1/p')
if [ -z "$build_base" ] || [ -z "$rust_minor" ]; then
  echo "images: the Dockerfile has no 'FROM rust:<x.y>-... AS build' line" >&2
  exit 1
fi
grep -q '^FROM scratch$' Dockerfile || {
  echo "images: the runtime stage is expected to be FROM scratch (no base image to make)" >&2
  exit 1
}

# 1. debootstrap, from Debian's packages, if missing.
if ! command -v debootstrap >/dev/null; then
  step "installing debootstrap"
  apt-get update -qq && apt-get install -y -qq debootstrap >/dev/null
fi

# 2. The host's toolchain, which must be the version the Dockerfile names.
sysroot=$(rustc --print sysroot)
host_rust=$(rustc --version | awk '{print $2}')
case "$host_rust" in
  "$rust_minor".*) ;;
  *)
    echo "images: the Dockerfile builds with $build_base but the host's rustc is $host_rust;" \
      "install $rust_minor (rustup toolchain install $rust_minor) or change the FROM line" >&2
    exit 1
    ;;
esac
toolchain_image=facepose-local/rust-toolchain:$host_rust-bookworm

# 3. The build rootfs: Debian bookworm minbase with what the official slim Rust image has
#    (ca-certificates, gcc, libc6-dev) and make (jemalloc's build), with the host's toolchain
#    copied in at the official image's paths; imported as one image with the official image's
#    environment. The rootfs folder is kept, so a lost image is imported again without
#    debootstrap.
rootfs=$work/rootfs-build
if ! has_image "$toolchain_image"; then
  if [ ! -e "$rootfs/.complete" ]; then
    step "debootstrap bookworm (minbase + gcc, libc6-dev, make) into $rootfs"
    t=$(date +%s)
    rm -rf "$rootfs"
    debootstrap --variant=minbase --include=ca-certificates,gcc,libc6-dev,make \
      bookworm "$rootfs" "$mirror" >"$work/debootstrap-build.log" 2>&1 || {
      tail -20 "$work/debootstrap-build.log" >&2
      exit 1
    }
    rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/*
    touch "$rootfs/.complete"
    elapsed "$t"
    figure '`debootstrap` of the build rootfs (cached after)' "$(($(date +%s) - t)) s"
  fi
  step "copying the host's Rust $host_rust (cargo, rustc, std) into the rootfs"
  t=$(date +%s)
  tc=$rootfs/usr/local/rustup/toolchains/$host_rust-x86_64-unknown-linux-gnu
  rm -rf "$rootfs/usr/local/rustup" "$rootfs/usr/local/cargo"
  mkdir -p "$tc/bin" "$rootfs/usr/local/cargo/bin"
  cp -a "$sysroot/bin/cargo" "$sysroot/bin/rustc" "$tc/bin/"
  cp -a "$sysroot/lib" "$tc/"
  for b in cargo rustc; do
    ln -s "../../rustup/toolchains/$host_rust-x86_64-unknown-linux-gnu/bin/$b" \
      "$rootfs/usr/local/cargo/bin/$b"
  done
  elapsed "$t"
  step "importing $toolchain_image"
  t=$(date +%s)
  tar -C "$rootfs" --exclude=./.complete -c . | docker import \
    --change 'ENV RUSTUP_HOME=/usr/local/rustup' \
    --change 'ENV CARGO_HOME=/usr/local/cargo' \
    --change 'ENV PATH=/usr/local/cargo/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change "ENV RUST_VERSION=$host_rust" \
    --change 'CMD ["bash"]' \
    - "$toolchain_image" >/dev/null
  # The toolchain is in the image now; the rootfs keeps only Debian's part.
  rm -rf "$rootfs/usr/local/rustup" "$rootfs/usr/local/cargo"
  elapsed "$t"
  figure 'toolchain copy and image import' "$(($(date +%s) - t)) s"
  built=1
fi

# 4. The crates of Cargo.lock, vendored on the host (cargo vendor, from its registry cache or
#    crates.io), in a layer with the source replacement; tagged as the Dockerfile's build base.
lock_sha=$(sha256sum Cargo.lock | cut -c1-16)
have_sha=$(docker image inspect -f '{{index .Config.Labels "facepose.cargo-lock"}}' \
  "$build_base" 2>/dev/null || true)
if [ "$have_sha" != "$lock_sha" ]; then
  step "vendoring the crates of Cargo.lock ($lock_sha) into $build_base"
  t=$(date +%s)
  ctx=$work/vendor-ctx
  rm -rf "$ctx"
  mkdir -p "$ctx"
  cargo vendor --locked --quiet "$ctx/vendor" >/dev/null
  cat >"$ctx/config.toml" <<'EOF'
# Written by scripts/images.sh: the crates come from the vendored folder, not crates.io.
[source.crates-io]
replace-with = "vendored-sources"

[source.vendored-sources]
directory = "/usr/local/cargo/vendor"
EOF
  cat >"$ctx/Dockerfile" <<EOF
FROM $toolchain_image
COPY vendor /usr/local/cargo/vendor
COPY config.toml /usr/local/cargo/config.toml
ENV CARGO_NET_OFFLINE=true
LABEL facepose.cargo-lock="$lock_sha"
EOF
  docker build -t "$build_base" "$ctx" >"$work/vendor-build.log" 2>&1 || {
    tail -20 "$work/vendor-build.log" >&2
    exit 1
  }
  vendored=$(du -sm "$ctx/vendor" | cut -f1)
  rm -rf "$ctx"
  elapsed "$t"
  figure 'vendor layer (`cargo vendor` and its `docker build`)' \
    "$(($(date +%s) - t)) s ($vendored MB of crates)"
  built=1
fi

# 5. The image itself, from the repository's Dockerfile as anyone builds it.
step "docker build -t facepose:dev ."
t=$(date +%s)
docker build -t facepose:dev "$repo" >"$work/docker-build.log" 2>&1 || {
  tail -40 "$work/docker-build.log" >&2
  exit 1
}
elapsed "$t"
# Which of the Dockerfile's two `cargo build` steps ran (the classic builder's log: "Running
# in" after a step, or "Using cache"): the dependencies' (a cold build), the sources' only, or
# none (nothing changed).
ran=$(awk '/^Step [0-9]+\/[0-9]+ : RUN .*cargo build/ { s++; next }
  /^Step / { s = 0 } s && /^ ---> Running in/ { n++ } END { print n + 0 }' "$work/docker-build.log")
first_ran=$(awk '/^Step [0-9]+\/[0-9]+ : RUN .*cargo build/ { s = ++k; next }
  /^Step / { s = 0 } s == 1 && /^ ---> Running in/ { print "yes" }' "$work/docker-build.log")
if [ "$first_ran" = yes ]; then
  figure '`docker build -t facepose:dev .`, cold (both `cargo build --release` steps)' \
    "$(($(date +%s) - t)) s on $(nproc) cores"
  built=1
elif [ "$ran" -gt 0 ]; then
  figure '`docker build -t facepose:dev .` after a source change (the second `cargo build`)' \
    "$(($(date +%s) - t)) s on $(nproc) cores"
  built=1
fi

# 6. The smoke test, then the size.
step "scripts/image-smoke.sh facepose:dev"
scripts/image-smoke.sh facepose:dev
size=$(docker image inspect -f '{{.Size}}' facepose:dev)
size_text="$(awk -v s="$size" 'BEGIN { printf "%.1f", s / 1e6 }') MB ($((size / 1000)) kB)"
echo "facepose:dev: $size_text"
echo "images: done in $(($(date +%s) - t_all)) s"
figure '`facepose:dev` image size (`docker image inspect -f {{.Size}}`)' "$size_text"
if [ "$built" = 0 ]; then
  figure '`scripts/images.sh` again, nothing changed (smoke test included)' "$(($(date +%s) - t_all)) s"
fi
if [ "${IMAGES_DOC:-1}" != 0 ]; then
  doc_rows docs/DEPLOY.md images scripts/images.sh <"$figures"
fi
