"""The numerical sub-commands of ``bonefit``: ``skeleton`` and ``translate``.

Each module has a ``register(subparsers, summary)`` function that :mod:`bonefit.cli` (the one
top-level parser) calls; this package never imports the service or the command module.
"""
