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

__all__ = ["TubeParameters", "TubeFlow", "TubeWall", "tube_data", "monolithic_window", "newton",
           "precice_tube", "initial_state"]

DISCRETISATIONS = ("cells", "nodes")


@dataclass(frozen=True)
class TubeParameters:
    """The tube, the fluid, the inflow and the discretisation.

    The inflow is v_in(t) = v0 (1 + amplitude sin^2(pi t / period)), or with
    ``inflow_shape = "sin"`` v0 (1 + amplitude sin(pi t / period)).
    ``discretisation``: ``"cells"`` (the stabilised finite volumes of the
    module docstring) or ``"nodes"`` (preCICE's elastic-tube-1d scheme);
    ``exchanged``: the wall's output, ``"radius"`` or ``"area"``.
    """

    length: float = 0.05          # m
    r0: float = 0.005             # m
    E: float = 3.0e5              # Pa
    h: float = 0.001              # m
    rho: float = 1000.0           # kg/m^3
    v0: float = 0.1               # m/s
    amplitude: float = 0.1
    period: float = 1.0           # s
    p_out: float = 0.0            # Pa (also the reference pressure p0 of the wall)
    cells: int = 100              # cells; with discretisation = "nodes": cells + 1 nodes
    discretisation: str = "cells"
    inflow_shape: str = "sin2"
    exchanged: str = "radius"

    def __post_init__(self):
        if self.discretisation not in DISCRETISATIONS:
            raise ValueError(f"discretisation = {self.discretisation!r}: one of {DISCRETISATIONS}")
        if self.inflow_shape not in ("sin2", "sin"):
            raise ValueError(f"inflow_shape = {self.inflow_shape!r}: 'sin2' or 'sin'")
        if self.exchanged not in ("radius", "area"):
            raise ValueError(f"exchanged = {self.exchanged!r}: 'radius' or 'area'")

    @property
    def points_count(self) -> int:
        return self.cells + 1 if self.discretisation == "nodes" else self.cells

    @property
    def a0(self) -> float:
        return np.pi * self.r0 ** 2

    @property
    def c2(self) -> float:
        """The Moens-Korteweg wave speed squared, E h / (2 rho r0)."""
        return self.E * self.h / (2.0 * self.rho * self.r0)

    def inflow(self, t: float) -> float:
        wave = np.sin(np.pi * t / self.period)
        return self.v0 * (1.0 + self.amplitude * (wave ** 2 if self.inflow_shape == "sin2" else wave))

    def points(self) -> np.ndarray:
        dz = self.length / self.cells
        z = np.arange(self.cells + 1) * dz if self.discretisation == "nodes" else (np.arange(self.cells) + 0.5) * dz
        return np.column_stack([z, np.zeros(z.size)])


def precice_tube(nodes: int = 101) -> TubeParameters:
    """preCICE's elastic-tube-1d tutorial (its Python solvers): L = 10, a0 = 1, E = 10^4, rho = 1,
    v_in = 10 + 3 sin(10 pi t), p_out = 0, 100 cells (101 nodes), the nodal scheme, the area exchanged."""
    return TubeParameters(length=10.0, r0=1.0 / np.sqrt(np.pi), E=1.0e4, h=1.0, rho=1.0, v0=10.0,
                          amplitude=0.3, period=0.1, p_out=0.0, cells=nodes - 1,
                          discretisation="nodes", inflow_shape="sin", exchanged="area")


