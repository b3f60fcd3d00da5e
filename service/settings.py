"""Service configuration: one ``Settings`` object read from ``BONEFIT_*`` variables at start-up."""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Every knob of the service; built once at start-up and passed down."""

    model_config = SettingsConfigDict(env_prefix="BONEFIT_", extra="ignore")

    data_dir: Path = Field(Path("bonefit-data"), description="SQLite files, artifacts.")
    database_url: str | None = Field(None, description="Job store; default sqlite in data_dir.")
    queue_url: str | None = Field(None, description="Queue; default sqlite in data_dir.")
    storage_url: str | None = Field(None, description="Artifacts; default file:// in data_dir.")
    s3_endpoint_url: str | None = None
    s3_access_key_id: str | None = None
    s3_secret_access_key: SecretStr | None = None
    s3_region: str | None = None
    api_keys: dict[str, str] = Field(default_factory=dict, description="API key → tenant.")
    metrics_token: SecretStr | None = Field(
        None, description="Bearer token /metrics requires; unset: open (loopback only "
                          "without API keys).")
    max_upload_bytes: int = Field(2 * 1024**3, gt=0)
    max_concurrent_uploads: int = Field(
        16, ge=1, description="Uploads in progress at once per API process; more: 503.")
    body_timeout_seconds: float = Field(
        30.0, gt=0, description="Longest wait for the next chunk of a request body; then 408.")
    body_min_bytes_per_second: float = Field(
        1024.0, ge=0, description="Average rate a request body must keep after its first "
                                  "body_timeout_seconds (0: none); slower: 408.")
    max_connections: int = Field(
        500, ge=1, description="Open connections and requests per API process (uvicorn "
                               "limit_concurrency); more: 503.")
    keep_alive_seconds: int = Field(5, ge=1, description="Idle keep-alive connections are "
                                                          "closed after this long.")
    lease_seconds: float = Field(30.0, gt=0)
    max_attempts: int = Field(3, ge=1)
    job_timeout_seconds: float = Field(
        3600.0, ge=0, description="Run time after which a job is stopped and failed (0: none).")
    job_memory_mb: int = Field(
        4096, ge=0, description="Memory a job may add to its worker process, MiB; a job "
                                "needing more fails with a 507 problem (0: no limit).")
    workers: int = Field(2, ge=0, description="Embedded worker processes of `bonefit serve`.")
    retention_seconds: float = Field(0.0, ge=0, description="TTL of recordings/results/jobs.")
    progress_interval_seconds: float = Field(0.5, ge=0)
    shutdown_grace_seconds: float = Field(10.0, ge=0)
    min_free_bytes: int = Field(
        256 * 1024**2, ge=0, description="Free space under data_dir below which /readyz "
                                         "fails (0: not checked).")
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    log_level: str = "info"

    @property
    def worker_heartbeat_seconds(self) -> float:
        """How often a worker records that it is alive (a third of the lease, at most 10 s)."""
        return min(self.lease_seconds / 3, 10.0)

    @property
    def worker_stale_seconds(self) -> float:
        """A worker unheard of for this long is not counted as alive by ``/readyz``."""
        return 3 * self.worker_heartbeat_seconds + 1.0

    @property
    def resolved_database_url(self) -> str:
        """The job-store URL, defaulting to SQLite under the data directory."""
        return self.database_url or f"sqlite:///{self.data_dir.resolve() / 'jobs.db'}"

    @property
    def resolved_queue_url(self) -> str:
        """The queue URL, defaulting to SQLite under the data directory."""
        return self.queue_url or f"sqlite:///{self.data_dir.resolve() / 'queue.db'}"

    @property
    def resolved_storage_url(self) -> str:
        """The artifact-storage URL, defaulting to a directory under the data directory."""
        return self.storage_url or f"file://{self.data_dir.resolve() / 'artifacts'}"

    def to_env(self) -> dict[str, str]:
        """These settings as ``BONEFIT_*`` variables, to hand them to a child process."""
        env: dict[str, str] = {}
        for name, value in self.model_dump(mode="json").items():
            if value is None:
                continue
            if name == "data_dir":
                value = str(self.data_dir.resolve())
            secret = getattr(self, name)
            if isinstance(secret, SecretStr):
                value = secret.get_secret_value()
            env[f"BONEFIT_{name.upper()}"] = (
                json.dumps(value) if isinstance(value, dict | list) else str(value))
        return env
