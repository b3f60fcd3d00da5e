"""The ``bonefit`` command (also ``python -m bonefit``): one parser for every sub-command.

Each sub-command lives in its layer (``skeleton`` and ``translate`` in
:mod:`bonefit.estimation.cli`, ``serve`` and ``worker`` in :mod:`bonefit.service.cli`,
``submit`` in :mod:`bonefit.client.batch`) as a ``register(subparsers)`` function. Only the
chosen command's module is imported, so ``bonefit --help`` and ``bonefit --version`` are fast
and work with the base install (numpy only); a command whose extra is not installed says which
one to install. Layers point one way: this module -> service -> estimation.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

EXIT_BAD_INPUT = 2
EXIT_MISSING_EXTRA = 3


@dataclass(frozen=True)
class Command:
    """Where a sub-command is registered and which extra it needs."""

    module: str
    register: str
    extra: str
    summary: str
    one_blas_thread: bool = False
    """Run with one BLAS thread (``estimation.threads``) and freed memory kept for reuse
    (``estimation.memory``): the estimating commands."""


COMMANDS = {
    "skeleton": Command("bonefit.estimation.cli.skeleton", "register", "estimation",
                        "estimate joint centres, bone lengths and orientations from 6-DOF "
                        "sensors", one_blas_thread=True),
    "translate": Command("bonefit.estimation.cli.translate", "register", "estimation",
                         "root path of an inertial-suit recording from its foot accelerometers",
                         one_blas_thread=True),
    "serve": Command("bonefit.service.cli", "register_serve", "service",
                     "run the REST API (with embedded workers unless --no-worker)"),
    "worker": Command("bonefit.service.cli", "register_worker", "service",
                      "run job workers against the configured queue"),
    "submit": Command("bonefit.client.batch", "register_submit", "client",
                      "upload and run many takes on a bonefit server"),
}
"""Sub-command name -> its registration; the one list of the CLI's commands."""

EXTRA_OF_MODULE = {"scipy": "estimation", "httpx": "client", "fastapi": "service",
                   "uvicorn": "service", "pydantic": "service", "pydantic_settings": "service",
                   "huey": "service", "sqlalchemy": "service", "redis": "service",
                   "boto3": "service", "botocore": "service", "prometheus_client": "service",
                   "multipart": "service", "psycopg": "service", "fastapi_offline": "service"}
"""Top-level module of a third-party dependency -> the extra that installs it."""


def package_version() -> str:
    """The installed distribution's version (``importlib.metadata``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bonefit")
    except PackageNotFoundError:  # running from a source tree that is not installed
        from . import __version__

        return __version__


class VersionAction(argparse.Action):
    """``--version``: print ``bonefit <version>`` and exit, the version looked up only then
    (importing ``importlib.metadata`` and searching the installed distributions took
    240-280 ms of every command's start on a loaded 2-core machine)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings, dest=dest, default=default, nargs=0,
                         help=help or "show the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        print(f"bonefit {package_version()}")  # on stdout, as argparse's own action
        parser.exit()


def missing_extra(exc: ModuleNotFoundError) -> str | None:
    """The extra that installs the module ``exc`` could not find, if it is one of ours."""
    return EXTRA_OF_MODULE.get((exc.name or "").split(".")[0])


def report_missing(name: str, extra: str) -> int:
    """Say which extra the command ``name`` needs; the exit code."""
    print(f"bonefit: error: `bonefit {name}` needs the {extra!r} extra: "
          f"pip install 'bonefit[{extra}]'", file=sys.stderr)
    return EXIT_MISSING_EXTRA


def registration(command: Command) -> Callable[[Any, str], None]:
    """The ``register(subparsers, summary)`` function of ``command`` (imports its module)."""
    register: Callable[[Any, str], None] = getattr(importlib.import_module(command.module),
                                                   command.register)
    return register


def chosen_command(argv: Sequence[str]) -> str | None:
    """The sub-command named on the command line (the first argument not an option)."""
    first = next((arg for arg in argv if not arg.startswith("-")), None)
    return first if first in COMMANDS else None


def build_parser(argv: Sequence[str] = ()) -> argparse.ArgumentParser:
    """The top-level parser: the command ``argv`` names is loaded with all its options, the
    others are listed by name and summary only (their modules are not imported)."""
    parser = argparse.ArgumentParser(
        prog="bonefit",
        description="Skeletons and root paths from body-worn motion-capture sensors.")
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    chosen = chosen_command(argv)
    for name, command in COMMANDS.items():
        if name == chosen:
            registration(command)(sub, command.summary)
        else:
            sub.add_parser(name, help=command.summary)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the parsed command; bad input exits 2 with a one-line reason."""
    from .estimation.errors import BonefitError

    try:
        code: int = args.run(args)
    except BonefitError as exc:
        print(f"bonefit: error: {exc.detail}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FileNotFoundError as exc:
        print(f"bonefit: error: no such file: {exc.filename}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ModuleNotFoundError as exc:
        extra = missing_extra(exc)
        if extra is None:
            raise
        return report_missing(args.command, extra)
    except KeyboardInterrupt:
        return 130
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``bonefit`` and ``python -m bonefit``; returns the exit code."""
    arguments = sys.argv[1:] if argv is None else list(argv)
    chosen = chosen_command(arguments)
    try:
        if chosen is not None and COMMANDS[chosen].one_blas_thread:
            from .estimation.memory import retain_freed_memory
            from .estimation.threads import limit_blas_threads

            limit_blas_threads()  # before the command's module imports numpy
            retain_freed_memory()
        parser = build_parser(arguments)
    except ModuleNotFoundError as exc:  # the chosen command's extra is not installed
        extra = missing_extra(exc)
        if extra is None:
            raise
        return report_missing(chosen or "", extra)
    return run(parser.parse_args(arguments))


def entry() -> NoReturn:
    """The ``bonefit`` console script and ``python -m bonefit``: :func:`main` on the
    command line, then exit with its code.

    After an estimating command (``Command.one_blas_thread``) every object left is frozen
    (``gc.freeze``) before the exit: the interpreter's teardown then skips the garbage
    collections over every object of numpy's and scipy's modules, which only delayed the
    exit (from ``main``'s return to the process's end 0.7-1.1 s after a 144,000-frame
    skeleton run on a loaded 2-core machine, 0.3-0.4 s frozen). Files are closed and threads
    joined by then; other commands exit as they did.
    """
    arguments = sys.argv[1:]
    code = main(arguments)
    chosen = chosen_command(arguments)
    if chosen is not None and COMMANDS[chosen].one_blas_thread:
        gc.freeze()
    sys.exit(code)
