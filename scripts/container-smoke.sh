#!/usr/bin/env bash
# Container smoke check without a Docker engine or a registry (see docs/deployment.md):
#   1. install podman, debootstrap and runc if missing (Debian/Ubuntu, root);
#   2. build a local base: debootstrap minbase -> localhost/debian:bookworm-minbase, plus Debian's
#      Python 3.11 -> localhost/bonefit-python:3.11-bookworm (both kept as a cache; --purge drops);
#   3. build the production Dockerfile FROM that base (podman build --isolation=chroot --from);
#   4. run it (runc, host network, API key set so it binds 0.0.0.0; default command: API and
#      embedded workers), wait for health (/healthz and the image's HEALTHCHECK), upload
#      estimation/examples/walk.csv, run a skeleton job to success, download its BVH; SIGTERM
#      must stop it with exit code 0;
#   5. the other command: `serve --no-worker` plus a `worker` container on the same data volume
#      (shared SQLite queue and store) run a second job; both stop cleanly on SIGTERM;
#   6. remove the containers, the volume and the image it built; exit non-zero on any failure.
#
# Usage: scripts/container-smoke.sh [--purge]     (--purge also removes the cached base images)
# Env:   DEBIAN_MIRROR (debootstrap mirror; default: debootstrap's own), SMOKE_PORT (default: free)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MINBASE=localhost/debian:bookworm-minbase
PYBASE=localhost/bonefit-python:3.11-bookworm
TAG="localhost/bonefit:smoke-$$"
NAME="bonefit-smoke-$$"
VOLUME="bonefit-smoke-$$"
API_KEY="smoke-$RANDOM$RANDOM"
CA=/etc/ssl/certs/ca-certificates.crt
PURGE=0
[[ "${1:-}" == "--purge" ]] && PURGE=1

PODMAN=(podman)
# --health-interval=disable: no systemd timer here; the smoke check runs the HEALTHCHECK itself.
RUN=(podman --runtime runc run --ulimit nofile=1024:1024 --ulimit nproc=1024:1024 --network=host
     --health-interval=disable)

log() { printf '[container-smoke] %s\n' "$*" >&2; }
die() { log "FAIL: $*"; exit 1; }

CONTAINERS=()
cleanup() {
    local rc=$? container
    for container in "${CONTAINERS[@]}"; do
        if [[ $rc -ne 0 ]]; then
            log "log of $container (last 40 lines):"
            "${PODMAN[@]}" logs --tail 40 "$container" >&2 2>&1 || true
        fi
        "${PODMAN[@]}" rm -f -v -t 2 "$container" >/dev/null 2>&1 || true
    done
    "${PODMAN[@]}" volume rm -f "$VOLUME" >/dev/null 2>&1 || true
    "${PODMAN[@]}" rmi -f "$TAG" >/dev/null 2>&1 || true
    # Intermediate build stages (dangling, labelled by the Dockerfile's base stage).
    "${PODMAN[@]}" image prune -f --filter label=org.opencontainers.image.title=bonefit \
        >/dev/null 2>&1 || true
    if [[ $PURGE -eq 1 ]]; then
        "${PODMAN[@]}" rmi -f "$PYBASE" "$MINBASE" >/dev/null 2>&1 || true
    fi
    [[ -n "${WORKDIR:-}" ]] && rm -rf "$WORKDIR"
    if [[ $rc -eq 0 ]]; then log "PASS"; else log "FAILED (exit $rc)"; fi
    exit $rc
}
trap cleanup EXIT
trap 'exit 130' INT TERM

WORKDIR="$(mktemp -d /tmp/bonefit-smoke.XXXXXX)"

# --- 1. tools ----------------------------------------------------------------------------------
need_packages=()
for pkg in podman debootstrap runc curl python3 ca-certificates; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" \
        || need_packages+=("$pkg")
