"""Fixtures of the coupling tests (pure numpy; also run under ``mpirun -n 2``)."""

from __future__ import annotations

import pathlib
import sys

import pytest

# This test directory is itself named "coupling" and has no __init__.py.  If
# <repo>/tests is on sys.path but <repo> is not (e.g. the `pytest` entry point
# after collecting a test module directly in tests/), `import coupling` would
# resolve to this directory as a namespace package.  Put the repository root
# first, as `python -m pytest` does.
_ROOT = str(pathlib.Path(__file__).resolve().parents[2])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

from coupling.parallel import default_comm  # noqa: E402


@pytest.fixture
def comm():
    """``MPI.COMM_WORLD`` (or the serial stand-in without mpi4py)."""
    return default_comm()

