# One image for every soilocp process: the command picks the role, e.g.
#   docker run --init soilocp:local router --listen tcp/0.0.0.0:7447
#   docker run --init -e SOILOCP_CONNECT=tcp/router:7447 soilocp:local service gateway
#
# BASE_IMAGE defaults to the official slim CPython image (needs a registry). With no registry,
# build the equivalent base with scripts/build-base-image.sh (debootstrap) and pass
# --build-arg BASE_IMAGE=soilocp-base:local; scripts/build-images.sh does both.
# Dependencies: if deploy/wheelhouse/ holds wheels (scripts/build-images.sh puts them there with
# `pip wheel` on the host) they are installed with --no-index: no network at build time.
# Otherwise pip fetches them from the package index (a machine with internet).
# Works with the classic builder and BuildKit alike (no BuildKit-only syntax).
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1 \
    VIRTUAL_ENV=/opt/soilocp \
    PATH=/opt/soilocp/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib \
    SOILOCP_MODE=client

# Unprivileged user and the virtual environment (python3 -m venv exists in both base images).
RUN set -eu; \
    useradd --system --uid 10001 --user-group --home-dir /var/lib/soilocp --create-home \
            --shell /usr/sbin/nologin soilocp; \
    python3 -m venv /opt/soilocp

# Dependencies first, in their own layer: a source change does not reinstall numpy & co.
COPY deploy/wheelhouse/ /tmp/wheelhouse/
RUN set -eu; \
    if ls /tmp/wheelhouse/*.whl >/dev/null 2>&1; then \
        pip install --no-index --find-links /tmp/wheelhouse /tmp/wheelhouse/*.whl; \
    fi

COPY pyproject.toml README.md /tmp/src/
COPY soilocp/ /tmp/src/soilocp/
COPY schemas/ /tmp/src/schemas/
COPY services/ /tmp/src/services/
RUN set -eu; \
    if ls /tmp/wheelhouse/*.whl >/dev/null 2>&1; then offline="--no-index --find-links /tmp/wheelhouse"; else offline=""; fi; \
    pip install $offline /tmp/src; \
    rm -rf /tmp/src /tmp/wheelhouse; \
    soilocp --version

COPY deploy/zenoh/ /etc/soilocp/zenoh/
COPY deploy/healthcheck.py /usr/local/bin/soilocp-healthcheck
RUN chmod 0755 /usr/local/bin/soilocp-healthcheck && sed -i '1s|.*|#!/opt/soilocp/bin/python3|' /usr/local/bin/soilocp-healthcheck

USER soilocp
WORKDIR /var/lib/soilocp
EXPOSE 7447
# Finds the soilocp process of this container and asks Zenoh whether it is there (see the script).
HEALTHCHECK --interval=10s --timeout=8s --start-period=20s --retries=3 CMD ["soilocp-healthcheck"]
# The services handle SIGTERM themselves (also as PID 1); run with --init / `init: true` so that
# a real init reaps zombies and forwards signals.
STOPSIGNAL SIGTERM
ENTRYPOINT ["soilocp"]
CMD ["--help"]
