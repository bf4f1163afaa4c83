# zenoh-perception service image.
#
#   docker build -t zenoh-perception .
#   docker run --network host zenoh-perception \
#       run --settings /app/config/perception.toml -m client -e tcp/127.0.0.1:7447
#
# docker-compose.yml runs it next to zenoh-bridge-ros2dds; see there for the whole ROS 2 set-up.
#
# Health: the HEALTHCHECK asks the running service for `perception/status` with
# `zenoh-perception status`, through the Zenoh router at $ZENOH_CONNECT (default: the bridge on
# this host, tcp/127.0.0.1:7447). The service must connect to the same router, which
# docker-compose.yml guarantees by using one variable for both. When you run the service against
# another router, pass `-e ZENOH_CONNECT=<endpoint>` to `docker run` as well.

ARG PYTHON_IMAGE=python:3.12-slim

# ---- build: install the package and its dependencies into a virtual environment ----------------
FROM ${PYTHON_IMAGE} AS build

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

RUN python -m venv /opt/venv

WORKDIR /src
# Only what `pip install .` needs (pyproject.toml names README.md as the long description).
COPY pyproject.toml README.md ./
COPY zenoh_perception ./zenoh_perception
RUN /opt/venv/bin/pip install . \
    && /opt/venv/bin/python -c "import cv2, zenoh, zenoh_perception"

# ---- runtime ----------------------------------------------------------------------------------
FROM ${PYTHON_IMAGE}

LABEL org.opencontainers.image.title="zenoh-perception" \
      org.opencontainers.image.description="ArUco tag perception over Zenoh for ROS 2 graphs" \
      org.opencontainers.image.licenses="Apache-2.0"

# No system packages: the wheels are self-contained. opencv-contrib-python-headless links only
# glibc, libstdc++, libgcc_s and zlib (checked with ldd), all in the slim image; it needs neither
# libGL nor libglib2.0 (those are for the GUI `opencv-python` wheels).
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    ZENOH_CONNECT=tcp/127.0.0.1:7447

COPY --from=build /opt/venv /opt/venv
COPY config/perception.toml /app/config/perception.toml

# An unprivileged user with a fixed numeric id (runAsNonRoot-friendly); the code and the settings
# stay owned by root, read-only for the service.
RUN groupadd --system --gid 10001 perception \
    && useradd --system --uid 10001 --gid perception --no-log-init \
       --home-dir /home/perception --create-home --shell /usr/sbin/nologin perception

USER 10001:10001
WORKDIR /app

# Shell form on purpose: $ZENOH_CONNECT is expanded when the check runs. `|| exit 1` maps any
# failure (no answer, no router, bad usage) to Docker's "unhealthy" code.
HEALTHCHECK --interval=15s --timeout=10s --start-period=30s --retries=3 \
    CMD zenoh-perception status -m client -e "$ZENOH_CONNECT" --no-multicast-scouting --timeout 2 \
        || exit 1

# `docker stop` sends SIGINT: every subcommand stops cleanly on it (`run`, `replay`, `demo` and
# `echo` handle SIGINT and SIGTERM alike, `status` and `bench` get Python's KeyboardInterrupt),
# whereas a subcommand without a SIGTERM handler would, as PID 1, ignore SIGTERM and be
# SIGKILLed after the grace period.
STOPSIGNAL SIGINT

ENTRYPOINT ["zenoh-perception"]
CMD ["run", "--settings", "/app/config/perception.toml"]
