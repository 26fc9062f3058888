#!/usr/bin/env bash
# Build the soilocp image with no container registry.
#
#   scripts/build-images.sh [--no-cache]
#
# 1. the base image: BASE_IMAGE (default soilocp-base:local) is built by build-base-image.sh
#    unless it exists already (a BASE_IMAGE of another name, e.g. python:3.11-slim, must be
#    present locally or pullable);
# 2. deploy/wheelhouse/: every dependency wheel (+ the build backend) by `pip wheel` on the host
#    (requirements read from pyproject.toml),
#    reusing the wheels already there when they still satisfy the requirements (no index query);
# 3. deploy/soilocp-wheel/: soilocp's own wheel, `pip wheel` of the repository on the host (maturin
#    compiles the Rust core with the host's cargo; the image has no Rust), offline from the wheelhouse;
# 4. `docker build` of the Dockerfile as SOILOCP_IMAGE (default soilocp:local).
# Environment: BASE_IMAGE, SOILOCP_IMAGE, PYTHON (interpreter whose pip builds the wheels; must be
# the base image's CPython minor version; default .venv/bin/python, else python3).
# Prints the time of each step.
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
base="${BASE_IMAGE:-soilocp-base:local}"
image="${SOILOCP_IMAGE:-soilocp:local}"
build_opts=()
for arg in "$@"; do
    case "$arg" in
        --no-cache) build_opts+=(--no-cache) ;;
        -h|--help) sed -n '2,18p' "$0"; exit 0 ;;
        *) echo "build-images: unknown argument $arg" >&2; exit 2 ;;
    esac
done
if [[ -z "${PYTHON:-}" ]]; then
    if [[ -x "$root/.venv/bin/python" ]]; then PYTHON="$root/.venv/bin/python"; else PYTHON=python3; fi
fi
t0=$(date +%s)

# --- 1. base ------------------------------------------------------------------------------
if [[ "$base" == soilocp-base:* ]]; then
    "$root/scripts/build-base-image.sh" "$base"
elif ! docker image inspect "$base" >/dev/null 2>&1; then
    echo "build-images: base image $base is not present locally; docker build will try to pull it"
fi
t1=$(date +%s)

# The wheels are built for the host's CPython: the base image must run the same minor version.
host_py="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
if docker image inspect "$base" >/dev/null 2>&1; then
    base_py="$(docker run --rm --entrypoint python3 "$base" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
    if [[ "$host_py" != "$base_py" ]]; then
        echo "build-images: host python $host_py ($PYTHON) != base image python $base_py: wheels would not match" >&2
        exit 1
    fi
fi

# --- 2. wheelhouse --------------------------------------------------------------------------
wheelhouse="$root/deploy/wheelhouse"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
# The requirements: soilocp's own dependencies and the image's extras (read from pyproject.toml, so the
# project itself is not built here: the image installs it from source) plus its build backend.
mapfile -t reqs < <("$PYTHON" - "$root/pyproject.toml" <<'PY'
import sys, tomllib
with open(sys.argv[1], "rb") as fh:
    data = tomllib.load(fh)
extras = data["project"]["optional-dependencies"]
# the extras the image's roles need (the Dockerfile's SOILOCP_EXTRAS): map service, Foxglove, dashboard, certs
image_extras = [r for x in ("map", "foxglove", "dashboard", "certs") for r in extras[x]]
for req in data["project"]["dependencies"] + image_extras + data["build-system"]["requires"]:
    print(req)
PY
)
if "$PYTHON" -m pip wheel -q --no-index --find-links "$wheelhouse" -w "$tmp" "${reqs[@]}" >/dev/null 2>&1; then
    echo "build-images: wheelhouse up to date (no index query)"
else
    rm -f "$tmp"/*.whl
    "$PYTHON" -m pip wheel -q --find-links "$wheelhouse" -w "$tmp" "${reqs[@]}"
fi
# replace the wheelhouse only if its set of wheels changed (untouched files keep the image's
# dependency layer cached)
if [[ "$(cd "$tmp" && ls *.whl)" != "$(cd "$wheelhouse" && ls *.whl 2>/dev/null)" ]]; then
    rm -f "$wheelhouse"/*.whl
    mv "$tmp"/*.whl "$wheelhouse"/
fi
echo "build-images: $(ls "$wheelhouse"/*.whl | wc -l) wheels, $(du -sh "$wheelhouse" | cut -f1) in deploy/wheelhouse"
t2=$(date +%s)

# --- 3. soilocp's wheel -------------------------------------------------------------------------
# rustup's cargo may not be on a non-login shell's PATH
[[ -x "$HOME/.cargo/bin/cargo" ]] && export PATH="$HOME/.cargo/bin:$PATH"
command -v cargo >/dev/null || { echo "build-images: cargo not found: soilocp's Rust core is built on the host (README)" >&2; exit 1; }
dist="$root/deploy/soilocp-wheel"
rm -f "$dist"/*.whl
"$PYTHON" -m pip wheel -q --no-deps --no-index --find-links "$wheelhouse" -w "$dist" "$root"
echo "build-images: $(cd "$dist" && ls *.whl)"
t2w=$(date +%s)

# --- 4. image -------------------------------------------------------------------------------
old_id="$(docker image inspect --format '{{.Id}}' "$image" 2>/dev/null || true)"
docker build -q --force-rm "${build_opts[@]}" --build-arg BASE_IMAGE="$base" -t "$image" "$root" >/dev/null
new_id="$(docker image inspect --format '{{.Id}}' "$image")"
if [[ -n "$old_id" && "$old_id" != "$new_id" ]]; then
    # the previous build of this tag is now untagged: drop it unless a container still uses it
    docker rmi "$old_id" >/dev/null 2>&1 || true
fi
t3=$(date +%s)
echo "build-images: $image from $base: base $((t1 - t0)) s, wheels $((t2 - t1)) s, soilocp wheel $((t2w - t2)) s, image $((t3 - t2w)) s, total $((t3 - t0)) s"
docker image ls "$image"
