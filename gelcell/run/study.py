"""Coupling-scheme comparison study: which scheme and acceleration to use on the device cases.

For every case (both devices with the cell; stiffness extremes of the cell
and of the gel) and every method (scheme x acceleration x partitioning
variant) the partitioned problem is solved from rest and compared with the
monolithic reference of the same case:

    converged or why not (diverged, stagnated, max_iterations), iterations,
    participant solves, wall time of the coupling loop, error against the
    monolithic solution (worst relative difference of the summary quantities
    and of the fields), final residual (worst relative residual of any data).

``run_study(quick=True)`` runs a representative subset in a few minutes; the
full study is a benchmark (``gelcell study --out DIR``).
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
import time
import typing

import numpy as np

from mpi4py import MPI

import coupling as cp
from femtools.io import atomic_directory, check_output_target, write_json
from gelcell.case import DEFAULT_GAMMA2, CaseParameters
from gelcell.case.casefile import read_bounded
from gelcell.coupled.defaults import coupling_config, default_robin_coefficient
from gelcell.coupled.device import Device
from gelcell.errors import ParameterError
from gelcell.post.fields import fields_from_device, relative_differences
from gelcell.post.quantities import flat_quantities, summarize
from gelcell.run.solve import solve_monolithic

__all__ = ["Method", "StudyCase", "study_cases", "study_methods", "study_mesh_size", "run_study",
           "markdown_table", "check_study_table", "update_study_table"]


@dataclasses.dataclass(frozen=True)
class StudyCase:
    """A device case of the study: geometry and stiffness variant."""

    name: str
    device: str
    cell_moduli: float = 1.0
    gel_moduli: float = 1.0

    def parameters(self, mesh_size: float) -> CaseParameters:
        p = CaseParameters.default(self.device, True).with_mesh_size(mesh_size)
        if self.cell_moduli != 1.0:
            p = p.with_cell_moduli(self.cell_moduli)
        if self.gel_moduli != 1.0:
            p = p.with_gel_moduli(self.gel_moduli)
        return p


@dataclasses.dataclass(frozen=True)
class Method:
    """A coupling method: scheme, acceleration (with options) and Robin coefficient on Gamma1."""

    name: str
    scheme: str
    acceleration: dict
    robin_factor: float = 1.0      # multiple of the device's default alpha_n
    gamma2: str = DEFAULT_GAMMA2      # the split on Gamma2, one of gelcell.case.GAMMA2

    def config(self, with_cell: bool, max_iterations: int, params: CaseParameters | None = None) -> dict:
        """The ``[coupling]`` table: the device default of the case (with ``params``: its Gamma2
        relaxation prior, gelcell.coupled.defaults.default_relaxation_prior), then this method's options."""
        base = coupling_config(self.scheme, self.acceleration["type"], with_cell=with_cell,
                               max_iterations=max_iterations, params=params, gamma2=self.gamma2)
        acc = dict(base["acceleration"])
        acc.update({k: v for k, v in self.acceleration.items()})
        base["acceleration"] = {k: v for k, v in acc.items()
                                if k in cp.config.ACCELERATION_OPTIONS[acc["type"]]}
        base.update(verbose=False, on_max_iterations="return", divergence_factor=1e4)
        return base


def study_cases(quick: bool = False) -> list[StudyCase]:
    if quick:
        return [StudyCase("shear", "shear"), StudyCase("normal", "normal"),
                StudyCase("shear cell x10", "shear", cell_moduli=10.0),
                StudyCase("normal cell x10", "normal", cell_moduli=10.0)]
    out = []
    for device in ("shear", "normal"):
        out += [StudyCase(device, device),
                StudyCase(f"{device} cell x0.1", device, cell_moduli=0.1),
                StudyCase(f"{device} cell x10", device, cell_moduli=10.0),
                StudyCase(f"{device} gel x0.1", device, gel_moduli=0.1),
                StudyCase(f"{device} gel x10", device, gel_moduli=10.0)]
    return out


