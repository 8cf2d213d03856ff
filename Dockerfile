# facepose: head pose from 2D facial landmarks, HTTP JSON and gRPC on one port (8080).
#
#   docker build -t facepose .
#   docker run --rm -p 8080:8080 --read-only facepose
#
# Two stages. The build stage compiles the binary on the official Rust image and gathers what
# the runtime needs: the binary, the few shared libraries `ldd` names (glibc, libgcc_s; jemalloc
# is linked in statically), an /etc/passwd naming uid 10001 and the models folder. The runtime
# stage is `scratch` with only those files: no shell, no package manager, no curl (the
# HEALTHCHECK is the binary's own `facepose healthcheck`), about 20 MB (docs/DEPLOY.md).
#
# The binary embeds the default model, served as version 1 while the models folder
# (/var/lib/facepose/models, owned by uid 10001) holds nothing else. Mount a volume there to keep
# retrained versions across restarts and share them between replicas (deploy/kubernetes/);
# without one, retrained versions live as long as the container. Nothing else is written: the
# image runs with --read-only; with a read-only root and no volume, retraining needs a tmpfs
# there (--tmpfs /var/lib/facepose/models:uid=10001,gid=10001), serving does not.
#
# Without a registry (the development machines): scripts/images.sh makes the base image this
# file's build stage names from Debian packages and the host's Rust toolchain and crates, then
# runs this same file; see docs/DEPLOY.md.

FROM rust:1.95-slim-bookworm AS build
# make builds jemalloc, the binary's allocator. The official image lacks it; the base image
# scripts/images.sh makes has it already, so that its build needs no network.
RUN command -v make >/dev/null \
 || { apt-get update \
   && apt-get install -y --no-install-recommends make=4.3-4.1 \
   && rm -rf /var/lib/apt/lists/*; }
WORKDIR /src
# Dependencies first, so that source edits do not rebuild them: the workspace's manifests with
# empty targets.
COPY Cargo.toml Cargo.lock ./
COPY crates/core/Cargo.toml crates/core/
COPY crates/eval/Cargo.toml crates/eval/
COPY crates/files/Cargo.toml crates/files/
COPY crates/records/Cargo.toml crates/records/
COPY crates/app/Cargo.toml crates/app/
COPY crates/service/Cargo.toml crates/service/
COPY crates/testkit/Cargo.toml crates/testkit/
COPY crates/protogen/Cargo.toml crates/protogen/
COPY python/Cargo.toml python/
RUN mkdir -p src crates/core/benches crates/service/benches crates/service/examples python/src \
 && for c in core eval files records app service testkit; do mkdir -p crates/$c/src && touch crates/$c/src/lib.rs; done \
 && touch python/src/lib.rs \
 && mkdir -p crates/protogen/src && echo 'fn main() {}' > crates/protogen/src/main.rs \
 && echo 'fn main() {}' > src/main.rs \
 && for b in hpr estimate train real_faces; do echo 'fn main() {}' > crates/core/benches/$b.rs; done \
 && echo 'fn main() {}' > crates/service/benches/service.rs \
 && for e in instructions loadgen; do echo 'fn main() {}' > crates/service/examples/$e.rs; done \
 && cargo build --release --locked --bin facepose
COPY src ./src
COPY crates ./crates
COPY models ./models
RUN touch src/main.rs crates/*/src/lib.rs && cargo build --release --locked --bin facepose
# The runtime's files under /rootfs: the binary, the shared libraries it loads (from ldd, so the
# paths are the architecture's own), /etc/passwd and /etc/group naming uid 10001, and the
# models folder.
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
RUN mkdir -p /rootfs/usr/local/bin /rootfs/etc /rootfs/var/lib/facepose/models \
 && cp target/release/facepose /rootfs/usr/local/bin/facepose \
 && ldd target/release/facepose | grep -o '/[^ ]*' | sort -u \
  | xargs -I{} cp --parents --dereference {} /rootfs/ \
 && printf 'root:x:0:0:root:/root:/sbin/nologin\nfacepose:x:10001:10001:facepose:/nonexistent:/sbin/nologin\n' > /rootfs/etc/passwd \
 && printf 'root:x:0:\nfacepose:x:10001:\n' > /rootfs/etc/group \
 && /rootfs/usr/local/bin/facepose --version

FROM scratch
COPY --from=build /rootfs /
# The models folder belongs to the service's user: a named volume mounted there takes its owner.
COPY --from=build --chown=10001:10001 /rootfs/var/lib/facepose /var/lib/facepose
USER 10001
ENV FACEPOSE_ADDR=0.0.0.0:8080 \
    FACEPOSE_MODELS=/var/lib/facepose/models \
    FACEPOSE_LOG_FORMAT=json
EXPOSE 8080
# Docker's health: GET /readyz on FACEPOSE_ADDR (0.0.0.0 taken as 127.0.0.1), exit 1 unless 2xx.
# It follows FACEPOSE_ADDR, not a --addr flag: change the port through the environment.
# Orchestrators use their own probes (GET /readyz, GET /healthz; deploy/kubernetes/).
HEALTHCHECK --interval=5s --timeout=3s --start-period=30s --retries=3 \
  CMD ["/usr/local/bin/facepose", "healthcheck", "--timeout", "2s"]
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/local/bin/facepose"]
CMD ["serve"]
