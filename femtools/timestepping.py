"""Backward Euler and variable-step BDF2 for a first time derivative in a UFL form.

A quasi-static field whose equations contain the velocity v = du/dt of one
of its unknowns u (the gel's network velocity v_s) needs the past values
u^n, u^{n-1} and the rate

    v^{n+1} = (scale / dt) (a0 u^{n+1} + a1 u^n + a2 u^{n-1})

    backward Euler:          (a0, a1, a2) = (1, -1, 0)
    BDF2, omega = dt/dt_prev: ((1 + 2 omega)/(1 + omega), -(1 + omega), omega^2/(1 + omega))

(``scale`` converts the unknown's unit into the velocity's, e.g. the
displacement unit d).  The coefficients are ``fem.Constant``s, so one
compiled form serves the steady state (all zero), both schemes and every dt.
"""

from __future__ import annotations

import numpy as np

from petsc4py import PETSc

from dolfinx import fem

__all__ = ["TIME_SCHEMES", "bdf_coefficients", "RateHistory"]

TIME_SCHEMES = ("be", "bdf2")


def bdf_coefficients(scheme: str, dt: float, dt_previous: float | None = None) -> tuple[float, float, float]:
    """``(a0, a1, a2)`` of backward Euler or variable-step BDF2 (see the module docstring)."""
    if scheme not in TIME_SCHEMES:
        raise ValueError(f"time scheme must be one of {TIME_SCHEMES}, got {scheme!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be finite and > 0, got {dt!r}")
    if scheme == "be":
        return (1.0, -1.0, 0.0)
    dt_previous = dt if dt_previous is None else float(dt_previous)
    if not (np.isfinite(dt_previous) and dt_previous > 0):
        raise ValueError(f"dt_previous must be finite and > 0, got {dt_previous!r}")
    omega = dt / dt_previous
    return ((1 + 2 * omega) / (1 + omega), -(1 + omega), omega**2 / (1 + omega))


