"""The one ``bonefit`` command module: version, lazy sub-commands, a missing extra named."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path
from types import ModuleType

import pytest

import bonefit.cli
from bonefit.cli import COMMANDS, main


def test_python_m_bonefit_prints_the_installed_version() -> None:
    done = subprocess.run([sys.executable, "-m", "bonefit", "--version"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"bonefit {version('bonefit')}"


def test_the_version_is_looked_up_only_for_version() -> None:
    # importlib.metadata is tens of milliseconds of every command's start
    code = ("import sys; from bonefit.cli import build_parser; "
            "build_parser(['skeleton']).parse_args(['skeleton', 'take.csv']); "
            "print('importlib.metadata' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


@pytest.mark.parametrize(("argv", "frozen"), [
    (["skeleton", "take.csv"], True), (["translate", "take.bvh"], True),
    (["serve"], False), (["submit", "take.csv"], False)])
def test_estimating_commands_exit_without_the_teardowns_collections(
        argv: list[str], frozen: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    froze: list[bool] = []
    monkeypatch.setattr(bonefit.cli.gc, "freeze", lambda: froze.append(True))
    monkeypatch.setattr(bonefit.cli, "main", lambda arguments: 5 if arguments == argv else 9)
    monkeypatch.setattr(sys, "argv", ["bonefit", *argv])
    with pytest.raises(SystemExit) as exit_:
        bonefit.cli.entry()
    assert exit_.value.code == 5
    assert froze == ([True] if frozen else [])


def test_python_m_bonefit_writes_whole_files_and_exits_with_the_code(tmp_path: Path) -> None:
    out = tmp_path / "walk.json"
    done = subprocess.run([sys.executable, "-m", "bonefit", "skeleton", "--example", "-o",
                           str(out), "--quiet"], capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stderr
    assert json.loads(out.read_text())["kind"] == "skeleton"
    bad = subprocess.run([sys.executable, "-m", "bonefit", "skeleton", str(tmp_path / "no.csv")],
                         capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2
    assert "no such file" in bad.stderr


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    for name, command in COMMANDS.items():
        assert name in out
        assert command.summary.split()[0] in out


def _missing(name: str) -> ModuleType:
    raise ModuleNotFoundError(f"No module named {name!r}", name=name)


@pytest.mark.parametrize(("command", "missing", "extra"), [
    ("skeleton", "scipy", "estimation"),
    ("serve", "uvicorn", "service"),
    ("submit", "httpx", "client"),
])
def test_a_missing_extra_is_named(monkeypatch: pytest.MonkeyPatch,
                                  capsys: pytest.CaptureFixture[str],
                                  command: str, missing: str, extra: str) -> None:
    monkeypatch.setattr(bonefit.cli.importlib, "import_module", lambda _: _missing(missing))
    assert main([command, "--some-flag"]) == bonefit.cli.EXIT_MISSING_EXTRA
    assert f"pip install 'bonefit[{extra}]'" in capsys.readouterr().err


def test_a_missing_extra_at_run_time_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    # a command can import its extra only when it runs (translate: scipy)
    args = bonefit.cli.build_parser(["worker"]).parse_args(["worker"])
    args.run = lambda _: _missing("scipy.spatial")
    assert bonefit.cli.run(args) == bonefit.cli.EXIT_MISSING_EXTRA
    assert "pip install 'bonefit[estimation]'" in capsys.readouterr().err


def test_a_missing_module_that_no_extra_installs_is_a_bug(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bonefit.cli.importlib, "import_module", lambda _: _missing("no_such"))
    with pytest.raises(ModuleNotFoundError):
        main(["skeleton"])


@pytest.mark.parametrize("command", ["skeleton", "translate"])
def test_estimating_commands_run_with_one_blas_thread_unless_told(
        command: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from bonefit.estimation.threads import BLAS_LIMITS

    for name in BLAS_LIMITS:  # recorded by monkeypatch, so restored after the test
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    with pytest.raises(SystemExit):
        main([command, "--help"])
    assert {name: os.environ.get(name) for name in BLAS_LIMITS} == {
        **BLAS_LIMITS, "MKL_NUM_THREADS": "3"}


def test_other_commands_leave_blas_threads_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    with pytest.raises(SystemExit):
        main(["--version"])
    assert "OPENBLAS_NUM_THREADS" not in os.environ
