"""The ``bonefit`` command line.

``skeleton`` and ``translate`` live here; other packages add commands (``serve``, ``worker``)
through the ``bonefit.commands`` entry-point group, each a ``register(subparsers)`` function,
so this package never imports them.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points

from ..errors import BonefitError
from . import skeleton, translate

EXIT_BAD_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every available sub-command."""
    parser = argparse.ArgumentParser(
        prog="bonefit",
        description="Skeletons and root paths from body-worn motion-capture sensors.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    skeleton.register(sub)
    translate.register(sub)
    for ep in sorted(entry_points(group="bonefit.commands"), key=lambda e: e.name):
        try:
            ep.load()(sub)
        except ImportError:  # extra not installed: the command is simply absent
            continue
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (2 on bad input, with a one-line reason)."""
    args = build_parser().parse_args(argv)
    try:
        code: int = args.run(args)
    except BonefitError as exc:
        print(f"bonefit: error: {exc.detail}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FileNotFoundError as exc:
        print(f"bonefit: error: no such file: {exc.filename}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130
    return code
