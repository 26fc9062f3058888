# One image for every soilocp process: the command picks the role, e.g.
#   docker run --init -p 127.0.0.1:7447:7447 soilocp:local router --listen tcp/0.0.0.0:7447
#   docker run --init -e SOILOCP_CONNECT=tcp/ROUTER_HOST:7447 soilocp:local service gateway
#
# BASE_IMAGE defaults to the official slim CPython image (needs a registry). With no registry,
# build the equivalent base with scripts/build-base-image.sh (debootstrap) and pass
# --build-arg BASE_IMAGE=soilocp-base:local; scripts/build-images.sh does both.
# Dependencies: if deploy/wheelhouse/ holds wheels (scripts/build-images.sh puts them there with
# `pip wheel` on the host) they are installed with --no-index: no network at build time.
# Otherwise pip fetches them from the package index (a machine with internet).
# soilocp itself comes as a wheel built on the host into deploy/soilocp-wheel/ (its Rust core is
# compiled there by maturin): the image has no Rust toolchain.
# Few instructions on purpose: each one is a layer commit, slow on some storage drivers.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}
# the extras every role of the image needs (the map service, Foxglove, the dashboard, soilocp certs);
# scripts/build-images.sh puts the same ones in the wheelhouse
ARG SOILOCP_EXTRAS=map,foxglove,dashboard,certs

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1 \
    VIRTUAL_ENV=/opt/soilocp \
    PATH=/opt/soilocp/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib

# Unprivileged user, the virtual environment (python3 -m venv works in both base images) and
# the dependencies, in a layer of their own: a source change does not reinstall numpy & co.
COPY deploy/wheelhouse/ /tmp/wheelhouse/
RUN set -eu; \
    useradd --system --uid 10001 --user-group --home-dir /var/lib/soilocp --create-home \
            --shell /usr/sbin/nologin soilocp; \
    python3 -m venv /opt/soilocp; \
    if ls /tmp/wheelhouse/*.whl >/dev/null 2>&1; then \
        pip install --no-index --find-links /tmp/wheelhouse /tmp/wheelhouse/*.whl; \
    fi

# Deployment configs and the health check land flat in /tmp/src, then move to /etc/soilocp
# (soilocp's own JSON for --config, native Zenoh JSON5 for ZENOH_CONFIG / zenohd).
COPY deploy/healthcheck.py deploy/fleet/ deploy/vehicle-two-unit/ deploy/zenoh/ /tmp/src/
COPY deploy/soilocp-wheel/ /tmp/dist/
RUN set -eu; \
    whl="$(ls /tmp/dist/soilocp-*.whl 2>/dev/null | head -n 1)"; \
    [ -n "$whl" ] || { echo "no soilocp wheel in deploy/soilocp-wheel/: build it on the host with scripts/build-images.sh" >&2; exit 1; }; \
    if ls /tmp/wheelhouse/*.whl >/dev/null 2>&1; then offline="--no-index --find-links /tmp/wheelhouse"; else offline=""; fi; \
    pip install $offline "${whl}[${SOILOCP_EXTRAS}]"; \
    mkdir -p /etc/soilocp; \
    install -d -o soilocp -g soilocp -m 0700 /etc/soilocp/certs; \
    mv /tmp/src/*.json /tmp/src/*.json5 /etc/soilocp/; \
    { echo '#!/opt/soilocp/bin/python3'; tail -n +2 /tmp/src/healthcheck.py; } > /usr/local/bin/soilocp-healthcheck; \
    chmod 0755 /usr/local/bin/soilocp-healthcheck; \
    rm -rf /tmp/src /tmp/dist /tmp/wheelhouse; \
    soilocp --version

USER soilocp
# Finds the soilocp process of this container and asks Zenoh whether it is there (see the script).
HEALTHCHECK --interval=30s --timeout=20s --start-period=60s --retries=3 CMD ["soilocp-healthcheck"]
# The services handle SIGTERM themselves (also as PID 1); run with --init / `init: true` so that
# a real init reaps zombies and forwards signals. Routers listen on 7447/tcp.
ENTRYPOINT ["soilocp"]
CMD ["--help"]
