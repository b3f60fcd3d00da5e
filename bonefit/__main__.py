"""``python -m bonefit``: the ``bonefit`` command."""

from .cli import entry

entry()
