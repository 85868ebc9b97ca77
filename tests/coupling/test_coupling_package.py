"""The ``coupling`` namespace: every module's public names, nothing private, no physics imports."""

from __future__ import annotations

import importlib
import pathlib
import pkgutil
import subprocess
import sys

import pytest

import coupling as cp

MODULES = sorted(m.name for m in pkgutil.iter_modules(cp.__path__) if m.name != "toys")


def test_the_namespace_exports_every_module_s_public_names():
    exported = set(cp.__all__)
    assert len(exported) == len(cp.__all__), "a name is listed twice"
    assert not [n for n in exported if n.startswith("_")]
    for name in MODULES:
        module = importlib.import_module(f"coupling.{name}")
        assert set(module.__all__) <= exported, (name, sorted(set(module.__all__) - exported))
        for public in module.__all__:
            assert getattr(cp, public) is getattr(module, public)


@pytest.mark.skip_in_parallel
def test_importing_coupling_loads_no_physics_or_toys():
    code = ("import sys, coupling; bad = [m for m in ('dolfinx', 'ufl', 'petsc4py', 'gmsh', 'femtools', "
            "'fluid', 'gel', 'cell', 'gelcell', 'coupling.toys') if m in sys.modules]; print(bad)")
    root = pathlib.Path(cp.__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