def study_methods(quick: bool = False) -> list[Method]:
    # the secant model alone (the device default adds the linearized prior where it pays: those rows below)
    iqn = {"type": "iqn-ils", "initial_relaxation": 0.5, "max_used_iterations": 100,
           "filter": {"type": "qr2", "limit": 1e-3}, "jacobian_prior": "none"}
    # the Newton step on the map linearised from the solvers' interface Jacobians (docs/coupling.md)
    linearized = {**iqn, "jacobian_prior": "linearized"}
    if quick:
        return [Method("none", "serial", {"type": "none"}),
                Method("none dirichlet gamma2", "serial", {"type": "none"}, gamma2="dirichlet"),
                Method("aitken", "serial", {"type": "aitken", "initial_relaxation": 0.5}),
                Method("iqn-ils", "serial", iqn),
                Method("iqn-ils", "parallel", iqn),
                # the device default (where it pays, Device.solve)
                Method("iqn-ils linearized prior", "serial", linearized)]
    accelerations = [
        ("none", {"type": "none"}),
        ("constant 0.5", {"type": "constant", "relaxation": 0.5}),
        ("constant 0.2", {"type": "constant", "relaxation": 0.2}),
        ("aitken", {"type": "aitken", "initial_relaxation": 0.5}),
        ("iqn-ils", iqn),
        ("iqn-ils no filter", {**iqn, "filter": {"type": "none"}}),
        ("iqn-ils 10 kept", {**iqn, "max_used_iterations": 10}),
        ("iqn-imvj", {**iqn, "type": "iqn-imvj"}),
    ]
    methods = [Method(name, scheme, acc) for scheme in ("serial", "parallel") for name, acc in accelerations]
    # the other splits of Gamma2 (docs/partitioning.md): plain Dirichlet-Neumann (with IQN-ILS: the
    # relaxation prior omega = 1/(1 + rho), the default before the cell was condensed into the gel,
    # and without it, the default before that) and Robin-Neumann (springs on the cell)
    aitken = {"type": "aitken", "initial_relaxation": 0.5}
    methods += [Method("none dirichlet gamma2", "serial", {"type": "none"}, gamma2="dirichlet"),
                Method("aitken dirichlet gamma2", "serial", aitken, gamma2="dirichlet"),
                Method("iqn-ils dirichlet gamma2", "serial", iqn, gamma2="dirichlet"),
                Method("iqn-ils dirichlet gamma2 no prior", "serial", {**iqn, "relaxation_prior": {}},
                       gamma2="dirichlet"),
                Method("iqn-ils robin gamma2", "serial", iqn, gamma2="robin"),
                Method("aitken robin gamma2", "serial", aitken, gamma2="robin")]
    # the linearized prior on both schemes and on plain Dirichlet-Neumann (instead of its relaxation prior)
    methods += [Method("iqn-ils linearized prior", "serial", linearized),
                Method("iqn-ils linearized prior", "parallel", linearized),
                Method("iqn-ils dirichlet gamma2 linearized prior", "serial", {**linearized, "relaxation_prior": {}},
                       gamma2="dirichlet")]
    # the preconditioner: residual-sum weights drift every iteration (the default is value scaling)
    methods.append(Method("iqn-ils residual-sum", "serial", {**iqn, "preconditioner": {"type": "residual-sum"}}))
    # the partitioning variant: the Robin coefficient of the fluid's mass condition on Gamma1/Gamma3
    for factor in (0.1, 10.0):
        methods += [Method(f"iqn-ils alpha x{factor:g}", "serial", iqn, factor),
                    Method(f"aitken alpha x{factor:g}", "serial", aitken, factor)]
    return methods


