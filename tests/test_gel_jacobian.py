"""PoroelasticGelSolver.interface_jacobian(): the interface map linearised at rest, against the solver.

The reference is the solver itself: for seeded random input arrays delta on
every input of every interface, central differences of ``interface_data``
(solves at +- eps delta from rest, each from rest: ``reset()``) must match
``J @ delta``.  The gel is nonlinear (phi_s0/J, neo-Hookean network, the
finite-strain interface terms), so a central difference has an O(eps^2)
truncation error: the test checks that the error drops ~4x when eps halves
(or is at the round-off floor already), and that the Richardson extrapolation
(4 D(eps/2) - D(eps))/3, with an O(eps^4) error, agrees with J to far better.

Steady solvers, and time-dependent ones with a backward Euler step set (one
step from rest with a zero history: v_s = u/dt).

The gel: a rectangle with two fluid interfaces on top that share their middle
node, two cell interfaces at the bottom (one with a random symmetric positive
definite interface stiffness K, one without), anchored between them, a
symmetry line on the left and on the right either an open boundary ("small")
or a second symmetry line ("finite": every boundary velocity is then held on
the interfaces, the pressure is set by the fluid interfaces only).
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

from dolfinx import mesh as dmesh

from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver

COMM = MPI.COMM_WORLD

LEFT, RIGHT, ANCHOR, CELL_K, CELL, TOP_A, TOP_B = 1, 2, 3, 4, 5, 6, 7

# moderately nonlinear parameters (strains of a few per cent at the loads below), paper units s = d = 1
PARAMS = GelParameters(phi_s0=0.2, xi=50.0, lambda_s=1.0, beta=0.5, eta=0.5, Ca=0.5)


def _mesh(nx=10, ny=4, width=1.0, height=0.5):
    """The rectangle [0, width] x [0, height]; the bottom split into CELL_K | ANCHOR | CELL, the top into
    TOP_A | TOP_B (sharing the middle node)."""
    msh = dmesh.create_rectangle(COMM, [np.array([0.0, 0.0]), np.array([width, height])], [nx, ny],
                                 dmesh.CellType.triangle, diagonal=dmesh.DiagonalType.crossed)
    facets = dmesh.locate_entities_boundary(msh, 1, lambda x: np.full(x.shape[1], True))
    mid = dmesh.compute_midpoints(msh, 1, facets)
    tol = 1e-10
    values = np.zeros(facets.size, dtype=np.int32)
    top, bottom = np.isclose(mid[:, 1], height, atol=tol), np.isclose(mid[:, 1], 0.0, atol=tol)
    values[top] = np.where(mid[top, 0] < 0.5 * width, TOP_A, TOP_B)
    values[bottom] = np.where(mid[bottom, 0] < 0.35 * width, CELL_K,
                              np.where(mid[bottom, 0] > 0.65 * width, CELL, ANCHOR))
    values[np.isclose(mid[:, 0], 0.0, atol=tol)] = LEFT
    values[np.isclose(mid[:, 0], width, atol=tol)] = RIGHT
    return msh, dmesh.meshtags(msh, 1, facets.astype(np.int32), values)


def _gel(kinematics, dt=None):
    """The test gel; ``dt``: a time-dependent solver with a backward Euler step dt set."""
    msh, ft = _mesh()
    symmetry = [(LEFT, 0)] + ([(RIGHT, 0)] if kinematics == "finite" else [])
    gel = PoroelasticGelSolver(msh, ft, PARAMS, no_slip=ANCHOR, symmetry=symmetry,
                               fluid_interfaces={"top_a": TOP_A, "top_b": TOP_B},
                               cell_interfaces={"cell_k": CELL_K, "cell": CELL}, kinematics=kinematics,
                               newton_reuse="never", newton_rtol=1e-13, transient=dt is not None)
    if dt is not None:
        gel.set_time_step(dt)               # reset() keeps it: every solve is one step from rest
    n = 2 * gel.interface_points("cell_k").shape[0]
    rng = np.random.default_rng(7)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    gel.set_interface_stiffnesses({"cell_k": (Q * rng.uniform(0.1, 1.0, n)) @ Q.T})
    return gel


def _inputs(gel):
    """Seeded random input arrays (same on every rank) for every input of every interface."""
    rng = np.random.default_rng(2024)
    scale = {"traction": 0.05, "velocity": 0.05, "force": 0.0005, "displacement": 0.001}
    out = {}
    for name in gel.interface_names():
        n = gel.interface_points(name).shape[0]
        for key in gel.input_names(name):
            out[name, key] = scale[key] * rng.uniform(-1.0, 1.0, (n, 2))
    return out


def _outputs(gel, data):
    gel.reset()
    for name in gel.interface_names():
        gel.set_interface_data(name, **{key: np.zeros((gel.interface_points(name).shape[0], 2))
                                        for key in gel.input_names(name)})
    for (name, key), values in data.items():
        gel.set_interface_data(name, **{key: values})
    gel.solve()
    return {(name, key): np.array(v).ravel() for name in gel.interface_names()
            for key, v in gel.interface_data(name).items()}


def _central(gel, data, eps):
    plus = _outputs(gel, {k: eps * v for k, v in data.items()})
    minus = _outputs(gel, {k: -eps * v for k, v in data.items()})
    return {k: (plus[k] - minus[k]) / (2 * eps) for k in plus}


#: (kinematics, time step): steady, and one backward Euler step from rest (v_s = u/dt)
CASES = [("small", None), ("finite", None), ("small", 0.5), ("finite", 0.5)]


@pytest.fixture(scope="module", params=CASES, ids=[f"{k}-{'steady' if dt is None else 'step'}" for k, dt in CASES])
def case(request):
    gel = _gel(*request.param)
    return gel, gel.interface_jacobian()


def test_keys_shapes_and_structure(case):
    gel, J = case
    outputs = {"top_a": {"traction", "mixture_velocity", "superficial_velocity", "interstitial_velocity"},
               "cell_k": {"displacement"}}
    if gel.kinematics == "finite":
        outputs["top_a"] |= {"normal_flux", "displacement"}
    outputs["top_b"], outputs["cell"] = outputs["top_a"], outputs["cell_k"]
    inputs = {"top_a": ("traction", "velocity"), "top_b": ("traction", "velocity"),
              "cell_k": ("force", "displacement"), "cell": ("force", "displacement")}
    expected = {((o, ok), (i, ik)) for o, keys in outputs.items() for ok in keys
                for i, ikeys in inputs.items() for ik in ikeys}
    assert set(J) == expected
    for ((o, ok), (i, ik)), block in J.items():
        assert block.shape == (2 * gel.interface_points(o).shape[0], 2 * gel.interface_points(i).shape[0])
        assert np.all(np.isfinite(block))
        if ok == "traction":
            ref = np.eye(block.shape[0]) if (o, ik) == (i, "traction") else 0.0
            assert np.array_equal(block, np.broadcast_to(ref, block.shape))
    # a displacement input without a stiffness does nothing
    assert not np.any(J[("cell_k", "displacement"), ("cell", "displacement")])
    assert np.abs(J[("cell_k", "displacement"), ("cell_k", "displacement")]).max() > 0
    # the same arrays on every rank
    for key, block in J.items():
        ref = COMM.bcast(block if COMM.rank == 0 else None, root=0)
        assert COMM.allreduce(np.array_equal(block, ref), op=MPI.LAND), key


#: relative error of a difference quotient that counts as round-off (Newton's rtol 1e-13 over eps ~ 1)
FLOOR = 1e-9


def _check_second_order(label, e1, e2, rich):
    """Errors of central differences at eps (e1) and eps/2 (e2) and of their Richardson extrapolation."""
    # the truncation error is O(eps^2): quartered when eps halves (unless at round-off already)
    assert e2 <= max(0.3 * e1, FLOOR), f"{label}: errors {e1:.2e} (eps) {e2:.2e} (eps/2)"
    # Richardson's extrapolation removes it (O(eps^4) left)
    assert rich <= max(0.1 * e2, FLOOR), f"{label}: Richardson error {rich:.2e}, eps/2 error {e2:.2e}"
    assert e1 < 0.02, f"{label}: eps error {e1:.2e}"


@pytest.mark.parametrize("kind", ["fluid", "cell"])
def test_against_central_differences(case, kind):
    """Per input (a column block of J at a time): central differences at eps and eps/2.

    Errors are relative to the largest response of that output to any input,
    so that a block that vanishes (at rest the flow does not see the network:
    the velocities do not depend on the cell's force) is compared with round-off.
    """
    gel, J = case
    data = _inputs(gel)
    reference = {}
    for (key_out, key_in), block in J.items():
        if key_in in data:
            response = np.abs(block @ data[key_in].ravel()).max()
            reference[key_out] = max(reference.get(key_out, 0.0), response)
    names = [k for k in data if (k[0].startswith("top") if kind == "fluid" else k[0].startswith("cell"))]
    eps = 1.0
    for key_in in names:
        delta = data[key_in]
        d1 = _central(gel, {key_in: delta}, eps)
        d2 = _central(gel, {key_in: delta}, eps / 2)
        for key_out in d1:
            if key_out[1] == "pressure":
                continue
            lin = J[key_out, key_in] @ delta.ravel()
            scale = reference[key_out]
            assert scale > 0, key_out
            e1 = np.abs(d1[key_out] - lin).max() / scale
            e2 = np.abs(d2[key_out] - lin).max() / scale
            rich = np.abs((4 * d2[key_out] - d1[key_out]) / 3 - lin).max() / scale
            label = f"{gel.kinematics}: d{key_out}/d{key_in}"
            if key_out[1] == "traction" or key_in == ("cell", "displacement"):
                # exact: the identity / a zero block (no stiffness there)
                assert e1 <= FLOOR and e2 <= FLOOR, f"{label}: errors {e1:.2e}, {e2:.2e}"
                continue
            _check_second_order(label, e1, e2, rich)


def test_combined_inputs(case):
    """All inputs at once: the differences equal the sum of J @ delta over the inputs."""
    gel, J = case
    data = _inputs(gel)
    d1, d2 = _central(gel, data, 1.0), _central(gel, data, 0.5)
    for key_out in d1:
        if key_out[1] == "pressure":
            continue
        lin = sum(J[key_out, key_in] @ delta.ravel() for key_in, delta in data.items())
        scale = np.abs(lin).max()
        assert scale > 0
        e1, e2 = (np.abs(d[key_out] - lin).max() / scale for d in (d1, d2))
        rich = np.abs((4 * d2[key_out] - d1[key_out]) / 3 - lin).max() / scale
        if key_out[1] == "traction":
            assert e1 <= FLOOR and e2 <= FLOOR, key_out
        else:
            _check_second_order(f"{gel.kinematics}: {key_out} (all inputs)", e1, e2, rich)


def test_cached_and_invalidated():
    gel = _gel("small")
    J = gel.interface_jacobian()
    again = gel.interface_jacobian()
    assert all(again[k] is J[k] for k in J)                # cached
    with pytest.raises(ValueError):
        J[next(iter(J))][0, 0] = 1.0                      # read-only
    gel.update_parameters(PARAMS.replace(lambda_s=3.0))
    stiffer = gel.interface_jacobian()
    key = (("cell_k", "displacement"), ("cell_k", "force"))
    assert not np.allclose(stiffer[key], J[key])


def test_time_step_changes_and_restores_the_map():
    """A time-dependent solver without a step is steady; a step changes the map (v_s = c0 u), set_steady
    restores it, and the steady map equals a steady solver's."""
    steady = _gel("small").interface_jacobian()
    gel = _gel("small", dt=0.5)
    stepped = gel.interface_jacobian()
    gel.set_steady()
    again = gel.interface_jacobian()
    key = (("top_a", "interstitial_velocity"), ("top_a", "traction"))
    assert not np.allclose(stepped[key], steady[key])
    for k in steady:
        scale = max(np.abs(steady[k]).max(), 1e-300)
        assert np.abs(again[k] - steady[k]).max() <= 1e-9 * scale, k


def test_paper_units_agree_with_viscous_units():
    """Device parameters in the paper's units (s = d = 1: the fluid rows ~Ca = 3e-10 times the network
    rows) and in the viscous units (s = d = Ca): the same map once the units are converted."""
    Ca = 3e-10
    unit = {"traction": Ca, "force": Ca, "displacement": Ca}          # stress and displacement quantities
    rng = np.random.default_rng(1)
    maps = []
    for prm in (GelParameters(Ca=Ca), GelParameters.viscous_units(Ca=Ca)):
        msh, ft = _mesh()
        gel = PoroelasticGelSolver(msh, ft, prm, no_slip=ANCHOR, symmetry=[(LEFT, 0), (RIGHT, 0)],
                                   fluid_interfaces={"top_a": TOP_A, "top_b": TOP_B},
                                   cell_interfaces={"cell_k": CELL_K, "cell": CELL}, kinematics="finite")
        if not maps:
            n = 2 * gel.interface_points("cell_k").shape[0]
            Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
            K = (Q * rng.uniform(0.1, 1.0, n)) @ Q.T          # s L0 per d L0: the same number in both units
        gel.set_interface_stiffnesses({"cell_k": K})
        maps.append(gel.interface_jacobian())
    paper, viscous = maps
    for key, block in viscous.items():
        (_, out), (_, inp) = key
        ref = block * unit.get(out, 1.0) / unit.get(inp, 1.0)
        scale = np.abs(ref).max()
        if scale > 0:
            assert np.abs(paper[key] - ref).max() <= 1e-7 * scale, key


def test_kept_matrix_of_a_solve_gives_the_same_map():
    """After a solve the solver holds the kept matrix (J_reference with the stiffness), which is then
    used instead of a new assembly: the same map."""
    msh, ft = _mesh()
    gel = PoroelasticGelSolver(msh, ft, PARAMS, no_slip=ANCHOR, symmetry=[(LEFT, 0)],
                               fluid_interfaces={"top_a": TOP_A, "top_b": TOP_B},
                               cell_interfaces={"cell_k": CELL_K, "cell": CELL})
    n = 2 * gel.interface_points("cell_k").shape[0]
    gel.set_interface_stiffnesses({"cell_k": 0.5 * np.eye(n)})
    fresh = gel.interface_jacobian()
    for (name, key), values in _inputs(gel).items():
        gel.set_interface_data(name, **{key: 0.1 * values})
    gel.solve()
    assert gel.newton.uses_reference_jacobian and gel.newton.stats["factorizations"] == 1
    gel._jacobian_cache = None                  # recompute (nothing changed)
    again = gel.interface_jacobian()
    for k in fresh:
        scale = max(np.abs(fresh[k]).max(), 1e-300)
        assert np.abs(again[k] - fresh[k]).max() <= 1e-9 * scale, k
