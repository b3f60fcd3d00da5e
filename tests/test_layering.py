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


# --------------------------------------------------------------------------- module graph

PACKAGES = ("estimation", "service")

PRIVATE_IMPORTS_ALLOWED: set[tuple[str, str]] = {
    # issue 18 §1/§3 (a18-core/a18-skel): slip's shared model reuses the joint equations'
    # slip basis and noise variance; they become public where slip and joints settle
    ("estimation.slip", "estimation.joints._slip_basis"),
    ("estimation.slip", "estimation.joints._white_variance"),
}
"""(importing module, imported private name) pairs still to be made public, with the issue."""

CYCLES_ALLOWED: set[frozenset[str]] = {
    # issue 18 §3 (a18-core): mvnx takes KinematicsRecording and GRAVITY from io/kinematics,
    # which dispatches to mvnx; they move to a core module
    frozenset({"estimation.io.kinematics", "estimation.io.mvnx"}),
    # issue 18 §3 (a18-io, after h16-uploads): tracker takes UNITS and fps_from_time from
    # io/sensors, which dispatches to tracker; the sensors split gives them their own module
    frozenset({"estimation.io.sensors", "estimation.io.tracker"}),
}
"""Import cycles (the set of their modules) still to be broken, with the issue."""


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p
            for package in PACKAGES for p in sorted((root / package).rglob("*.py"))}


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes under ``if TYPE_CHECKING:`` (no run-time dependency)."""
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skipped.update(id(child) for stmt in node.body for child in ast.walk(stmt))
    return skipped


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, str]]:
    """(imported module, imported name or "") for every run-time import of a project module,
    at module level or inside a function; relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    skipped = _type_checking_only(tree)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found: list[tuple[str, str]] = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found.extend((a.name, "") for a in node.names if a.name.split(".")[0] in PACKAGES)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            target = ".".join([*base, *([node.module] if node.module else [])])
            if target.split(".")[0] not in PACKAGES:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                found.append((sub, "") if sub in modules else (target, alias.name))
    return found


def private_imports(modules: dict[str, Path]) -> set[tuple[str, str]]:
    """(module, private name) pairs: a ``_name`` taken from another module. A package's own
    ``_module`` (``estimation._rows``) is private to that package and may be imported in it."""
    bad: set[tuple[str, str]] = set()
    for name, path in modules.items():
        for target, attr in imports_of(name, path, modules):
            if attr.startswith("_") and not attr.startswith("__"):
                bad.add((name, f"{target}.{attr}"))
            private = [p for p in target.split(".") if p.startswith("_") and p != "__init__"]
            owner = target.rsplit(".", 1)[0]
            if private and not (name == owner or name.startswith(owner + ".")):
                bad.add((name, target))
    return bad


def import_cycles(modules: dict[str, Path]) -> list[frozenset[str]]:
    """Strongly connected components of more than one module (Tarjan's algorithm)."""
    graph = {name: {t for t, _ in imports_of(name, path, modules) if t in modules and t != name}
             for name, path in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[frozenset[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in graph[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(frozenset(component))

    for name in sorted(graph):
        if name not in index:
            visit(name)
    return cycles


def test_no_private_name_is_imported_across_modules() -> None:
    found = private_imports(project_modules())
    assert found <= PRIVATE_IMPORTS_ALLOWED, sorted(found - PRIVATE_IMPORTS_ALLOWED)
    assert not PRIVATE_IMPORTS_ALLOWED - found, "fixed: remove from the allow-list"


def test_no_import_cycle() -> None:
    found = set(import_cycles(project_modules()))
    assert found <= CYCLES_ALLOWED, [sorted(c) for c in found - CYCLES_ALLOWED]
    assert not CYCLES_ALLOWED - found, "fixed: remove from the allow-list"


def test_checkers_catch_a_cycle_and_a_private_import(tmp_path: Path) -> None:
    files = {
        "estimation/__init__.py": "from . import _lazy\n",
        "estimation/_lazy.py": "",
        "estimation/a.py": "from .b import public\n",
        "estimation/b.py": "def public(): from .c import _hidden\n",
        "estimation/c.py": "from typing import TYPE_CHECKING\nimport estimation.a\n"
                           "if TYPE_CHECKING:\n    from .d import _typed\n",
        "estimation/d.py": "",
        "service/__init__.py": "",
        "service/x.py": "from estimation import _lazy\nfrom estimation.d import thing\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    modules = project_modules(tmp_path)
    assert import_cycles(modules) == [frozenset({"estimation.a", "estimation.b", "estimation.c"})]
    assert private_imports(modules) == {("estimation.b", "estimation.c._hidden"),
                                        ("service.x", "estimation._lazy")}
