"""``interface_jacobian()`` of the Stokes solvers against the solvers themselves.

The fluid's interface outputs are affine in its interface inputs (the operator
does not depend on the data), so for any base data g and increment delta

    interface_data(g + delta) - interface_data(g) = J delta

to round-off, J the dense blocks of ``interface_jacobian()`` summed over the
inputs.  ``MovingStokesSolver`` with zero displacement solves the same linear
problem by Newton with the exact Jacobian at rest (a first step exact up to
round-off, a second confirming it), so the same tolerance holds.

Cases: an enclosed channel (every boundary but the Robin interfaces no-slip:
the Schur complement needs its kept pressure dof), whose interfaces share
corner nodes and end at nodes a wall fixes; an open channel with an inflow
and a symmetry line (component condition) fixing one component of an
interface end node; a plate with a curved Robin hole inside a no-slip box;
the moving-mesh solver with its ``normal_flux`` input; the normal-flow device
on both kinematics paths.  Runs serially and under ``mpirun -n 2``.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
import pytest

from mpi4py import MPI

from fluid import FluidInterface, StokesSolver
from fluid.ale import MovingStokesSolver

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "mpi_scripts"))
from fluid_cases import BOTTOM, HOLE, INLET, OUTER, OUTLET, TOP, channel_mesh, plate_with_hole_mesh  # noqa: E402

COMM = MPI.COMM_WORLD
#: round-off bound relative to the output's norm (observed: ~1e-14 on these cases)
RTOL = 1e-9
OUTPUTS = ("velocity", "traction")


def robin_inputs(solver) -> dict[str, list[str]]:
    """The linearised inputs per interface (not the mesh displacement)."""
    return {name: [k for k in solver.input_names(name) if k != "displacement"]
            for name in solver.interface_names()}


def random_data(solver, rng, scale=1.0) -> dict[str, dict[str, np.ndarray]]:
    return {name: {k: scale * rng.standard_normal((len(solver.interface_points(name)), 2)) for k in keys}
            for name, keys in robin_inputs(solver).items()}


def outputs_at(solver, data) -> dict[str, dict[str, np.ndarray]]:
    for name, arrays in data.items():
        solver.set_interface_data(name, **arrays)
    solver.solve()
    return {name: solver.interface_data(name) for name in solver.interface_names()}


def check_against_solver(solver, seed=0, scale=1.0) -> dict:
    """Assert out(g + delta) - out(g) = J delta for random g, delta on every input; return J."""
    rng = np.random.default_rng(seed)
    base, delta = random_data(solver, rng, scale), random_data(solver, rng, scale)
    out0 = outputs_at(solver, base)
    out1 = outputs_at(solver, {n: {k: base[n][k] + delta[n][k] for k in a} for n, a in base.items()})
    J = solver.interface_jacobian()
    names = solver.interface_names()
    inputs = robin_inputs(solver)
    expected = {((o, ok), (i, ik)) for o in names for ok in OUTPUTS for i in names for ik in inputs[i]}
    assert set(J) == expected
    for o in names:
        n_out = len(solver.interface_points(o))
        for ok in OUTPUTS:
            predicted = np.zeros(2 * n_out)
            for i in names:
                for ik in inputs[i]:
                    block = J[((o, ok), (i, ik))]
                    assert block.shape == (2 * n_out, 2 * len(solver.interface_points(i)))
                    predicted += block @ delta[i][ik].ravel()
            change = (out1[o][ok] - out0[o][ok]).ravel()
            size = max(np.linalg.norm(out0[o][ok]), np.linalg.norm(out1[o][ok]))
            error = np.linalg.norm(predicted - change)
            assert np.linalg.norm(change) > 1e-3 * size, f"{o}/{ok}: the increment changes nothing"
            assert error <= RTOL * size, f"{o}/{ok}: |J delta - change| = {error:.3e}, |out| = {size:.3e}"
    # the same arrays on every rank
    for key, block in J.items():
        ref = COMM.bcast(block if COMM.rank == 0 else None, root=0)
        assert np.array_equal(ref, block), f"{key}: differs between ranks"
    return J


def enclosed_channel(cls=StokesSolver, **kwargs):
    """[0, 2] x [0, 1], no slip on top, Robin on the other three sides (sharing two corner nodes).

    With the interface velocities kept, the rest of the fluid is enclosed by
    Dirichlet conditions: the eliminated block is singular without the kept
    pressure dof.  The interfaces' top end nodes are fixed by the wall.
    """
    msh, ft = channel_mesh(2.0, 1.0, 0.25)
    return cls(msh, ft, viscosity=0.8, velocity_bcs=[(TOP, (0.0, 0.0))],
               interfaces={"in": FluidInterface(INLET, alpha_n=2.0, alpha_t=1.0),
                           "out": FluidInterface(OUTLET, alpha_n=0.5, alpha_t=0.0),
                           "bottom": FluidInterface(BOTTOM, alpha_n=3.0, alpha_t=0.7)}, **kwargs)


def test_enclosed_channel_with_shared_and_fixed_end_nodes():
    solver = enclosed_channel()
    J = check_against_solver(solver)
    # nodes the wall fixes: no velocity response, zero traction rows (as interface_data has them)
    for name in solver.interface_names():
        top = np.flatnonzero(np.isclose(solver.interface_points(name)[:, 1], 1.0))
        assert top.size == 1 or name == "bottom"
        rows = np.hstack([2 * top, 2 * top + 1])
        for (out, _), block in J.items():
            if out[0] == name and rows.size:
                assert not np.any(block[rows]), f"{out}: fixed node rows are not zero"
    # shared corner (0, 0): an input on "bottom" moves "in"'s velocity there
    assert np.abs(J[(("in", "velocity"), ("bottom", "robin_normal"))]).max() > 0
    # cached until the operator changes; a new coefficient gives a new (and still exact) map
    t0 = time.perf_counter()
    again = solver.interface_jacobian()
    assert time.perf_counter() - t0 < 0.05
    assert all(np.array_equal(again[k], J[k]) for k in J)
    solver.set_robin_coefficients("out", alpha_n=4.0, alpha_t=0.3)
    J2 = check_against_solver(solver, seed=1)
    assert not np.allclose(J2[(("out", "velocity"), ("out", "robin_normal"))],
                           J[(("out", "velocity"), ("out", "robin_normal"))])


def test_open_channel_with_inflow_and_symmetry_line():
    """Inflow at x = 0, symmetry line V_y = 0 at y = 1, Robin bottom and outlet, body force.

    The bottom's end at the inflow is fixed in both components, the outlet's
    end on the symmetry line in one (V_y fixed, V_x free); the other ends are
    the corner the two interfaces share.
    """
    msh, ft = channel_mesh(2.0, 1.0, 0.25)
    solver = StokesSolver(msh, ft, viscosity=1.3, body_force=(0.3, -0.2),
                          velocity_bcs=[(INLET, lambda x: np.vstack([x[1] * (1 - x[1]), 0 * x[0]]))],
                          component_bcs=[(TOP, 1, 0.0)],
                          interfaces={"bottom": FluidInterface(BOTTOM, alpha_n=5.0, alpha_t=0.0),
                                      "out": FluidInterface(OUTLET, alpha_n=0.0, alpha_t=2.0)})
    J = check_against_solver(solver)
    pts = solver.interface_points("out")
    top = int(np.flatnonzero(np.isclose(pts[:, 1], 1.0))[0])
    block = J[(("out", "traction"), ("out", "robin_normal"))]
    assert not np.any(block[2 * top + 1]) and np.any(block[2 * top]), "V_y fixed, V_x free at the top end"


def test_curved_hole_in_a_no_slip_box():
    msh, ft = plate_with_hole_mesh(0.2)
    solver = StokesSolver(msh, ft, viscosity=0.8, velocity_bcs=[(OUTER, (0.0, 0.0))],
                          interfaces={"hole": FluidInterface(HOLE, alpha_n=2.0, alpha_t=1.5)})
    check_against_solver(solver)


def test_moving_solver_at_rest_with_normal_flux():
    solver = enclosed_channel(MovingStokesSolver)
    assert "normal_flux" in robin_inputs(solver)["in"]
    for name in solver.interface_names():
        solver.set_interface_data(name, displacement=np.zeros((len(solver.interface_points(name)), 2)))
    J = check_against_solver(solver)
    # at rest the moving solver's map is the fixed-mesh one
    fixed = enclosed_channel().interface_jacobian()
    for key, block in fixed.items():
        assert np.allclose(J[key], block, rtol=0, atol=1e-12 * np.abs(block).max())


def test_dirichlet_parts_are_not_linearised():
    msh, ft = channel_mesh(2.0, 1.0, 0.5)
    solver = StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(TOP, (0.0, 0.0))],
                          interfaces={"in": FluidInterface(INLET, tangential="dirichlet")})
    with pytest.raises(NotImplementedError, match="Dirichlet part"):
        solver.interface_jacobian()


@pytest.mark.parametrize("kinematics", ["finite", "small"])
def test_normal_flow_device(kinematics):
    """The device's fluid: upstream part enclosed by the inflow, symmetry lines and Gamma1."""
    from gelcell.coupled.device import Device
    from gelcell.case import CaseParameters
    params = CaseParameters.default("normal").with_mesh_size(3.0).with_kinematics(kinematics)
    device = Device(params)
    fluid = device.fluid
    assert isinstance(fluid, MovingStokesSolver) == (kinematics == "finite")
    # data of the size the coupling sends: alpha_n V with V ~ 1
    check_against_solver(fluid, scale=device.alpha_n)
