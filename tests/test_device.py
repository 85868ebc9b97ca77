"""Coupled device runs: partitioned (IQN-ILS, Aitken) against the monolithic reference.

The partitioned scheme and the monolithic system discretise the same
equations on the same meshes (docs/partitioning.md), so their solutions must
agree to the coupling tolerance; the tests ask for 1e-6 relative, far above
the 1e-10 coupling residual and far below any discretisation error.
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from mpi_run import run_mpi

from gelcell.post.residuals import interface_residuals
from gelcell.case import CaseParameters
from gelcell.post.fields import relative_differences
from gelcell.post.quantities import flat_quantities
from gelcell.output.summary import report
from gelcell.run.solve import solve_monolithic, solve_partitioned

MESH = 3.0   # test-sized: every element size x3 (16 edges around the cell)


def _params(case: str, **kw) -> CaseParameters:
    p = CaseParameters.default(case, True).with_mesh_size(MESH)
    if "ca" in kw:
        p = p.with_ca(kw["ca"])
    return p


@pytest.fixture(scope="module", params=["shear", "normal"])
def runs(request):
    case = request.param
    p = _params(case)
    mono = solve_monolithic(p, checks=False)
    part = {acc: solve_partitioned(p, {"acceleration": {"type": acc}}, verbose=False, checks=False)
            for acc in ("iqn-ils", "aitken")}
    part["parallel iqn-ils"] = solve_partitioned(p, {"scheme": "parallel-implicit"}, verbose=False, checks=False)
    return case, mono, part


@pytest.mark.parametrize("acceleration", ["iqn-ils", "aitken", "parallel iqn-ils"])
def test_partitioned_equals_monolithic(runs, acceleration):
    """Serial (Gauss-Seidel) scheme with both accelerations, and the parallel (Jacobi) scheme."""
    case, mono, part = runs
    run = part[acceleration]
    assert run.summary["coupling"]["converged"]
    qm, qp = flat_quantities(mono.summary), flat_quantities(run.summary)
    assert qm.keys() == qp.keys()
    for key in qm:
        # components of a vector (e.g. the centroid's y on a symmetry line, ~0) are compared
        # relative to the vector's size
        base = key.split("[")[0]
        scale = max(abs(v) for k, v in qm.items() if k.split("[")[0] == base)
        assert abs(qp[key] - qm[key]) <= 1e-6 * scale, (case, acceleration, key, qp[key], qm[key])
    diffs = relative_differences(run.fields, mono.fields)
    assert max(diffs.values()) <= 1e-6, (case, acceleration, diffs)


def _direct_solvers(device) -> dict:
    """The device's direct solvers (the gel's blocks once they exist): {name: DirectSolver}."""
    out = {"fluid": device.fluid.newton.solver, "fluid mesh motion": device.fluid.motion.solver.solver,
           "gel": device.gel.newton.solver, "cell": device.cell._newton.solver}
    blocks = device.gel.newton._blocks
    out.update({f"gel block {k}": s for k, s in enumerate(blocks.solvers if blocks is not None else [])
                if s is not None})
    return out


def test_steady_runs_factorise_with_the_amf_ordering(runs):
    """A steady device gives its field solvers MUMPS's AMF ordering (gelcell.coupled.defaults.STEADY_SOLVER_OPTIONS),
    and MUMPS's analysis used it (INFOG(7)) for every factorisation the run made."""
    from gelcell.coupled.defaults import STEADY_SOLVER_OPTIONS
    _, _, part = runs
    device = part["iqn-ils"].solver
    factorised = []
    for name, solver in _direct_solvers(device).items():
        assert solver.ordering == STEADY_SOLVER_OPTIONS["mat_mumps_icntl_7"] == 2, name
        try:
            F = solver.ksp.getPC().getFactorMatrix()
        except PETSc.Error:          # never factorised (the gel's exact Jacobian at these loads)
            continue
        factorised.append(name)
        assert F.getMumpsInfog(7) == 2, (name, F.getMumpsInfog(7))
    assert {"fluid", "fluid mesh motion", "cell", "gel block 0", "gel block 1"} <= set(factorised)


def test_time_dependent_devices_keep_mumps_automatic_ordering():
    """~1000 back-substitutions per factorisation: the automatic choice's trees solve faster (docs/performance.md)."""
    from femtools.linalg import DEFAULT_ORDERING
    from gelcell.coupled.device import Device
    device = Device(_params("shear"), transient=True)
    for name, solver in _direct_solvers(device).items():
        assert solver.ordering == DEFAULT_ORDERING == 7, name


def test_interface_conditions_at_solver_tolerance(runs):
    """Every interface condition holds on both solutions to the coupling/solver tolerance."""
    case, mono, part = runs
    for name, run in (("monolithic", mono), ("iqn-ils", part["iqn-ils"])):
        residuals = interface_residuals(run.fields)
        worst = max(v for r in residuals.values() for v in r.values())
        # coupling to 1e-10 relative; the network-slip and permeability conditions involve the
        # network's partial traction, ~1e-4 of the total, hence up to ~1e-6 amplification of round-off
        assert worst < 1e-8, (case, name, residuals)


