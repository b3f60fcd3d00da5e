"""The numerical core imports only the standard library, numpy and scipy; never the service;
and its packages load their parts lazily, so that the API process runs without scipy."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED_THIRD_PARTY = {"numpy", "scipy"}


def imported_top_levels(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("path", sorted((ROOT / "estimation").rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_estimation_imports_only_stdlib_numpy_scipy(path: Path) -> None:
    foreign = {
        name for name in imported_top_levels(path)
        if name not in sys.stdlib_module_names and name not in ALLOWED_THIRD_PARTY
        and name != "estimation"
    }
    assert not foreign, f"{path.name} imports {sorted(foreign)}"


def test_checker_catches_a_forbidden_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("import fastapi\nfrom service import app\nimport numpy as np\n")
    assert imported_top_levels(bad) == {"fastapi", "service", "numpy"}


def run_fresh(code: str) -> None:
    """Run ``code`` in a new interpreter (nothing imported yet); fail with its stderr."""
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_public_names_resolve_and_load_lazily() -> None:
    code = (
        "import sys, estimation, estimation.io\n"
        "assert 'scipy' not in sys.modules, 'importing the package loaded scipy'\n"
        "for package in (estimation, estimation.io):\n"
        "    for name in package.__all__:\n"
        "        assert getattr(package, name) is not None, name\n"
        "        assert name in dir(package), name\n"
        "assert 'scipy' in sys.modules\n"
        "try:\n"
        "    estimation.no_such_name\n"
        "except AttributeError as exc:\n"
        "    assert 'no_such_name' in str(exc)\n"
        "else:\n"
        "    raise AssertionError('an unknown name resolved')\n")
    run_fresh(code)


def test_api_process_does_not_load_scipy() -> None:
    # uploads are sniffed in the API process: without scipy it needs ~40 MB less memory
    code = ("import sys, service.app, service.cli, service.routes, service.uploads\n"
            "loaded = sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')\n"
            "assert not loaded, loaded[:5]\n")
    run_fresh(code)


def test_worker_preload_loads_what_the_kinds_run() -> None:
    code = ("import sys\nfrom service.kinds import preload\npreload()\n"
            "assert 'scipy.spatial.transform' in sys.modules\n"
            "assert 'estimation.skeleton' in sys.modules and 'estimation.translation' in "
            "sys.modules\n")
    run_fresh(code)
