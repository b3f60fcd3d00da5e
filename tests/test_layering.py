"""The numerical core imports only the standard library, numpy and scipy; never the service;
and its packages load their parts lazily, so that the API process runs without scipy."""

from __future__ import annotations

import ast
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED_THIRD_PARTY = {"numpy", "scipy"}


def imported_names(path: Path) -> set[str]:
    """Dotted names of the absolute imports of a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def foreign_imports(path: Path) -> set[str]:
    """What a file of the numerical core imports beyond stdlib, numpy, scipy and itself."""
    return {
        name for name in imported_names(path)
        if name.split(".")[0] not in sys.stdlib_module_names
        and name.split(".")[0] not in ALLOWED_THIRD_PARTY
        and name != "bonefit.estimation" and not name.startswith("bonefit.estimation.")
    }


@pytest.mark.parametrize("path", sorted((ROOT / "estimation").rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_estimation_imports_only_stdlib_numpy_scipy(path: Path) -> None:
    foreign = foreign_imports(path)
    assert not foreign, f"{path.name} imports {sorted(foreign)}"


def test_checker_catches_a_forbidden_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("import fastapi\nfrom bonefit.service import app\nimport numpy as np\n"
                   "from bonefit import cli\nfrom bonefit.estimation.io import sensors\n")
    assert foreign_imports(bad) == {"fastapi", "bonefit.service", "bonefit"}


def run_fresh(code: str) -> None:
    """Run ``code`` in a new interpreter (nothing imported yet); fail with its stderr."""
    done = subprocess.run([sys.executable, "-c", code], cwd=tempfile.gettempdir(),
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_packages_load_under_one_name_only() -> None:
    # Top-level `estimation` or `service` would be a second copy of every module (two
    # BonefitError classes): the installed environment has no such packages, and the packages
    # refuse to load under another name even with the repository root on sys.path.
    run_fresh("import importlib.util, bonefit.estimation, bonefit.service\n"
              "assert importlib.util.find_spec('estimation') is None\n"
              "assert importlib.util.find_spec('service') is None\n")
    for name in ("estimation", "service", "estimation.errors", "service.app"):
        done = subprocess.run([sys.executable, "-c", f"import {name}"], cwd=ROOT,
                              capture_output=True, text=True)
        assert done.returncode == 1
        assert f"import bonefit.{name.split('.')[0]}, not" in done.stderr


def test_the_command_loads_only_the_chosen_command() -> None:
    # `bonefit --help` must work with the base install (numpy) and stay fast
    run_fresh("import sys\nfrom bonefit.cli import build_parser\nbuild_parser(['--help'])\n"
              "heavy = {'scipy', 'httpx', 'fastapi', 'uvicorn', 'pydantic', 'sqlalchemy'}\n"
              "loaded = sorted(heavy & {m.split('.')[0] for m in sys.modules})\n"
              "assert not loaded, loaded\n")


def test_public_names_resolve_and_load_lazily() -> None:
    code = (
        "import sys, bonefit.estimation, bonefit.estimation.io\n"
        "assert 'scipy' not in sys.modules, 'importing the package loaded scipy'\n"
        "for package in (bonefit.estimation, bonefit.estimation.io):\n"
        "    for name in package.__all__:\n"
        "        assert getattr(package, name) is not None, name\n"
        "        assert name in dir(package), name\n"
        "assert 'scipy' in sys.modules\n"
        "try:\n"
        "    bonefit.estimation.no_such_name\n"
        "except AttributeError as exc:\n"
        "    assert 'no_such_name' in str(exc)\n"
        "else:\n"
        "    raise AssertionError('an unknown name resolved')\n")
    run_fresh(code)


def test_results_and_their_json_readers_load_without_scipy() -> None:
    # the Python client reads result documents into these classes with numpy only; the
    # names stay importable from where they were (the BVH writer's and estimator's modules)
    run_fresh("import sys\n"
              "from bonefit.estimation import SkeletonResult, TranslationResult\n"
              "from bonefit.estimation.io import offsets_from_dict, result_from_dict\n"
              "from bonefit.estimation.io import skeleton_from_dict, translation_from_dict\n"
              "assert 'scipy' not in sys.modules\n"
              "from bonefit.estimation.io import skeleton\n"
              "from bonefit.estimation import translation\n"
              "assert skeleton.skeleton_from_dict is skeleton_from_dict\n"
              "assert skeleton.offsets_from_dict is offsets_from_dict\n"
              "assert translation.TranslationResult is TranslationResult\n")


def test_api_process_does_not_load_scipy() -> None:
    # uploads are sniffed in the API process: without scipy it needs ~40 MB less memory
    code = ("import sys, bonefit.cli, bonefit.service.app, bonefit.service.cli, "
            "bonefit.service.routes, bonefit.service.uploads\n"
            "loaded = sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')\n"
            "assert not loaded, loaded[:5]\n")
    run_fresh(code)


def test_worker_preload_loads_what_the_kinds_run() -> None:
    code = ("import sys\nfrom bonefit.service.kinds import preload\npreload()\n"
            "assert 'scipy.spatial.transform' in sys.modules\n"
            "assert 'bonefit.estimation.skeleton' in sys.modules\n"
            "assert 'bonefit.estimation.translation' in sys.modules\n")
    run_fresh(code)


# ------------------------------------------------- private names and import cycles (issue 18 §3)

PACKAGES = ("estimation", "service")
"""Directories of the repository installed as ``bonefit.<name>``."""
# Private helpers of estimation/io still imported elsewhere: the io engineers make them public
# (issue 18 §3); each entry is (importing module, name). Do not add to this list.
KNOWN_PRIVATE_IMPORTS: set[tuple[str, str]] = set()


def module_files(root: Path) -> dict[str, Path]:
    """Dotted module name (``bonefit.estimation.io``) -> file of every module of ``PACKAGES``
    and of ``bonefit``'s own modules under ``root``."""
    out = {}
    own = [p for p in (root / "bonefit").rglob("*.py")
           if p.relative_to(root / "bonefit").parts[0] not in PACKAGES]
    for path in own + [p for d in PACKAGES for p in (root / d).rglob("*.py")]:
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[0] != "bonefit":
            parts.insert(0, "bonefit")
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return dict(sorted(out.items()))


