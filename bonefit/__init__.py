"""bonefit: skeletons and root paths from body-worn motion-capture sensors.

The top-level package; :mod:`bonefit.client` is the Python client of the REST service
(``pip install 'bonefit[client]'``: httpx and numpy only).
"""

from __future__ import annotations

__version__ = "0.1.0"