def _jacobian(residual, x: np.ndarray, f: np.ndarray, nodes: int | None, reach: int) -> np.ndarray:
    """Finite-difference Jacobian: column by column, or (``nodes``) by groups of columns.

    With ``nodes``, unknown j and equation k belong to node ``j % nodes`` and
    ``k % nodes``, and an equation depends only on unknowns within ``reach``
    nodes of its own: unknowns ``2 reach + 1`` nodes apart are perturbed together.
    """
    step = 1e-7 * np.maximum(np.abs(x), 1e-3)
    jac = np.zeros((f.size, x.size))
    if nodes is None:
        for j in range(x.size):
            xj = x.copy()
            xj[j] += step[j]
            jac[:, j] = (residual(xj) - f) / step[j]
        return jac
    stride = 2 * reach + 1
    rows = np.arange(f.size)
    row_node = rows % nodes
    for block in range(x.size // nodes):
        for colour in range(stride):
            cols = block * nodes + np.arange(colour, nodes, stride)
            xj = x.copy()
            xj[cols] += step[cols]
            df = residual(xj) - f
            # the one perturbed node within reach of each equation's node
            near = colour + stride * np.round((row_node - colour) / stride).astype(int)
            ok = (near >= 0) & (near < nodes)
            j = block * nodes + near[ok]
            jac[rows[ok], j] = df[ok] / step[j]
    return jac


def newton(residual, x0: np.ndarray, tol: float = 1e-13, max_iterations: int = 30,
           nodes: int | None = None, reach: int = 2, scale: float | None = None) -> np.ndarray:
    """Solve residual(x) = 0 by Newton with a finite-difference Jacobian (:func:`_jacobian`).

    Stops at ``‖residual‖ <= tol * scale``; ``scale`` defaults to max(‖residual(x0)‖, 1).
    """
    x = x0.copy()
    f = residual(x)
    scale = max(np.linalg.norm(f), 1.0) if scale is None else scale
    for _ in range(max_iterations):
        if np.linalg.norm(f) <= tol * scale:
            return x
        x = x - np.linalg.solve(_jacobian(residual, x, f, nodes, reach), f)
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


def nodal_flow_residual(params: TubeParameters, v, p, a, v_n, p_n, a_n, v_in: float, dt: float) -> np.ndarray:
    """The nodal scheme's equations (module docstring), ordered so that equation k sits on node k % (m + 1)."""
    dz, rho, c2 = params.length / params.cells, params.rho, params.c2
    q, q_n = p / rho, p_n / rho
    a_f, v_f, q_f = 0.5 * (a[:-1] + a[1:]), 0.5 * (v[:-1] + v[1:]), 0.5 * (q[:-1] + q[1:])
    flux = a_f * v_f                                                   # faces 1/2 ... m-1/2
    continuity = dz * (a[1:-1] - a_n[1:-1]) / dt + np.diff(flux)
    momentum = (dz * (a[1:-1] * v[1:-1] - a_n[1:-1] * v_n[1:-1]) / dt + flux[1:] * v[1:-1] - flux[:-1] * v[:-2]
                + np.diff(a_f * q_f) - q[1:-1] * np.diff(a_f))
    w = np.sqrt(c2 - q_n[-1] / 2.0) - (v[-1] - v_n[-1]) / 4.0
    first = np.concatenate([[v[0] - v_in], continuity, [v[-1] - 2.0 * v[-2] + v[-3]]])
    second = np.concatenate([[q[0] - 2.0 * q[1] + q[2]], momentum, [q[-1] - 2.0 * (c2 - w * w)]])
    return np.concatenate([first, second])


def wall_radius(params: TubeParameters, p: np.ndarray) -> np.ndarray:
    """r(p) of the ring model: a = a0 ((p0/rho - 2 c^2) / (p/rho - 2 c^2))^2."""
    ratio = (params.p_out / params.rho - 2.0 * params.c2) / (p / params.rho - 2.0 * params.c2)
    return params.r0 * np.abs(ratio)


def _nodal_newton(v: np.ndarray, p: np.ndarray) -> dict:
    """Newton options of the nodal scheme: the Jacobian by groups of nodes, and the tutorial's
    measure ‖residual‖ / ‖(v, p)‖ (its limit 1e-10, here 1e-12)."""
    return {"nodes": v.size, "tol": 1e-12, "scale": float(np.linalg.norm(np.concatenate([v, p])))}


def wall_output(params: TubeParameters, p: np.ndarray) -> np.ndarray:
    """What the wall writes: its radius, or (``exchanged = "area"``) its area."""
    r = wall_radius(params, p)
    return np.pi * r ** 2 if params.exchanged == "area" else r


def _area(params: TubeParameters, values: np.ndarray) -> np.ndarray:
    return values if params.exchanged == "area" else np.pi * values ** 2


def initial_state(params: TubeParameters) -> dict:
    """Velocity v0 = v_in(0), pressure p_out, radius r0 at every point."""
    n = params.points_count
    return {"v": np.full(n, params.inflow(0.0)), "p": np.full(n, params.p_out), "r": np.full(n, params.r0)}


class TubeFlow(cp.Participant):
    """The flow solver: reads ``radius`` (or ``area``), writes ``pressure`` (one value per point)."""

    name = "flow"

    def __init__(self, params: TubeParameters):
        self.params = params
        state = initial_state(params)
        self.v, self.p = state["v"], state["p"]
        self.a = np.pi * state["r"] ** 2
        self.v_n, self.p_n, self.a_n = self.v.copy(), self.p.copy(), self.a.copy()
        self.t_new, self.dt = 0.0, 1.0
        self.outlet: list[tuple[float, float, float]] = []   # (t, area, pressure) at the last point per window

    def interface_points(self, mesh_name):
        return self.params.points()

    def initial_data(self, data_name):
        return self.p[:, None].copy()

    def begin_window(self, t, dt):
        # the state at t: the last window's end
        self.v_n, self.p_n, self.a_n = self.v.copy(), self.p.copy(), self.a.copy()
        self.t_new, self.dt = t + dt, dt

    def end_window(self, accepted):
        # the window's end area is the accepted radius (the wall's last output), as in the monolithic solve
        self.a = _area(self.params, accepted[self.params.exchanged][:, 0])
        self.outlet.append((self.t_new, float(self.a[-1]), float(self.p[-1])))

    def save_state(self):
        return {k: getattr(self, k).copy() for k in ("v", "p", "a", "v_n", "p_n", "a_n")}

    def load_state(self, state):
        for k, value in state.items():
            setattr(self, k, np.array(value, dtype=float))

    def solve(self, inputs):
        params, n = self.params, self.params.points_count
        self.a = _area(params, inputs[params.exchanged][:, 0])
        v_in = params.inflow(self.t_new)
        if params.discretisation == "nodes":
            def residual(x):
                return nodal_flow_residual(params, x[:n], x[n:], self.a, self.v_n, self.p_n, self.a_n,
                                           v_in, self.dt)
            x = newton(residual, np.concatenate([self.v, self.p]), **_nodal_newton(self.v, self.p))
        else:
            def residual(x):
                return flow_residual(params, x[:n], x[n:], self.a, self.v_n, self.a_n, v_in, self.dt)
            x = newton(residual, np.concatenate([self.v, self.p]))
        self.v, self.p = x[:n], x[n:]
        return {"pressure": self.p[:, None].copy()}


class TubeWall(cp.Participant):
    """The wall solver (independent rings, no inertia): reads ``pressure``, writes ``radius`` (or ``area``)."""

    name = "wall"

    def __init__(self, params: TubeParameters):
        self.params = params

    def interface_points(self, mesh_name):
        return self.params.points()

    def initial_data(self, data_name):
        return wall_output(self.params, np.full((self.params.points_count, 1), self.params.p_out))

    def save_state(self):
        return {}

    def load_state(self, state):
        pass

    def solve(self, inputs):
        return {self.params.exchanged: wall_output(self.params, inputs["pressure"][:, 0])[:, None]}


def tube_data(params: TubeParameters | None = None) -> list[cp.Data]:
    """``pressure`` (flow -> wall) and ``radius`` or ``area`` (wall -> flow)."""
    exchanged = "radius" if params is None else params.exchanged
    return [cp.Data("pressure", "wall", 1, "flow", ("wall",)),
            cp.Data(exchanged, "wall", 1, "wall", ("flow",))]


def monolithic_window(params: TubeParameters, state: dict, t: float, dt: float) -> dict:
    """One backward-Euler window of flow and wall solved together by Newton; returns the new state."""
    m = params.points_count
    v_in = params.inflow(t + dt)
    a_n = np.pi * state["r"] ** 2

    def residual(x):
        v, p, r = x[:m], x[m:2 * m], x[2 * m:]
        if params.discretisation == "nodes":
            flow = nodal_flow_residual(params, v, p, np.pi * r ** 2, state["v"], state["p"], a_n, v_in, dt)
        else:
            flow = flow_residual(params, v, p, np.pi * r ** 2, state["v"], a_n, v_in, dt)
        return np.concatenate([flow, (r - wall_radius(params, p)) / params.r0])

    nodal = _nodal_newton(state["v"], state["p"]) if params.discretisation == "nodes" else {}
    x = newton(residual, np.concatenate([state["v"], state["p"], state["r"]]), **nodal)
    return {"v": x[:m], "p": x[m:2 * m], "r": x[2 * m:]}
