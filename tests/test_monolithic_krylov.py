"""The monolithic reference's iterative path (``--monolithic --solver iterative``).

FGMRES with the gel-first block sweep (gelcell.coupled.monolithic_krylov) solves each Newton
step to 1e-10 relative, Newton stops at 1e-12: the discrete solution is MUMPS's.  References:

* the direct (MUMPS) monolithic solve of the same case, every summary quantity to 1e-8 (far
  above the linear solves' error, far below any discretisation change): both 2D devices with
  their cell, finite and small kinematics, two time windows from rest, the coarse 3D device;
* a preconditioner whose blocks are mesh-independent (algebraic multigrid on the gel's blocks,
  MUMPS on the fluid's) keeps the FGMRES iterations per Newton step bounded as the mesh is
  refined: halving every element size may add at most half the coarse count plus 5.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from mpi4py import MPI

from gelcell.case import CaseParameters, TimeSettings
from gelcell.output.timeseries import COLUMNS
from gelcell.post.quantities import DeviceQuantities
from gelcell.run.backends import MonolithicBackend
from gelcell.run.solve import solve_monolithic
from gelcell.run.transient import TransientRun
from agreement import assert_quantities_agree
from device3d_cases import monolithic as monolithic_3d, params_3d
from transient_cases import tau

MESH = 3.0          # every element size x3, as tests/test_solver_choice.py
RTOL = 1e-8


@functools.lru_cache(maxsize=None)
def _solve(case: str, solver: str, mesh: float = MESH, kinematics: str = "finite"):
    p = CaseParameters.default(case, True).with_mesh_size(mesh).with_kinematics(kinematics)
    return solve_monolithic(p, checks=False, solver=solver)


def _krylov(run) -> dict:
    return run.summary["solver"]["krylov"]["monolithic"]


@pytest.mark.parametrize("case, kinematics", [("shear", "finite"), ("normal", "finite"), ("shear", "small")])
def test_iterative_equals_direct(case, kinematics):
    direct, iterative = _solve(case, "direct", kinematics=kinematics), _solve(case, "iterative", kinematics=kinematics)
    assert direct.summary["solver"] == {"kind": "direct", "fields": {"monolithic": "direct"}}
    solver = iterative.summary["solver"]
    assert (solver["kind"], solver["fields"]) == ("iterative", {"monolithic": "iterative"})
    krylov = _krylov(iterative)
    # every Newton step solved by FGMRES, every FGMRES iteration applying the gel's inner GMRES at least once
    assert krylov["solves"] >= 1 and krylov["iterations"] >= krylov["solves"]
    assert krylov["inner_iterations"] >= krylov["iterations"]
    assert_quantities_agree(iterative.summary, direct.summary, (case, kinematics), RTOL)


def test_the_fgmres_iterations_stay_bounded_as_the_mesh_is_refined():
    coarse, fine = _krylov(_solve("shear", "iterative")), _krylov(_solve("shear", "iterative", MESH / 2))
    assert fine["mean"] <= 1.5 * coarse["mean"] + 5, (coarse, fine)


def _series(solver: str, windows: int) -> tuple[dict, int]:
    """The monolithic time series of the shear device with its cell over ``windows`` backward-Euler windows,
    and the Krylov iterations it took."""
    p = CaseParameters.default("shear", True).with_mesh_size(2 * MESH)
    settings = TimeSettings(transient=True, dt=tau(p) / 40, t_end=windows * tau(p) / 40, scheme="be")
    backend = MonolithicBackend(p, MPI.COMM_WORLD, settings.scheme, settings.waveform, solver=solver)
    state = TransientRun(backend, p, settings, MPI.COMM_WORLD).run()
    series = {c: np.array([r[c] for r in state["rows"]], dtype=float) for c in COLUMNS}
    return series, backend.solver.newton.stats["krylov_iterations"]


def test_iterative_equals_direct_in_a_time_dependent_run():
    """Two windows from rest: the undrained start and a step on its history (the fixed-stress term of the
    gel's pressure block depends on dt)."""
    (direct, none), (iterative, krylov) = _series("direct", 2), _series("iterative", 2)
    assert none == 0 and krylov > 0
    assert np.array_equal(direct["t"], iterative["t"]) and len(direct["t"]) == 3
    for column in DeviceQuantities.TIMESERIES:
        scale = np.abs(direct[column]).max()
        assert np.all(np.abs(iterative[column] - direct[column]) <= RTOL * scale), column


def test_iterative_equals_direct_on_the_3d_device():
    """The coarse 3D shear device (tests/device3d_cases.py): the gel's blocks by GAMG."""
    iterative = solve_monolithic(params_3d("shear"), checks=False, solver="iterative")
    assert iterative.summary["solver"]["fields"] == {"monolithic": "iterative"}
    assert_quantities_agree(iterative.summary, monolithic_3d("shear").summary, "3d", RTOL)
