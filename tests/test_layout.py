"""The packages import one way: each module only from its own package or from the packages below it.

Read from the source (``ast``, every import statement, those inside
functions too), so the test also holds for imports that run late.  The
order is the one the README's layout gives; a cycle among modules fails
even inside one package.
"""

from __future__ import annotations

import ast
import functools
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: gelcell's sub-packages from the bottom up; errors, diskcache and machine are the floor
GELCELL_LAYERS = [("errors", "diskcache", "machine"), ("case",), ("geometry",), ("coupled",), ("post",), ("output",),
                  ("run",), ("cli",)]
#: the top-level packages and what each may import of the project
PACKAGES = {"coupling": set(), "femtools": {"coupling"}, "fluid": {"femtools"}, "gel": {"femtools"},
            "cell": {"femtools"}, "gelcell": {"coupling", "femtools", "fluid", "gel", "cell"}}


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: pathlib.Path, modules: set[str]) -> set[str]:
    """Every project module ``path`` imports (``from a.b import c``: a.b.c if it is a module, else a.b)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                found.add(sub if sub in modules else node.module)
    return {m for m in found if m.split(".")[0] in PACKAGES}


def _project_modules() -> dict[str, pathlib.Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


MODULES = _project_modules()


def _layer(module: str) -> int | None:
    parts = module.split(".")
    if parts[0] != "gelcell" or len(parts) < 2:
        return None
    for rank, names in enumerate(GELCELL_LAYERS):
        if parts[1] in names:
            return rank
    raise AssertionError(f"{module}: gelcell.{parts[1]} is in no layer of GELCELL_LAYERS")


@functools.lru_cache(maxsize=None)
def _edges() -> dict[str, set[str]]:
    """module -> the project modules it imports (only those that exist as modules)."""
    return {m: {t for t in _imports(p, set(MODULES)) if t in MODULES and t != m} for m, p in MODULES.items()}


def test_every_gelcell_module_is_in_a_layer():
    for m in MODULES:
        _layer(m)


@pytest.mark.parametrize("package", sorted(PACKAGES))
def test_packages_import_only_what_they_may(package):
    bad = []
    for m, targets in _edges().items():
        if m.split(".")[0] != package:
            continue
        for t in targets:
            top = t.split(".")[0]
            if top != package and top not in PACKAGES[package]:
                bad.append(f"{m} imports {t}")
    assert not bad, bad


def test_gelcell_imports_one_way():
    bad = []
    for m, targets in _edges().items():
        if m == "gelcell" or _layer(m) is None:      # gelcell/__init__.py hands names on
            continue
        for t in targets:
            if _layer(t) is not None and _layer(t) > _layer(m):
                bad.append(f"{m} ({GELCELL_LAYERS[_layer(m)][0]}) imports {t} ({GELCELL_LAYERS[_layer(t)][0]})")
    assert not bad, bad


def _cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``edges`` (as a list of modules), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for t in sorted(edges.get(m, ())):
            if state.get(t) == 1:
                return stack[stack.index(t):] + [t]
            if t not in state and (found := visit(t)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(edges):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_no_import_cycle():
    edges = _edges()
    cycle = _cycle(edges)
    assert cycle is None, " -> ".join(cycle)


def test_the_cycle_finder_finds_cycles():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def _external_imports(path: pathlib.Path) -> set[str]:
    """The top-level names of every module ``path`` imports."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module.split(".")[0])
    return found


def test_the_case_layer_needs_no_finite_elements_and_no_gmsh():
    """gelcell.case describes and validates a run: reading a case file never starts dolfinx or gmsh."""
    heavy = {"dolfinx", "ufl", "basix", "petsc4py", "gmsh", "femtools", "fluid", "gel", "cell"}
    bad = {str(p.relative_to(ROOT)): sorted(_external_imports(p) & heavy)
           for p in (ROOT / "gelcell" / "case").rglob("*.py")}
    assert not {k: v for k, v in bad.items() if v}
