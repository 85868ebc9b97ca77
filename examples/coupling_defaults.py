# # The coupling library's defaults, by measurement
#
# Iteration totals for the choices behind three defaults of `coupling/`: the
# state reload of an implicit scheme's windows (`state_reload`), the data a
# convergence measure covers (`data`), and the quasi-Newton QR filter
# (`acceleration.filter`).  Each variant changes one setting of a baseline and
# is run on
#
# * the 1D flexible tube (examples/flexible_tube, Aitken and IQN-ILS, several
#   time windows), against the same run's baseline answer;
# * the devices (`gelcell run`, shear and normal with a cell, mesh size 3):
#   steady with the default prior and with `--jacobian-prior none`, and a few
#   time windows of a time-dependent run; the answer (the Gamma1 profiles,
#   the time series) against the baseline's.
#
# docs/coupling-study.md, "Library defaults, by measurement", has the table.
#
# Usage:
#
#     .venv/bin/python examples/coupling_defaults.py tube [--windows 20]
#     .venv/bin/python examples/coupling_defaults.py device [--out DIR]
#
# (`--variants NAME ...` runs only those variants and the baseline.)

from __future__ import annotations

import argparse
import csv
import json
import pathlib
import subprocess
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT / "flexible_tube"))

import coupling as cp  # noqa: E402
import tube  # noqa: E402

#: the end of a device's time-dependent run: a few windows of its default dt (shear 6, normal 4)
T_END = {"shear": 2e-7, "normal": 6e-7}
#: the baseline's own filter (the tube: the library's, the devices: coupling_config's) is not rerun
SAME_AS_BASELINE = {"tube": ("filter qr2 1e-2", "accelerated, qr2 1e-2"),
                    "device": ("filter qr2 1e-3", "accelerated, qr2 1e-3")}
#: one setting changed from the baseline per variant (a [coupling] table on top of the baseline's)
VARIANTS = {
    "baseline": {},
    "state_reload = window": {"state_reload": "window"},
    "data = accelerated": {"data": "accelerated"},
    "filter qr2 1e-2": {"filter": {"type": "qr2", "limit": 1e-2}},
    "filter qr2 1e-3": {"filter": {"type": "qr2", "limit": 1e-3}},
    "filter qr2 1e-4": {"filter": {"type": "qr2", "limit": 1e-4}},
    "filter qr1 1e-2": {"filter": {"type": "qr1", "limit": 1e-2}},
    "no filter": {"filter": {"type": "none"}},
    "accelerated, window": {"data": "accelerated", "state_reload": "window"},
    "accelerated, qr2 1e-2": {"data": "accelerated", "filter": {"type": "qr2", "limit": 1e-2}},
    "accelerated, qr2 1e-3": {"data": "accelerated", "filter": {"type": "qr2", "limit": 1e-3}},
    "accelerated, qr2 1e-4": {"data": "accelerated", "filter": {"type": "qr2", "limit": 1e-4}},
    "accelerated, no filter": {"data": "accelerated", "filter": {"type": "none"}},
}
TUBE_ACCELERATIONS = {
    "aitken": {"type": "aitken", "initial_relaxation": 0.01},
    "iqn-ils": {"type": "iqn-ils", "initial_relaxation": 0.01},
    "iqn-ils, 8 windows reused": {"type": "iqn-ils", "initial_relaxation": 0.01, "time_windows_reused": 8},
}


def _tube_config(acceleration: dict, variant: dict, limit: float) -> dict:
    """The tube's [coupling] table: the library's defaults before the study, then ``variant`` on top."""
    measure = {"type": "relative", "limit": limit, "data": variant.get("data", "*")}
    acc = dict(acceleration)
    if acc["type"] != "aitken":
        acc["filter"] = variant.get("filter", {"type": "qr2", "limit": 1e-2})
    config = {"scheme": "serial-implicit", "order": ["flow", "wall"], "verbose": False, "max_iterations": 200,
              "convergence": [measure], "acceleration": acc}
    if "state_reload" in variant:
        config["state_reload"] = variant["state_reload"]
    return config


def tube_table(windows: int, names: list[str], dt: float = 1e-3, limit: float = 1e-10) -> None:
    """Print the tube's iteration totals per acceleration and variant, and the answer's change."""
    params = tube.TubeParameters(cells=100, period=0.01)
    print(f"flexible tube: 100 cells, dt = {dt:g} s, {windows} windows; total iterations "
          f"(max |r - r_baseline| / r0)")
    for label, acceleration in TUBE_ACCELERATIONS.items():
        row, reference = [], None
        for name, variant in VARIANTS.items():
            if ("filter" in variant and acceleration["type"] == "aitken") or name in SAME_AS_BASELINE["tube"] \
                    or (name not in names and name != "baseline"):
                continue            # Aitken has no filter
            scheme = cp.build_scheme(_tube_config(acceleration, variant, limit),
                                     [tube.TubeFlow(params), tube.TubeWall(params)], tube.tube_data())
            try:
                counts = scheme.run(t_end=windows * dt, dt=dt).iterations_per_window
            except cp.CouplingError as exc:
                row.append(f"{name}: failed ({str(exc).split(':')[0]})")
                print(f"  {label}: {row[-1]}", flush=True)
                continue
            radius = scheme.latest("radius")[:, 0]
            reference = radius if reference is None else reference
            row.append(f"{name}: {sum(counts)} ({np.max(np.abs(radius - reference)) / params.r0:.0e})")
            print(f"  {label}: {row[-1]}", flush=True)


