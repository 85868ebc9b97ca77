r"""Acceleration of the coupling fixed-point iteration.

Notation (per coupling iteration ``k`` of a time window): ``x_k`` is the
input of the fixed-point operator (the accelerated data as read by the
participants), ``x̃_k = G(x_k)`` its output (the data as newly written) and
``r_k = x̃_k - x_k`` the residual.  An acceleration maps ``(x_k, x̃_k)`` to
the next input ``x_{k+1}``:

* :class:`NoAcceleration`: ``x_{k+1} = x̃_k`` (plain fixed-point iteration).
* :class:`ConstantRelaxation`: ``x_{k+1} = x_k + ω r_k``.
* :class:`AitkenRelaxation`: ``x_{k+1} = x_k + ω_k r_k`` with
  ``ω_k = -ω_{k-1} (r_{k-1}ᵀ (r_k - r_{k-1})) / ‖r_k - r_{k-1}‖²`` (scaled
  residuals), ``ω_0`` the initial relaxation (in later windows
  ``sign(ω_prev) min(ω_0, |ω_prev|)``), |ω| clipped to ``[omega_min, omega_max]``.
* :class:`IQNILS` (interface quasi-Newton, inverse Jacobian from a least-squares
  model): with the difference matrices ``V = [Δr_k, Δr_{k-1}, ...]``,
  ``W = [Δx̃_k, Δx̃_{k-1}, ...]`` (newest first, ``Δr_k = r_k - r_{k-1}``,
  ``Δx̃_k = x̃_k - x̃_{k-1}``, columns of up to ``time_windows_reused`` past
  windows kept),

  .. math::  α = \arg\min_α ‖P (V α + r_k)‖_2 ,\qquad x_{k+1} = x̃_k + W α ,

  solved by the QR factorisation ``P V = Q R``: ``α = -R^{-1} Qᵀ P r_k``.
  ``P = diag(w)`` is the preconditioner (per-data scaling).  Before each solve
  the QR filter deletes (nearly) linearly dependent columns, oldest first.
* :class:`IQNIMVJ` (multi-vector Jacobian): the inverse Jacobian of the
  previous windows ``J_prev`` is kept (dense, physical units) and updated
  with the current window's columns,

  .. math::  J = J_{prev} + (W - J_{prev} V) Z ,\qquad Z = (V_s^T V_s)^{-1} V_s^T P = R^{-1} Qᵀ P,

  ``x_{k+1} = x̃_k - J r_k``; at the end of a window ``J_prev ← J``.

In the first iteration of the first window (or of every window with
``enforce_initial_relaxation``), and whenever no usable column is left, the
quasi-Newton methods relax: ``x_{k+1} = x_k + ω_0 r_k``.

**Prior inverse Jacobian** (generalised Broyden).  IQN-ILS implicitly takes
``J0 = 0`` outside the span of its columns: there it does a plain
fixed-point step ``x̃``.  With a prior ``J0`` (``relaxation_prior``:
``J0 = diag(1 - ω_d)``, one relaxation factor per data; or a *surrogate*
object whose ``inverse_jacobian(r)`` returns ``J0 r``, e.g. the same
coupled problem on a coarser mesh) the update is

.. math::  x_{k+1} = x̃_k - J_0 r_k + (W - J_0 V) α ,\qquad α = \arg\min_α ‖P (V α + r_k)‖_2 ,

i.e. the multi-vector update of ``J0`` by the secant pairs; without columns
it is the prior's step ``x̃_k - J0 r_k`` (for the relaxation prior:
``x_k + ω_d r_k`` per data).  IQN-IMVJ uses the prior as its first
``J_prev``.

Zero or near-zero difference columns (``‖P Δr‖ ≤ 100 ε max(‖P x̃_k‖,
‖P x̃_{k-1}‖)``) carry no information and are skipped, never used.

Every acceleration exports its complete state (kept columns, past windows,
relaxation, preconditioner weights, inverse Jacobian) with
:meth:`Acceleration.state_dict` and restores it with
:meth:`Acceleration.load_state_dict`.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from coupling.config import AccelerationConfig, PreconditionerConfig
from coupling.layout import VectorLayout

__all__ = [
    "AccelerationInfo", "Preconditioner", "Acceleration", "NoAcceleration", "ConstantRelaxation",
    "AitkenRelaxation", "IQNILS", "IQNIMVJ", "qr_filter", "relaxation_prior_diagonal", "build_acceleration",
]

_EPS = np.finfo(float).eps
_ZERO_COLUMN_FACTOR = 100.0 * _EPS


@dataclass
class AccelerationInfo:
    """What the last :meth:`Acceleration.compute` did.

    Attributes:
        relaxation: The relaxation factor used, or ``None`` for a quasi-Newton step.
        columns_used: Number of columns in the least-squares system.
        columns_filtered: Columns deleted in this call (QR filter or zero columns).
        columns_dropped: Columns dropped in this call (``max_used_iterations``
            or columns of windows older than ``time_windows_reused``).
    """

    relaxation: float | None = None
    columns_used: int = 0
    columns_filtered: int = 0
    columns_dropped: int = 0


# --------------------------------------------------------------------------- preconditioner
class Preconditioner:
    """Per-data scaling weights ``w`` of the accelerated vector (see :class:`PreconditionerConfig`).

    Update rules (``update(window_complete, values, residual)``, called with
    ``window_complete=False`` in every iteration and ``True`` once when a
    window converges):

    * ``"value"``: ``w_d = 1/‖x_d‖`` in every iteration of the first window
      (as preCICE: the first iterates of a parallel scheme can be orders of
      magnitude off the converged values, and weights frozen at them skew
      the least squares) and then once when each window completes;
    * ``"residual"``: ``w_d = 1/‖r_d‖`` in every iteration;
    * ``"residual-sum"``: ``s_d += ‖r_d‖/‖r‖`` in every iteration, ``w_d = 1/s_d``;
      ``s`` is reset when a window completes;
    * after ``freeze_after`` completed windows the weights stay constant.

    A zero norm leaves the previous weight unchanged.
    """

    def __init__(self, config: PreconditionerConfig, layout: VectorLayout):
        self.kind = config.type
        self.freeze_after = config.freeze_after
        self.layout = layout
        n = len(layout.names)
        self.data_weights = np.ones(n)
        self.residual_sum = np.zeros(n)
        self.windows_completed = 0
        self.frozen = False
        self.first_update = True
        if self.kind == "constant":
            names = set(layout.names)
            given = set(config.factors)
            if given != names:
                raise ValueError(
                    "coupling.acceleration.preconditioner.factors must name exactly the "
                    f"accelerated data {sorted(names)}; missing {sorted(names - given)}, "
                    f"not accelerated {sorted(given - names)}")
            self.data_weights = np.array([1.0 / config.factors[d] for d in layout.names])

    @property
    def weights(self) -> np.ndarray:
        """Weight of every entry of the concatenated vector."""
        sizes = np.diff(self.layout.offsets)
        return np.repeat(self.data_weights, sizes)

    def update(self, window_complete: bool, values: np.ndarray, residual: np.ndarray) -> None:
        """Update the weights (see the class docstring)."""
        if self.frozen:
            return
        if window_complete:
            self.windows_completed += 1
            if 0 < self.freeze_after <= self.windows_completed:
                self.frozen = True
        if self.kind == "value":
            if window_complete or self.first_update:
                norms = self.layout.norms(values)
                ok = norms > 0.0
                self.data_weights[ok] = 1.0 / norms[ok]
                self.first_update = self.first_update and not window_complete
        elif self.kind == "residual":
            if not window_complete:
                norms = self.layout.norms(residual)
                ok = norms > 0.0
                self.data_weights[ok] = 1.0 / norms[ok]
        elif self.kind == "residual-sum":
            if window_complete:
                self.residual_sum[:] = 0.0
            else:
                norms = self.layout.norms(residual)
                total = math.sqrt(float(np.sum(norms ** 2)))
                if total > 0.0:
                    self.residual_sum += norms / total
                ok = self.residual_sum > 0.0
                self.data_weights[ok] = 1.0 / self.residual_sum[ok]

    def state_dict(self) -> dict[str, Any]:
        """Exportable state."""
        return {"kind": self.kind, "data_weights": self.data_weights.copy(),
                "residual_sum": self.residual_sum.copy(), "windows_completed": self.windows_completed,
                "frozen": self.frozen, "first_update": self.first_update}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a state from :meth:`state_dict`."""
        if state["kind"] != self.kind:
            raise ValueError(f"preconditioner state of type {state['kind']!r} cannot be loaded "
                             f"into a {self.kind!r} preconditioner")
        self.data_weights = np.array(state["data_weights"], dtype=float).reshape(-1)
        self.residual_sum = np.array(state["residual_sum"], dtype=float).reshape(-1)
        if self.data_weights.size != len(self.layout.names):
            raise ValueError("preconditioner state does not match the number of accelerated data")
        self.windows_completed = int(state["windows_completed"])
        self.frozen = bool(state["frozen"])
        self.first_update = bool(state["first_update"])


