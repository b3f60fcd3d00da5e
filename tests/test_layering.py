"""The numerical core imports only the standard library, numpy and scipy; never the service."""

from __future__ import annotations

import ast
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
