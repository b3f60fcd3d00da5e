"""``/v1/recordings``: upload (streamed, hashed, sniffed), list, get and delete recordings."""

from __future__ import annotations

import math
import re
import shutil
import time
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from ..artifacts import tenant_prefix
from ..jobs import Recording, new_id
from ..problems import Problem, not_found
from ..runtime import Runtime
from ..schemas import RecordingOut, RecordingPage, UploadFormat
from ..storage import refuse_when_full
from ..uploads import UploadSink, cap_summary, receive_multipart, receive_raw, sniff, too_large
from .common import Cursor, Limit, Tenant, fetch_or_404, page_cursor, runtime_of

router = APIRouter()

MULTIPART_OVERHEAD = 64 * 1024
MAX_FILENAME_BYTES = 200
"""Longest stored file name in UTF-8 bytes (file systems allow 255 bytes, not characters)."""
MAX_CONTENT_TYPE_CHARS = 200
"""Longest stored media type (the job store's column)."""
OCTET_STREAM = "application/octet-stream"


def _clean_filename(name: str | None) -> str | None:
    """The base name without control characters (they break logs and some databases),
    cut to ``MAX_FILENAME_BYTES`` UTF-8 bytes, keeping its extension."""
    if not name:
        return None
    name = "".join(c for c in name if c.isprintable()).replace("\\", "/").rsplit("/", 1)[-1]
    if name in ("", ".", ".."):
        return None
    if len(name.encode()) > MAX_FILENAME_BYTES:
        suffix = _suffix(name)
        stem = name[:len(name) - len(suffix)].encode()[:MAX_FILENAME_BYTES - len(suffix)]
        name = stem.decode("utf-8", "ignore") + suffix  # "ignore": a character cut in two
    return name


def _stored_content_type(value: str, field: str) -> str:
    """``value`` if it can be stored as a recording's media type, else the 422 problem."""
    if len(value) > MAX_CONTENT_TYPE_CHARS or not value.isprintable():
        what = (f"{len(value)} characters" if len(value) > MAX_CONTENT_TYPE_CHARS
                else "a control character")
        raise Problem(422, "Invalid request", f"{field}: expected a media type of at most "
                      f"{MAX_CONTENT_TYPE_CHARS} printable characters, got {what}",
                      slug="invalid-request", field=field)
    return value


def _suffix(filename: str | None) -> str:
    """A safe file extension (``.csv``) of ``filename``, or ""; format sniffing uses it."""
    suffix = Path(filename or "").suffix
    return suffix.lower() if re.fullmatch(r"\.[A-Za-z0-9]{1,10}", suffix) else ""


