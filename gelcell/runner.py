"""Run one device case (partitioned or monolithic) and write its results.

Used by ``gelcell run`` and ``gelcell sweep``; also importable::

    from gelcell.runner import run_case
    summary = run_case(CaseParameters.default("shear"), out="results/shear")
"""

from __future__ import annotations

import os
import sys
import time
import typing

import numpy as np

from mpi4py import MPI

import coupling as cp
from femtools.io import atomic_directory, check_output_target
from gelcell.checks import format_residuals, interface_residuals
from gelcell.device import Device, coupling_config, default_robin_coefficient, reuse_key
from gelcell.geometry import build_device
from gelcell.monolithic import MonolithicCoefficients, MonolithicSolver
from gelcell.output import DerivedFields, write_fields, write_json_file, write_profiles
from gelcell.parameters import DEFAULT_GAMMA2, CaseParameters, ParameterError
from gelcell.plots import FigureWorker, FigureWorkerError, figure_data, figure_worker
from gelcell.results import DeviceFields, fields_from_device, fields_from_monolithic, summarize
from gelcell.validity import check_case, model_warnings

__all__ = ["run_case", "solve_partitioned", "solve_monolithic", "format_summary", "CaseRun",
           "partitioned_config", "ReuseStore"]


class ReuseStore:
    """The coupling state carried from one solve to the next of a sweep (see :func:`solve_partitioned`).

    Attributes:
        key: What identifies the scaled problem (and the coupling configuration) of the states.
        states: ``[(Ca, scheme.reuse_state()), ...]`` of the last three solves with that key.
    """

    def __init__(self) -> None:
        self.key: typing.Any = None
        self.states: list[tuple[float, dict]] = []

    @property
    def state(self) -> dict | None:
        """The newest reusable state (None if none)."""
        return self.states[-1][1] if self.states else None

    def add(self, key: typing.Any, ca: float, state: dict) -> None:
        if key != self.key:
            self.key, self.states = key, []
        self.states = [(c, st) for c, st in self.states if c != float(ca)]
        self.states = (self.states + [(float(ca), state)])[-3:]

    def prediction(self, ca: float) -> dict | None:
        """The newest state with its interface data and participant states extrapolated to ``ca``.

        Lagrange polynomial in Ca through the last two (linear) or three
        (quadratic) solves; the newest state as it is with only one (or far
        outside the known values).  In
        solver units the data and fields depend on Ca only through the
        strain-sized nonlinearity, smooth in Ca: the extrapolation removes
        its first- (second-) order part.  None without a state.
        """
        if not self.states:
            return None
        newest = self.states[-1][1]
        # far outside the known values a polynomial amplifies the states' 1e-10 convergence noise:
        # fall back to fewer points (linear beyond 2x their span, none beyond 10x)
        cs = [c for c, _ in self.states]
        reach = abs(float(ca) - cs[-1]) / max(max(cs) - min(cs), 1e-300)
        used = self.states if reach <= 2.0 else self.states[-2:] if reach <= 10.0 else self.states[-1:]
        if len(used) < 2:
            return newest
        weights = cp.lagrange_weights([c for c, _ in used], ca)

        def combine(parts):
            first = parts[0]
            if isinstance(first, dict):
                return {k: combine([p[k] for p in parts]) for k in first}
            if isinstance(first, np.ndarray) and first.dtype.kind == "f" and \
                    all(isinstance(p, np.ndarray) and p.shape == first.shape for p in parts):
                return sum(w * p for w, p in zip(weights, parts))
            return parts[-1]

        states = [st for _, st in used]
        out = dict(newest)
        out["values"] = combine([st["values"] for st in states])
        out["participants"] = combine([st.get("participants") or {} for st in states])
        return out


class CaseRun(typing.NamedTuple):
    """A solved case: its fields, its summary, and the solver object behind it."""

    fields: DeviceFields
    summary: dict
    solver: typing.Any


def _dofs(space) -> int:
    return space.dofmap.index_map.size_global * space.dofmap.index_map_bs


