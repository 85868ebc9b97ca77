"""MPI-aware pytest helpers.

* Every test module runs unchanged on 1 rank (``pytest``) and on several ranks
  (``mpirun -n 2 python -m pytest``): tests reduce over ``MPI.COMM_WORLD``
  before asserting.  Tests that only make sense on one process use the
  ``skip_in_parallel`` marker (e.g. tests that themselves launch ``mpirun``).
* ``tests/mpi_run.py`` (``run_mpi``) launches a script on N ranks from a serial
  test and returns the JSON it prints; this directory is put on ``sys.path`` so
  tests can ``from mpi_run import run_mpi``.
* After each test (and its fixtures' teardown) every rank calls ``gc.collect()``,
  destroys the dropped PETSc objects of the meshes built by femtools
  (``femtools.petscgarbage``: petsc4py leaves them on their communicator's
  garbage list) and meets at a barrier, so that PETSc objects are destroyed
  collectively (as dolfinx's own conftest does).  The survivors are then frozen
  (``gc.freeze``) until the test file ends, so each collection traverses only
  what the test made; after a file's last test everything is collected.
"""

import gc
import os
import pathlib
import sys

import pytest

if "PYTEST_XDIST_WORKER" in os.environ:
    # a pytest-xdist worker inherits the variables of its controller's MPI singleton (PMIx server
    # address, ess=singleton): without them it starts its own, as a serial pytest does, and the
    # mpirun and gelcell processes of its tests do not report to the controller's server (they fail)
    for name in [k for k in os.environ if k.startswith(("PMIX_", "OMPI_MCA_ess", "OMPI_MCA_orte_",
                                                          "OMPI_MCA_pmix", "OMPI_APP_CTX_"))]:
        del os.environ[name]

from mpi4py import MPI  # noqa: E402

from femtools import petscgarbage  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def pytest_configure(config):
    config.addinivalue_line("markers", "skip_in_parallel: run only when MPI.COMM_WORLD has one rank")


def pytest_runtest_setup(item):
    if item.get_closest_marker("skip_in_parallel") and MPI.COMM_WORLD.size > 1:
        pytest.skip("serial-only test")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    yield                                    # the fixtures' own teardown first (a module's, after its last test)
    if nextitem is None or nextitem.module is not item.module:
        gc.unfreeze()                        # the module's objects too: one full collection per module
    gc.collect()
    petscgarbage.collect(MPI.COMM_WORLD, collected=True)      # the PETSc objects of the test's meshes
    # what survived is not traversed again until the module ends: a full collection of a suite's heap
    # costs ~0.2 s, and a test file has dozens of tests
    gc.freeze()
    MPI.COMM_WORLD.Barrier()


@pytest.fixture
def comm():
    return MPI.COMM_WORLD


@pytest.fixture
def shared_tmp_path(tmp_path, comm):
    """A temporary directory that is the same on every MPI rank (rank 0's ``tmp_path``)."""
    path = comm.bcast(str(tmp_path) if comm.Get_rank() == 0 else None, root=0)
    return pathlib.Path(path)


@pytest.fixture
def empty_cache(shared_tmp_path, monkeypatch):
    """``empty_cache(directory_variable, switch_variable)``: point a gelcell disk cache at an empty
    directory, the same on every rank, with the cache enabled; returns the directory."""
    def use(directory_variable: str, switch_variable: str) -> pathlib.Path:
        path = shared_tmp_path / directory_variable.lower()
        monkeypatch.setenv(directory_variable, str(path))
        monkeypatch.delenv(switch_variable, raising=False)
        return path
    return use


@pytest.fixture
def cli_stderr(capsys, comm):
    """``cli_stderr()``: what the CLI printed on stderr since the last read, as rank 0 printed it.

    The CLI prints an error once, on rank 0; every rank gets rank 0's text, so a
    test asserts the same message on every rank.
    """
    return lambda: comm.bcast(capsys.readouterr().err, root=0)
