#!/usr/bin/env bash
# Builds the load balancer's image for deploy/compose/, facepose-local/haproxy:bookworm: HAProxy
# from Debian bookworm's packages, on a machine whose Docker Engine can pull nothing (no
# registry). The image is a debootstrap rootfs imported with `docker import`, as
# scripts/images.sh makes its build base.
#
#   scripts/lb-image.sh          # as root (debootstrap needs it); skipped if the image exists
#   scripts/lb-image.sh --force  # build again
#
# - `debootstrap --variant=minbase --include=haproxy bookworm`: Debian's haproxy (2.6), which
#   speaks HTTP/2 on both sides (`proto h2`), checks servers over HTTP and has `retry-on`;
# - the apt caches and lists removed (about 150 MB imported);
# - imported with HAProxy as its command, running as the `haproxy` user the package creates
#   (the configuration binds port 8080, above 1024, so no capability is needed). `docker
#   import` cannot set a stop signal: the compose file sets SIGUSR1, HAProxy's soft stop
#   (finish the requests in flight, then exit).
# The rootfs folder is cached under target/images/ (remove it to start over).
set -euo pipefail
cd "$(dirname "$0")/.."
image=${LB_IMAGE:-facepose-local/haproxy:bookworm}
work=target/images
rootfs=$work/rootfs-haproxy
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

if ! timeout 10 docker info >/dev/null 2>&1; then
  echo "lb-image: no Docker engine answers (docker info failed): nothing built" >&2
  exit 1
fi
if [ "${1:-}" != --force ] && docker image inspect "$image" >/dev/null 2>&1; then
  echo "lb-image: $image exists (--force builds it again)"
  exit 0
fi
if ! command -v debootstrap >/dev/null; then
  echo "== installing debootstrap"
  apt-get update -qq && apt-get install -y -qq debootstrap >/dev/null
fi
mkdir -p "$work"

# 1. The rootfs: Debian bookworm minbase with haproxy (kept between runs).
if [ ! -e "$rootfs/.complete" ]; then
  echo "== debootstrap bookworm (minbase + haproxy) into $rootfs"
  t=$(date +%s)
  rm -rf "$rootfs"
  debootstrap --variant=minbase --include=haproxy bookworm "$rootfs" "$mirror" \
    >"$work/debootstrap-haproxy.log" 2>&1 || {
    tail -20 "$work/debootstrap-haproxy.log" >&2
    exit 1
  }
  rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/*
  # HAProxy's runtime folder (its stats socket goes there), owned by its user.
  mkdir -p "$rootfs/run/haproxy"
  chroot "$rootfs" chown haproxy:haproxy /run/haproxy
  touch "$rootfs/.complete"
  echo "   ($(($(date +%s) - t)) s)"
fi

# 2. The image: the rootfs as one layer, HAProxy in the foreground (-W: master-worker, which
#    reloads and soft-stops cleanly; -db: no daemon) on /usr/local/etc/haproxy/haproxy.cfg,
#    the path the compose file mounts the configuration at.
echo "== importing $image"
version=$(chroot "$rootfs" dpkg-query -W -f '${Version}' haproxy)
tar -C "$rootfs" --exclude=./.complete -c . | docker import \
  --change 'USER haproxy' \
  --change 'EXPOSE 8080' \
  --change "LABEL org.opencontainers.image.description=\"HAProxy $version from Debian bookworm\"" \
  --change 'ENTRYPOINT ["/usr/sbin/haproxy", "-W", "-db"]' \
  --change 'CMD ["-f", "/usr/local/etc/haproxy/haproxy.cfg"]' \
  - "$image" >/dev/null
size=$(docker image inspect -f '{{.Size}}' "$image")
echo "lb-image: $image (haproxy $version), $((size / 1000000)) MB"
