"""Run a script under ``mpirun -n N`` and read the JSON it prints on its last line.

Used by tests that check "same answer on 1 and 2 ranks": the test runs a
small script from ``tests/mpi_scripts/`` with 1 and with 2 processes and
compares the numbers.  The script must print one JSON object (rank 0 only)
as its last line of standard output.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

SCRIPTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "mpi_scripts")


def mpirun_available() -> bool:
    return shutil.which("mpirun") is not None


def run_mpi(script: str, nprocs: int = 2, args: list[str] | None = None, timeout: float = 600) -> dict:
    """Run ``tests/mpi_scripts/<script>`` on ``nprocs`` ranks; return its JSON result.

    Skipped when pytest itself runs under mpirun (an MPI process cannot launch
    another MPI job); the serial pytest run does these comparisons.
    """
    if "OMPI_COMM_WORLD_SIZE" in os.environ or "PMI_SIZE" in os.environ:
        pytest.skip("runs its own mpirun: done by the serial pytest run")
    if nprocs > 1 and not mpirun_available():
        pytest.skip("mpirun not available")
    path = script if os.path.isabs(script) else os.path.join(SCRIPTS, script)
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMPI_MCA_mpi_yield_when_idle="1",
               MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    cmd = [sys.executable, path] + list(args or [])
    if nprocs > 1:
        cmd = ["mpirun", "-n", str(nprocs)] + cmd
    # stdin: not the caller's (mpirun forwards it to rank 0; a pytest-xdist worker's is its channel)
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, stdin=subprocess.DEVNULL)
    if proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n"
                             f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    if not lines:
        raise AssertionError(f"{' '.join(cmd)} printed nothing; stderr:\n{proc.stderr[-3000:]}")
    return json.loads(lines[-1])


def assert_same_on_one_and_two_ranks(script: str, rtol: float = 1e-9) -> None:
    """Run ``script`` on 1 and 2 ranks; every number it reports agrees to ``rtol`` of its largest value."""
    import numpy as np

    one, two = run_mpi(script, 1), run_mpi(script, 2)
    assert two["ranks"] == 2
    for key, ref in one.items():
        if key == "ranks":
            continue
        a, b = np.asarray(ref, dtype=float), np.asarray(two[key], dtype=float)
        assert a.shape == b.shape, key
        assert np.abs(a - b).max() <= rtol * max(np.abs(a).max(), 1e-300), (key, a, b)
