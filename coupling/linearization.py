"""The coupled map linearised from the participants' own Jacobians, and the Newton prior it gives.

A participant that can linearise itself implements ``jacobian()``: for each
pair (output data, input data) the dense derivative of the output's values
with respect to the input's, on its own points, flattened as the data are
(point by point, component by component)::

    {("Gamma1/velocity", "Gamma1/gel_traction"): J,  ...}   # J: (N_out dim_out, N_in dim_in)

Pairs left out are zero (an output absent from every pair does not depend on
the inputs).  :func:`coupled_jacobian` composes these derivatives along one
sweep of a scheme, with the data mappings, into ``A = dG/dx`` of the
fixed-point map ``x -> G(x)`` on the accelerated vector.

:class:`LinearizedPrior` turns ``A`` into the quasi-Newton prior
``J0 = I - (I - A)^-1`` (the acceleration's ``surrogate`` hook): in the
directions its secant columns do not span, IQN then takes the Newton step
``x + (I - A)^-1 r`` instead of the plain fixed-point step ``x~``.  For an
affine map whose participants report their exact derivatives, the first step
is the fixed point; for a mildly nonlinear one (the participants linearised
at rest) each step removes all but the nonlinear remainder, and the secant
columns take care of that.

Cost.  In a serial scheme every accelerated data depends on ``x`` only
through what the participants after the first one read: the first one's
outputs and the accelerated data read before they are written again, ``z``.
So ``A = C Z`` (``C = d(final)/dz``, ``Z = dz/dx``), and when ``z`` is
shorter than ``x`` the prior factorises ``I - Z C`` instead of ``I - A``
(Woodbury): ``(I - A)^-1 = I + C (I - Z C)^-1 Z``.  Derivatives are carried
per (data, variable) block, so identity and mapping blocks stay sparse and
zero blocks are never multiplied.

Operators that change.  A participant whose linearisation changes during a
run (a time step of another size or scheme) says so with ``jacobian_key()``,
a hashable that changes with its ``jacobian()``; participants without it are
taken as constant.  :class:`LinearizedPrior` keeps the factorisations of the
last few keys and factorises anew for a key it does not hold.
"""

from __future__ import annotations

import time
import warnings
from collections import OrderedDict
from typing import Any, Hashable, Mapping

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

__all__ = ["coupled_jacobian", "operator_key", "LinearizedPrior"]

Blocks = dict[str, Any]           # variable name -> (size of the data, size of the variable) matrix


def _participant_jacobian(scheme: Any, name: str) -> Mapping[tuple[str, str], np.ndarray]:
    participant = scheme.participants[name]
    method = getattr(participant, "jacobian", None)
    if not callable(method):
        raise TypeError(f"participant {name!r} has no jacobian(): the linearized prior needs every "
                        f"participant's derivatives (coupling.linearization)")
    blocks = method()
    if not isinstance(blocks, Mapping):
        raise TypeError(f"participant {name!r}: jacobian() must return a dict (output, input) -> array, "
                        f"got {type(blocks).__name__}")
    return blocks


def operator_key(scheme: Any) -> tuple[Hashable, ...]:
    """Every participant's ``jacobian_key()`` in the scheme's order (None for one without it)."""
    keys = []
    for name in scheme.order:
        method = getattr(scheme.participants[name], "jacobian_key", None)
        keys.append(method() if callable(method) else None)
    return tuple(keys)


def _size(scheme: Any, name: str) -> int:
    return int(np.prod(scheme.values[name].shape))


def _identity(scheme: Any, names) -> dict[str, Blocks]:
    return {n: {n: sp.identity(_size(scheme, n), format="csr")} for n in names}


def _add(blocks: Blocks, var: str, M: Any) -> None:
    total = blocks[var] + M if var in blocks else M
    blocks[var] = total if sp.issparse(total) else np.asarray(total)    # sparse + dense is an np.matrix


def _product(J: np.ndarray, M: Any) -> np.ndarray:
    return np.asarray((M.T @ J.T).T) if sp.issparse(M) else J @ M


