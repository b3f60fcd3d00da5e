"""Slow clients against a real `bonefit serve --no-worker`: threads and file descriptors.

N clients each start an upload (``Content-Length`` 1 MB) and then send one byte per second
(the server gets a 5 s body timeout, so the minimum body rate sheds them within the run).
The server's thread and descriptor counts are sampled before, while they trickle, and after
they have gone; a well-behaved client is timed while they trickle. With the concurrent-upload
cap, the clients over it are answered 503 at once; those under it hold no thread or buffer
until their first 2 MiB.

    python benchmarks/service_slow_clients.py            # 200 clients for 15 s
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import sys
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from service_common import EXAMPLE, running_server, temp_dir


def counts(pid: int) -> tuple[int, int]:
    """Threads and open descriptors of ``pid``."""
    threads = len(os.listdir(f"/proc/{pid}/task"))
    return threads, len(os.listdir(f"/proc/{pid}/fd"))


def start_slow(port: int) -> socket.socket | None:
    """A connection that announced a 1 MB upload; None if the server refused it."""
    try:
        sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        sock.sendall(b"POST /v1/recordings?filename=slow.csv HTTP/1.1\r\nHost: x\r\n"
                     b"Content-Length: 1000000\r\n\r\n")
        return sock
    except OSError:
        return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clients", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--body-timeout", type=float, default=5.0,
                        help="BONEFIT_BODY_TIMEOUT_SECONDS of the server (default 5)")
    args = parser.parse_args()
    env = {"BONEFIT_BODY_TIMEOUT_SECONDS": str(args.body_timeout)}
    with temp_dir("bonefit-slow-") as tmp, running_server(tmp / "data", no_worker=True,
                                                          extra_env=env) as server:
        port = int(server.base_url.rsplit(":", 1)[1])
        before = counts(server.pid)
        socks = [s for s in (start_slow(port) for _ in range(args.clients)) if s is not None]
        peak = before
        refused = 0
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            for sock in list(socks):
                try:
                    sock.setblocking(False)
                    with contextlib.suppress(BlockingIOError):
                        if sock.recv(65536):  # answered (503 over the cap, 408): shed
                            refused += 1
                            socks.remove(sock)
                            sock.close()
                            continue
                    sock.setblocking(True)
                    sock.sendall(b"0")
                except OSError:
                    socks.remove(sock)
                    sock.close()
            peak = max(peak, counts(server.pid))
            time.sleep(1.0)
        start = time.monotonic()
        r = httpx.post(f"{server.base_url}/v1/recordings", content=EXAMPLE.read_bytes(),
                       params={"filename": "walk.csv"}, timeout=60)
        meanwhile = time.monotonic() - start
        trickling = len(socks)
        for sock in socks:
            sock.close()
        time.sleep(2.0)
        after = counts(server.pid)
    print(f"{args.clients} slow clients for {args.seconds:.0f} s (body timeout "
          f"{args.body_timeout:g} s): {refused} shed (503 over the cap, then 408 too slow), "
          f"{trickling} still trickling at the end")
    print(f"threads: {before[0]} before, {peak[0]} peak, {after[0]} after; "
          f"descriptors: {before[1]} before, {peak[1]} peak, {after[1]} after")
    print(f"a normal upload meanwhile: {r.status_code} in {meanwhile:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
