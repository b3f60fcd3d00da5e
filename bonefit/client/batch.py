"""``bonefit submit``: upload and run many takes on a server, resumably.

Each take's result files are written beside its name in OUTDIR (``walk01.json``,
``walk01.bvh``...). ``OUTDIR/.bonefit-submit.json`` records the finished job of every
(sha256 of the file, kind, params); on the next run a take whose record names a job the
server still has as succeeded is not run again.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import httpx

from .errors import ProblemError
from .results import Job
from .sync import Client

STATE_FILE = ".bonefit-submit.json"
EXIT_FAILED = 1
EXIT_USAGE = 2


@dataclass(frozen=True)
class Take:
    """One file to run: where it is, the stem its results get, and its resume key."""

    path: Path
    name: str
    sha256: str

    def key(self, kind: str, params: Mapping[str, Any]) -> str:
        """What identifies an equivalent finished job: file content, kind and params."""
        return f"{self.sha256}:{kind}:{json.dumps(params, sort_keys=True)}"


@dataclass(frozen=True)
class Outcome:
    """How one take went: ``done``, ``skipped`` (finished in an earlier run) or ``failed``."""

    take: Take
    status: str
    job_id: str | None = None
    seconds: float = 0.0
    reason: str = ""
    files: tuple[str, ...] = ()


def parse_params(items: Iterable[str]) -> dict[str, Any]:
    """``k=v`` pairs; ``v`` is read as JSON when it parses (numbers, lists, true), else a
    string. ValueError names a malformed item."""
    params: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--param {item!r}: expected KEY=VALUE, e.g. method=llsf")
        try:
            params[key.strip()] = json.loads(value)
        except ValueError:
            params[key.strip()] = value
    return params


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (as the server computes it on upload)."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1024 * 1024):
            digest.update(chunk)
    return digest.hexdigest()


def collect_takes(paths: Sequence[Path]) -> list[Take]:
    """The takes with distinct result names (a repeated stem gets ``-2``, ``-3``...)."""
    takes: list[Take] = []
    used: set[str] = set()
    for path in paths:
        name, n = path.stem, 1
        while name in used:
            n += 1
            name = f"{path.stem}-{n}"
        used.add(name)
        takes.append(Take(path, name, sha256_of(path)))
    return takes


class State:
    """The resume record in OUTDIR: key → {job, take, files}; saved after every take."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.lock = threading.Lock()
        try:
            loaded = json.loads(path.read_text())
            self.runs: dict[str, dict[str, Any]] = dict(loaded.get("runs", {}))
        except (OSError, ValueError, AttributeError):
            self.runs = {}

    def get(self, key: str) -> dict[str, Any] | None:
        """The record of an earlier finished job, if any."""
        with self.lock:
            return self.runs.get(key)

    def record(self, key: str, entry: dict[str, Any]) -> None:
        """Remember a finished job and save the file (atomically)."""
        with self.lock:
            self.runs[key] = entry
            partial = self.path.with_name(self.path.name + ".part")
            partial.write_text(json.dumps({"version": 1, "runs": self.runs}, indent=1))
            partial.replace(self.path)


@dataclass
class Board:
    """One progress display for every take: a rewritten line on a terminal, else a line per
    finished take."""

    total: int
    out: TextIO = field(default_factory=lambda: sys.stderr)
    lock: threading.Lock = field(default_factory=threading.Lock)
    active: dict[str, float] = field(default_factory=dict)
    finished: int = 0
    failed: int = 0

    def progress(self, name: str, fraction: float) -> None:
        """A take's job progressed."""
        with self.lock:
            self.active[name] = fraction
            self._line(f"{name} {fraction:.0%}")

    def finish(self, outcome: Outcome) -> None:
        """A take ended."""
        with self.lock:
            self.active.pop(outcome.take.name, None)
            self.finished += 1
            self.failed += outcome.status == "failed"
            if self.out.isatty():
                self._line(f"{outcome.take.name} {outcome.status}")
            else:
                reason = f": {outcome.reason}" if outcome.reason else ""
                print(f"[{self.finished}/{self.total}] {outcome.take.name} {outcome.status}"
                      f"{reason}", file=self.out, flush=True)

    def _line(self, last: str) -> None:
        if not self.out.isatty():
            return
        text = (f"[{self.finished}/{self.total} done, {self.failed} failed, "
                f"{len(self.active)} running] {last}")
        self.out.write("\r\x1b[K" + text[:120])
        self.out.flush()

    def close(self) -> None:
        """End the rewritten line."""
        if self.out.isatty():
            self.out.write("\n")


