# facepose: head pose from 2D facial landmarks, HTTP JSON and gRPC on one port (8080).
#
#   docker build -t facepose .
#   docker run --rm -p 8080:8080 facepose
#
# The binary embeds the default model, served as version 1 while the models folder
# (/var/lib/facepose/models, writable by the service's user) holds nothing else. Mount a volume
# there to keep retrained versions across restarts and share them between replicas
# (deploy/kubernetes/); without one, retrained versions live as long as the container.

FROM rust:1.95-slim-bookworm AS build
# make builds jemalloc, the binary's allocator.
RUN apt-get update \
 && apt-get install -y --no-install-recommends make=4.3-4.1 \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
# Dependencies first, so that source edits do not rebuild them: the workspace's manifests with
# empty targets.
COPY Cargo.toml Cargo.lock ./
COPY crates/core/Cargo.toml crates/core/
COPY crates/files/Cargo.toml crates/files/
COPY crates/app/Cargo.toml crates/app/
COPY crates/service/Cargo.toml crates/service/
COPY crates/testkit/Cargo.toml crates/testkit/
COPY crates/protogen/Cargo.toml crates/protogen/
RUN mkdir -p src crates/core/benches crates/core/examples crates/service/benches crates/service/examples \
 && for c in core files app service testkit; do mkdir -p crates/$c/src && touch crates/$c/src/lib.rs; done \
 && mkdir -p crates/protogen/src && echo 'fn main() {}' > crates/protogen/src/main.rs \
 && echo 'fn main() {}' > src/main.rs \
 && for b in hpr estimate train; do echo 'fn main() {}' > crates/core/benches/$b.rs; done \
 && echo 'fn main() {}' > crates/core/examples/convention.rs \
 && echo 'fn main() {}' > crates/service/benches/service.rs \
 && for e in instructions loadgen; do echo 'fn main() {}' > crates/service/examples/$e.rs; done \
 && cargo build --release --locked --bin facepose
COPY src ./src
COPY crates ./crates
COPY models ./models
RUN touch src/main.rs crates/*/src/lib.rs && cargo build --release --locked --bin facepose

FROM debian:bookworm-slim
RUN apt-get update \
 && apt-get install -y --no-install-recommends ca-certificates=20230311+deb12u1 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --home-dir /nonexistent --shell /usr/sbin/nologin facepose \
 && mkdir -p /var/lib/facepose/models \
 && chown facepose /var/lib/facepose/models
COPY --from=build /src/target/release/facepose /usr/local/bin/facepose
USER 10001
ENV FACEPOSE_ADDR=0.0.0.0:8080 \
    FACEPOSE_MODELS=/var/lib/facepose/models \
    FACEPOSE_LOG_FORMAT=json
EXPOSE 8080
# Readiness and liveness belong to the orchestrator (GET /readyz, GET /healthz); the image has
# no curl, so no HEALTHCHECK here.
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/local/bin/facepose"]
CMD ["serve"]