class RateHistory:
    """Past values of one unknown and its time-discrete rate as a UFL expression.

    Args:
        space: the (collapsed) space of the unknown; the past values live in it.
        current: the unknown as a UFL expression (e.g. a component of ``ufl.split``).
        scale: velocity per unit of the unknown and of time (e.g. the displacement unit).
        name: prefix of the past values' names.

    Attributes:
        rate: the UFL expression c0 current + c1 u^n + c2 u^{n-1}.
        past: ``[u^n, u^{n-1}]`` as Functions on ``space``.
        length: how many past values are held (0, 1 or 2).
        step: ``None`` (steady: rate 0) or ``{"dt", "scheme", "a"}``.
    """

    def __init__(self, space: fem.FunctionSpace, current, scale: float, name: str = "u"):
        msh = space.mesh
        self.scale = float(scale)
        self.past = [fem.Function(space, name=f"{name}_n"), fem.Function(space, name=f"{name}_nm1")]
        self.constants = [fem.Constant(msh, PETSc.ScalarType(0.0)) for _ in range(3)]
        c0, c1, c2 = self.constants
        self.rate = c0 * current + c1 * self.past[0] + c2 * self.past[1]
        self.length = 0
        self.step: dict | None = None

    def set_step(self, dt: float, scheme: str = "be", dt_previous: float | None = None) -> bool:
        """Use the scheme for the next solves; True if c0 (hence the Jacobian) changed."""
        if scheme == "bdf2" and self.length < 2:
            raise RuntimeError("BDF2 needs two past states; start with one backward Euler step")
        a = bdf_coefficients(scheme, dt, dt_previous)
        old = self.coefficients[0]
        self.step = {"dt": float(dt), "scheme": scheme, "a": a}
        self._apply()
        return not np.isclose(self.coefficients[0], old, rtol=1e-14, atol=0.0)

    def set_steady(self) -> bool:
        """Rate 0 (the past values are kept); True if that changed c0."""
        old = self.coefficients[0]
        self.step = None
        self._apply()
        return old != 0.0

    def set_scale(self, scale: float) -> None:
        self.scale = float(scale)
        self._apply()

    def _apply(self) -> None:
        a = (0.0, 0.0, 0.0) if self.step is None else self.step["a"]
        dt = 1.0 if self.step is None else self.step["dt"]
        for const, coefficient in zip(self.constants, a):
            const.value = self.scale * coefficient / dt

    @property
    def coefficients(self) -> tuple[float, float, float]:
        """(c0, c1, c2): the rate is c0 u + c1 u^n + c2 u^{n-1}."""
        return tuple(float(c.value) for c in self.constants)

    def nodal_rate(self, current: np.ndarray) -> np.ndarray:
        """The rate at the nodes, given the current values in ``space``'s layout."""
        c0, c1, c2 = self.coefficients
        return c0 * current + c1 * self.past[0].x.array + c2 * self.past[1].x.array

    def push(self, current: np.ndarray) -> None:
        """u^{n-1} <- u^n <- current (values in ``space``'s layout, ghosts included)."""
        self.past[1].x.array[:] = self.past[0].x.array
        self.past[0].x.array[:] = current
        self.length = min(self.length + 1, 2)

    def reset(self) -> None:
        for f in self.past:
            f.x.array[:] = 0.0
        self.length = 0

    def state(self) -> dict[str, np.ndarray]:
        return {"past_0": self.past[0].x.array.copy(), "past_1": self.past[1].x.array.copy(),
                "length": np.array(self.length)}

    def step_state(self) -> np.ndarray:
        """The step in use: ``[dt, a0, a1, a2]``, or an empty array when steady (for a checkpoint)."""
        if self.step is None:
            return np.empty(0)
        return np.array([self.step["dt"], *self.step["a"]], dtype=float)

    def load_step(self, values) -> None:
        """Use the step of :meth:`step_state` again (the rate of the state it was saved with)."""
        values = np.asarray(values, dtype=float).ravel()
        if values.size == 0:
            self.step = None
        elif values.size == 4:
            a = tuple(float(c) for c in values[1:])
            self.step = {"dt": float(values[0]), "scheme": "be" if a[2] == 0.0 else "bdf2", "a": a}
        else:
            raise ValueError(f"a time step is [dt, a0, a1, a2], got {values.size} numbers")
        self._apply()

    def load(self, state) -> None:
        for k, f in enumerate(self.past):
            values = np.asarray(state[f"past_{k}"], dtype=float)
            if values.shape != f.x.array.shape:
                raise ValueError(f"past value {k} has shape {values.shape}, expected {f.x.array.shape}")
            f.x.array[:] = values
        self.length = int(state["length"])


class WindowClock:
    """The times of a :class:`RateHistory`'s past values, so that entering a time window is idempotent.

    ``enter(t, dt, push)`` is called when the window [t, t + dt] starts (the gel
    participant's ``begin_window``), and may be called again for the same t
    (a window retaken after a restore, a participant of the coupling's earlier
    protocol before every solve): the first call for a new t pushes the state
    reached at t (``push()``), later calls do not.  It returns the scheme of the step:
    backward Euler for the first step (one past value), else ``scheme`` with
    the previous step length for BDF2.
    """

    def __init__(self, scheme: str = "be"):
        if scheme not in TIME_SCHEMES:
            raise ValueError(f"time scheme must be one of {TIME_SCHEMES}, got {scheme!r}")
        self.scheme = scheme
        self.times: list[float | None] = [None, None]     # of u^n and u^{n-1}

    def enter(self, t: float, dt: float, push) -> tuple[str, float | None]:
        if self.times[0] != t:
            push()
            self.times = [t, self.times[0]]
        t_n, t_nm1 = self.times
        if self.scheme == "bdf2" and t_nm1 is not None:
            return "bdf2", t_n - t_nm1
        return "be", None

    def state(self) -> np.ndarray:
        return np.array([np.nan if t is None else t for t in self.times])

    def load(self, times) -> None:
        self.times = [None if np.isnan(t) else float(t) for t in np.asarray(times, dtype=float)]
