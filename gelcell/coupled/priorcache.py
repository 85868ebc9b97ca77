"""A disk cache of the factorised linearized prior, so that a warm steady run does not compute it.

The linearized prior (:class:`coupling.LinearizedPrior`) is the Newton step of
the coupled map linearised at rest.  Computing it (the field solvers' interface
Jacobians, their composition and one dense LU) costs more than the coupling
iterations it saves in one run; loading it costs a small part of one
iteration (docs/performance.md).  It does not depend on Ca (solver units,
:func:`gelcell.coupled.defaults.reuse_key`), so one entry
serves every run of a scaled problem, and a wrong entry could only cost
iterations: the residual that stops the coupling is the real map's.

* Key: the sha256 of everything the prior depends on (:func:`cache_key`): the
  mesh cache's key (geometry, element sizes, versions), the content of a
  geometry file (its groups name the boundary conditions), every parameter
  except Ca, the device's interface conditions (Robin coefficients, the split
  on Gamma2), the scheme (type, order, accelerated data and their shapes), the
  interface points, :data:`CACHE_FORMAT` (the entry's layout) and
  :data:`PRIOR_FORMAT` (the version of what the code computes: bump it with a
  change of the interface Jacobians or their composition).  Editing a
  docstring or a comment keeps the entries.
* What: steady runs, of the built-in devices and of geometry files; and a
  time-dependent run's priors, one entry per operator (:class:`WindowPriors`,
  keyed also by the participants' ``jacobian_key``, the gel's c0 = a0/dt, and
  by Ca: the steady argument for leaving it out says nothing of the time unit).
* Where: ``$GELCELL_PRIOR_CACHE_DIR``, else ``$XDG_CACHE_HOME/gelcell/priors``,
  else ``~/.cache/gelcell/priors``.  ``GELCELL_PRIOR_CACHE=0`` turns it off.
* Size: an entry is the dense factorisation, uncompressed (tens of MB at the
  default mesh); entries over :data:`MAX_ENTRY_BYTES` are not
  written, and the most recently used ones up to :data:`MAX_BYTES` are kept.

Rank 0 reads and writes; the other ranks receive the arrays.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from typing import Any, Mapping

import numpy as np

from gelcell import diskcache
from gelcell.coupled.defaults import reuse_key
from gelcell.geometry import meshcache

__all__ = ["CACHE_FORMAT", "PRIOR_FORMAT", "MAX_BYTES", "MAX_ENTRY_BYTES", "MAX_RUN_BYTES", "WindowPriors",
           "cache_dir", "cache_key", "enabled", "load", "store"]

#: version of the entry layout; bump it when that changes
CACHE_FORMAT = 1
#: an entry larger than this is not written
MAX_ENTRY_BYTES = 256 * 2**20
#: the most recently used entries kept, together at most this size
MAX_BYTES = 2 * 2**30
#: what one time-dependent run writes at most (:class:`WindowPriors`)
MAX_RUN_BYTES = MAX_BYTES // 2
#: version of the prior the code computes (the solvers' interface Jacobians, the device's data and
#: their composition): bump it when a change of that code changes a prior
PRIOR_FORMAT = 1
_ARRAYS = {"C", "Z", "A", "lu", "piv"}
_ENTRY_NAME = re.compile(r"^(shear|normal|file)-[0-9a-f]{64}\.npz$")


def enabled() -> bool:
    """False if ``GELCELL_PRIOR_CACHE=0`` (always compute the prior)."""
    return diskcache.enabled("GELCELL_PRIOR_CACHE")


def cache_dir() -> str:
    """``$GELCELL_PRIOR_CACHE_DIR``, else ``$XDG_CACHE_HOME/gelcell/priors``, else ``~/.cache/gelcell/priors``."""
    return os.environ.get("GELCELL_PRIOR_CACHE_DIR") or os.path.join(diskcache.cache_root(), "priors")


def _points_hash(scheme: Any) -> str:
    h = hashlib.sha256()
    for name in scheme.layout.names:
        d = scheme.data[name]
        for who in (d.writer,) + tuple(d.readers):
            h.update(np.ascontiguousarray(scheme.points(who, d.mesh), dtype=float).tobytes())
    return h.hexdigest()


def _file_hash(params: Any) -> str | None:
    if params.case != "file":
        return None
    with open(params.geometry.file, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def cache_key(device: Any, scheme: Any, operator: Any = None) -> str:
    """sha256 (hex) of a canonical JSON of everything the linearized prior of ``scheme`` depends on;
    ``operator``: a time-dependent run's ``coupling.operator_key`` (then Ca is part of the key too)."""
    return _hash(_key_data(device, scheme), device, operator)