def _sweep(scheme: Any, participants: list[str], carry: dict[str, Blocks]) -> dict[str, Blocks]:
    """Carry the derivatives of every data along ``participants`` (serial: newest values)."""
    carry = dict(carry)
    dim = {name: scheme.values[name].shape[1] for name in scheme.data}
    written: dict[str, Blocks] = {}
    for p in participants:
        reads, writes = scheme._reads[p], scheme._writes[p]
        # inputs on the reader's points (the data mapping, per component); outputs on its own
        inputs: dict[str, Blocks] = {}
        rows: dict[str, int] = {}
        for d in reads:
            P = sp.kron(sp.csr_matrix(scheme.mapping(d, p).matrix), sp.identity(dim[d]), format="csr")
            inputs[d] = {v: (P @ M if sp.issparse(M) else np.asarray(P @ M)) for v, M in carry.get(d, {}).items()}
            rows[d] = P.shape[0]
        outputs: dict[str, Blocks] = {d: {} for d in writes}
        for (out, inp), J in _participant_jacobian(scheme, p).items():
            if out not in writes:
                raise ValueError(f"participant {p!r}: jacobian() has output {out!r}, which it does not "
                                 f"write; it writes {sorted(writes)}")
            if inp not in reads:
                raise ValueError(f"participant {p!r}: jacobian() has input {inp!r}, which it does not "
                                 f"read; it reads {sorted(reads)}")
            J = np.asarray(J, dtype=float)
            expected = (_size(scheme, out), rows[inp])
            if J.shape != expected:
                raise ValueError(f"participant {p!r}: jacobian()[({out!r}, {inp!r})] has shape {J.shape}, "
                                 f"expected {expected} (values flattened point by point)")
            for v, M in inputs[inp].items():
                _add(outputs[out], v, _product(J, M))
        if scheme.serial:
            carry.update(outputs)
        else:
            written.update(outputs)
    return carry if scheme.serial else {**carry, **written}


def _dense(scheme: Any, blocks: dict[str, Blocks], rows: list[str], columns: list[str]) -> np.ndarray:
    """The block matrix d(rows)/d(columns) as one dense array."""
    r0 = np.cumsum([0] + [_size(scheme, n) for n in rows])
    c0 = np.cumsum([0] + [_size(scheme, n) for n in columns])
    out = np.zeros((r0[-1], c0[-1]))
    for i, r in enumerate(rows):
        for j, c in enumerate(columns):
            M = blocks.get(r, {}).get(c)
            if M is not None:
                out[r0[i]:r0[i + 1], c0[j]:c0[j + 1]] = M.toarray() if sp.issparse(M) else M
    return out


def coupled_jacobian(scheme: Any) -> np.ndarray:
    """``A = dG/dx`` of an implicit scheme's fixed-point map, from the participants' ``jacobian()``.

    One symbolic sweep: every data's value is carried as its derivatives with
    respect to ``x`` (the accelerated vector, in the scheme's layout).  Serial
    schemes read the newest values, so a data written earlier in the sweep is
    carried forward, exactly as the real sweep does; parallel schemes read the
    values of ``x`` for every input.

    Raises:
        TypeError: If a participant has no ``jacobian()``.
        ValueError: If a block names unknown data, data the participant does not
            read or write, or has the wrong shape.
    """
    names = list(scheme.layout.names)
    final = _sweep(scheme, list(scheme.order), _identity(scheme, names))
    return _dense(scheme, final, names, names)


def _inner_variables(scheme: Any) -> list[str]:
    """``z`` of a serial sweep: the first participant's outputs, then the accelerated data read later
    before they are written again."""
    first, rest = scheme.order[0], scheme.order[1:]
    z = list(scheme._writes[first])
    fresh = set(z)
    for p in rest:
        z += [d for d in scheme._reads[p] if d in scheme.layout.names and d not in fresh and d not in z]
        fresh |= set(scheme._writes[p])
    return z