def quantity_error(summary: dict, reference: dict) -> float:
    """Worst difference of the summary quantities, relative to each quantity's size.

    Components of a vector (the centroid's [x, y]) are measured against the
    vector's size, and the volume change against int |J - 1| (it is a sum of
    compressions and dilatations that largely cancel).
    """
    a, b = flat_quantities(summary), flat_quantities(reference)
    worst = 0.0
    for key, ref in b.items():
        base = key.split("[")[0]
        scale = max(abs(v) for k, v in b.items() if k.split("[")[0] == base)
        if "volume_change" in key and "magnitude" not in key and "share" not in key:
            scale = max(scale, b["gel.local_volume_change_magnitude"] * abs(ref) / max(
                abs(b["gel.volume_change_below_gamma1"]), 1e-300) if key.startswith("gel.relative")
                else b["gel.local_volume_change_magnitude"])
        if key.endswith("share_of_cell"):
            scale = max(abs(ref), b["gel.local_volume_change_magnitude"] / max(
                abs(b["gel.volume_change_below_gamma1"]), 1e-300))
        if scale > 0:
            worst = max(worst, abs(a[key] - ref) / scale)
    return worst


def _classify(result: cp.CouplingResult | None, error: Exception | None) -> str:
    if error is not None:
        return "diverged"
    if result.converged:
        return "converged"
    history = np.nanmax(np.array(list(result.residual_history.values()), dtype=float), axis=0)
    tail = history[-10:]
    if tail.size >= 10 and tail[-1] > 0.1 * tail[0]:
        return "stagnated"
    return "max_iterations"


def _diverged_data(message: str) -> str | None:
    """The data whose residual blew up, or the participant that failed (from the error message)."""
    m = re.search(r"residual of data '([^']+)'", message)
    if m:
        return m.group(1)
    m = re.search(r"participant '([^']+)' failed", message)
    worst = re.search(r"residual norms of '([^']+)'", message)
    if m:
        return f"{m.group(1)} solver failed" + (f"; worst {worst.group(1)}" if worst else "")
    return None


def run_one(case: StudyCase, method: Method, mesh_size: float, reference, max_iterations: int,
            comm: MPI.Comm) -> dict:
    """One partitioned solve of the study; a record of the outcome."""
    params = case.parameters(mesh_size)
    device = Device(params, comm, robin_coefficient=method.robin_factor * default_robin_coefficient(params),
                    gamma2=method.gamma2)
    config = method.config(True, max_iterations, params)
    t0 = time.perf_counter()
    result, error = None, None
    try:
        result = device.solve(config, verbose=False)
    except cp.CouplingError as exc:
        error, result = exc, exc.result
    wall = time.perf_counter() - t0
    status = _classify(result if error is None else None, error)
    history = {k: [float(x) for x in v] for k, v in result.residual_history.items()}
    # the convergence measures' last values (the forward data they leave out only change)
    last = result.windows[-1].records[-1].measures if result.windows and result.windows[-1].records else []
    final = max((m.value for m in last), default=float("nan"))
    record = {"case": case.name, "scheme": method.scheme, "acceleration": method.name,
              "robin_factor": method.robin_factor, "converged": status == "converged", "status": status,
              "reason": str(error) if error is not None else result.reason,
              "diverged_data": _diverged_data(str(error)) if error is not None else None,
              "iterations": int(result.iterations), "participant_solves": int(result.iterations) * 3,
              "wall_time": wall, "final_residual": final, "error_quantities": None, "error_fields": None,
              "history": list(np.nanmax(np.array(list(history.values()), dtype=float), axis=0))
              if history and result.iterations else []}
    if status == "converged":
        fields = fields_from_device(device)
        record["error_quantities"] = quantity_error(summarize(fields), reference.summary)
        record["error_fields"] = max(relative_differences(fields, reference.fields).values())
    return record