done
if [[ ${#need_packages[@]} -gt 0 ]]; then
    [[ $EUID -eq 0 ]] || die "needs root to install: ${need_packages[*]}"
    log "installing ${need_packages[*]}"
    apt-get update -q >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
        "${need_packages[@]}" >/dev/null
fi

# --- 2. local base images ------------------------------------------------------------------------
if ! "${PODMAN[@]}" image exists "$MINBASE"; then
    log "debootstrap bookworm minbase (about 30 s)"
    rootfs="$WORKDIR/rootfs"
    # shellcheck disable=SC2086  # DEBIAN_MIRROR is optional: empty means debootstrap's default
    debootstrap --variant=minbase bookworm "$rootfs" ${DEBIAN_MIRROR:-} >"$WORKDIR/debootstrap.log" 2>&1 \
        || { tail -20 "$WORKDIR/debootstrap.log" >&2; die "debootstrap failed"; }
    tar -C "$rootfs" -c . | "${PODMAN[@]}" import - "$MINBASE" >/dev/null
    rm -rf "$rootfs"
fi
if ! "${PODMAN[@]}" image exists "$PYBASE"; then
    log "building $PYBASE"
    "${PODMAN[@]}" build --isolation=chroot --format docker -q -t "$PYBASE" \
        -f "$ROOT/scripts/container/python-base.Dockerfile" "$ROOT/scripts/container" >/dev/null
fi

# --- 3. the production image ---------------------------------------------------------------------
log "building $TAG from the production Dockerfile"
build_started=$SECONDS
"${PODMAN[@]}" build --isolation=chroot --format docker --from "$PYBASE" \
    -v "$CA:$CA:ro" -t "$TAG" "$ROOT" >"$WORKDIR/build.log" 2>&1 \
    || { tail -30 "$WORKDIR/build.log" >&2; die "image build failed"; }
log "built in $((SECONDS - build_started)) s, $("${PODMAN[@]}" image inspect -f '{{.Size}}' "$TAG" \
    | awk '{printf "%.0f MB", $1 / 1e6}')"

# --- 4. run it (default: API + embedded workers) and complete a job ------------------------------
[[ "$("${RUN[@]}" --rm --entrypoint id "$TAG" -u)" != "0" ]] || die "the image runs as root"

PORT="${SMOKE_PORT:-$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')}"
BASE="http://127.0.0.1:$PORT"
AUTH=(-H "Authorization: Bearer $API_KEY")
KEYS="{\"$API_KEY\": \"smoke\"}"

json_field() { python3 -c 'import json, sys; print(json.load(sys.stdin)[sys.argv[1]])' "$1"; }

wait_healthy() {  # container name
    log "waiting for $BASE/healthz ($1)"
    for _ in $(seq 120); do
        curl -fsS -o /dev/null "$BASE/healthz" 2>/dev/null && return 0
        [[ "$("${PODMAN[@]}" inspect -f '{{.State.Running}}' "$1")" == "true" ]] \
            || die "container $1 exited"
        sleep 0.5
    done
    die "/healthz never answered ($1)"
}

run_job() {  # recording id -> checks a skeleton job succeeds and its BVH downloads
    local job status=queued
    job="$(curl -fsS "${AUTH[@]}" -H 'Content-Type: application/json' \
        -d "{\"kind\": \"skeleton\", \"recording_id\": \"$1\", \"params\": {}}" \
        "$BASE/v1/jobs" | json_field id)" || die "job submission failed"
    for _ in $(seq 240); do
        status="$(curl -fsS "${AUTH[@]}" "$BASE/v1/jobs/$job" | json_field status)"
        [[ "$status" == "succeeded" || "$status" == "failed" || "$status" == "cancelled" ]] && break
        sleep 0.5
    done
    [[ "$status" == "succeeded" ]] || {
        curl -sS "${AUTH[@]}" "$BASE/v1/jobs/$job" >&2 || true
        die "job $job ended $status"
    }
    curl -fsS "${AUTH[@]}" -o "$WORKDIR/result.bvh" "$BASE/v1/jobs/$job/result?format=bvh" \
        || die "BVH download failed"
    head -1 "$WORKDIR/result.bvh" | grep -q '^HIERARCHY' || die "the result is not a BVH file"
    log "job $job succeeded; BVH $(wc -c <"$WORKDIR/result.bvh") bytes"
}

stop_cleanly() {  # container name: SIGTERM must end it with exit code 0
    "${PODMAN[@]}" stop -t 20 "$1" >/dev/null
    local code
    code="$("${PODMAN[@]}" inspect -f '{{.State.ExitCode}}' "$1")"
    [[ "$code" == "0" ]] || die "SIGTERM: $1 exited with $code, not 0"
    log "SIGTERM: $1 exited cleanly"
}

# The data volume is shared by the second phase's API and worker containers.
CONTAINERS+=("$NAME")
"${RUN[@]}" -d --name "$NAME" -v "$VOLUME:/var/lib/bonefit" -e BONEFIT_API_KEYS="$KEYS" \
    "$TAG" serve --host 0.0.0.0 --port "$PORT" >/dev/null
wait_healthy "$NAME"
"${PODMAN[@]}" --runtime runc healthcheck run "$NAME" >/dev/null 2>&1 \
    || die "the image's HEALTHCHECK failed"
curl -fsS -o /dev/null "${AUTH[@]}" "$BASE/readyz" || die "/readyz is not ready"
code="$(curl -s -o /dev/null -w '%{http_code}' "$BASE/v1/jobs")"
[[ "$code" == "401" ]] || die "a request without an API key answered $code, not 401"

log "uploading walk.csv"
recording="$(curl -fsS "${AUTH[@]}" -H 'Content-Type: text/csv' --data-binary \
    "@$ROOT/estimation/examples/walk.csv" "$BASE/v1/recordings?filename=walk.csv&format=sensor-csv" \
    | json_field id)" || die "upload failed"
run_job "$recording"
stop_cleanly "$NAME"

# --- 5. the other command: API --no-worker + a `bonefit worker` container ------------------------
# Both on the same volume, so they share the embedded SQLite queue and job store.
CONTAINERS+=("$NAME-api" "$NAME-worker")
"${RUN[@]}" -d --name "$NAME-api" -v "$VOLUME:/var/lib/bonefit" -e BONEFIT_API_KEYS="$KEYS" \
    "$TAG" serve --host 0.0.0.0 --port "$PORT" --no-worker >/dev/null
wait_healthy "$NAME-api"
curl -fsS "${AUTH[@]}" "$BASE/v1/recordings/$recording" >/dev/null \
    || die "the restarted API lost the recording"
"${RUN[@]}" -d --name "$NAME-worker" -v "$VOLUME:/var/lib/bonefit" "$TAG" worker >/dev/null
"${PODMAN[@]}" --runtime runc healthcheck run "$NAME-worker" >/dev/null 2>&1 \
    || die "the worker container's HEALTHCHECK failed"
run_job "$recording"
stop_cleanly "$NAME-worker"
stop_cleanly "$NAME-api"