# --------------------------------------------------------------------------- QR filter
def qr_filter(matrix: np.ndarray, kind: str, limit: float) -> list[int]:
    """Indices of the columns to delete from a (scaled) difference matrix.

    Columns are ordered newest first, so older columns are the ones deleted.

    * Columns that are exactly zero or not finite are always deleted.
    * ``"qr1"``: factorise ``V = Q R``; while some ``|R_ii| < limit ‖R‖_F``,
      delete the first such column and refactorise (as preCICE's QR1).
      Columns beyond the row count are deleted (they are necessarily dependent).
    * ``"qr2"``: Gram–Schmidt (with one re-orthogonalisation) newest first;
      delete a column whose part orthogonal to the kept newer ones is below
      ``limit`` times its norm (as preCICE's QR2).
    * ``"none"``: only the zero/non-finite columns.

    Args:
        matrix: ``(n, m)`` array.
        kind: ``"none"``, ``"qr1"`` or ``"qr2"``.
        limit: Threshold in (0, 1).

    Returns:
        Sorted list of column indices to delete.
    """
    return _filter_columns(matrix, kind, limit)[0]


def _filter_columns(matrix: np.ndarray, kind: str, limit: float) -> tuple[list[int], np.ndarray | None]:
    """:func:`qr_filter`'s deletions, and for ``"qr2"`` an orthonormal basis of the kept columns."""
    n, m = matrix.shape
    norms = np.linalg.norm(matrix, axis=0) if m else np.zeros(0)
    deleted = [j for j in range(m) if not np.isfinite(norms[j]) or norms[j] == 0.0]
    keep = [j for j in range(m) if j not in deleted]
    if kind == "none" or not keep:
        return sorted(deleted), None
    if kind == "qr1":
        while len(keep) > n:
            deleted.append(keep.pop())
        while len(keep) > 1:
            r = np.linalg.qr(matrix[:, keep], mode="r")
            diag = np.abs(np.diag(r))
            bad = np.flatnonzero(diag < limit * np.linalg.norm(r))
            if bad.size == 0:
                break
            deleted.append(keep.pop(int(bad[0])))
    elif kind == "qr2":
        dependent, basis = _qr2_deleted(matrix, keep, norms, limit)
        return sorted(deleted + dependent), basis
    else:
        raise ValueError(f"qr_filter: kind = {kind!r} is not allowed; allowed: 'none', 'qr1', 'qr2'")
    return sorted(deleted), None


