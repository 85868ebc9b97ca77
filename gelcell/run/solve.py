"""Solve one device case, partitioned or monolithic, into its fields and the summary of its quantities.

Used by every run (:mod:`gelcell.run.steady`, sweeps, the study) and
importable::

    from gelcell.run.solve import solve_partitioned
    run = solve_partitioned(CaseParameters.default("shear"))
    run.summary["gel"]["max_interstitial_speed"]
"""

from __future__ import annotations

import time
import typing

from mpi4py import MPI

import coupling as cp
from gelcell.case import DEFAULT_GAMMA2, CaseParameters
from gelcell.coupled.defaults import partitioned_config, reuse_key
from gelcell.coupled.device import Device
from gelcell.coupled.monolithic import MonolithicSolver, monolithic_coefficients
from gelcell.coupled.reuse import ReuseStore
from gelcell.geometry import described
from gelcell.geometry.meshes import build_meshes
from gelcell.post.fields import DeviceFields, fields_from_device, fields_from_monolithic
from gelcell.post.quantities import summarize
from gelcell.post.residuals import interface_residuals
from gelcell.post.validity import check_case
from gelcell.run.cost import cost_summary, device_unknowns, monolithic_unknowns

__all__ = ["CaseRun", "solve_partitioned", "solve_monolithic", "solver_summary", "monolithic_solver_kind",
           "monolithic_solver_summary"]


class CaseRun(typing.NamedTuple):
    """A solved case: its fields, its summary, and the solver object behind it."""

    fields: DeviceFields
    summary: dict
    solver: typing.Any


def solve_partitioned(params: CaseParameters, coupling: typing.Mapping | None = None,
                      comm: MPI.Comm = MPI.COMM_WORLD, verbose: bool = True,
                      robin_coefficient: float | None = None, checks: bool = True,
                      gamma2: str = DEFAULT_GAMMA2, reuse: ReuseStore | None = None, solver: str = "direct",
                      petsc_options: typing.Mapping | None = None) -> CaseRun:
    """Solve a case with the partitioned scheme; summary with coupling, timing and checks.

    ``coupling``: the ``[coupling]`` table (the device's defaults fill in the
    rest, :func:`gelcell.coupled.defaults.partitioned_config`).  ``reuse``: a
    :class:`~gelcell.coupled.reuse.ReuseStore` carried across related solves
    (a sweep).  If it holds the state of a solve with the same
    :func:`~gelcell.coupled.defaults.reuse_key` (the same scaled problem, e.g.
    another Ca) and the same coupling configuration, that state starts this
    solve; afterwards the store holds this solve's state.  ``solver``,
    ``petsc_options``: the fields' linear solves (``[solver] kind`` and
    ``[solver.petsc]``, :class:`~gelcell.coupled.device.Device`); the summary's
    ``solver`` says what each field got.
    """
    t0 = time.perf_counter()
    params = described(params)
    check_case(params, solver)
    config = partitioned_config(params, coupling, gamma2=gamma2)
    choice = {"solver": solver, "petsc_options": petsc_options, "distribute": config.get("distribute")}
    device = Device(params, comm, robin_coefficient=robin_coefficient, gamma2=gamma2, **choice)
    t1 = time.perf_counter()
    key = None
    if reuse is not None:
        key = (reuse_key(params), repr(sorted(config.items())), robin_coefficient, gamma2)
    reused = reuse is not None and reuse.key == key and reuse.state is not None
    try:
        result = device.solve(config, verbose=verbose, reuse=reuse.prediction(params.physics.ca) if reused else None)
    except cp.CouplingError:
        if not reused:
            raise
        # the reused information did not fit after all: solve this value from scratch
        reused = False
        device = Device(params, comm, robin_coefficient=robin_coefficient, gamma2=gamma2, **choice)
        result = device.solve(config, verbose=verbose)
    if reuse is not None:
        reuse.add(key, params.physics.ca, device.scheme.reuse_state(participants=True))
    t_solve = time.perf_counter() - t1
    fields = fields_from_device(device)
    summary = summarize(fields)
    summary["method"] = "partitioned"
    summary["coupling"] = _coupling_summary(device, config, result, reused)
    summary["solver"] = solver_summary(device)
    unknowns = device_unknowns(device)
    summary["mesh"] = _mesh_summary(unknowns, fields)
    summary["cost"] = cost_summary(unknowns, comm)
    summary["timing"] = {"setup": device.mesh_time + device.setup_time, "coupling": t_solve,
                         **{f"solve_{k}": v for k, v in result.timing.items()},
                         "total": time.perf_counter() - t0}
    if checks:
        summary["interface_residuals"] = interface_residuals(fields)
    return CaseRun(fields, summary, device)


