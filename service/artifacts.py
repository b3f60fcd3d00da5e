"""Artifact storage for uploaded recordings and job results: local disk or S3."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol
from urllib.parse import urlsplit

from .errors import (
    ArtifactsUnavailable,
    BackendError,
    StorageFull,
    says_disk_full,
    translate_methods,
)

if TYPE_CHECKING:
    from .settings import Settings

CHUNK = 1024 * 1024


def tenant_prefix(tenant: str) -> str:
    """The tenant as the first segment of its artifact keys."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", tenant) or "_"


class ArtifactStore(Protocol):
    """Named blobs; keys look like ``tenant/recordings/<id>``."""

    def put_file(self, key: str, path: Path) -> None:
        """Store the file at ``path`` under ``key`` (the file may be moved away)."""

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        """The stored bytes, in chunks; FileNotFoundError if absent."""

    def as_file(self, key: str) -> contextlib.AbstractContextManager[Path]:
        """A local path holding the stored bytes while the context is open."""

    def delete(self, key: str) -> None:
        """Remove ``key`` if present."""

    def size(self, key: str) -> int | None:
        """The stored bytes' length; None if ``key`` is absent."""

    def ping(self) -> None:
        """Raise if the storage is unreachable."""


def artifact_error(exc: Exception) -> BackendError | None:
    """The service's error for a storage error (a full disk, an outage); None for others,
    among them FileNotFoundError, which says a key is absent."""
    if isinstance(exc, FileNotFoundError):
        return None
    if says_disk_full(exc):
        return StorageFull(f"the artifact storage is full ({type(exc).__name__})",
                           storage=ArtifactsUnavailable.storage)
    botocore = sys.modules.get("botocore.exceptions")  # not loaded: not an S3 error
    if botocore is not None and isinstance(exc, botocore.ConnectionError
                                           | botocore.HTTPClientError):
        return ArtifactsUnavailable(f"the artifact storage is unreachable "
                                    f"({type(exc).__name__})")
    return None


def _raise_translated(exc: Exception) -> None:
    """Raise the service's error for ``exc`` if there is one (generators are not wrapped)."""
    mapped = artifact_error(exc)
    if mapped is not None:
        raise mapped from exc


@translate_methods(artifact_error)
class LocalArtifactStore:
    """Blobs as files under a directory."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def _path(self, key: str) -> Path:
        path = (self.root / key).resolve()
        if not path.is_relative_to(self.root.resolve()):
            raise ValueError(f"bad artifact key {key!r}")
        return path

    def put_file(self, key: str, path: Path) -> None:
        """Move the file into place (copy across file systems); atomic for readers."""
        target = self._path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        staging = target.with_name(f".{target.name}.{os.getpid()}.part")
        shutil.move(path, staging)
        os.replace(staging, target)

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        """Read the file in chunks."""
        with self._path(key).open("rb") as fh:
            while chunk := fh.read(CHUNK):
                yield chunk

    @contextlib.contextmanager
    def as_file(self, key: str) -> Iterator[Path]:
        """The file itself."""
        path = self._path(key)
        if not path.exists():
            raise FileNotFoundError(key)
        yield path

    def delete(self, key: str) -> None:
        """Remove the file."""
        self._path(key).unlink(missing_ok=True)

    def size(self, key: str) -> int | None:
        """The file's size."""
        try:
            return self._path(key).stat().st_size
        except FileNotFoundError:
            return None

    def ping(self) -> None:
        """Check the directory is writable."""
        self.root.mkdir(parents=True, exist_ok=True)
        if not os.access(self.root, os.W_OK):
            raise PermissionError(f"{self.root} is not writable")


@translate_methods(artifact_error)
class S3ArtifactStore:
    """Blobs in an S3-compatible bucket under a prefix."""

    def __init__(self, bucket: str, prefix: str, client: Any) -> None:
        self.bucket = bucket
        self.prefix = prefix.strip("/")
        self.client = client

    def _key(self, key: str) -> str:
        return f"{self.prefix}/{key}" if self.prefix else key

    def put_file(self, key: str, path: Path) -> None:
        """Upload (multipart for large files)."""
        self.client.upload_file(str(path), self.bucket, self._key(key))

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        """Stream the object."""
        try:
            body = self.client.get_object(Bucket=self.bucket, Key=self._key(key))["Body"]
        except self.client.exceptions.NoSuchKey:
            raise FileNotFoundError(key) from None
        except Exception as exc:
            _raise_translated(exc)
            raise
        try:
            while chunk := body.read(CHUNK):
                yield chunk
        finally:
            body.close()

    @contextlib.contextmanager
    def as_file(self, key: str) -> Iterator[Path]:
        """Download to a temporary file."""
        with tempfile.TemporaryDirectory(prefix="bonefit-") as tmp:
            path = Path(tmp) / key.rsplit("/", 1)[-1]
            try:
                self.client.download_file(self.bucket, self._key(key), str(path))
            except Exception as exc:
                if _is_missing(exc):
                    raise FileNotFoundError(key) from exc
                _raise_translated(exc)
                raise
            yield path

    def delete(self, key: str) -> None:
        """Delete the object."""
        self.client.delete_object(Bucket=self.bucket, Key=self._key(key))

    def size(self, key: str) -> int | None:
        """The object's ``ContentLength``."""
        try:
            head = self.client.head_object(Bucket=self.bucket, Key=self._key(key))
        except Exception as exc:
            if _is_missing(exc):
                return None
            raise
        return int(head["ContentLength"])

    def ping(self) -> None:
        """Head the bucket."""
        self.client.head_bucket(Bucket=self.bucket)


def _is_missing(exc: Exception) -> bool:
    response = getattr(exc, "response", None) or {}
    return str(response.get("Error", {}).get("Code")) in ("404", "NoSuchKey", "NotFound")


def open_artifacts(settings: Settings) -> ArtifactStore:
    """The artifact store configured by ``BONEFIT_STORAGE_URL``."""
    url = settings.resolved_storage_url
    parts = urlsplit(url)
    if parts.scheme == "file":
        return LocalArtifactStore(Path(parts.path))
    if parts.scheme == "s3":
        import boto3  # only distributed deployments pay for importing boto3
        from botocore.config import Config

        secret = settings.s3_secret_access_key
        client = boto3.client(
            "s3", endpoint_url=settings.s3_endpoint_url, region_name=settings.s3_region,
            aws_access_key_id=settings.s3_access_key_id,
            aws_secret_access_key=secret.get_secret_value() if secret else None,
            config=Config(retries={"max_attempts": 3, "mode": "standard"},
                          s3={"addressing_style": "path"}))
        return S3ArtifactStore(parts.netloc, parts.path, client)
    raise ValueError(f"unsupported storage URL {url!r} (use file:// or s3://)")
