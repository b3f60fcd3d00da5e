# bonefit: one image for the API (`bonefit serve`, the default) and the worker (`bonefit worker`).
#
#   docker build -t bonefit .
#   docker run -p 8000:8000 -e BONEFIT_API_KEYS='{"secret-key": "studio-a"}' bonefit
#   docker run bonefit worker --concurrency 2
#
# With no registry, build FROM a local Python base instead (scripts/container-smoke.sh):
#   podman build --isolation=chroot --from localhost/bonefit-python:3.11-bookworm -t bonefit .
# `--from` replaces the first FROM only; every later stage derives from `base`.

FROM python:3.11-slim-bookworm AS base

LABEL org.opencontainers.image.title="bonefit" \
      org.opencontainers.image.description="Skeletons and root paths from body-worn motion-capture sensors: REST service and worker" \
      org.opencontainers.image.licenses="MIT"

ENV LANG=C.UTF-8 \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PATH=/opt/bonefit/bin:$PATH

RUN groupadd --gid 10001 bonefit \
    && useradd --no-log-init --uid 10001 --gid bonefit --home-dir /var/lib/bonefit \
       --no-create-home --shell /usr/sbin/nologin bonefit

# --- build: the project and its service extra in a venv, no compilers needed (wheels only) ---
FROM base AS build

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ONLY_BINARY=numpy,scipy,psycopg-binary

RUN python3 -m venv /opt/bonefit
WORKDIR /src

# Dependencies first, from pyproject.toml alone: this layer survives source edits.
COPY pyproject.toml README.md ./
# The base dependencies plus the `service` extra (which names `bonefit[estimation]`: scipy).
RUN python3 -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; \
x = p['optional-dependencies']; d = p['dependencies'] + x['estimation'] + x['service']; \
print('\n'.join(r for r in d if not r.startswith('bonefit')))" > requirements.txt \
    && pip install --no-cache-dir -r requirements.txt

# bonefit/estimation and bonefit/service are symlinks to these two (one `bonefit` namespace);
# the wheel built from "." holds copies of the files.
COPY bonefit ./bonefit
COPY estimation ./estimation
COPY service ./service
# The project itself ("."), not a registry package: its pins live in pyproject.toml.
# hadolint ignore=DL3013
RUN pip install --no-cache-dir --no-deps . \
    && bonefit --version \
    && bonefit serve --help > /dev/null \
    && bonefit worker --help > /dev/null

# --- runtime ---
FROM base

COPY --from=build /opt/bonefit /opt/bonefit
COPY scripts/container/healthcheck.py /opt/bonefit/healthcheck.py

RUN install -d -o bonefit -g bonefit -m 0750 /var/lib/bonefit

ENV BONEFIT_DATA_DIR=/var/lib/bonefit \
    BONEFIT_PORT=8000 \
    OMP_NUM_THREADS=1 \
    OPENBLAS_NUM_THREADS=1 \
    MKL_NUM_THREADS=1

WORKDIR /var/lib/bonefit
VOLUME ["/var/lib/bonefit"]
USER 10001:10001
EXPOSE 8000

# The API answers GET /healthz; a worker container reports healthy while its process runs.
HEALTHCHECK --interval=15s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python3", "/opt/bonefit/healthcheck.py"]

# Exec form: bonefit is PID 1 and receives SIGTERM directly (graceful shutdown re-queues jobs).
ENTRYPOINT ["bonefit"]
CMD ["serve", "--host", "0.0.0.0", "--port", "8000"]
