"""Container health check for the bonefit image (standard library only).

The API container is healthy when ``GET /healthz`` answers 200 on loopback; the port comes from
``--port`` on PID 1's command line, else ``BONEFIT_PORT``, else 8000. A worker container
(``bonefit worker``) has no HTTP port: it is healthy while its main process runs.
"""

from __future__ import annotations

import os
import sys
import urllib.request
from pathlib import Path


def main_command() -> list[str]:
    try:
        raw = Path("/proc/1/cmdline").read_bytes()
    except OSError:
        return []
    return [part.decode(errors="replace") for part in raw.split(b"\0") if part]


def port_from(argv: list[str]) -> int:
    for i, arg in enumerate(argv):
        if arg == "--port" and i + 1 < len(argv):
            return int(argv[i + 1])
        if arg.startswith("--port="):
            return int(arg.split("=", 1)[1])
    return int(os.environ.get("BONEFIT_PORT", "8000"))


def main(argv: list[str] | None = None) -> int:
    """0 when healthy; ``argv`` is PID 1's command line unless given."""
    argv = main_command() if argv is None else argv
    if "worker" in argv[1:4]:
        return 0
    url = f"http://127.0.0.1:{port_from(argv)}/healthz"
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # never via a proxy
    try:
        with opener.open(url, timeout=4) as response:
            return 0 if response.status == 200 else 1
    except OSError as exc:
        print(f"{url}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