def _qr2_deleted(matrix: np.ndarray, columns: list[int], norms: np.ndarray,
                 limit: float) -> tuple[list[int], np.ndarray]:
    """QR2's deletions: Gram–Schmidt newest first, by blocks of Householder QR (LAPACK).

    A column's part orthogonal to the kept newer columns is the diagonal entry
    of R when the columns are factorised in order, so one QR of a block gives
    the test for all of its columns up to the first one deleted; the columns
    after it are factorised again against the new basis (projected out twice,
    as in Gram–Schmidt with re-orthogonalisation).  The decisions are those of
    Gram–Schmidt column by column (:func:`qr_filter`).

    Returns the deleted columns and an orthonormal basis of the kept ones (in their order).
    """
    n = matrix.shape[0]
    deleted: list[int] = []
    basis = np.zeros((n, 0))
    pending = list(columns)
    while pending:
        room = n - basis.shape[1]
        if room == 0:                       # the basis spans R^n: every further column is dependent
            return deleted + pending, basis
        block_columns = pending[:room]
        block = matrix[:, block_columns].astype(float)
        for _ in range(2 if basis.shape[1] else 0):
            block -= basis @ (basis.T @ block)
        q, r = np.linalg.qr(block, mode="reduced")
        rho = np.abs(np.diag(r))
        bad = np.flatnonzero((rho <= limit * norms[block_columns]) | (rho <= np.finfo(float).tiny))
        if bad.size == 0:
            basis = np.hstack([basis, q])
            pending = pending[room:]
            continue
        b = int(bad[0])
        basis = np.hstack([basis, q[:, :b]])
        deleted.append(block_columns[b])
        pending = pending[b + 1:]
    return deleted, basis


