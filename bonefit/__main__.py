"""``python -m bonefit``: the ``bonefit`` command."""

import sys

from .cli import main

sys.exit(main())