def _plain(value: Any) -> Any:
    """JSON-ready: numpy scalars and paths as plain values, NaN and infinities as null."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bool | int | str) or value is None:
        return value
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return number if math.isfinite(number) else None


def _is_form(content_type: str) -> bool:
    """Whether the body is a multipart form (the file is its ``file`` field)."""
    return content_type.lower().startswith("multipart/form-data")


def _refuse_declared_size(request: Request, limit: int, multipart: bool) -> None:
    """413 before reading a body whose Content-Length is over ``limit`` (with room for a
    form's headers)."""
    length = request.headers.get("content-length")
    if length and length.isdigit() and int(length) > limit + (MULTIPART_OVERHEAD if multipart
                                                               else 0):
        raise too_large(limit)


async def _receive(request: Request, sink: UploadSink, filename: str | None,
                   content_type: str) -> tuple[str | None, str]:
    """Stream the body (or the form's ``file`` field) into ``sink``; the file's name and
    media type (the form's, where the query and the request did not say)."""
    if _is_form(content_type):
        part_name, part_type = await receive_multipart(request.stream(), content_type, sink)
        filename = filename or _clean_filename(part_name)
        content_type = (_stored_content_type(part_type, "file.Content-Type") if part_type
                        else OCTET_STREAM)
    else:
        await receive_raw(request.stream(), sink)
    await sink.close()
    request.app.state.upload_bytes.inc(sink.size)
    if content_type.startswith("application/x-www-form-urlencoded"):
        content_type = OCTET_STREAM  # curl --data-binary's default: not a form
    return filename, content_type


async def _store(runtime: Runtime, rec: Recording, path: Path) -> None:
    """Put the file in artifact storage and its row in the job store (or neither)."""
    with refuse_when_full("artifact storage"):
        await run_in_threadpool(runtime.artifacts.put_file, rec.key, path)
    with refuse_when_full("job database"):
        try:
            await run_in_threadpool(runtime.store.add_recording, rec)
        except Exception:
            await run_in_threadpool(runtime.artifacts.delete, rec.key)
            raise


async def _upload(request: Request, who: str, sink: UploadSink, *, filename: str | None,
                  content_type: str, format: str) -> Recording:
    """Receive, sniff and store the upload spooled in ``sink``; its recording."""
    with refuse_when_full("upload spool"):
        filename, content_type = await _receive(request, sink, filename, content_type)
        suffix = _suffix(filename)
        # the readers name the file in their messages: give it the client's name
        sink.path = sink.path.rename(sink.path.parent / (filename or f"recording{suffix}"))
        fmt, summary = await run_in_threadpool(sniff, sink.path, format, filename,
                                                 sink.rows.rows if sink.rows else None)
    rec_id = sink.path.parent.name  # the spool directory is named by the recording's id
    key = f"{tenant_prefix(who)}/recordings/{rec_id}{suffix}"
    rec = Recording(id=rec_id, tenant=who, key=key, filename=filename,
                    content_type=content_type, format=fmt, size=sink.size,
                    sha256=sink.sha256.hexdigest(), created_at=time.time(),
                    summary=cap_summary(_plain(summary)))
    await _store(runtime_of(request), rec, sink.path)
    return rec


@router.post("/recordings", status_code=201, response_model=RecordingOut,
             summary="Upload a recording",
             openapi_extra={"requestBody": {"required": True, "content": {
                 OCTET_STREAM: {"schema": {"type": "string", "format": "binary"}},
                 "multipart/form-data": {"schema": {"type": "object", "properties": {
                     "file": {"type": "string", "format": "binary"}}}}}}})
async def upload_recording(
    request: Request, who: Tenant,
    filename: Annotated[str | None, Query(max_length=255)] = None,
    format: Annotated[UploadFormat, Query()] = "auto",
) -> JSONResponse:
    """Stream the body (or the form's ``file`` field) to storage, hash it, and sniff it."""
    settings = runtime_of(request).settings
    content_type = _stored_content_type(request.headers.get("content-type", OCTET_STREAM),
                                        "Content-Type")
    _refuse_declared_size(request, settings.max_upload_bytes, _is_form(content_type))
    spool = settings.data_dir / "uploads" / new_id()
    # only a sensor CSV's summary uses the row count
    with refuse_when_full("upload spool"):
        sink = UploadSink(spool / "upload.part", settings.max_upload_bytes,
                          count_rows=format in ("auto", "sensor-csv"))
    try:
        rec = await _upload(request, who, sink, filename=_clean_filename(filename),
                            content_type=content_type, format=format)
    finally:
        sink.discard()  # a malformed, partial or refused upload leaves nothing behind
        shutil.rmtree(spool, ignore_errors=True)
    body = RecordingOut.of(rec).model_dump(mode="json")
    return JSONResponse(body, status_code=201,
                        headers={"Location": f"/v1/recordings/{rec.id}"})


@router.get("/recordings", response_model=RecordingPage, summary="List recordings")
async def list_recordings(request: Request, who: Tenant, limit: Limit = 50,
                          cursor: Cursor = None) -> RecordingPage:
    """The tenant's recordings, newest first."""
    recs = await run_in_threadpool(runtime_of(request).store.list_recordings, who,
                                   before=cursor, limit=limit)
    return RecordingPage(items=[RecordingOut.of(r) for r in recs],
                         next_cursor=page_cursor(recs, limit))


async def _recording(request: Request, who: str, rec_id: str) -> Recording:
    return await fetch_or_404("recording", rec_id, runtime_of(request).store.get_recording,
                              who, rec_id)


@router.get("/recordings/{recording_id}", response_model=RecordingOut,
            summary="Get a recording")
async def get_recording(request: Request, who: Tenant, recording_id: str) -> RecordingOut:
    """Metadata of one recording."""
    return RecordingOut.of(await _recording(request, who, recording_id))


@router.delete("/recordings/{recording_id}", status_code=204, summary="Delete a recording")
async def delete_recording(request: Request, who: Tenant, recording_id: str) -> Response:
    """Delete the recording and its bytes (jobs and their results stay)."""
    runtime = runtime_of(request)
    rec = await _recording(request, who, recording_id)
    # the bytes first: on a full disk that frees the space the database needs to record the
    # deletion (a failure after it leaves a record without bytes, which a retry deletes)
    await run_in_threadpool(runtime.artifacts.delete, rec.key)
    if await run_in_threadpool(runtime.store.delete_recording, who, recording_id) is None:
        raise not_found("recording", recording_id)
    return Response(status_code=204)
