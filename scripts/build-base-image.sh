#!/usr/bin/env bash
# Build a minimal Debian + CPython base image WITHOUT any container registry.
#
#   scripts/build-base-image.sh [--force] [IMAGE]      (default IMAGE: soilocp-base:local)
#
# debootstrap fetches a minimal Debian of the host's own release from the mirror that the
# host's apt sources name (read now from /etc/apt/sources.list{,.d/*}; no mirror is stored in
# the repository), adds python3 + venv (same CPython minor as the host, so the wheels built by
# scripts/build-images.sh match its ABI), tini and a few runtime libraries, and `docker import`s
# the tree. The result stands in for python:3.11-slim as the Dockerfile's BASE_IMAGE.
# An existing image of that name is kept (cache) unless --force is given.
# Environment: SOILOCP_BASE_SUITE (default: host VERSION_CODENAME), SOILOCP_BASE_UPGRADE=0 to
# skip applying the -updates/-security suites, SOILOCP_BASE_WORKDIR (default /var/tmp).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
force=0
image="soilocp-base:local"
for arg in "$@"; do
    case "$arg" in
        --force) force=1 ;;
        -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
        -*) echo "build-base-image: unknown option $arg" >&2; exit 2 ;;
        *) image="$arg" ;;
    esac
done

if [[ $force -eq 0 ]] && docker image inspect "$image" >/dev/null 2>&1; then
    echo "build-base-image: $image already exists (use --force to rebuild)"
    exit 0
fi
if [[ $(id -u) -ne 0 ]]; then
    echo "build-base-image: debootstrap needs root" >&2
    exit 1
fi

suite="${SOILOCP_BASE_SUITE:-$(. /etc/os-release && echo "${VERSION_CODENAME:-}")}"
if [[ -z "$suite" ]]; then
    echo "build-base-image: cannot tell the host's Debian codename; set SOILOCP_BASE_SUITE" >&2
    exit 1
fi
mirror="$(python3 "$here/debian_mirror.py" "$suite")"
arch="$(dpkg --print-architecture)"
echo "build-base-image: $suite/$arch from $mirror -> $image"

if ! command -v debootstrap >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq debootstrap >/dev/null
fi

workdir="$(mktemp -d "${SOILOCP_BASE_WORKDIR:-/var/tmp}/soilocp-base.XXXXXX")"
rootfs="$workdir/rootfs"
cleanup() {
    # a failed chroot step may leave these mounted; never leave them behind
    for m in "$rootfs/proc" "$rootfs/dev/pts" "$rootfs/dev"; do
        mountpoint -q "$m" 2>/dev/null && umount -l "$m" || true
    done
    rm -rf "$workdir"
}
trap cleanup EXIT

start=$(date +%s)
# minbase: Essential packages + apt; the rest is what the Python services need at run time.
# libstdc++6/libgcc-s1: allowed system libraries of manylinux wheels (numpy, scipy, matplotlib).
debootstrap --variant=minbase --arch="$arch" --components=main \
    --include=python3,python3-venv,tini,passwd,libstdc++6,ca-certificates \
    "$suite" "$rootfs" "$mirror" >"$workdir/debootstrap.log" 2>&1 || {
        tail -n 30 "$workdir/debootstrap.log" >&2
        echo "build-base-image: debootstrap failed" >&2
        exit 1
    }

# Apply the -updates and -security suites that the host itself uses (same mirror lookup).
{
    echo "deb $mirror $suite main"
    for extra in "$suite-updates" "$suite-security"; do
        if uri="$(python3 "$here/debian_mirror.py" "$extra" 2>/dev/null)"; then
            echo "deb $uri $extra main"
        fi
    done
} >"$rootfs/etc/apt/sources.list"
if [[ "${SOILOCP_BASE_UPGRADE:-1}" != 0 ]]; then
    mount -t proc proc "$rootfs/proc"
    chroot "$rootfs" /usr/bin/env DEBIAN_FRONTEND=noninteractive \
        sh -c 'apt-get update -qq && apt-get -y -qq upgrade >/dev/null' || {
            echo "build-base-image: applying updates failed" >&2
            exit 1
        }
    umount "$rootfs/proc"
fi

# Trim what an image never needs (same spirit as the official slim images).
chroot "$rootfs" apt-get clean
rm -rf "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/cache/apt/*.bin \
       "$rootfs"/usr/share/doc/* "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/* \
       "$rootfs"/var/log/*.log "$rootfs"/tmp/*
: >"$rootfs/etc/machine-id"

python_version="$(chroot "$rootfs" python3 -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])')"
tar --numeric-owner -C "$rootfs" -c . | docker import \
    --change 'ENV LANG=C.UTF-8' \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'CMD ["python3"]' \
    --message "soilocp base: debian $suite minbase + python3 $python_version (debootstrap)" \
    - "$image" >/dev/null
echo "build-base-image: built $image (debian $suite, python $python_version) in $(( $(date +%s) - start )) s"
docker image ls "$image"