def monolithic_coefficients(params: CaseParameters) -> MonolithicCoefficients:
    """The monolithic reference's coefficients; with finite kinematics its I13 rows are weighted by the
    partitioned fluid's default Robin coefficient (gelcell.monolithic, docs/finite-strain.md)."""
    ph = params.physics
    finite = params.kinematics == "finite"
    return MonolithicCoefficients(phi_s0=ph.phi_s0, xi=ph.xi, lambda_s=ph.lambda_s, beta=ph.beta, eta=ph.eta,
                                  Ca=ph.ca, mu_c=params.mu_c, lambda_c=params.lambda_c,
                                  stress_scale=params.stress_scale, displacement_scale=params.displacement_scale,
                                  kinematics=params.kinematics,
                                  interface_weight=default_robin_coefficient(params) if finite else None)


def partitioned_config(params: CaseParameters, scheme: str = "serial", acceleration: str = "iqn-ils",
                       coupling: typing.Mapping | None = None, transient: bool = False,
                       gamma2: str = DEFAULT_GAMMA2) -> dict:
    """The ``[coupling]`` table of a partitioned run (defaults < the case's < ``coupling``), validated.

    Raises :class:`ParameterError` naming the bad key or value, before anything is meshed.
    """
    config = coupling_config(scheme, acceleration, with_cell=params.with_cell,
                             overrides=dict(coupling or params.coupling or {}), transient=transient,
                             params=params, gamma2=gamma2)
    try:
        cp.load_config(config)
    except ValueError as exc:
        raise ParameterError(f"the [coupling] table is invalid: {exc}") from None
    return config


def solve_partitioned(params: CaseParameters, scheme: str = "serial", acceleration: str = "iqn-ils",
                      coupling: typing.Mapping | None = None, comm: MPI.Comm = MPI.COMM_WORLD,
                      verbose: bool = True, robin_coefficient: float | None = None,
                      checks: bool = True, gamma2: str = DEFAULT_GAMMA2,
                      reuse: "ReuseStore | None" = None) -> CaseRun:
    """Solve a case with the partitioned scheme; summary with coupling, timing and checks.

    ``reuse``: a :class:`ReuseStore` carried across related solves (a sweep).
    If it holds the state of a solve with the same :func:`gelcell.device.reuse_key`
    (the same scaled problem, e.g. another Ca) and the same coupling
    configuration, that state starts this solve; afterwards the store holds
    this solve's state.
    """
    t0 = time.perf_counter()
    check_case(params)
    config = partitioned_config(params, scheme, acceleration, coupling, gamma2=gamma2)
    device = Device(params, comm, robin_coefficient=robin_coefficient, gamma2=gamma2)
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
        device = Device(params, comm, robin_coefficient=robin_coefficient, gamma2=gamma2)
        result = device.solve(config, verbose=verbose)
    if reuse is not None:
        reuse.add(key, params.physics.ca, device.scheme.reuse_state(participants=True))
    t_solve = time.perf_counter() - t1
    fields = fields_from_device(device)
    summary = summarize(fields)
    summary["method"] = "partitioned"
    summary["coupling"] = {
        "scheme": config["scheme"], "acceleration": config["acceleration"]["type"],
        "robin_coefficient": device.alpha_n, "gamma2": device.gamma2,
        "gamma2_coefficient": device.kappa if device.gamma2 == "robin" else None,
        "jacobian_prior": "none" if device.linearized_prior is None else "linearized",
        "prior_source": device.prior_source,
        "iterations": result.iterations, "converged": result.converged,
        "reason": result.reason, "reused": reused, "residual_history": result.residual_history,
        "relaxation": result.relaxation}
    summary["mesh"] = {
        "fluid": {"cells": _cells(device.fluid.velocity), "dofs": _dofs(device.fluid.W)},
        "gel": {"cells": _cells(fields.displacement), "dofs": _dofs(device.gel.W)},
    }
    if device.cell is not None:
        summary["mesh"]["cell"] = {"cells": _cells(device.cell.displacement),
                                   "dofs": _dofs(device.cell.displacement.function_space)}
    summary["timing"] = {"setup": device.mesh_time + device.setup_time, "coupling": t_solve,
                         **{f"solve_{k}": v for k, v in result.timing.items()},
                         "total": time.perf_counter() - t0}
    if checks:
        summary["interface_residuals"] = interface_residuals(fields)
    return CaseRun(fields, summary, device)


