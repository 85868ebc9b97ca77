"""The ``coupling`` namespace: every module's public names, nothing private, no physics imports."""

from __future__ import annotations

import importlib
import os
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


_SERIAL_RUN = """
import os, sys
import coupling as cp
from coupling.toys import affine_pair_problem
imported = 'mpi4py' in sys.modules
problem = affine_pair_problem()
participants, data = problem.build()
scheme = cp.build_scheme({"order": list(problem.order), "verbose": False,
                          "convergence": [{"type": "relative", "limit": 1e-10}],
                          "acceleration": {"type": "iqn-ils"}}, participants, data)
result = scheme.solve()
print(imported, 'mpi4py' in sys.modules, type(scheme.comm).__name__, result.converged)
"""


def _without_launcher_env():
    """The environment of a process no MPI launcher started (this test may itself run under mpirun)."""
    return {k: v for k, v in os.environ.items()
            if not k.startswith(("OMPI_", "PMI", "PMIX_", "MV2_", "HYDRA_"))}


@pytest.mark.skip_in_parallel
def test_a_serial_scheme_neither_imports_nor_initialises_mpi():
    """import coupling, build_scheme and solve, serially: mpi4py stays out of sys.modules."""
    root = pathlib.Path(cp.__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", _SERIAL_RUN], cwd=root, capture_output=True, text=True,
                         check=True, env=_without_launcher_env())
    assert out.stdout.split() == ["False", "False", "SerialComm", "True"]


@pytest.mark.skip_in_parallel
def test_an_application_that_imported_mpi4py_gets_comm_world():
    pytest.importorskip("mpi4py")
    root = pathlib.Path(cp.__file__).resolve().parents[1]
    code = "from mpi4py import MPI\nimport coupling as cp\nprint(cp.default_comm() is MPI.COMM_WORLD)"
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True,
                         env=_without_launcher_env())
    assert out.stdout.strip() == "True"
    assert isinstance(cp.SerialComm(), cp.SerialComm) and "SerialComm" in cp.__all__