def markdown_table(records: list[dict], references: dict[str, dict] | None = None) -> str:
    """The study as a Markdown table (one row per run)."""
    lines = ["| case | scheme | acceleration | outcome | iterations | solves | wall [s] | "
             "error vs monolithic | final residual |",
             "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in records:
        err = "-" if r["error_quantities"] is None else f"{max(r['error_quantities'], r['error_fields']):.1e}"
        outcome = r["status"] + (f" ({r['diverged_data']})" if r.get("diverged_data") else "")
        lines.append(f"| {r['case']} | {r['scheme']} | {r['acceleration']} | {outcome} | {r['iterations']} | "
                     f"{r['participant_solves']} | {r['wall_time']:.2f} | {err} | {r['final_residual']:.1e} |")
    if references:
        lines += ["", "| case | monolithic Newton iterations | monolithic wall [s] | best method | "
                  "iterations | wall [s] |", "|---|---:|---:|---|---:|---:|"]
        for case, ref in references.items():
            ok = [r for r in records if r["case"] == case and r["converged"]]
            best = min(ok, key=lambda r: r["wall_time"]) if ok else None
            name = f"{best['scheme']} {best['acceleration']}" if best else "-"
            lines.append(f"| {case} | {ref['newton_iterations']} | {ref['wall_time']:.2f} | {name} | "
                         f"{best['iterations'] if best else '-'} | "
                         f"{best['wall_time'] if best else float('nan'):.2f} |")
    return "\n".join(lines)


def iteration_matrix(records: list[dict]) -> str:
    """Iterations to convergence, one row per method and one column per case (Markdown).

    Entries that did not converge show why: ``div`` (diverged), ``stag``
    (stagnated) or ``max`` (iteration limit while still decreasing).
    """
    cases, methods = [], []
    for r in records:
        if r["case"] not in cases:
            cases.append(r["case"])
        key = (r["scheme"], r["acceleration"])
        if key not in methods:
            methods.append(key)
    short = {"diverged": "div", "stagnated": "stag", "max_iterations": "max"}
    lines = ["| scheme | acceleration | " + " | ".join(cases) + " |",
             "|---|---|" + "---:|" * len(cases)]
    for scheme, acc in methods:
        cells = []
        for case in cases:
            r = next((x for x in records if x["case"] == case and x["scheme"] == scheme
                      and x["acceleration"] == acc), None)
            cells.append("" if r is None else str(r["iterations"]) if r["converged"]
                         else f"{short.get(r['status'], r['status'])} ({r['iterations']})")
        lines.append(f"| {scheme} | {acc} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _plot(path: str, records: list[dict], cases: list[StudyCase]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ncol = min(len(cases), 2)
    nrow = int(np.ceil(len(cases) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(7 * ncol, 4 * nrow), squeeze=False)
    methods = list(dict.fromkeys((r["scheme"], r["acceleration"]) for r in records))
    colors = plt.get_cmap("tab20")
    for ax, case in zip(axes.ravel(), cases):
        for r in records:
            if r["case"] != case.name or not r["history"]:
                continue
            h = np.maximum(np.array(r["history"], dtype=float), 1e-16)
            i = methods.index((r["scheme"], r["acceleration"]))
            # colour: method; solid: converged, dotted: did not
            ax.semilogy(np.arange(1, len(h) + 1), h, "-" if r["converged"] else ":", color=colors(i % 20),
                        label=f"{r['scheme']} {r['acceleration']}", lw=1)
        ax.axhline(1e-10, color="k", lw=0.5)
        ax.set_title(case.name)
        ax.set_xlabel("coupling iteration")
        ax.set_ylabel("worst relative residual")
        ax.set_ylim(1e-14, 1e6)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    for ax in axes.ravel()[len(cases):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def study_mesh_size(quick: bool, mesh_size: float | None = None) -> float:
    """The element size factor of the study: ``mesh_size``, else 3 with ``quick``, else 2."""
    return mesh_size if mesh_size is not None else (3.0 if quick else 2.0)


def run_study(out: str | None, *, quick: bool = False, mesh_size: float | None = None,
              max_iterations: int = 150, comm: MPI.Comm = MPI.COMM_WORLD,
              log: typing.Callable[[str], None] | None = None) -> dict:
    """Run the study; write study.csv/json/md and study_convergence.png into ``out``.

    ``out`` is checked before the first case is meshed (``femtools.io.check_output_target``).
    """
    mesh_size = study_mesh_size(quick, mesh_size)
    if out is not None:
        check_output_target(out, comm)
    log = log or ((lambda msg: print(msg, flush=True)) if comm.rank == 0 else (lambda msg: None))
    cases, methods = study_cases(quick), study_methods(quick)
    records, references = [], {}
    for case in cases:
        t0 = time.perf_counter()
        ref = solve_monolithic(case.parameters(mesh_size), comm, checks=False)
        references[case.name] = {"newton_iterations": ref.summary["monolithic"]["newton_iterations"],
                                 "wall_time": time.perf_counter() - t0,
                                 "solve_time": ref.summary["timing"]["solve"]}
        for method in methods:
            r = run_one(case, method, mesh_size, ref, max_iterations, comm)
            records.append(r)
            log(f"{case.name:18s} {method.scheme:8s} {method.name:20s} {r['status']:14s} "
                f"{r['iterations']:4d} it  {r['wall_time']:6.2f} s  "
                f"error {r['error_quantities'] if r['error_quantities'] is not None else float('nan'):.1e}")
    table = markdown_table(records, references)
    study = {"quick": quick, "mesh_size": mesh_size, "max_iterations": max_iterations, "records": records,
             "monolithic": references, "table": table}
    if out is not None:
        with atomic_directory(out, comm) as tmp:
            write_json(os.path.join(tmp, "study.json"), study, comm)
            if comm.rank == 0:
                keys = [k for k in records[0] if k != "history"]
                with open(os.path.join(tmp, "study.csv"), "w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
                    w.writeheader()
                    w.writerows(records)
                with open(os.path.join(tmp, "study.md"), "w") as f:
                    f.write("## Iterations to a relative residual of 1e-10\n\n" + iteration_matrix(records)
                            + "\n\n## Every run\n\n" + table + "\n")
                _plot(os.path.join(tmp, "study_convergence.png"), records, cases)
    return study


TABLE_BEGIN = "<!-- coupling-study:begin (generated by examples/coupling_study.py --quick --update-table) -->"
TABLE_END = "<!-- coupling-study:end -->"


#: a Markdown document that holds the study table is at most a few hundred kB
MAX_TABLE_FILE_BYTES = 16 << 20


def check_study_table(path: str) -> str:
    """The text of the Markdown file ``path`` if the study table can go there (before the study runs).

    Raises ParameterError if it is not a readable, writable UTF-8 file with the
    markers :data:`TABLE_BEGIN` and :data:`TABLE_END`, in this order.
    """
    try:
        text = read_bounded(path, "--update-table file", MAX_TABLE_FILE_BYTES).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterError(f"--update-table {path}: not UTF-8 text (byte {exc.start})") from None
    begin, end = text.find(TABLE_BEGIN), text.find(TABLE_END)
    if begin < 0 or end < begin:
        raise ParameterError(f"--update-table {path}: the file lacks the coupling-study markers (a line "
                             f"{TABLE_BEGIN}, later a line {TABLE_END}) between which the table goes")
    if not os.access(path, os.W_OK):
        raise ParameterError(f"--update-table {path}: the file is not writable")
    return text


def update_study_table(path: str, table: str) -> None:
    """Replace the study table between the coupling-study markers of the Markdown file ``path``."""
    text = check_study_table(path)
    head, rest = text.split(TABLE_BEGIN, 1)
    _, tail = rest.split(TABLE_END, 1)
    with open(path, "w") as f:
        f.write(head + TABLE_BEGIN + "\n" + table + "\n" + TABLE_END + tail)