def imported_modules(name: str, path: Path, modules: dict[str, Path],
                     node: ast.ImportFrom) -> list[tuple[str, str]]:
    """(module, imported name) per name of a ``from ... import`` statement: the module the
    name comes from, or the submodule itself when the name is one."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    if node.level:
        parts = package[:len(package) - (node.level - 1)]
        source = ".".join(parts + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    return [(f"{source}.{a.name}" if f"{source}.{a.name}" in modules else source, a.name)
            for a in node.names]


def private_imports(root: Path) -> set[tuple[str, str]]:
    """(importing module, name) of every ``_name`` imported from another module (private
    modules such as ``_rows`` are allowed inside their package), and of every
    ``module._name`` attribute read through an imported module."""
    modules = module_files(root)
    found = set()
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                for source, imported in imported_modules(name, path, modules, node):
                    alias = next(a.asname or a.name for a in node.names if a.name == imported)
                    if source.endswith(f".{imported}") or source == imported:
                        aliases.add(alias)  # a module
                    elif imported.startswith("_") and not imported.startswith("__"):
                        found.add((name, imported))
            elif isinstance(node, ast.Import):
                aliases.update(a.asname or a.name.split(".")[0] for a in node.names)
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and node.attr.startswith("_")
                    and not node.attr.startswith("__")):
                found.add((name, f"{node.value.id}.{node.attr}"))
    return found


def import_cycles(root: Path) -> list[list[str]]:
    """Cycles (strongly connected groups) of the module-level imports between modules of
    ``PACKAGES``; imports inside functions or ``if TYPE_CHECKING:`` do not count."""
    modules = module_files(root)
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps: set[str] = set()
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ImportFrom):
                deps.update(s for s, _ in imported_modules(name, path, modules, node)
                            if s in modules)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name in modules)
        graph[name] = deps - {name}
    reach: dict[str, set[str]] = {name: set() for name in graph}
    for start in graph:
        todo = list(graph[start])
        while todo:
            nxt = todo.pop()
            if nxt not in reach[start]:
                reach[start].add(nxt)
                todo.extend(graph[nxt])
    cycles = {tuple(sorted({m} | {o for o in reach[m] if m in reach[o]}))
              for m in graph if m in reach[m]}
    return [list(c) for c in sorted(cycles)]


def test_no_private_name_is_imported_across_modules() -> None:
    assert private_imports(ROOT) - KNOWN_PRIVATE_IMPORTS == set()


def test_no_import_cycle() -> None:
    assert import_cycles(ROOT) == []


def test_checkers_catch_a_private_import_and_a_cycle(tmp_path: Path) -> None:
    package = tmp_path / "estimation"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "_rows.py").write_text("def helper() -> None: ...\n")
    (package / "a.py").write_text("from . import _rows as rows\nfrom .b import _secret\n")
    (package / "b.py").write_text("from . import a\n_secret = 1\n")
    (package / "c.py").write_text("from . import b\nx = b._secret\n")
    assert private_imports(tmp_path) == {("bonefit.estimation.a", "_secret"),
                                         ("bonefit.estimation.c", "b._secret")}
    assert import_cycles(tmp_path) == [["bonefit.estimation.a", "bonefit.estimation.b"]]


@pytest.mark.parametrize("path", sorted((ROOT / "service").rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_service_never_imports_the_command_module_or_the_client(path: Path) -> None:
    # layers point one way: bonefit.cli -> bonefit.service -> bonefit.estimation
    upward = {n for n in imported_names(path)
              if n == "bonefit" or n.startswith(("bonefit.cli", "bonefit.client"))}
    assert not upward, f"{path.name} imports {sorted(upward)}"
