"""``bonefit skeleton``: placeholder until its estimation lands."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    """Add the ``skeleton`` command to the sub-parsers."""
    parser: argparse.ArgumentParser = sub.add_parser("skeleton", help="(not yet available)")
    parser.set_defaults(run=lambda args: 1)