def _cells(f) -> int:
    msh = f.function_space.mesh
    return msh.topology.index_map(msh.topology.dim).size_global


def solve_monolithic(params: CaseParameters, comm: MPI.Comm = MPI.COMM_WORLD, checks: bool = True) -> CaseRun:
    """Solve a case with the monolithic reference; same summary as the partitioned run."""
    t0 = time.perf_counter()
    check_case(params)
    dev_mesh = build_device(params, comm, whole=True)
    msh, ct, ft = dev_mesh.whole
    layout = dev_mesh.layout
    solver = MonolithicSolver(msh, ct, ft, layout.boundaries, monolithic_coefficients(params),
                              cell_region_tags=layout.cell_region_tags or None)
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
    summary["mesh"] = {"whole": {"cells": msh.topology.index_map(2).size_global, "dofs": solver.num_dofs},
                       "fluid": {"cells": _cells(fields.fluid_velocity)},
                       "gel": {"cells": _cells(fields.displacement)}}
    if fields.cell_displacement is not None:
        summary["mesh"]["cell"] = {"cells": _cells(fields.cell_displacement)}
    summary["timing"] = {"setup": solver.setup_time + (t1 - t0 - solver.setup_time), "solve": t_solve,
                         "total": time.perf_counter() - t0}
    if checks:
        summary["interface_residuals"] = interface_residuals(fields)
    return CaseRun(fields, summary, solver)


_ROWS = [
    ("max |v_f| in the gel", ("gel", "max_interstitial_speed"), "velocity"),
    ("max |u_s| in the gel", ("gel", "max_network_displacement"), "length"),
    ("max von Mises of sigma_s", ("gel", "max_network_von_mises"), "stress"),
    ("volume change below Gamma1", ("gel", "volume_change_below_gamma1"), "area"),
    ("  share due to the cell", ("gel", "volume_change_share_of_cell"), None),
    ("cell centroid displacement x", ("cell", "centroid_displacement", 0), "length"),
    ("cell centroid displacement y", ("cell", "centroid_displacement", 1), "length"),
    ("max |u_c| in the cell", ("cell", "max_displacement"), "length"),
    ("cell von Mises strain min", ("cell", "von_mises_strain", 0), None),
    ("cell von Mises strain max", ("cell", "von_mises_strain", 1), None),
    ("cell von Mises stress min", ("cell", "von_mises_stress", 0), "stress"),
    ("cell von Mises stress max", ("cell", "von_mises_stress", 1), "stress"),
    ("traction near cell: pressure", ("cell", "max_traction_von_mises", "pressure"), "stress"),
    ("traction near cell: Brinkman", ("cell", "max_traction_von_mises", "brinkman"), "stress"),
    ("traction near cell: network", ("cell", "max_traction_von_mises", "network"), "stress"),
    ("traction near cell: total", ("cell", "max_traction_von_mises", "total"), "stress"),
]
_UNITS = {"velocity": "µm/s", "length": "µm", "stress": "mPa", "area": "µm²", None: "-"}


def _get(d, path):
    for k in path:
        if d is None:
            return None
        d = d[k]
    return d


def _flat(block: dict | None, prefix: str, names: typing.Iterable[str]) -> dict:
    return {f"{prefix}.{k}": (None if block is None else block[k]) for k in names}


_GEL_KEYS = ("max_interstitial_speed", "max_network_displacement", "max_network_von_mises",
             "max_network_von_mises_location", "volume_change_below_gamma1", "local_volume_change_magnitude",
             "relative_volume_change_below_gamma1", "volume_change_share_of_cell")
