# # The 1D flexible tube: two small solvers coupled through the public `coupling` API
#
# Runs the flow and wall solvers of `tube.py` (docs/couple-your-own-code.md)
# and prints the coupling iterations of every time window.
#
# * `--case own` (default): this example's tube (stabilised finite volumes,
#   dt = 1 ms) with Aitken and IQN-ILS (without and with reuse of 8 windows),
#   and the largest difference of the coupled answer to a monolithic Newton
#   solve of the same discrete equations.
# * `--case precice`: preCICE's elastic-tube-1d tutorial (its Python fluid and
#   solid solvers and its precice-config.xml), with the iterations of every
#   window of preCICE's own run next to ours, and the outlet area and
#   pressure against preCICE's watch point and the monolithic solve.
#
# Usage:
#
#     .venv/bin/python examples/flexible_tube/run.py [--cells 100] [--dt 1e-3] [--windows 10]
#     .venv/bin/python examples/flexible_tube/run.py --case precice [--windows 100]

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import coupling as cp  # noqa: E402
import tube  # noqa: E402

ACCELERATIONS = {
    "aitken": {"type": "aitken", "initial_relaxation": 0.01},
    "iqn-ils": {"type": "iqn-ils", "initial_relaxation": 0.01},
    "iqn-ils, 8 windows reused": {"type": "iqn-ils", "initial_relaxation": 0.01, "time_windows_reused": 8},
}

# preCICE's elastic-tube-1d, as run by the preCICE project: precice/tutorials commit 174d2db
# (2021-04-12, "now with the files", in the pull request #184 that moved the tutorial from
# precice/elastictube1d; preCICE v2).  Case: elastic-tube-1d/precice-config.xml,
# fluid-python/FluidSolver.py + thetaScheme.py, solid-python/SolidSolver.py of that commit.
# Iterations of its 100 windows: elastic-tube-1d/solid-python/precice-Solid-iterations.log
# (the same column in fluid-python/precice-Fluid-iterations.log); 857 in all.
PRECICE_ITERATIONS = (
    20, 11, 10, 8, 8, 8, 8, 8, 8, 8, 8, 8, 9, 8, 8, 8, 8, 7, 8, 8,
    8, 9, 9, 9, 9, 9, 9, 9, 8, 8, 8, 7, 9, 9, 9, 9, 8, 8, 8, 9,
    8, 9, 9, 8, 8, 9, 9, 8, 9, 7, 9, 8, 8, 8, 8, 8, 9, 8, 8, 9,
    8, 9, 9, 9, 10, 9, 9, 8, 9, 8, 9, 8, 8, 9, 9, 9, 8, 7, 8, 9,
    9, 9, 10, 9, 9, 9, 8, 9, 9, 8, 7, 8, 9, 8, 9, 8, 7, 8, 8, 9,
)
# Its outlet watch point (z = L) at the end of every 10th window, (area, pressure):
# elastic-tube-1d/fluid-python/precice-Fluid-watchpoint-outlet.log of the same commit.
PRECICE_OUTLET = {
    10: (1.0113854738050181, 100.0476232405990373),
    20: (0.9970698019660774, -26.0254126419100018),
    30: (1.0039470713737775, 34.8767972682343981),
    40: (0.9970162137947041, -26.5024397287892626),
    50: (1.0039383369728487, 34.7998461966705150),
    60: (0.9970161064691261, -26.5033951500030085),
    70: (1.0039382003217605, 34.7986422769675059),
    80: (0.9970159312263399, -26.5049551761817952),
    90: (1.0039380807818341, 34.7975891093585901),
    100: (0.9970159413670273, -26.5048649029073182),
}
# Its <coupling-scheme:serial-implicit> (first Fluid): max-iterations 40 (a window is then
# accepted), relative-convergence-measure 1e-5 on Pressure and on CrossSectionLength (the area),
# IQN-ILS on CrossSectionLength: initial-relaxation 0.01, max-used-iterations 50,
# time-windows-reused 8, filter QR2 1e-3; time-window-size 0.01, max-time 1.
PRECICE_DT = 0.01
PRECICE_ACCELERATIONS = {
    "iqn-ils, 8 windows reused": {"type": "iqn-ils", "initial_relaxation": 0.01, "max_used_iterations": 50,
                                  "time_windows_reused": 8, "filter": {"type": "qr2", "limit": 1e-3}},
    "iqn-ils, no reuse": {"type": "iqn-ils", "initial_relaxation": 0.01, "max_used_iterations": 50,
                          "filter": {"type": "qr2", "limit": 1e-3}},
    "aitken": {"type": "aitken", "initial_relaxation": 0.01},
}


def coupled(params: tube.TubeParameters, acceleration: dict, dt: float, windows: int, limit: float = 1e-10):
    """The coupled run; returns (iterations per window, the scheme)."""
    config = {"scheme": "serial-implicit", "order": ["flow", "wall"], "verbose": False, "max_iterations": 200,
              "convergence": [{"type": "relative", "limit": limit, "data": "radius"}],
              "acceleration": acceleration}
    scheme = cp.build_scheme(config, [tube.TubeFlow(params), tube.TubeWall(params)], tube.tube_data(params))
    return scheme.run(t_end=windows * dt, dt=dt).iterations_per_window, scheme


