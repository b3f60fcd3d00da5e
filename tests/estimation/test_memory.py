"""``memory.retain_freed_memory``: freed blocks kept for reuse by the estimating commands."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

import bonefit.cli
from bonefit.estimation import memory

GLIBC = platform.libc_ver()[0] == "glibc"

# Rounds of ten 3 MB arrays allocated and freed together: glibc's dynamic thresholds hand
# the freed 30 MB back to the system every round (its trim threshold is twice the largest
# freed block), so each round faults its pages in anew; kept, later rounds reuse them.
FAULTS = """
import resource, sys
import numpy as np
from bonefit.estimation.memory import retain_freed_memory
kept = retain_freed_memory() if sys.argv[1] == "kept" else None
def round_():
    arrays = [np.ones(3 << 17) for _ in range(10)]
    del arrays
round_()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    round_()
print(kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(mode: str) -> tuple[str, int]:
    """(what ``retain_freed_memory`` returned, minor page faults of the later rounds)."""
    env = {k: v for k, v in os.environ.items()
           if k != "GLIBC_TUNABLES" and not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", FAULTS, mode], capture_output=True, text=True,
                         check=True, env=env).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not GLIBC, reason="mallopt thresholds are glibc's")
def test_freed_blocks_are_reused_instead_of_faulted_in_again() -> None:
    returned, kept = faults("kept")
    _, default = faults("default")
    assert returned == "True"
    # 20 rounds of 30 MB are about 150,000 pages faulted in by default
    assert default > 50_000
    assert kept < default / 10


@pytest.mark.parametrize("environ", [{"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1"},
                                     {"MALLOC_ARENA_MAX_": "2"}])
def test_a_users_own_malloc_settings_stay(environ: dict[str, str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(memory.ctypes, "CDLL", lambda _: pytest.fail("mallopt was called"))
    assert memory.retain_freed_memory(environ) is False


def test_without_mallopt_nothing_is_set(monkeypatch: pytest.MonkeyPatch) -> None:
    class NoMallopt:  # another C library (musl, macOS): no such function
        def __init__(self, _name: object) -> None:
            pass

    monkeypatch.setattr(memory.ctypes, "CDLL", NoMallopt)
    assert memory.retain_freed_memory({}) is False


@pytest.mark.parametrize(("argv", "called"), [(["skeleton", "--help"], True),
                                              (["translate", "--help"], True),
                                              (["--version"], False)])
def test_the_estimating_commands_keep_freed_memory(argv: list[str], called: bool,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[bool] = []
    monkeypatch.setattr(memory, "retain_freed_memory", lambda: calls.append(True) or True)
    with pytest.raises(SystemExit):
        bonefit.cli.main(argv)
    assert calls == ([True] if called else [])
