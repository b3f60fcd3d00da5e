"""The ``bonefit serve`` and ``bonefit worker`` commands (registered by :mod:`bonefit.cli`)."""

from __future__ import annotations

import argparse
import logging
import re
import signal
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import Any

log = logging.getLogger("bonefit.service")


class BadSettings(Exception):
    """A BONEFIT_* variable or flag has an invalid value."""


def _settings(args: argparse.Namespace, **extra: Any) -> Any:
    from pydantic import ValidationError
    from pydantic_settings import SettingsError

    from .settings import Settings

    overrides = {k: v for k, v in extra.items() if v is not None}
    if args.data_dir is not None:
        overrides["data_dir"] = args.data_dir
    try:
        return Settings(**overrides)
    except SettingsError as exc:  # a dict variable that is not JSON
        found = re.search(r'field "(\w+)"', str(exc))
        name = found.group(1).upper() if found else "?"
        raise BadSettings(f"cannot parse BONEFIT_{name}: expected JSON") from None
    except ValidationError as exc:
        first = exc.errors()[0]
        name = "_".join(str(p) for p in first["loc"][:1]).upper()
        raise BadSettings(f"invalid setting BONEFIT_{name}: {first['msg']}") from None


def _guarded(command: Any) -> Any:
    """Print a one-line error (exit 2) instead of a traceback for bad settings."""

    def run(args: argparse.Namespace) -> int:
        try:
            code: int = command(args)
        except BadSettings as exc:
            print(f"bonefit: error: {exc}", file=sys.stderr)
            return 2
        return code

    return run


def _logging(level: str) -> None:
    logging.basicConfig(level=level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s[%(process)d]: %(message)s")


def serve(args: argparse.Namespace) -> int:
    """Run the API (uvicorn) and, unless --no-worker, the embedded worker pool."""
    import uvicorn

    from .app import create_app
    from .pool import WorkerPool

    settings = _settings(args, host=args.host, port=args.port, workers=args.workers)
    _logging(settings.log_level)
    if not settings.api_keys:
        log.warning("no API keys configured (BONEFIT_API_KEYS): serving loopback clients only, "
                    "as tenant 'local'")
    app = create_app(settings)
    pool = None
    if not args.no_worker and settings.workers > 0:
        pool = WorkerPool(settings, settings.workers)
        pool.start()
        log.info("started %d embedded worker processes", settings.workers)
    # uvicorn re-raises the signal after its graceful shutdown: make that return here instead
    signal.signal(signal.SIGTERM, _ignore)
    try:
        uvicorn.Server(uvicorn.Config(app, host=settings.host, port=settings.port,
                                      log_level=settings.log_level, access_log=False,
                                      timeout_graceful_shutdown=10,
                                      limit_concurrency=settings.max_connections,
                                      timeout_keep_alive=settings.keep_alive_seconds)).run()
    finally:
        if pool is not None:
            pool.stop()
    return 0


def _ignore(signum: int, frame: FrameType | None) -> None:
    """Signal handler that only lets the main loop notice."""


def worker(args: argparse.Namespace) -> int:
    """Run worker processes that take jobs from the queue."""
    from .pool import WorkerPool
    from .worker import run_worker

    settings = _settings(args)
    _logging(settings.log_level)
    if args.concurrency == 1:
        return run_worker(settings, parent_pid=args.parent_pid)
    pool = WorkerPool(settings, args.concurrency)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    pool.start()
    log.info("started %d worker processes", args.concurrency)
    while not stop.wait(1.0):
        pass
    pool.stop()
    return 0


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError("must be at least 1")
    return value


def register_serve(sub: Any, summary: str) -> None:
    """Add ``serve`` to the ``bonefit`` sub-commands."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "serve", help=summary,
        description="Run the REST API. Settings come from BONEFIT_* variables; flags win.")
    parser.add_argument("--host", help="interface to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port (default 8000)")
    parser.add_argument("--data-dir", type=Path, help="local state (default ./bonefit-data)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="embedded worker processes (default 2)")
    parser.add_argument("--no-worker", action="store_true",
                        help="API only; run `bonefit worker` elsewhere")
    parser.set_defaults(run=_guarded(serve))


def register_worker(sub: Any, summary: str) -> None:
    """Add ``worker`` to the ``bonefit`` sub-commands."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "worker", help=summary,
        description="Take jobs from BONEFIT_QUEUE_URL and run them.")
    parser.add_argument("--concurrency", type=_positive, default=1, metavar="N",
                        help="worker processes (default 1)")
    parser.add_argument("--data-dir", type=Path, help="local state (default ./bonefit-data)")
    parser.add_argument("--parent-pid", type=int, help=argparse.SUPPRESS)
    parser.set_defaults(run=_guarded(worker))