def precice_coupled(acceleration: dict, windows: int = 100, params: tube.TubeParameters | None = None):
    """preCICE's elastic-tube-1d with its coupling configuration (``PRECICE_*`` above).

    Returns (the result, the flow participant, the scheme).
    """
    params = tube.precice_tube() if params is None else params
    config = {"scheme": "serial-implicit", "order": ["flow", "wall"], "verbose": False, "max_iterations": 40,
              "on_max_iterations": "continue",
              "convergence": [{"type": "relative", "limit": 1e-5, "data": "pressure"},
                              {"type": "relative", "limit": 1e-5, "data": "area"}],
              "acceleration": acceleration}
    flow = tube.TubeFlow(params)
    scheme = cp.build_scheme(config, [flow, tube.TubeWall(params)], tube.tube_data(params))
    return scheme.run(t_end=windows * PRECICE_DT, dt=PRECICE_DT), flow, scheme


def monolithic(params: tube.TubeParameters, dt: float, windows: int) -> dict:
    """The monolithic solve; returns the final state and ``outlet``: (area, pressure) at the last point
    after every window."""
    state, outlet = tube.initial_state(params), []
    for k in range(windows):
        state = tube.monolithic_window(params, state, k * dt, dt)
        outlet.append((np.pi * state["r"][-1] ** 2, state["p"][-1]))
    return {**state, "outlet": np.array(outlet)}


def _own(args) -> None:
    params = tube.TubeParameters(cells=args.cells, period=0.01)
    reference = monolithic(params, args.dt, args.windows)
    print(f"flexible tube: {args.cells} cells, dt = {args.dt:g} s, {args.windows} windows, "
          f"L/(c dt) = {params.length / np.sqrt(params.c2) / args.dt:.2f}")
    for label, acceleration in ACCELERATIONS.items():
        counts, scheme = coupled(params, acceleration, args.dt, args.windows)
        dr = np.max(np.abs(scheme.latest("radius")[:, 0] - reference["r"])) / params.r0
        dp = np.max(np.abs(scheme.latest("pressure")[:, 0] - reference["p"])) / np.max(np.abs(reference["p"]))
        print(f"{label:28s} iterations {counts}  mean {np.mean(counts):.1f}  "
              f"vs monolithic: radius {dr:.1e}, pressure {dp:.1e}")


def _precice(args) -> None:
    windows = min(args.windows, len(PRECICE_ITERATIONS))
    params = tube.precice_tube()
    reference = monolithic(params, PRECICE_DT, windows)
    published = np.array(PRECICE_ITERATIONS[:windows])
    print(f"preCICE elastic-tube-1d: {params.points_count} nodes, dt = {PRECICE_DT} s, {windows} windows; "
          f"published: precice/tutorials 174d2db, mean {published.mean():.2f}")
    for label, acceleration in PRECICE_ACCELERATIONS.items():
        result, flow, _ = precice_coupled(acceleration, windows, params)
        ours = np.array(result.iterations_per_window)
        unconverged = sum(not w.converged for w in result.windows)
        print(f"\n{label}: mean {ours.mean():.2f} ({unconverged} windows at max-iterations 40)")
        if label == "iqn-ils, 8 windows reused":
            same = int(np.sum(ours == published))
            print(f"  published mean {published.mean():.2f}; same count in {same} of {windows} windows, "
                  f"largest difference {int(np.max(np.abs(ours - published)))}")
            for start in range(0, windows, 20):
                print(f"  windows {start + 1:3d}-: ours {' '.join(f'{n:2d}' for n in ours[start:start + 20])}")
                print(f"               preCICE {' '.join(f'{n:2d}' for n in published[start:start + 20])}")
            outlet = np.array([(a, p) for _, a, p in flow.outlet])
            for k, (a_pub, p_pub) in PRECICE_OUTLET.items():
                if k <= windows:
                    a, p = outlet[k - 1]
                    a_mono, p_mono = reference["outlet"][k - 1]
                    print(f"  outlet, window {k:3d}: area {a:.8f} (preCICE {a_pub:.8f}, monolithic {a_mono:.8f}), "
                          f"pressure {p:9.4f} (preCICE {p_pub:9.4f}, monolithic {p_mono:9.4f})")
        else:
            print(f"  iterations {' '.join(str(n) for n in ours)}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--case", choices=("own", "precice"), default="own")
    parser.add_argument("--cells", type=int, default=100, help="--case own only")
    parser.add_argument("--dt", type=float, default=1e-3, help="--case own only")
    parser.add_argument("--windows", type=int, default=None, help="default: 10 (own), 100 (precice)")
    args = parser.parse_args(argv)
    if args.windows is None:
        args.windows = 100 if args.case == "precice" else 10
    (_precice if args.case == "precice" else _own)(args)


if __name__ == "__main__":
    main()
