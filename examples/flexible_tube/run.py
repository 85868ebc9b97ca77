# # The 1D flexible tube: two small solvers coupled through the public `coupling` API
#
# Runs the flow and wall solvers of `tube.py` (docs/couple-your-own-code.md)
# with Aitken and IQN-ILS (without and with reuse of 8 windows), prints the
# coupling iterations of every time window and the largest difference of the
# coupled answer to a monolithic Newton solve of the same discrete equations.
#
# Usage:
#
#     .venv/bin/python examples/flexible_tube/run.py [--cells 100] [--dt 1e-3] [--windows 10]

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


def coupled(params: tube.TubeParameters, acceleration: dict, dt: float, windows: int, limit: float = 1e-10):
    """The coupled run; returns (iterations per window, the scheme)."""
    config = {"scheme": "serial-implicit", "order": ["flow", "wall"], "verbose": False, "max_iterations": 200,
              "convergence": [{"type": "relative", "limit": limit, "data": "radius"}],
              "acceleration": acceleration}
    scheme = cp.build_scheme(config, [tube.TubeFlow(params), tube.TubeWall(params)], tube.tube_data())
    return scheme.run(t_end=windows * dt, dt=dt).iterations_per_window, scheme


def monolithic(params: tube.TubeParameters, dt: float, windows: int) -> dict:
    m = params.cells
    state = {"v": np.full(m, params.v0), "p": np.full(m, params.p_out), "r": np.full(m, params.r0)}
    for k in range(windows):
        state = tube.monolithic_window(params, state, k * dt, dt)
    return state


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cells", type=int, default=100)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--windows", type=int, default=10)
    args = parser.parse_args(argv)
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


if __name__ == "__main__":
    main()