class LinearizedPrior:
    """Quasi-Newton prior ``J0 r = r - (I - A)^-1 r`` from the participants' linearisations.

    ``A`` (:func:`coupled_jacobian`) is computed at the first use, once the
    participants have been set up for the solve, and kept: it belongs to one
    operator, named by :func:`operator_key` (a steady run, or time windows of
    one step size and scheme).  When the key changes, the factorisation of the
    new key is taken from the last ``kept`` ones, else from ``store``, else
    computed.  Serial schemes factorise the shorter ``I - Z C`` when the inner
    vector ``z`` is shorter than ``x`` (module docstring).

    ``store``: where factorisations outlive the run (e.g. a disk cache), an
    object with ``load(key) -> state | None`` and ``save(key, state)``, the
    states those of :meth:`state`; both are called on every rank, and ``load``
    must return the same on each.  A state that is not this operator's can
    only cost iterations: the coupling stops on the real map's residual.

    Attributes:
        setup_time: seconds spent on the derivatives, the factorisations and the loads.
        factorizations: how many factorisations were computed.
        loaded: how many were taken from ``store``.
    """

    accepts_matrices = True      # inverse_jacobian takes the secant columns in one call

    def __init__(self, scheme: Any, kept: int = 4, store: Any = None):
        self._scheme = scheme
        self.store = store
        self._factors: dict[str, Any] | None = None
        self._key: tuple | None = None
        self._kept: OrderedDict[tuple, dict[str, Any]] = OrderedDict()
        self.kept = int(kept)
        self.setup_time = 0.0
        self.factorizations = 0
        self.loaded = 0

    @property
    def jacobian(self) -> np.ndarray | None:
        """``A`` (dense) once the prior has been set up, else None."""
        f = self._factors
        if f is None:
            return None
        return f["A"] if "A" in f else f["C"] @ f["Z"]

    def _factorize(self) -> None:
        t0 = time.perf_counter()
        scheme = self._scheme
        names = list(scheme.layout.names)
        z = _inner_variables(scheme) if scheme.serial and len(scheme.order) > 1 else None
        inner = sum(_size(scheme, n) for n in z) if z is not None else scheme.layout.size
        self.check_memory(scheme.layout.size, min(inner, scheme.layout.size))
        if z is not None and inner < scheme.layout.size:
            first = _sweep(scheme, [scheme.order[0]], _identity(scheme, names))
            dz = {n: first[n] if n in scheme._writes[scheme.order[0]] else {n: sp.identity(_size(scheme, n))}
                  for n in z}
            final = _sweep(scheme, list(scheme.order[1:]), _identity(scheme, z))
            C = _dense(scheme, final, names, z)
            Z = _dense(scheme, dz, z, names)
            K = np.eye(Z.shape[0]) - Z @ C
            self._check(C, Z)
            self._factors = {"C": C, "Z": Z, "lu": self._lu(K)}
        else:
            A = coupled_jacobian(scheme)
            self._check(A)
            self._factors = {"A": A, "lu": self._lu(np.eye(A.shape[0]) - A)}
        self.setup_time += time.perf_counter() - t0
        self.factorizations += 1

    def _current(self) -> dict[str, Any]:
        """The factorisation of the operator the participants linearise now (kept, or computed)."""
        key = operator_key(self._scheme)
        if self._factors is None or key != self._key:
            if self._factors is not None:
                self._kept[self._key] = self._factors
            self._factors = self._kept.pop(key, None)
            self._key = key
            if self._factors is None:
                self._load_or_factorize(key)
            while len(self._kept) >= max(self.kept, 1):
                self._kept.popitem(last=False)             # the least recently used
        return self._factors

    def _load_or_factorize(self, key: tuple) -> None:
        """The factorisation of ``key`` from ``store``, else computed (and given to ``store``)."""
        if self.store is not None:
            t0 = time.perf_counter()
            state = self.store.load(key)
            if state is not None and self._rows(state) == self._scheme.layout.size:
                self._factors = dict(state)
                self.loaded += 1
                self.setup_time += time.perf_counter() - t0
                return
        self._factorize()
        if self.store is not None:
            self.store.save(key, self.state())

    @staticmethod
    def _rows(state: Mapping[str, Any]) -> int:
        return state["A"].shape[0] if "A" in state else state["C"].shape[0]

    @staticmethod
    def _lu(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")          # a singular matrix is reported below, by name
            lu = sla.lu_factor(M, check_finite=False)
        pivots = np.abs(np.diag(lu[0]))
        if pivots.size and not pivots.min() > 1e-13 * max(pivots.max(), 1.0):
            raise ValueError("linearized prior: I - A is singular (the linearised coupled map has an eigenvalue 1, "
                             "so its fixed point is not unique); use another prior")
        return lu

    @staticmethod
    def check_memory(n: int, m: int) -> None:
        """Refuse before allocating when the dense system of ``n`` unknowns (inner vector ``m``) would
        not fit: MemoryError above half of MemAvailable (Linux; elsewhere no check)."""
        need = 8.0 * (2 * n * m + 3 * m * m) if m < n else 8.0 * 3 * n * n      # C, Z, I - Z C, LU (or A)
        try:
            with open("/proc/meminfo") as fh:
                available = next(float(line.split()[1]) * 1024 for line in fh if line.startswith("MemAvailable:"))
        except (OSError, StopIteration, ValueError):
            return
        if need > 0.5 * available:
            raise MemoryError(f"linearized prior: its dense interface system ({n} unknowns, inner {m}) needs about "
                              f"{need / 2**30:.1f} GiB, more than half of the {available / 2**30:.1f} GiB available; "
                              f"use coupling.acceleration.jacobian_prior = 'none' at this size")

    @staticmethod
    def _check(*arrays: np.ndarray) -> None:
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise ValueError("linearized prior: a participant's jacobian() has NaN or Inf entries")

    def state(self) -> dict[str, Any] | None:
        """The factorised map (shared, not copied: it is never modified), or None before first use."""
        return None if self._factors is None else dict(self._factors)

    def load_state(self, state: Mapping[str, Any] | None) -> None:
        """Use the factorisation of another solve with the same linearised map (e.g. the next solve of a sweep)."""
        if state is None:
            return
        n = self._scheme.layout.size
        rows = self._rows(state)
        if rows != n:
            raise ValueError(f"linearized prior: the state is for {rows} unknowns, this scheme has {n}")
        self._factors = dict(state)
        self._key = operator_key(self._scheme)

    def inverse_jacobian(self, r: np.ndarray) -> np.ndarray:
        """``J0 r``: the part of ``r`` the Newton step on the linearised map does not take (a vector,
        or a matrix of them as columns)."""
        f = self._current()
        if "A" in f:
            return r - sla.lu_solve(f["lu"], r, check_finite=False)
        # r - (I + C K^-1 Z) r
        return -(f["C"] @ sla.lu_solve(f["lu"], f["Z"] @ r, check_finite=False))