def _coupling_summary(device: Device, config: dict, result: cp.CouplingResult, reused: bool) -> dict:
    """What the coupling ran (scheme, acceleration, coefficients, prior) and how it converged."""
    return {
        "scheme": config["scheme"], "acceleration": config["acceleration"]["type"],
        "robin_coefficient": device.alpha_n, "gamma2": device.gamma2,
        "gamma2_coefficient": device.kappa if device.gamma2 == "robin" else None,
        "jacobian_prior": "none" if device.linearized_prior is None else "linearized",
        "prior_source": device.prior_source, "prior_reason": device.prior_declined,
        "interface_unknowns": device.scheme.layout.size,
        "iterations": result.iterations, "converged": result.converged,
        "reason": result.reason, "reused": reused, "residual_history": result.residual_history,
        "relaxation": result.relaxation,
        "distribute": device.distribute}


def solver_summary(device: Device) -> dict:
    """``solver`` of the summary: the ``kind`` asked for and what each field got (``fields``)."""
    out = {"kind": device.solver, "fields": dict(device.solver_kinds)}
    krylov = device.krylov_iterations()
    if krylov:
        out["krylov"] = krylov
    return out


def _mesh_summary(unknowns: dict[str, int], fields: DeviceFields) -> dict:
    """Global cells and degrees of freedom of each field's mesh (``unknowns``: :func:`device_unknowns`)."""
    mesh = {"fluid": {"cells": _cells(fields.fluid_velocity), "dofs": unknowns["fluid"]},
            "gel": {"cells": _cells(fields.displacement), "dofs": unknowns["gel"]}}
    if fields.cell_displacement is not None:
        mesh["cell"] = {"cells": _cells(fields.cell_displacement), "dofs": unknowns["cell"]}
    return mesh


def _cells(f) -> int:
    msh = f.function_space.mesh
    return msh.topology.index_map(msh.topology.dim).size_global


def monolithic_solver_kind(solver: str) -> str:
    """What solves the monolithic reference for ``[solver] kind``: ``auto`` picks MUMPS at every size
    (its iterative path is slower than MUMPS on every device measured, docs/performance.md)."""
    if solver not in ("direct", "auto", "iterative"):
        raise ValueError(f"solver = {solver!r}: give 'direct', 'iterative' or 'auto'")
    return "iterative" if solver == "iterative" else "direct"


def monolithic_solver_summary(asked: str, solver: MonolithicSolver) -> dict:
    """``solver`` of a monolithic summary; on the iterative path also the FGMRES iterations (``krylov``)
    and the gel's inner GMRES iterations they took (``inner_iterations``)."""
    out = {"kind": asked, "fields": {"monolithic": solver.solver_kind}}
    stats = solver.newton.stats
    if solver.solver_kind == "iterative":
        solves, its = int(stats["solves"]), int(stats["krylov_iterations"])
        out["krylov"] = {"monolithic": {"solves": solves, "iterations": its, "mean": its / solves if solves else 0.0,
                                        "inner_iterations": int(sum(solver.newton.solver.inner_iterations))}}
    return out


def solve_monolithic(params: CaseParameters, comm: MPI.Comm = MPI.COMM_WORLD, checks: bool = True,
                     solver: str = "direct") -> CaseRun:
    """Solve a case with the monolithic reference; same summary as the partitioned run.

    ``solver``: ``"direct"`` (MUMPS), ``"iterative"`` (FGMRES with the gel-first block sweep,
    :mod:`gelcell.coupled.monolithic_krylov`) or ``"auto"`` (:func:`monolithic_solver_kind`).
    """
    asked, kind = solver, monolithic_solver_kind(solver)
    t0 = time.perf_counter()
    params = described(params)
    check_case(params)
    dev_mesh = build_meshes(params, comm, whole=True)
    msh, ct, ft = dev_mesh.whole
    layout = dev_mesh.layout
    solver = MonolithicSolver(msh, ct, ft, layout.boundaries, monolithic_coefficients(params),
                              cell_region_tags=layout.cell_region_tags or None, solver=kind)
    t1 = time.perf_counter()
    iterations = solver.solve()
    t_solve = time.perf_counter() - t1
    fields = fields_from_monolithic(solver, dev_mesh, params)
    summary = summarize(fields)
    summary["method"] = "monolithic"
    summary["monolithic"] = {"newton_iterations": iterations, "newton_history": solver.newton.history,
                             "active_dofs": int(solver.newton.num_active_dofs),
                             "dofs": solver.num_dofs}
    summary["coupling"] = None
    summary["solver"] = monolithic_solver_summary(asked, solver)
    whole = msh.topology.index_map(msh.topology.dim).size_global
    summary["mesh"] = {"whole": {"cells": whole, "dofs": solver.num_dofs},
                       "fluid": {"cells": _cells(fields.fluid_velocity)},
                       "gel": {"cells": _cells(fields.displacement)}}
    if fields.cell_displacement is not None:
        summary["mesh"]["cell"] = {"cells": _cells(fields.cell_displacement)}
    summary["cost"] = cost_summary(monolithic_unknowns(solver), comm)
    summary["timing"] = {"setup": solver.setup_time + (t1 - t0 - solver.setup_time), "solve": t_solve,
                         "total": time.perf_counter() - t0}
    if checks:
        summary["interface_residuals"] = interface_residuals(fields)
    return CaseRun(fields, summary, solver)