# --------------------------------------------------------------------------- base class
class Acceleration(abc.ABC):
    """Base class: maps ``(x_k, x̃_k)`` to the next iterate ``x_{k+1}``.

    Usage per time window::

        for k in range(max_iterations):
            x_tilde = G(x)
            if converged:
                acc.window_converged(x, x_tilde)
                break
            x = acc.compute(x, x_tilde)

    Args:
        config: The acceleration options.
        layout: Layout of the accelerated vector (per-data blocks for scaling).
    """

    kind = "base"

    def __init__(self, config: AccelerationConfig, layout: VectorLayout):
        self.config = config
        self.layout = layout
        self.preconditioner = Preconditioner(config.preconditioner, layout)
        self.iteration = 0
        self.windows_completed = 0
        self.info = AccelerationInfo()
        self.window_info = AccelerationInfo()

    def _check(self, x: np.ndarray, x_tilde: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(x, dtype=float).reshape(-1)
        x_tilde = np.asarray(x_tilde, dtype=float).reshape(-1)
        if x.shape != (self.layout.size,) or x_tilde.shape != (self.layout.size,):
            raise ValueError(f"{type(self).__name__}: expected vectors of size {self.layout.size}, "
                             f"got {x.shape} and {x_tilde.shape}")
        return x, x_tilde

    def compute(self, x: np.ndarray, x_tilde: np.ndarray) -> np.ndarray:
        """Return the next iterate ``x_{k+1}`` from ``x_k`` and ``x̃_k = G(x_k)``."""
        x, x_tilde = self._check(x, x_tilde)
        self.info = AccelerationInfo()
        x_next = self._compute(x, x_tilde, x_tilde - x)
        self.iteration += 1
        return x_next

    def window_converged(self, x: np.ndarray, x_tilde: np.ndarray) -> None:
        """Close the current window whose converged iterate is ``(x, x̃)``."""
        x, x_tilde = self._check(x, x_tilde)
        self.window_info = AccelerationInfo()
        self.preconditioner.update(True, x_tilde, x_tilde - x)
        self._window_converged(x, x_tilde, x_tilde - x)
        self.iteration = 0
        self.windows_completed += 1

    @abc.abstractmethod
    def _compute(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Method-specific update."""

    def _window_converged(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> None:
        """Method-specific end of window (default: nothing)."""

    @property
    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        """The kept difference matrices ``(V, W)`` (unscaled, newest column first)."""
        n = self.layout.size
        return np.zeros((n, 0)), np.zeros((n, 0))

    def state_dict(self) -> dict[str, Any]:
        """Complete exportable state (arrays and JSON-compatible scalars)."""
        state = {"kind": self.kind, "size": self.layout.size, "iteration": self.iteration,
                 "windows_completed": self.windows_completed,
                 "preconditioner": self.preconditioner.state_dict()}
        state.update(self._state())
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a state exported by :meth:`state_dict`."""
        if state["kind"] != self.kind:
            raise ValueError(f"acceleration state of type {state['kind']!r} cannot be loaded into "
                             f"{type(self).__name__} ({self.kind!r})")
        if int(state["size"]) != self.layout.size:
            raise ValueError(f"acceleration state is for vectors of size {state['size']}, this "
                             f"acceleration has size {self.layout.size}")
        self.iteration = int(state["iteration"])
        self.windows_completed = int(state["windows_completed"])
        self.preconditioner.load_state_dict(state["preconditioner"])
        self._load_state(state)

    def _state(self) -> dict[str, Any]:
        return {}

    def _load_state(self, state: dict[str, Any]) -> None:
        pass


class NoAcceleration(Acceleration):
    """Plain fixed-point iteration: ``x_{k+1} = x̃_k``."""

    kind = "none"

    def _compute(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        self.info.relaxation = 1.0
        return x_tilde.copy()


class ConstantRelaxation(Acceleration):
    """Constant under-relaxation: ``x_{k+1} = x_k + ω r_k``.

    For an affine ``G(x) = A x + b`` the error obeys
    ``e_{k+1} = ((1 - ω) I + ω A) e_k``: the asymptotic rate is the spectral
    radius ``max_i |1 - ω (1 - λ_i)|``.
    """

    kind = "constant"

    def _compute(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        omega = self.config.relaxation
        self.info.relaxation = omega
        return x + omega * r


class AitkenRelaxation(Acceleration):
    """Aitken's dynamic relaxation (Irons–Tuck form, vector version).

    ``ω_k = -ω_{k-1} (P r_{k-1})ᵀ P (r_k - r_{k-1}) / ‖P (r_k - r_{k-1})‖²``;
    for a scalar affine ``G`` this is the secant step, exact after two
    iterations.  If ``r_k = r_{k-1}`` the previous ω is kept.
    """

    kind = "aitken"

    def __init__(self, config: AccelerationConfig, layout: VectorLayout):
        super().__init__(config, layout)
        self.omega = config.initial_relaxation
        self.previous_residual: np.ndarray | None = None

    def _bounded(self, omega: float) -> float:
        sign = -1.0 if (omega < 0.0 and not self.config.positive_relaxation) else 1.0
        magnitude = min(max(abs(omega), self.config.omega_min), self.config.omega_max)
        return sign * magnitude

    def _compute(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        self.preconditioner.update(False, x, r)
        w = self.preconditioner.weights
        omega0 = self.config.initial_relaxation
        if self.iteration == 0 or self.previous_residual is None:
            if self.windows_completed == 0:
                omega = omega0
            else:
                omega = math.copysign(min(omega0, abs(self.omega)), self.omega)
        else:
            previous = w * self.previous_residual
            dr = w * r - previous
            denominator = float(dr @ dr)
            omega = self.omega
            if denominator > 0.0 and math.isfinite(denominator):
                omega = -self.omega * float(previous @ dr) / denominator
        omega = self._bounded(omega)
        self.omega = omega
        self.previous_residual = r.copy()
        self.info.relaxation = omega
        return x + omega * r

    def _window_converged(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> None:
        self.previous_residual = None

    def _state(self) -> dict[str, Any]:
        return {"omega": self.omega, "previous_residual": self.previous_residual}

    def _load_state(self, state: dict[str, Any]) -> None:
        self.omega = float(state["omega"])
        prev = state["previous_residual"]
        self.previous_residual = None if prev is None else np.array(prev, dtype=float)


def relaxation_prior_diagonal(table: dict[str, float], layout: VectorLayout) -> np.ndarray | None:
    """``1 - ω`` per entry of the accelerated vector from a ``relaxation_prior`` table (None if empty).

    Raises:
        ValueError: If the table names a data that is not accelerated.
    """
    if not table:
        return None
    unknown = sorted(set(table) - set(layout.names) - {"*"})
    if unknown:
        raise ValueError(f"coupling.acceleration.relaxation_prior names {unknown}, which are not "
                         f"accelerated data; accelerated data: {list(layout.names)} (or '*')")
    default = table.get("*", 1.0)
    omegas = np.array([table.get(name, default) for name in layout.names], dtype=float)
    return np.repeat(1.0 - omegas, np.diff(layout.offsets))


class _QuasiNewton(Acceleration):
    """Column management shared by IQN-ILS and IQN-IMVJ.

    Attributes:
        surrogate: ``None`` or an object with ``inverse_jacobian(r)``: the
            prior ``J0 r`` of a cheaper model of the same coupled problem
            (module docstring).  ``r`` is one residual vector of the
            accelerated layout; the result has the same shape.  It replaces
            the relaxation prior.  A surrogate with ``accepts_matrices = True``
            also takes a matrix of such vectors (columns) in one call.
    """

    reuse_windows = 0

    def __init__(self, config: AccelerationConfig, layout: VectorLayout):
        super().__init__(config, layout)
        n = layout.size
        self.V = np.zeros((n, 0))
        self.W = np.zeros((n, 0))
        self.window_columns: list[int] = [0]  # columns per window, current window first
        self.previous_residual: np.ndarray | None = None
        self.previous_output: np.ndarray | None = None
        #: (V, weights, orthonormal basis of P V) left by the last QR2 filter; valid while V and P are
        self._kept_basis: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.prior_diagonal = relaxation_prior_diagonal(dict(config.relaxation_prior), layout)
        self.surrogate: Any = None

    def _has_prior(self) -> bool:
        return self.surrogate is not None or self.prior_diagonal is not None

    def _prior(self, r: np.ndarray) -> np.ndarray:
        """``J0 r`` for a vector, or ``J0 R`` column by column for a matrix."""
        if self.surrogate is None:
            return (self.prior_diagonal[:, None] if r.ndim == 2 else self.prior_diagonal) * r
        if r.ndim == 2 and r.shape[1] == 0:
            return np.zeros_like(r)
        if r.ndim == 2 and not getattr(self.surrogate, "accepts_matrices", False):
            return np.column_stack([self._prior(r[:, j]) for j in range(r.shape[1])])
        out = np.asarray(self.surrogate.inverse_jacobian(r.copy()), dtype=float)
        out = out.reshape(-1) if r.ndim == 1 else out
        if out.shape != r.shape:
            raise ValueError(f"surrogate.inverse_jacobian returned shape {out.shape}, expected {r.shape}")
        return out

    def _prior_step(self, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        self.info.relaxation = None
        return x_tilde - self._prior(r)

    @property
    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        return self.V.copy(), self.W.copy()

    # -- column bookkeeping
    def _remove_columns(self, indices: list[int]) -> None:
        if not indices:
            return
        bounds = np.cumsum(self.window_columns)
        for j in indices:
            window = int(np.searchsorted(bounds, j, side="right"))
            self.window_columns[window] -= 1
        keep = np.setdiff1d(np.arange(self.V.shape[1]), indices)
        self.V = self.V[:, keep]
        self.W = self.W[:, keep]

    def _add_columns(self, r: np.ndarray, x_tilde: np.ndarray, info: AccelerationInfo) -> None:
        if self.previous_residual is not None:
            w = self.preconditioner.weights
            dv = r - self.previous_residual
            dw = x_tilde - self.previous_output
            scale = max(float(np.linalg.norm(w * x_tilde)), float(np.linalg.norm(w * self.previous_output)))
            size = float(np.linalg.norm(w * dv))
            if not math.isfinite(size) or size <= _ZERO_COLUMN_FACTOR * scale or size == 0.0:
                info.columns_filtered += 1
            else:
                self.V = np.column_stack([dv, self.V])
                self.W = np.column_stack([dw, self.W])
                self.window_columns[0] += 1
        self.previous_residual = r.copy()
        self.previous_output = x_tilde.copy()
        excess = self.V.shape[1] - self.config.max_used_iterations
        if excess > 0:
            self._remove_columns(list(range(self.V.shape[1] - excess, self.V.shape[1])))
            info.columns_dropped += excess

    def _filter(self, info: AccelerationInfo) -> None:
        if self.V.shape[1] == 0:
            return
        weights = self.preconditioner.weights
        deleted, basis = _filter_columns(weights[:, None] * self.V, self.config.filter.type,
                                         self.config.filter.limit)
        self._remove_columns(deleted)
        info.columns_filtered += len(deleted)
        # QR2 has factorised the kept columns already: the least-squares step reuses that basis
        self._kept_basis = None if basis is None else (self.V, weights.copy(), basis)

    def _least_squares_factors(self) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, R)`` of the scaled ``P V`` (after filtering)."""
        weights = self.preconditioner.weights
        scaled = weights[:, None] * self.V
        cached = self._kept_basis
        if cached is not None and cached[0] is self.V and np.array_equal(cached[1], weights):
            q = cached[2]
            return q, np.triu(q.T @ scaled)
        return np.linalg.qr(scaled, mode="reduced")

    def _alpha(self, r: np.ndarray) -> np.ndarray:
        w = self.preconditioner.weights
        rhs = -(w * r)
        if self.config.filter.type == "none":
            return np.linalg.lstsq(w[:, None] * self.V, rhs, rcond=None)[0]
        q, rr = self._least_squares_factors()
        return sla.solve_triangular(rr, q.T @ rhs)

    def _relax(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        omega = self.config.initial_relaxation
        self.info.relaxation = omega
        return x + omega * r

    def _has_model(self) -> bool:
        return self.V.shape[1] > 0

    def _compute(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        self.preconditioner.update(False, x, r)
        self._add_columns(r, x_tilde, self.info)
        first = self.iteration == 0
        if first and (self.windows_completed == 0 or self.config.enforce_initial_relaxation):
            self.info.columns_used = 0
            return self._prior_step(x_tilde, r) if self._has_prior() else self._relax(x, r)
        self._filter(self.info)
        if not self._has_model():
            return self._prior_step(x_tilde, r) if self._has_prior() else self._relax(x, r)
        self.info.columns_used = self.V.shape[1]
        return self._quasi_newton_step(x, x_tilde, r)

    @abc.abstractmethod
    def _quasi_newton_step(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The method's update once the model exists."""

    def _start_new_window(self) -> None:
        self.window_columns.insert(0, 0)
        dropped = 0
        while len(self.window_columns) > self.reuse_windows + 1:
            count = self.window_columns[-1]
            n = self.V.shape[1]
            if count:
                self.V = self.V[:, : n - count]
                self.W = self.W[:, : n - count]
            dropped += count
            self.window_columns.pop()
        self.window_info.columns_dropped += dropped
        self.previous_residual = None
        self.previous_output = None

    def _state(self) -> dict[str, Any]:
        # the QR2 basis of the kept columns too: a restored solve then takes the least-squares
        # steps the uninterrupted one takes, to the bit (a QR computed afresh differs in round-off)
        cached = self._kept_basis if self._kept_basis is not None and self._kept_basis[0] is self.V else None
        # copies in the arrays' own memory order: BLAS rounds a C- and an F-ordered matrix differently
        return {"V": self.V.copy(order="K"), "W": self.W.copy(order="K"), "window_columns": list(self.window_columns),
                "previous_residual": self.previous_residual, "previous_output": self.previous_output,
                "kept_basis": None if cached is None else cached[2].copy(order="K"),
                "kept_basis_weights": None if cached is None else cached[1].copy()}

    def _load_state(self, state: dict[str, Any]) -> None:
        n = self.layout.size
        self.V = np.array(state["V"], dtype=float).reshape(n, -1)
        self.W = np.array(state["W"], dtype=float).reshape(n, -1)
        self.window_columns = [int(c) for c in state["window_columns"]]
        if sum(self.window_columns) != self.V.shape[1]:
            raise ValueError("quasi-Newton state: window column counts do not match V")
        prev_r, prev_o = state["previous_residual"], state["previous_output"]
        self.previous_residual = None if prev_r is None else np.array(prev_r, dtype=float)
        self.previous_output = None if prev_o is None else np.array(prev_o, dtype=float)
        basis, weights = state.get("kept_basis"), state.get("kept_basis_weights")
        self._kept_basis = None if basis is None or weights is None else \
            (self.V, np.array(weights, dtype=float).reshape(n), np.array(basis, dtype=float).reshape(n, -1))


class IQNILS(_QuasiNewton):
    """Interface quasi-Newton with an inverse Jacobian from a least-squares model (IQN-ILS).

    ``x_{k+1} = x̃_k + W α`` with ``α = argmin ‖P (V α + r_k)‖`` (see the
    module docstring).  For an affine ``G`` on ``R^n`` with independent
    columns this terminates: ``x_{n+1}`` is the fixed point (up to rounding).
    """

    kind = "iqn-ils"

    def __init__(self, config: AccelerationConfig, layout: VectorLayout):
        super().__init__(config, layout)
        self.reuse_windows = config.time_windows_reused

    def _quasi_newton_step(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        alpha = self._alpha(r)
        if self._has_prior():
            return x_tilde - self._prior(r) + (self.W - self._prior(self.V)) @ alpha
        return x_tilde + self.W @ alpha

    def _window_converged(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> None:
        if self.reuse_windows > 0:
            self._add_columns(r, x_tilde, self.window_info)
        self._start_new_window()


class IQNIMVJ(_QuasiNewton):
    """Interface quasi-Newton with a multi-vector inverse Jacobian (IQN-IMVJ).

    The inverse Jacobian of past windows ``J_prev`` (dense ``n × n``, physical
    units, zero initially) is combined with the current window's columns:
    ``x_{k+1} = x̃_k - J_prev r_k + (W - J_prev V) α`` with
    ``α = argmin ‖P (V α + r_k)‖``; when the window converges
    ``J_prev ← J_prev + (W - J_prev V) R^{-1} Qᵀ P``.  With ``J_prev = 0`` the
    first window is identical to IQN-ILS without reuse.
    """

    kind = "iqn-imvj"

    def __init__(self, config: AccelerationConfig, layout: VectorLayout):
        super().__init__(config, layout)
        self.reuse_windows = 0
        self.jacobian: np.ndarray | None = None

    def _has_model(self) -> bool:
        return self.V.shape[1] > 0 or self.jacobian is not None

    def _quasi_newton_step(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> np.ndarray:
        if self.jacobian is None:
            if self._has_prior():
                return x_tilde - self._prior(r) + (self.W - self._prior(self.V)) @ self._alpha(r)
            return x_tilde + self.W @ self._alpha(r)
        step = -(self.jacobian @ r)
        if self.V.shape[1]:
            step += (self.W - self.jacobian @ self.V) @ self._alpha(r)
        return x_tilde + step

    def _window_converged(self, x: np.ndarray, x_tilde: np.ndarray, r: np.ndarray) -> None:
        self._add_columns(r, x_tilde, self.window_info)
        self._filter(self.window_info)
        if self.V.shape[1]:
            w = self.preconditioner.weights
            q, rr = self._least_squares_factors()
            z = sla.solve_triangular(rr, q.T) * w[None, :]
            if self.jacobian is None and self._has_prior():
                prior = self._prior(np.eye(self.layout.size))
                self.jacobian = prior + (self.W - prior @ self.V) @ z
            elif self.jacobian is None:
                self.jacobian = self.W @ z
            else:
                self.jacobian = self.jacobian + (self.W - self.jacobian @ self.V) @ z
        self._start_new_window()

    def _state(self) -> dict[str, Any]:
        state = super()._state()
        state["jacobian"] = None if self.jacobian is None else self.jacobian.copy()
        return state

    def _load_state(self, state: dict[str, Any]) -> None:
        super()._load_state(state)
        jac = state["jacobian"]
        n = self.layout.size
        self.jacobian = None if jac is None else np.array(jac, dtype=float).reshape(n, n)


_ACCELERATIONS: dict[str, type[Acceleration]] = {
    "none": NoAcceleration, "constant": ConstantRelaxation, "aitken": AitkenRelaxation,
    "iqn-ils": IQNILS, "iqn-imvj": IQNIMVJ,
}


def build_acceleration(config: AccelerationConfig, layout: VectorLayout) -> Acceleration:
    """Create the acceleration named by ``config.type`` for vectors of ``layout``."""
    return _ACCELERATIONS[config.type](config, layout)