def _device_table(variant: dict, transient: bool) -> dict:
    """A case file's [coupling] table: the device's defaults before the study, then ``variant`` on top."""
    table: dict = {"convergence": [{"type": "relative", "limit": 1e-10, "data": variant.get("data", "*")}]}
    if "state_reload" in variant:
        table["state_reload"] = variant["state_reload"]
    if "filter" in variant:
        table["acceleration"] = {"filter": variant["filter"]}
    return table


def _toml(table: dict) -> str:
    lines = ["[coupling]"]
    lines += [f'state_reload = "{table["state_reload"]}"'] if "state_reload" in table else []
    for m in table.get("convergence", []):
        lines += ["[[coupling.convergence]]", f'type = "{m["type"]}"', f'limit = {m["limit"]}',
                  f'data = "{m["data"]}"']
    if "acceleration" in table:
        f = table["acceleration"]["filter"]
        lines += ["[coupling.acceleration.filter]", f'type = "{f["type"]}"']
        lines += [f'limit = {f["limit"]}'] if "limit" in f else []
    return "\n".join(lines) + "\n"


def _run_device(case: str, prior: str | None, transient: bool, t_end: float, variant: dict,
                out: pathlib.Path) -> tuple[list[int], np.ndarray]:
    """One `gelcell run`: (iterations per window, the answer as an array)."""
    out.mkdir(parents=True, exist_ok=True)
    config = out / "case.toml"
    config.write_text(_toml(_device_table(variant, transient)))
    result = out / "result"
    cmd = [sys.executable, "-c", "from gelcell.cli import main; main()", "run", case, "--mesh-size", "3",
           "--config", str(config), "--no-figures", "--quiet", "--out", str(result)]
    cmd += ["--jacobian-prior", prior] if prior else []
    cmd += ["--transient", "--t-end", f"{t_end:g}"] if transient else []
    if not (result / "summary.json").exists():           # a run of an earlier call is kept
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if not (result / "summary.json").exists():
        return [], np.array([])                          # not converged (or failed)
    if transient:
        with open(result / "timeseries.csv") as fh:
            rows = list(csv.DictReader(fh))
        iterations = [int(r["iterations"]) for r in rows[1:]]
        answer = np.array([[float(v) for k, v in r.items() if k not in ("iterations", "residual")] for r in rows])
    else:
        iterations = [json.loads((result / "summary.json").read_text())["coupling"]["iterations"]]
        answer = np.loadtxt(result / "gamma1_profiles.csv", delimiter=",", skiprows=1)
    return iterations, answer


def _answer_change(answer: np.ndarray, reference: np.ndarray) -> float:
    """max over columns of max |a - a_ref| / max |a_ref| (columns that are not all zero)."""
    scale = np.max(np.abs(reference), axis=0)
    keep = scale > 0
    return float(np.max(np.max(np.abs(answer - reference), axis=0)[keep] / scale[keep]))


def device_table(out: pathlib.Path, names: list[str]) -> None:
    """Print the devices' iterations per variant (steady: the run's; time-dependent: per window)."""
    runs = [(case, prior, transient) for transient in (False, True) for case in ("shear", "normal")
            for prior in (None, "none")]
    for case, prior, transient in runs:
        label = f"{case} {'time-dependent' if transient else 'steady'}, prior {prior or 'default'}"
        reference, row = None, []
        for name, variant in VARIANTS.items():
            if ("state_reload" in variant and not transient) or name in SAME_AS_BASELINE["device"] \
                    or (name not in names and name != "baseline"):
                continue            # steady runs never restore a state
            tag = f"{case}-{'tr' if transient else 'st'}-{prior or 'default'}-{name.replace(' ', '_')}"
            iterations, answer = _run_device(case, prior, transient, T_END[case], variant, out / tag)
            if not iterations:
                row.append(f"{name}: failed")
                print(f"  {label}: {row[-1]}", flush=True)
                continue
            reference = answer if reference is None else reference
            total = f"{sum(iterations)} {iterations}" if transient else f"{iterations[0]}"
            row.append(f"{name}: {total} ({_answer_change(answer, reference):.0e})")
            print(f"  {label}: {row[-1]}", flush=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("what", choices=("tube", "device"))
    parser.add_argument("--windows", type=int, default=20, help="tube: time windows")
    parser.add_argument("--out", default="results/coupling-defaults", help="device: the runs' directory")
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), help="the variants to run (and the baseline)")
    args = parser.parse_args(argv)
    if args.what == "tube":
        tube_table(args.windows, args.variants)
    else:
        device_table(pathlib.Path(args.out), args.variants)


if __name__ == "__main__":
    main()
