"""Toy participants and coupled problems with known answers, for examples and tests.

No finite elements: every participant solves its problem exactly (dense
linear algebra or closed-form 1-D solutions), so coupled answers can be
compared with a monolithic / analytic solution to rounding accuracy.  They
are the reference problems of ``examples/coupling_toys.py`` and of the
coupling tests, and a check of any change to the schemes or accelerations.

* :class:`AffineParticipant`: ``out = M @ in + b`` on ``n`` points.
* :class:`ElasticBar`: a 1-D linear elastic bar ``(k u')' + f = 0`` on
  ``[a, b]`` solved in closed form, each end fixed (``u = 0``), Dirichlet
  (reads the interface displacement, writes the axial force ``N = k u'``)
  or Neumann (reads ``N``, writes the displacement).  Sign convention: the
  interface force is the axial (normal) force ``N``, tension positive; it is
  continuous across an interface.
* :class:`LinearOdeParticipant`: backward Euler for
  ``u' = -K(t) u + C y + s(t)`` with ``y`` read from the other participant
  and ``u`` written; has a state (checkpoint/restore needed).

:func:`toy_problems` returns the catalogue used by
``examples/coupling_toys.py`` and the tests; :func:`run_toy` runs one problem
with one scheme and acceleration and returns a record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from coupling.errors import CouplingDivergedError, CouplingNotConvergedError
from coupling.participant import Data, Participant
from coupling.schemes import build_scheme

__all__ = ["AffineParticipant", "BarEnd", "ElasticBar", "LinearOdeParticipant", "series_bars_exact",
           "ToyProblem", "affine_pair_problem", "two_bar_problem", "chain_problem",
           "transient_problem", "toy_problems", "acceleration_options", "run_toy",
           "ACCELERATION_NAMES", "SCHEME_NAMES"]

ACCELERATION_NAMES = ("none", "constant", "aitken", "iqn-ils", "iqn-imvj")
SCHEME_NAMES = ("serial", "parallel")


# --------------------------------------------------------------------------- participants
class AffineParticipant(Participant):
    """``outputs[w] = Σ_r M[w, r] @ inputs[r] + b[w]`` on 1-D points ``0..n-1``.

    Args:
        name: Participant name.
        mesh: Mesh name of all its data.
        n: Number of points (all data are scalar, dim 1).
        matrices: ``{(written, read): (n, n) array}``.
        offsets: ``{written: (n,) array}``.
    """

    def __init__(self, name: str, mesh: str, n: int,
                 matrices: dict[tuple[str, str], np.ndarray], offsets: dict[str, np.ndarray]):
        self.name = name
        self.mesh = mesh
        self.n = n
        self.matrices = {k: np.array(v, dtype=float) for k, v in matrices.items()}
        self.offsets = {k: np.array(v, dtype=float).reshape(n) for k, v in offsets.items()}

    def interface_points(self, mesh_name: str) -> np.ndarray:
        return np.arange(self.n, dtype=float)[:, None]

    def solve(self, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {}
        for written, b in self.offsets.items():
            value = b.copy()
            for (w, r), m in self.matrices.items():
                if w == written:
                    value += m @ inputs[r].reshape(self.n)
            out[written] = value[:, None]
        return out

    def jacobian(self) -> dict[tuple[str, str], np.ndarray]:
        """``d outputs[w] / d inputs[r] = M[w, r]`` (exact: the participant is affine)."""
        return {k: m.copy() for k, m in self.matrices.items()}


@dataclass(frozen=True)
class BarEnd:
    """Boundary condition at one end of an :class:`ElasticBar`.

    Attributes:
        kind: ``"fixed"`` (u = 0), ``"dirichlet"`` (reads displacement
            ``read``, writes force ``write``) or ``"neumann"`` (reads force
            ``read``, writes displacement ``write``).
        mesh: Interface mesh name (not for ``"fixed"``).
        read: Name of the data read.
        write: Name of the data written.
    """

    kind: str = "fixed"
    mesh: str = ""
    read: str = ""
    write: str = ""


class ElasticBar(Participant):
    """Linear elastic bar ``(k u')' + f = 0`` on ``[a, b]``, solved in closed form.

    ``u(ξ) = c0 + c1 ξ - f ξ² / (2k)``, ``N = k u' = k c1 - f ξ`` with
    ``ξ = x - a``; the two end conditions fix ``c0, c1``.

    Args:
        name: Participant name.
        a, b: End coordinates.
        stiffness: Axial stiffness ``k = EA``.
        load: Uniform distributed load ``f``.
        left, right: End conditions.
    """

    def __init__(self, name: str, a: float, b: float, stiffness: float, load: float,
                 left: BarEnd, right: BarEnd):
        if left.kind == "neumann" and right.kind == "neumann":
            raise ValueError(f"bar {name!r}: two Neumann ends leave a rigid-body mode")
        self.name = name
        self.a, self.b = float(a), float(b)
        self.k, self.f = float(stiffness), float(load)
        self.left, self.right = left, right

    def interface_points(self, mesh_name: str) -> np.ndarray:
        for end, x in ((self.left, self.a), (self.right, self.b)):
            if end.kind != "fixed" and end.mesh == mesh_name:
                return np.array([[x]])
        raise KeyError(f"bar {self.name!r} has no interface {mesh_name!r}")

    def solve(self, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        length, k, f = self.b - self.a, self.k, self.f
        rows, rhs = [], []
        for end, xi in ((self.left, 0.0), (self.right, length)):
            value = float(inputs[end.read].reshape(-1)[0]) if end.kind != "fixed" else 0.0
            if end.kind in ("fixed", "dirichlet"):
                rows.append([1.0, xi])
                rhs.append(value + f * xi * xi / (2.0 * k))
            else:
                rows.append([0.0, k])
                rhs.append(value + f * xi)
        c0, c1 = np.linalg.solve(np.array(rows), np.array(rhs))
        out = {}
        for end, xi in ((self.left, 0.0), (self.right, length)):
            if end.kind == "dirichlet":
                out[end.write] = np.array([[k * c1 - f * xi]])
            elif end.kind == "neumann":
                out[end.write] = np.array([[c0 + c1 * xi - f * xi * xi / (2.0 * k)]])
        return out

    def jacobian(self) -> dict[tuple[str, str], np.ndarray]:
        """d(written end value)/d(read end value): the bar is affine, so one unit difference is exact."""
        ends = [e for e in (self.left, self.right) if e.kind != "fixed"]
        zero = {e.read: np.zeros((1, 1)) for e in ends}
        base = self.solve(zero)
        out = {}
        for e in ends:
            moved = self.solve({**zero, e.read: np.ones((1, 1))})
            for w in base:
                out[(w, e.read)] = moved[w] - base[w]
        return out


def series_bars_exact(segments: Sequence[tuple[float, float, float, float]]
                      ) -> tuple[Callable[[float], float], Callable[[float], float]]:
    """Exact solution of bars in series, fixed at both outer ends.

    Args:
        segments: ``(a, b, k, f)`` per bar, contiguous, left to right.

    Returns:
        ``(u, N)``: displacement and axial force as functions of ``x``.
    """
    m = len(segments)
    c = _series_bars_coefficients(segments)

    def locate(x: float) -> int:
        for i, (_, b_i, _, _) in enumerate(segments):
            if x <= b_i + 1e-14:
                return i
        return m - 1

    def u(x: float) -> float:
        i = locate(x)
        a_i, _, k_i, f_i = segments[i]
        xi = x - a_i
        return float(c[2 * i] + c[2 * i + 1] * xi - f_i * xi * xi / (2.0 * k_i))

    def n_force(x: float) -> float:
        i = locate(x)
        a_i, _, k_i, f_i = segments[i]
        return float(k_i * c[2 * i + 1] - f_i * (x - a_i))

    return u, n_force


def _series_bars_coefficients(segments: Sequence[tuple[float, float, float, float]]) -> np.ndarray:
    """``[c0_0, c1_0, c0_1, c1_1, ...]`` of the bars in series: ``u = 0`` at both outer ends,
    ``u`` and ``N`` continuous at every joint."""
    m = len(segments)
    a_mat = np.zeros((2 * m, 2 * m))
    rhs = np.zeros(2 * m)
    row = 0
    a_mat[row, 0] = 1.0  # u(0) = 0
    row += 1
    for i in range(m - 1):
        a, b, k, f = segments[i]
        _, _, k2, _ = segments[i + 1]
        length = b - a
        # continuity of u: c0_i + c1_i L - f L²/(2k) = c0_{i+1}
        a_mat[row, 2 * i], a_mat[row, 2 * i + 1], a_mat[row, 2 * i + 2] = 1.0, length, -1.0
        rhs[row] = f * length ** 2 / (2.0 * k)
        row += 1
        # continuity of N: k c1_i - f L = k2 c1_{i+1}
        a_mat[row, 2 * i + 1], a_mat[row, 2 * i + 3] = k, -k2
        rhs[row] = f * length
        row += 1
    a, b, k, f = segments[-1]
    a_mat[row, 2 * m - 2], a_mat[row, 2 * m - 1] = 1.0, b - a
    rhs[row] = f * (b - a) ** 2 / (2.0 * k)
    return np.linalg.solve(a_mat, rhs)


class LinearOdeParticipant(Participant):
    """Backward Euler for ``u' = -K(t) u + C y + s(t)`` on ``m`` interface points.

    Reads ``y`` (data ``read``), writes ``u`` (data ``write``).  State: ``u``
    and ``u_n`` (``u_old``), which ``begin_window`` sets to the ``u`` reached.
    In the window ``[t, t + dt]``: ``(I/dt + K(t+dt)) u = u_n/dt + C y + s(t+dt)``.
    """

    def __init__(self, name: str, mesh: str, read: str, write: str,
                 stiffness: Callable[[float], np.ndarray], coupling: np.ndarray,
                 source: Callable[[float], np.ndarray], u0: np.ndarray):
        self.name = name
        self.mesh = mesh
        self.read, self.write = read, write
        self.stiffness, self.coupling, self.source = stiffness, np.array(coupling, dtype=float), source
        self.u = np.array(u0, dtype=float)
        self.u0 = self.u.copy()
        self.u_old = self.u.copy()
        self.t_new = 0.0
        self.dt = 1.0

    def interface_points(self, mesh_name: str) -> np.ndarray:
        return np.arange(self.u.size, dtype=float)[:, None]

    def save_state(self) -> dict[str, Any]:
        return {"u": self.u.copy(), "u_old": self.u_old.copy()}

    def load_state(self, state: dict[str, Any]) -> None:
        self.u = np.array(state["u"], dtype=float)
        self.u_old = np.array(state.get("u_old", self.u), dtype=float)

    def begin_window(self, t: float, dt: float) -> None:
        # u_n is kept apart from the iterate u: the window's solves all start from it
        self.u_old = self.u.copy()
        self.t_new = t + dt
        self.dt = dt

    def initial_data(self, data_name: str) -> np.ndarray | None:
        return self.u0[:, None].copy()

    def solve(self, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        m = self.u.size
        lhs = np.eye(m) / self.dt + self.stiffness(self.t_new)
        rhs = self.u_old / self.dt + self.coupling @ inputs[self.read].reshape(m) + self.source(self.t_new)
        self.u = np.linalg.solve(lhs, rhs)
        return {self.write: self.u[:, None].copy()}


# --------------------------------------------------------------------------- problems
@dataclass
class ToyProblem:
    """A coupled toy problem with a known answer.

    Attributes:
        name: Short name.
        build: Returns fresh ``(participants, data)``.
        exact: Data name -> exact value (steady: converged data; transient:
            data at ``t_end``).
        order: Serial execution order.
        relaxation: A constant relaxation factor that converges in the serial scheme.
        transient: ``(t_end, dt)`` for time-dependent problems, else ``None``.
        description: One line.
        extra: Problem-specific facts, e.g. :func:`affine_pair_problem`'s serial
            iteration operator ``"T"`` and its ``"eigenvalues"``.
    """

    name: str
    build: Callable[[], tuple[list[Participant], list[Data]]]
    exact: dict[str, np.ndarray]
    order: tuple[str, ...]
    relaxation: float
    transient: tuple[float, float] | None = None
    description: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def _symmetric_with_eigenvalues(eigenvalues: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    n = eigenvalues.size
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return q @ np.diag(eigenvalues) @ q.T


def affine_pair_problem(n: int = 8, eigenvalues: Sequence[float] | None = None,
                        seed: int = 1) -> ToyProblem:
    """Two affine participants on ``n`` points: A: ``z = S y + a``, B: ``y = T S⁻¹ z + b``.

    The serial fixed-point operator on ``y`` is ``T`` (symmetric, eigenvalues
    ``eigenvalues``, default ``linspace(-3, -0.5, n)``: plain iteration
    diverges); the parallel (Jacobi) operator has eigenvalues ``±sqrt(λ)``.
    """
    rng = np.random.default_rng(seed)
    lam = np.linspace(-3.0, -0.5, n) if eigenvalues is None else np.asarray(eigenvalues, float)
    s = _symmetric_with_eigenvalues(np.linspace(0.5, 2.0, n), rng)
    t = _symmetric_with_eigenvalues(lam, rng)
    m_b = t @ np.linalg.inv(s)
    a = rng.standard_normal(n)
    b = rng.standard_normal(n)
    # y = T S^-1 (S y + a) + b = T y + T S^-1 a + b
    y = np.linalg.solve(np.eye(n) - t, m_b @ a + b)
    z = s @ y + a

    def build() -> tuple[list[Participant], list[Data]]:
        pa = AffineParticipant("A", "Gamma", n, {("Gamma/z", "Gamma/y"): s}, {"Gamma/z": a})
        pb = AffineParticipant("B", "Gamma", n, {("Gamma/y", "Gamma/z"): m_b}, {"Gamma/y": b})
        data = [Data("Gamma/z", "Gamma", 1, "A", ("B",)), Data("Gamma/y", "Gamma", 1, "B", ("A",))]
        return [pa, pb], data

    return ToyProblem("affine-%d" % n, build, {"Gamma/z": z[:, None], "Gamma/y": y[:, None]},
                      ("A", "B"), relaxation=0.3,
                      description=f"affine pair, serial eigenvalues in [{lam.min():g}, {lam.max():g}]",
                      extra={"T": t, "eigenvalues": lam})


def two_bar_problem(ratio: float = 10.0, scale: float = 1.0) -> ToyProblem:
    """Dirichlet–Neumann coupling of two bars, stiffness ratio ``k1/k2 = ratio``.

    Bar 1 on ``[0, 1]`` (stiffness ``ratio``, load 1, fixed at 0) reads the
    interface displacement and writes the axial force; bar 2 on ``[1, 2]``
    (stiffness 1, load 2, fixed at 2) reads the force and writes the
    displacement.  The serial iteration map is ``d ↦ -ratio d + c``: plain
    iteration diverges for ratio > 1.  ``scale`` multiplies the loads (all
    answers scale with it; used to test scale invariance).
    """
    k1, k2, f1, f2 = float(ratio), 1.0, 1.0 * scale, 2.0 * scale
    u, n_force = series_bars_exact([(0.0, 1.0, k1, f1), (1.0, 2.0, k2, f2)])
    exact = {"Gamma/displacement": np.array([[u(1.0)]]), "Gamma/force": np.array([[n_force(1.0)]])}

    def build() -> tuple[list[Participant], list[Data]]:
        bar1 = ElasticBar("dirichlet_bar", 0.0, 1.0, k1, f1, BarEnd("fixed"),
                          BarEnd("dirichlet", "Gamma", "Gamma/displacement", "Gamma/force"))
        bar2 = ElasticBar("neumann_bar", 1.0, 2.0, k2, f2,
                          BarEnd("neumann", "Gamma", "Gamma/force", "Gamma/displacement"),
                          BarEnd("fixed"))
        data = [Data("Gamma/force", "Gamma", 1, "dirichlet_bar", ("neumann_bar",)),
                Data("Gamma/displacement", "Gamma", 1, "neumann_bar", ("dirichlet_bar",))]
        return [bar1, bar2], data

    return ToyProblem(f"two-bar-{ratio:g}", build, exact, ("dirichlet_bar", "neumann_bar"),
                      relaxation=1.5 / (1.0 + ratio),
                      description=f"Dirichlet-Neumann bars, stiffness ratio {ratio:g}")


def chain_problem(k_b: float = 1.0, k_c: float = 10.0) -> ToyProblem:
    """Three bars A–B–C in series with two interfaces (Γ1: A|B, Γ2: B|C).

    A ``[0, 1]`` (k 1, f 1): fixed | Neumann on Γ1.  B ``[1, 2]`` (k ``k_b``,
    f 0.5): Dirichlet on Γ1 | Neumann on Γ2.  C ``[2, 3]`` (k ``k_c``, f 2):
    Dirichlet on Γ2 | fixed.  Serial order A, B, C: the forces on Γ1 and Γ2
    are the backward (accelerated) data.  With the defaults the serial
    iteration matrix is ``[[0, 1], [-10, -10]]`` (eigenvalues -1.13 and -8.87):
    plain iteration diverges.
    """
    segments = [(0.0, 1.0, 1.0, 1.0), (1.0, 2.0, k_b, 0.5), (2.0, 3.0, k_c, 2.0)]
    u, n_force = series_bars_exact(segments)
    exact = {"Gamma1/displacement": np.array([[u(1.0)]]), "Gamma1/force": np.array([[n_force(1.0)]]),
             "Gamma2/displacement": np.array([[u(2.0)]]), "Gamma2/force": np.array([[n_force(2.0)]])}

    def build() -> tuple[list[Participant], list[Data]]:
        a = ElasticBar("A", 0.0, 1.0, 1.0, 1.0, BarEnd("fixed"),
                       BarEnd("neumann", "Gamma1", "Gamma1/force", "Gamma1/displacement"))
        b = ElasticBar("B", 1.0, 2.0, k_b, 0.5,
                       BarEnd("dirichlet", "Gamma1", "Gamma1/displacement", "Gamma1/force"),
                       BarEnd("neumann", "Gamma2", "Gamma2/force", "Gamma2/displacement"))
        c = ElasticBar("C", 2.0, 3.0, k_c, 2.0,
                       BarEnd("dirichlet", "Gamma2", "Gamma2/displacement", "Gamma2/force"),
                       BarEnd("fixed"))
        data = [Data("Gamma1/displacement", "Gamma1", 1, "A", ("B",)),
                Data("Gamma1/force", "Gamma1", 1, "B", ("A",)),
                Data("Gamma2/displacement", "Gamma2", 1, "B", ("C",)),
                Data("Gamma2/force", "Gamma2", 1, "C", ("B",))]
        return [a, b, c], data

    return ToyProblem("chain-3", build, exact, ("A", "B", "C"), relaxation=0.15,
                      description=f"three bars A-B-C, stiffness 1 | {k_b:g} | {k_c:g}")


def transient_problem(m: int = 6, coupling: float = 25.0, dt: float = 0.1, windows: int = 10,
                      variation: float = 0.2, seed: int = 3) -> ToyProblem:
    """Two linear ODE systems coupled through their states (backward Euler windows).

    A: ``u' = -K_A(t) u + c S y_B + s_A(t)``; B: ``v' = -K_B(t) v - c y_A + s_B(t)``
    with ``K_A(t) = diag(1..m)(1 + variation sin t)``, ``K_B(t) = 2(1 + variation cos t) I``,
    ``S`` SPD (eigenvalues in [0.5, 1.5]).  The exact answer is the monolithic
    backward-Euler solution with the same ``dt``; the coupled answer matches
    it only if every participant is restored to its window-start state
    between coupling iterations.
    """
    rng = np.random.default_rng(seed)
    s_mat = _symmetric_with_eigenvalues(np.linspace(0.5, 1.5, m), rng)
    ka0 = np.diag(np.arange(1.0, m + 1.0))
    phase_a, phase_b = rng.uniform(0, 2 * np.pi, m), rng.uniform(0, 2 * np.pi, m)
    u0, v0 = rng.standard_normal(m), rng.standard_normal(m)

    def k_a(t: float) -> np.ndarray:
        return ka0 * (1.0 + variation * math.sin(t))

    def k_b(t: float) -> np.ndarray:
        return 2.0 * (1.0 + variation * math.cos(t)) * np.eye(m)

    def s_a(t: float) -> np.ndarray:
        return np.sin(t + phase_a)

    def s_b(t: float) -> np.ndarray:
        return np.cos(2.0 * t + phase_b)

    c_a, c_b = coupling * s_mat, -coupling * np.eye(m)
    u, v, t = u0.copy(), v0.copy(), 0.0
    eye = np.eye(m)
    for _ in range(windows):
        t_new = t + dt
        lhs = np.block([[eye / dt + k_a(t_new), -c_a], [-c_b, eye / dt + k_b(t_new)]])
        rhs = np.concatenate([u / dt + s_a(t_new), v / dt + s_b(t_new)])
        sol = np.linalg.solve(lhs, rhs)
        u, v, t = sol[:m], sol[m:], t_new
    exact = {"Gamma/a": u[:, None], "Gamma/b": v[:, None]}

    def build() -> tuple[list[Participant], list[Data]]:
        pa = LinearOdeParticipant("A", "Gamma", "Gamma/b", "Gamma/a", k_a, c_a, s_a, u0)
        pb = LinearOdeParticipant("B", "Gamma", "Gamma/a", "Gamma/b", k_b, c_b, s_b, v0)
        data = [Data("Gamma/a", "Gamma", 1, "A", ("B",)), Data("Gamma/b", "Gamma", 1, "B", ("A",))]
        return [pa, pb], data

    return ToyProblem("transient", build, exact, ("A", "B"), relaxation=0.18,
                      transient=(windows * dt, dt),
                      description=f"two coupled ODE systems, {windows} windows of dt = {dt:g}")


def toy_problems() -> list[ToyProblem]:
    """The catalogue run by ``examples/coupling_toys.py``."""
    return [affine_pair_problem(), two_bar_problem(10.0), two_bar_problem(100.0), chain_problem(),
            transient_problem()]


def acceleration_options(name: str, problem: ToyProblem) -> dict[str, Any]:
    """The ``[coupling.acceleration]`` table used for ``name`` on ``problem``."""
    if name == "none":
        return {"type": "none"}
    if name == "constant":
        return {"type": "constant", "relaxation": problem.relaxation}
    if name == "aitken":
        return {"type": "aitken", "initial_relaxation": 0.1,
                "preconditioner": {"type": "residual-sum"}}
    common = {"type": name, "initial_relaxation": 0.1, "max_used_iterations": 100,
              "filter": {"type": "qr2", "limit": 1e-8}, "preconditioner": {"type": "residual-sum"}}
    if name == "iqn-ils" and problem.transient is not None:
        common["time_windows_reused"] = 8
    return common


def run_toy(problem: ToyProblem, scheme: str, acceleration: str, *, limit: float = 1e-10,
            max_iterations: int = 200, verbose: bool = False) -> dict[str, Any]:
    """Run one toy problem; return ``{problem, scheme, acceleration, converged, iterations, error, reason}``.

    Args:
        problem: The :class:`ToyProblem`.
        scheme: ``"serial"`` or ``"parallel"`` (implicit).
        acceleration: One of :data:`ACCELERATION_NAMES`.
        limit: Relative convergence limit on every data.
        max_iterations: Per window.
        verbose: Print the progress lines.

    Returns:
        The record; ``error`` is the maximum over data of
        ``‖value - exact‖ / ‖exact‖`` (``None`` if the run failed), and
        ``iterations`` the total number of coupling iterations.
    """
    participants, data = problem.build()
    config = {"scheme": f"{scheme}-implicit", "order": list(problem.order),
              "max_iterations": max_iterations, "verbose": verbose,
              "convergence": [{"data": "*", "type": "relative", "limit": limit}],
              "acceleration": acceleration_options(acceleration, problem)}
    sch = build_scheme(config, participants, data)
    record: dict[str, Any] = {"problem": problem.name, "scheme": scheme, "acceleration": acceleration}
    try:
        if problem.transient is None:
            result = sch.solve()
        else:
            t_end, dt = problem.transient
            result = sch.run(t_end=t_end, dt=dt)
    except (CouplingDivergedError, CouplingNotConvergedError) as exc:
        record.update(converged=False, iterations=exc.result.iterations, error=None,
                      reason=str(exc).split(";")[0])
        return record
    error = max(float(np.linalg.norm(sch.latest(n) - v) / np.linalg.norm(v))
                for n, v in problem.exact.items())
    record.update(converged=bool(result.converged), iterations=result.iterations, error=error,
                  reason=result.reason)
    return record