def _hash(data: dict, device: Any, operator: Any) -> str:
    if operator is not None:
        data = {**data, "window": {"operator": repr(tuple(operator)), "ca": repr(device.params.physics.ca)}}
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _key_data(device: Any, scheme: Any) -> dict:
    params = device.params
    return {"format": CACHE_FORMAT, "prior_format": PRIOR_FORMAT, "mesh": meshcache.cache_key(params),
            "geometry_file": _file_hash(params),
            "problem": reuse_key(params),
            "interfaces": {"alpha_n": repr(device.alpha_n), "alpha_t": repr(device.alpha_t),
                           "gamma2": device.gamma2, "kappa": repr(device.kappa)},
            "scheme": {"type": scheme.scheme_name, "order": list(scheme.order),
                       "data": [[n, list(scheme.values[n].shape), scheme.data[n].mapping]
                                for n in scheme.layout.names]},
            "points": _points_hash(scheme)}


def _cached(device: Any) -> bool:
    return enabled() and not device.transient


def _path(device: Any, scheme: Any) -> str:
    return _entry_path(device, cache_key(device, scheme))


def _entry_path(device: Any, key: str) -> str:
    return os.path.join(cache_dir(), f"{device.params.case}-{key}.npz")


def _to_npz(state: Mapping[str, Any]) -> dict:
    out = {k: v for k, v in state.items() if k != "lu"}
    out["lu"], out["piv"] = state["lu"]
    out["format"] = np.array(CACHE_FORMAT)
    return out


def _from_npz(data: Any) -> dict:
    """The prior's state; ValueError if the entry is not a complete, finite one of this format."""
    if int(data["format"]) != CACHE_FORMAT or not {"lu", "piv"} <= set(data.files) <= _ARRAYS | {"format"}:
        raise ValueError("not a prior entry of this format")
    arrays = {k: np.array(data[k]) for k in data.files if k != "format"}
    if not all(np.all(np.isfinite(a)) for a in arrays.values()):
        raise ValueError("non-finite entries")
    lu, piv = arrays.pop("lu"), arrays.pop("piv")
    n = lu.shape[0]
    inner_ok = ("A" in arrays and arrays["A"].shape == (n, n)) or (
        "C" in arrays and "Z" in arrays and arrays["Z"].shape == (n, arrays["C"].shape[0])
        and arrays["C"].shape[1] == n)
    if lu.shape != (n, n) or piv.shape != (n,) or not inner_ok:
        raise ValueError("inconsistent shapes")
    return {**arrays, "lu": (lu, piv)}


def load(device: Any, scheme: Any, comm: Any) -> dict | None:
    """The cached prior state of ``scheme`` (:meth:`coupling.LinearizedPrior.load_state`) or None, on
    every rank (collective)."""
    return _read(_path(device, scheme), comm) if _cached(device) else None


def store(device: Any, scheme: Any, state: Mapping[str, Any], comm: Any) -> None:
    """Write the prior state of ``scheme`` (rank 0; skipped if too large or if writing fails)."""
    if _cached(device):
        _write(_path(device, scheme), state, comm)


class WindowPriors:
    """The disk cache of a time-dependent run's priors, one entry per operator: the ``store`` of its
    :class:`coupling.LinearizedPrior` (``load`` collective, ``save`` on rank 0).

    One run writes at most :data:`MAX_RUN_BYTES`: an adaptive run's tens of operators (70 MB
    each at the default mesh) would otherwise evict every other entry, its own first ones too."""

    def __init__(self, device: Any, scheme: Any, comm: Any):
        self._device, self._comm = device, comm
        self._data = _key_data(device, scheme)          # the run's part of every key, hashed once
        self.written = 0

    def _path(self, operator: Any) -> str:
        return _entry_path(self._device, _hash(self._data, self._device, operator))

    def load(self, operator: Any) -> dict | None:
        return _read(self._path(operator), self._comm)

    def save(self, operator: Any, state: Mapping[str, Any]) -> None:
        self.written += _write(self._path(operator), state, self._comm, MAX_RUN_BYTES - self.written)


def _read(path: str, comm: Any) -> dict | None:
    state = diskcache.read_npz(path, _from_npz) if comm.rank == 0 else None
    return comm.bcast(state, root=0) if comm.size > 1 else state


def _write(path: str, state: Mapping[str, Any], comm: Any, budget: int = MAX_ENTRY_BYTES) -> int:
    """Write one entry on rank 0 if it fits ``budget`` and :data:`MAX_ENTRY_BYTES`; its size, or 0."""
    if comm.rank != 0:
        return 0
    arrays = _to_npz(state)
    size = sum(a.nbytes for a in arrays.values())
    if size > min(budget, MAX_ENTRY_BYTES):
        return 0
    if not diskcache.write_npz(path, arrays, compressed=False):     # dense floats do not compress
        return 0
    diskcache.prune(os.path.dirname(path), _ENTRY_NAME, max_entries=1000, max_bytes=MAX_BYTES)
    return size