_CELL_KEYS = ("centroid_displacement", "max_displacement", "von_mises_strain", "von_mises_stress",
              "max_traction_von_mises")


def report(summary: dict, params: CaseParameters) -> dict:
    """The layout of summary.json: ``case``, ``cell`` (bool), quantities as dotted keys.

    Every quantity appears as a top-level dotted key (``gel.max_interstitial_speed``,
    ``cell.centroid_displacement``, ... ; ``null`` for cell quantities without a
    cell), in the paper's dimensionless units; the ``si`` block repeats them in
    µm/s, µm and mPa.  ``gel_quantities``/``cell_quantities`` hold the same
    values nested.
    """
    gel, cell = summary.pop("gel"), summary.pop("cell")
    si = summary.pop("si")
    out = {"case": params.case, "cell": bool(params.with_cell), "method": summary.pop("method")}
    out.update(_flat(gel, "gel", _GEL_KEYS))
    out.update(_flat(cell, "cell", _CELL_KEYS))
    out["si"] = {"units": si["units"], **_flat(si["gel"], "gel", _GEL_KEYS), **_flat(si["cell"], "cell", _CELL_KEYS)}
    if "cells" in si:
        out["si"]["cells"] = si["cells"]
    out["parameters"] = params.to_dict()
    out["cell_moduli_note"] = (f"cell moduli mu_c = {params.cell.mu_c:g} Pa, lambda_c = {params.cell.lambda_c:g} Pa "
                               f"= {params.cell_moduli_multiple:g} x the gel's drained modulus phi_s0 mu_s")
    out.update(summary)
    out["gel_quantities"], out["cell_quantities"] = gel, cell
    model = out["model"] = dict(out.get("model") or {})
    model["max_cell_strain"] = None if cell is None else cell["von_mises_strain"][1]
    model["warnings"] = model_warnings(model)
    return out


