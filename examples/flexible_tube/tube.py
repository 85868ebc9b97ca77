"""The 1D flexible tube: a flow solver and a wall solver coupled through the public ``coupling`` API.

Incompressible inviscid flow in a straight elastic tube of length L (the
case of the IQN-ILS literature, e.g. Degroote, Bathe, Vierendeels 2009).
With a = pi r^2 the cross-section, v the axial velocity, p the pressure:

    flow:  da/dt + d(a v)/dz = 0,   d(a v)/dt + d(a v^2)/dz + (a / rho) dp/dz = 0
           v(0, t) = v_in(t),       p(L, t) = p_out
    wall:  a = a0 ((p0/rho - 2 c^2) / (p/rho - 2 c^2))^2,   c^2 = E h / (2 rho r0)

(independent elastic rings; c the Moens-Korteweg wave speed).  Finite
volumes on m cells of length dz, backward Euler in time, central face
values and a pressure-stabilisation term (collocated p and v):

    dz (a_i - a_i^n)/dt + [a v]_{i-1/2}^{i+1/2} - alpha [p_{i+1} - 2 p_i + p_{i-1}] / rho = 0
    dz (a_i v_i - a_i^n v_i^n)/dt + [a v v]_{i-1/2}^{i+1/2} + a_i [p]_{i-1/2}^{i+1/2} / rho = 0

with alpha = a0 / (v0 + dz/dt) and ghost cells: v_{-1} = 2 v_in - v_0,
p_{-1} = p_0, a_{-1} = a_0 (inlet), p_m = 2 p_out - p_{m-1}, v_m = v_{m-1},
a_m = a_{m-1} (outlet).  The flow solver (Newton) reads the wall's radius
and writes the pressure; the wall reads the pressure and writes the
radius.  :func:`monolithic_window` solves the same discrete equations of a
window at once with Newton (the reference of the coupled answer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import coupling as cp

__all__ = ["TubeParameters", "TubeFlow", "TubeWall", "tube_data", "monolithic_window", "newton"]


@dataclass(frozen=True)
class TubeParameters:
    """The tube, the fluid and the inflow v_in(t) = v0 (1 + amplitude sin^2(pi t / period))."""

    length: float = 0.05          # m
    r0: float = 0.005             # m
    E: float = 3.0e5              # Pa
    h: float = 0.001              # m
    rho: float = 1000.0           # kg/m^3
    v0: float = 0.1               # m/s
    amplitude: float = 0.1
    period: float = 1.0           # s
    p_out: float = 0.0            # Pa (also the reference pressure p0 of the wall)
    cells: int = 100

    @property
    def a0(self) -> float:
        return np.pi * self.r0 ** 2

    @property
    def c2(self) -> float:
        """The Moens-Korteweg wave speed squared, E h / (2 rho r0)."""
        return self.E * self.h / (2.0 * self.rho * self.r0)

    def inflow(self, t: float) -> float:
        return self.v0 * (1.0 + self.amplitude * np.sin(np.pi * t / self.period) ** 2)

    def points(self) -> np.ndarray:
        dz = self.length / self.cells
        return np.column_stack([(np.arange(self.cells) + 0.5) * dz, np.zeros(self.cells)])


def newton(residual, x0: np.ndarray, tol: float = 1e-13, max_iterations: int = 30) -> np.ndarray:
    """Solve residual(x) = 0 by Newton with a finite-difference Jacobian (column by column)."""
    x = x0.copy()
    f = residual(x)
    scale = max(np.linalg.norm(f), 1.0)
    for _ in range(max_iterations):
        if np.linalg.norm(f) <= tol * scale:
            return x
        jac = np.empty((f.size, x.size))
        for j in range(x.size):
            step = 1e-7 * max(abs(x[j]), 1e-3)
            xj = x.copy()
            xj[j] += step
            jac[:, j] = (residual(xj) - f) / step
        x = x - np.linalg.solve(jac, f)
        f = residual(x)
    raise RuntimeError(f"tube Newton: residual {np.linalg.norm(f):.3e} after {max_iterations} iterations")


def flow_residual(params: TubeParameters, v, p, a, v_n, a_n, v_in: float, dt: float) -> np.ndarray:
    """The discrete continuity and momentum equations of every cell (module docstring)."""
    dz, rho = params.length / params.cells, params.rho
    alpha = params.a0 / (params.v0 + dz / dt)
    vg = np.concatenate([[2.0 * v_in - v[0]], v, [v[-1]]])
    pg = np.concatenate([[p[0]], p, [2.0 * params.p_out - p[-1]]])
    ag = np.concatenate([[a[0]], a, [a[-1]]])
    av_face = 0.5 * (ag[:-1] * vg[:-1] + ag[1:] * vg[1:])          # faces -1/2 ... m-1/2
    avv_face = av_face * 0.5 * (vg[:-1] + vg[1:])
    p_face = 0.5 * (pg[:-1] + pg[1:])
    continuity = (dz * (a - a_n) / dt + np.diff(av_face)
                  - alpha * (pg[2:] - 2.0 * pg[1:-1] + pg[:-2]) / rho)
    momentum = dz * (a * v - a_n * v_n) / dt + np.diff(avv_face) + a * np.diff(p_face) / rho
    return np.concatenate([continuity, momentum])


def wall_radius(params: TubeParameters, p: np.ndarray) -> np.ndarray:
    """r(p) of the ring model: a = a0 ((p0/rho - 2 c^2) / (p/rho - 2 c^2))^2."""
    ratio = (params.p_out / params.rho - 2.0 * params.c2) / (p / params.rho - 2.0 * params.c2)
    return params.r0 * np.abs(ratio)


class TubeFlow(cp.Participant):
    """The flow solver: reads ``radius``, writes ``pressure`` (one value per cell)."""

    name = "flow"

    def __init__(self, params: TubeParameters):
        self.params = params
        m = params.cells
        self.v, self.p = np.full(m, params.v0), np.full(m, params.p_out)
        self.a = np.full(m, params.a0)
        self.v_n, self.a_n = self.v.copy(), self.a.copy()
        self.t_new, self.dt = 0.0, 1.0

    def interface_points(self, mesh_name):
        return self.params.points()

    def initial_data(self, data_name):
        return self.p[:, None].copy()

    def begin_window(self, t, dt):
        self.v_n, self.a_n = self.v.copy(), self.a.copy()   # the state at t: the last window's end
        self.t_new, self.dt = t + dt, dt

    def end_window(self, accepted):
        # the window's end area is the accepted radius (the wall's last output), as in the monolithic solve
        self.a = np.pi * accepted["radius"][:, 0] ** 2

    def save_state(self):
        return {k: getattr(self, k).copy() for k in ("v", "p", "a", "v_n", "a_n")}

    def load_state(self, state):
        for k, value in state.items():
            setattr(self, k, np.array(value, dtype=float))

    def solve(self, inputs):
        m = self.params.cells
        self.a = np.pi * inputs["radius"][:, 0] ** 2
        v_in = self.params.inflow(self.t_new)

        def residual(x):
            return flow_residual(self.params, x[:m], x[m:], self.a, self.v_n, self.a_n, v_in, self.dt)

        x = newton(residual, np.concatenate([self.v, self.p]))
        self.v, self.p = x[:m], x[m:]
        return {"pressure": self.p[:, None].copy()}


class TubeWall(cp.Participant):
    """The wall solver (independent rings, no inertia): reads ``pressure``, writes ``radius``."""

    name = "wall"

    def __init__(self, params: TubeParameters):
        self.params = params

    def interface_points(self, mesh_name):
        return self.params.points()

    def initial_data(self, data_name):
        return np.full((self.params.cells, 1), self.params.r0)

    def save_state(self):
        return {}

    def load_state(self, state):
        pass

    def solve(self, inputs):
        return {"radius": wall_radius(self.params, inputs["pressure"][:, 0])[:, None]}


def tube_data() -> list[cp.Data]:
    return [cp.Data("pressure", "wall", 1, "flow", ("wall",)),
            cp.Data("radius", "wall", 1, "wall", ("flow",))]


def monolithic_window(params: TubeParameters, state: dict, t: float, dt: float) -> dict:
    """One backward-Euler window of flow and wall solved together by Newton; returns the new state."""
    m = params.cells
    v_in = params.inflow(t + dt)

    def residual(x):
        v, p, r = x[:m], x[m:2 * m], x[2 * m:]
        flow = flow_residual(params, v, p, np.pi * r ** 2, state["v"], np.pi * state["r"] ** 2, v_in, dt)
        return np.concatenate([flow, (r - wall_radius(params, p)) / params.r0])

    x = newton(residual, np.concatenate([state["v"], state["p"], state["r"]]))
    return {"v": x[:m], "p": x[m:2 * m], "r": x[2 * m:]}