@dataclass(frozen=True)
class Batch:
    """What every take of one ``bonefit submit`` shares."""

    client: Client
    kind: str
    params: Mapping[str, Any]
    format: str
    outdir: Path
    state: State
    board: Board

    def earlier(self, take: Take) -> Outcome | None:
        """The take's earlier finished job, verified on the server (files re-fetched if
        missing), or None."""
        entry = self.state.get(take.key(self.kind, self.params))
        if entry is None:
            return None
        try:
            job = self.client.job(entry["job"])
        except ProblemError:
            return None  # deleted, purged or another server: run it again
        if job.status != "succeeded":
            return None
        return Outcome(take, "skipped", job.id, files=self.fetch(take, job))

    def fetch(self, take: Take, job: Job) -> tuple[str, ...]:
        """Download every result format of the job beside the take's name (missing ones)."""
        files = []
        for fmt in sorted(job.results):
            target = self.outdir / f"{take.name}.{fmt}"
            if not target.exists():
                self.client.download(job, fmt, target)
            files.append(target.name)
        return tuple(files)

    def run(self, take: Take) -> Outcome:
        """Upload, submit, wait and download one take; failures become an outcome."""
        start = time.monotonic()
        try:
            return self.earlier(take) or self._run(take, start)
        except ProblemError as exc:
            return Outcome(take, "failed", reason=str(exc), seconds=time.monotonic() - start)
        except (httpx.HTTPError, OSError) as exc:
            reason = f"{type(exc).__name__}: {exc}"
            return Outcome(take, "failed", reason=reason, seconds=time.monotonic() - start)

    def _run(self, take: Take, start: float) -> Outcome:
        try:
            recording = self.client.upload(take.path, format=self.format)
        except ProblemError as exc:
            raise ProblemError({**exc.problem, "detail": f"upload refused: {exc.detail}"}
                               ) from exc
        job = self.client.submit(self.kind, recording, self.params)
        job = self.client.wait(job, progress=lambda j: self.board.progress(take.name, j.fraction))
        if job.status != "succeeded":
            detail = (job.error or {}).get("detail") or job.message or "no detail"
            return Outcome(take, "failed", job.id, time.monotonic() - start,
                           f"job {job.status}: {detail}")
        files = self.fetch(take, job)
        self.state.record(take.key(self.kind, self.params),
                          {"job": job.id, "take": take.path.name, "files": list(files)})
        return Outcome(take, "done", job.id, time.monotonic() - start, files=files)


def summary(outcomes: Sequence[Outcome]) -> str:
    """The table printed at the end: take, status, job, seconds, files or reason."""
    rows = [("take", "status", "job", "seconds", "result / reason")]
    for o in outcomes:
        rows.append((o.take.path.name, o.status, o.job_id or "-", f"{o.seconds:.1f}",
                     o.reason or ", ".join(o.files)))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r[:4], widths, strict=True)) + "  " + r[4]
             for r in rows]
    counts = {s: sum(o.status == s for o in outcomes) for s in ("done", "skipped", "failed")}
    lines.append(f"{counts['done']} done, {counts['skipped']} already done, "
                 f"{counts['failed']} failed")
    return "\n".join(lines)


def submit_all(takes: Sequence[Take], batch: Batch, jobs: int) -> list[Outcome]:
    """Run the takes with at most ``jobs`` at a time; outcomes in the takes' order."""

    def one(take: Take) -> Outcome:
        outcome = batch.run(take)
        batch.board.finish(outcome)
        return outcome

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        return list(pool.map(one, takes))


def run_submit(args: argparse.Namespace) -> int:
    """The ``bonefit submit`` command."""
    try:
        params = parse_params(args.param)
    except ValueError as exc:
        print(f"bonefit: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    missing = [str(p) for p in args.takes if not p.is_file()]
    if missing:
        print(f"bonefit: error: no such file: {', '.join(missing)}", file=sys.stderr)
        return EXIT_USAGE
    args.outdir.mkdir(parents=True, exist_ok=True)
    takes = collect_takes(args.takes)
    api_key = args.api_key or os.environ.get("BONEFIT_API_KEY") or None
    board = Board(len(takes))
    with Client(args.server, api_key) as client:
        batch = Batch(client, args.kind, params, args.format, args.outdir,
                      State(args.outdir / STATE_FILE), board)
        try:
            outcomes = submit_all(takes, batch, args.jobs)
        finally:
            board.close()
    print(summary(outcomes))
    return EXIT_FAILED if any(o.status == "failed" for o in outcomes) else 0


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return value


def register_submit(sub: Any, summary: str) -> None:
    """Add ``submit`` to the ``bonefit`` sub-commands (called by :mod:`bonefit.cli`)."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "submit", help=summary,
        description="Upload TAKES to a bonefit server, run a job on each (at most --jobs at a "
                    "time) and write each result beside its name in OUTDIR. Takes already "
                    "finished with the same file content, kind and params are not run again. "
                    "Exits 1 if any take failed.")
    parser.add_argument("takes", nargs="+", type=Path, metavar="TAKE")
    parser.add_argument("--server", required=True, metavar="URL",
                        help="the server, e.g. http://127.0.0.1:8000")
    parser.add_argument("--api-key", metavar="KEY",
                        help="API key (default: $BONEFIT_API_KEY; none for a loopback server)")
    parser.add_argument("--kind", default="skeleton", help="job kind (default skeleton)")
    parser.add_argument("--param", action="append", default=[], metavar="K=V",
                        help="a job parameter, repeatable; V is JSON or a string")
    parser.add_argument("--format", default="auto", help="upload format (default auto)")
    parser.add_argument("--jobs", type=_positive, default=4, metavar="N",
                        help="takes in flight at once (default 4)")
    parser.add_argument("-o", "--outdir", type=Path, required=True, help="where results go")
    parser.set_defaults(run=run_submit)