def format_summary(summary: dict) -> str:
    """A short table: quantity, paper's dimensionless value, SI value."""
    lines = [f"{'quantity':32s} {'dimensionless':>14s} {'SI':>14s}  unit", "-" * 70]
    for label, path, kind in _ROWS:
        key, rest = f"{path[0]}.{path[1]}", path[2:]
        v = _get(summary.get(key), rest) if key in summary else None
        if v is None:
            continue
        si = _get(summary["si"][key], rest)
        lines.append(f"{label:32s} {v:14.6e} {si:14.6e}  {_UNITS[kind]}")
    cells = summary.get("cells") or []
    if len(cells) > 1:
        lines.append("per cell (dimensionless): centroid displacement x, y; von Mises strain max; stress max")
        for cl in cells:
            lines.append(f"  {cl['name']:8s} at ({cl['centre'][0]:.4g}, {cl['centre'][1]:.4g}) "
                         f"{cl['centroid_displacement'][0]:12.4e} {cl['centroid_displacement'][1]:12.4e} "
                         f"{cl['von_mises_strain'][1]:12.4e} {cl['von_mises_stress'][1]:12.4e}")
    c = summary.get("coupling")
    if c and "iterations" in c:
        prior = (f" (linearized prior: {c['prior_source']})" if c.get("jacobian_prior") == "linearized"
                 and c.get("prior_source") else "")
        lines.append(f"coupling: {c['scheme']} / {c['acceleration']}{prior}, {c['iterations']} iterations, "
                     f"converged={c['converged']}")
    t = summary.get("timing", {})
    if t:
        lines.append("timing [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in t.items()))
    return "\n".join(lines)


def _write_outputs(tmp: str, run: CaseRun, summary: dict, comm, *, monolithic: bool, figures: bool, fields: bool,
                   overlay_profiles: dict | None, extra_json: dict | None, worker: FigureWorker | None) -> list[str]:
    """Write every file of a steady run into ``tmp`` (summary.json last); returns the names written.

    The figures' data is gathered first; a ``worker`` draws them while this
    process writes the fields, profiles and records (if it fails, they are
    drawn here).
    """
    written = ["summary.json"]
    derived = DerivedFields(run.fields) if fields or figures else None     # shared by XDMF and figures
    profiles = write_profiles(tmp, run.fields, comm)                      # the figures show them: first
    data = figure_data(run.fields, profiles, summary, overlay_profiles, derived) if figures else None
    if worker is not None and data is not None:
        worker.submit(tmp, data)
    if fields:
        written += write_fields(tmp, run.fields, derived)
    written += [f"{k.lower()}_profiles.{ext}" for k in profiles for ext in ("h5", "csv")]
    if not monolithic:
        run.solver.scheme.write_records(os.path.join(tmp, "coupling"))
        written.append("coupling/")
    if data is not None:
        written += collect_figures(tmp, data, worker)
    for name, value in (extra_json or {}).items():
        write_json_file(os.path.join(tmp, name), value, comm)
        written.append(name)
    summary["files"] = written
    write_json_file(os.path.join(tmp, "summary.json"), summary, comm)
    return written


def collect_figures(tmp: str, data: dict, worker: FigureWorker | None) -> list[str]:
    """The figures drawn by ``worker``, or here if there is none or it failed (rank 0's data)."""
    if worker is not None:
        try:
            return worker.result()
        except FigureWorkerError as exc:
            print(f"gelcell: warning: {exc}; drawing the figures in this process", file=sys.stderr, flush=True)
    from gelcell.figures import render_device_figures
    return render_device_figures(tmp, data)


def run_case(params: CaseParameters, out: str | None, *, monolithic: bool = False, scheme: str = "serial",
             acceleration: str = "iqn-ils", coupling: typing.Mapping | None = None,
             comm: MPI.Comm = MPI.COMM_WORLD, verbose: bool = True, figures: bool = True,
             fields: bool = True, overlay_profiles: dict | None = None, stream=None,
             extra_json: dict | None = None, gamma2: str = DEFAULT_GAMMA2, shown_path: str | None = None,
             reuse: ReuseStore | None = None) -> dict:
    """Solve one case and write its outputs into ``out`` (whole or not at all).

    ``out`` and the model's limits are checked before anything is meshed; the
    model's warnings go to stderr and to ``model.warnings`` in the summary.
    ``shown_path`` is the path printed for ``out`` (the final path of a run
    written inside a sweep's temporary directory).
    """
    stream = stream or sys.stdout
    say = (lambda msg: print(msg, file=stream, flush=True)) if comm.rank == 0 else (lambda msg: None)
    if out is not None:
        check_output_target(out, comm)
    device = params.label
    n_cells = len(params.geometry.cell_list()) if params.with_cell else 0
    say(f"gelcell: {device}, {'without cell' if not n_cells else 'with cell' if n_cells == 1 else f'{n_cells} cells'}, "
        f"{'monolithic' if monolithic else f'partitioned ({scheme}, {acceleration})'}")
    # a serial run draws its figures in a second process, which imports matplotlib while this one solves
    with figure_worker(out is not None and figures, comm) as worker:
        if monolithic:
            run = solve_monolithic(params, comm)
        else:
            run = solve_partitioned(params, scheme, acceleration, coupling, comm, verbose, gamma2=gamma2, reuse=reuse)
        summary = report(run.summary, params)
        say(format_summary(summary))
        if "interface_residuals" in summary:
            say(format_residuals(summary["interface_residuals"]))
        if comm.rank == 0:
            for warning in summary["model"]["warnings"]:
                print(f"gelcell: warning: {warning}", file=sys.stderr, flush=True)
        if out is None:
            return summary
        with atomic_directory(out, comm) as tmp:
            try:
                written = _write_outputs(tmp, run, summary, comm, monolithic=monolithic, figures=figures,
                                         fields=fields, overlay_profiles=overlay_profiles, extra_json=extra_json,
                                         worker=worker)
            finally:
                if worker is not None:
                    worker.close()          # before the directory is promoted or removed
    say(f"wrote {shown_path or os.path.abspath(out)}: " + ", ".join(written))
    return summary