def test_summary_has_the_promised_layout(runs):
    case, mono, part = runs
    s = report(dict(part["iqn-ils"].summary), _params(case))
    for key in ("case", "cell", "parameters", "mesh", "gel.max_interstitial_speed",
                "gel.max_network_displacement", "gel.max_network_von_mises", "cell.centroid_displacement",
                "cell.max_displacement", "cell.von_mises_strain", "cell.von_mises_stress",
                "cell.max_traction_von_mises", "gel.volume_change_below_gamma1",
                "gel.volume_change_share_of_cell", "coupling", "timing", "si"):
        assert key in s, key
    assert s["cell"] is True and s["case"] == case
    assert set(s["cell.max_traction_von_mises"]) == {"pressure", "brinkman", "network", "total"}
    for key in ("scheme", "acceleration", "iterations", "converged", "residual_history"):
        assert key in s["coupling"]
    # SI: lengths in µm (L0 = 250 µm), velocities in µm/s (V0 = 3 µm/s), stresses in mPa (mu_s = 40 kPa)
    assert s["si"]["cell.max_displacement"] == pytest.approx(250.0 * s["cell.max_displacement"], rel=1e-12)
    assert s["si"]["gel.max_interstitial_speed"] == pytest.approx(3.0 * s["gel.max_interstitial_speed"], rel=1e-9)
    assert s["si"]["gel.max_network_von_mises"] == pytest.approx(4e7 * s["gel.max_network_von_mises"], rel=1e-9)


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_linear_in_ca_at_small_strain(case):
    """Stresses, displacements and strains scale with Ca; velocities (in V0) do not.

    At fixed moduli Ca only sets the flow speed V0: in the paper's units the
    flow is Ca-independent and the loads on the network are proportional to
    Ca.  The strains are ~1e-6 x Ca/3e-10, so the neo-Hookean and phi_s(J)
    nonlinearities stay below 1e-4 at Ca = 1e-8.
    """
    a = solve_partitioned(_params(case, ca=3e-10), verbose=False, checks=False).summary
    b = solve_partitioned(_params(case, ca=1e-8), verbose=False, checks=False).summary
    qa, qb = flat_quantities(a), flat_quantities(b)
    ratio = 1e-8 / 3e-10
    for key in qa:
        if key == "gel.max_interstitial_speed":
            assert qb[key] == pytest.approx(qa[key], rel=1e-3), key
        elif "volume_change" in key and "magnitude" not in key:
            # a sum of dilatations and compressions that cancel ~1e3-fold: linear relative
            # to the magnitude of the local volume changes, int |J - 1|
            scale = qa["gel.local_volume_change_magnitude"]
            if key.endswith("share_of_cell"):
                scale = scale / abs(qa["gel.volume_change_below_gamma1"])
            if key.startswith("gel.relative"):
                scale = scale * abs(qa[key] / qa["gel.volume_change_below_gamma1"])
            b_value = qb[key] if key.endswith("share_of_cell") else qb[key] / ratio
            assert abs(b_value - qa[key]) <= 1e-3 * scale, key
        else:
            assert qb[key] / ratio == pytest.approx(qa[key], rel=1e-3), key


def test_same_summary_on_one_and_two_ranks():
    serial = run_mpi("device_summary.py", 1, ["normal", "3"])
    parallel = run_mpi("device_summary.py", 2, ["normal", "3"])
    for key, value in serial.items():
        assert parallel[key] == pytest.approx(value, rel=1e-8, abs=1e-14 * abs(value) + 1e-300), key


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_each_participant_alone_reproduces_its_part(case):
    """Fresh solvers fed the converged interface data reproduce the coupled solution.

    Each participant of a new Device (solvers at rest) solves alone with the
    data it reads at the converged state; its fields must equal its part of
    the coupled solution (to the coupling tolerance), which shows that every
    field problem of the split is well posed on its own (docs/partitioning.md).
    """
    from gelcell.coupled.defaults import coupling_config
    from gelcell.coupled.device import Device
    from gelcell.post.fields import fields_from_device

    p = _params(case)
    coupled = Device(p)
    coupled.solve(coupling_config(with_cell=True), verbose=False)
    fresh = Device(p)
    for participant in fresh.participants:
        inputs = {d.name: coupled.scheme.mapped(d.name, participant.name)
                  for d in coupled.data if participant.name in d.readers}
        outputs = participant.solve(inputs)
        for name, value in outputs.items():
            ref = coupled.scheme.latest(name)
            assert np.linalg.norm(value - ref) <= 1e-8 * np.linalg.norm(ref), (participant.name, name)
    diffs = relative_differences(fields_from_device(fresh), fields_from_device(coupled))
    assert max(diffs.values()) <= 1e-8, diffs


@pytest.mark.parametrize("case", ["shear", "normal"])
@pytest.mark.parametrize("gamma2", ["robin", "dirichlet"])
def test_other_gamma2_splits_reach_the_same_solution(case, gamma2):
    """Robin-Neumann and plain Dirichlet-Neumann on Gamma2 (the default condenses the cell's
    stiffness into the gel) are other iterations for the same discrete problem."""
    p = _params(case)
    part = solve_partitioned(p, verbose=False, checks=False, gamma2=gamma2)
    mono = solve_monolithic(p, checks=False)
    assert part.summary["coupling"]["converged"] and part.summary["coupling"]["gamma2"] == gamma2
    diffs = relative_differences(part.fields, mono.fields)
    assert max(diffs.values()) <= 1e-6, diffs
