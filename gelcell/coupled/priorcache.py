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
* What: steady runs, of the built-in devices and of geometry files; a
  time-dependent run's prior depends on its step.
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

__all__ = ["CACHE_FORMAT", "PRIOR_FORMAT", "MAX_BYTES", "MAX_ENTRY_BYTES", "cache_dir", "cache_key", "enabled",
           "load", "store"]

#: version of the entry layout; bump it when that changes
CACHE_FORMAT = 1
#: an entry larger than this is not written
MAX_ENTRY_BYTES = 256 * 2**20
#: the most recently used entries kept, together at most this size
MAX_BYTES = 2 * 2**30
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


def cache_key(device: Any, scheme: Any) -> str:
    """sha256 (hex) of a canonical JSON of everything the linearized prior of ``scheme`` depends on."""
    params = device.params
    data = {"format": CACHE_FORMAT, "prior_format": PRIOR_FORMAT, "mesh": meshcache.cache_key(params),
            "geometry_file": _file_hash(params),
            "problem": reuse_key(params),
            "interfaces": {"alpha_n": repr(device.alpha_n), "alpha_t": repr(device.alpha_t),
                           "gamma2": device.gamma2, "kappa": repr(device.kappa)},
            "scheme": {"type": scheme.scheme_name, "order": list(scheme.order),
                       "data": [[n, list(scheme.values[n].shape), scheme.data[n].mapping]
                                for n in scheme.layout.names]},
            "points": _points_hash(scheme)}
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _cached(device: Any) -> bool:
    return enabled() and not device.transient


def _path(device: Any, scheme: Any) -> str:
    return os.path.join(cache_dir(), f"{device.params.case}-{cache_key(device, scheme)}.npz")


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
    if not _cached(device):
        return None
    state = diskcache.read_npz(_path(device, scheme), _from_npz) if comm.rank == 0 else None
    return comm.bcast(state, root=0) if comm.size > 1 else state


def store(device: Any, scheme: Any, state: Mapping[str, Any], comm: Any) -> None:
    """Write the prior state of ``scheme`` (rank 0; skipped if too large or if writing fails)."""
    if not _cached(device) or comm.rank != 0:
        return
    arrays = _to_npz(state)
    if sum(a.nbytes for a in arrays.values()) > MAX_ENTRY_BYTES:
        return
    path = _path(device, scheme)
    if diskcache.write_npz(path, arrays, compressed=False):     # dense floats do not compress
        diskcache.prune(os.path.dirname(path), _ENTRY_NAME, max_entries=1000, max_bytes=MAX_BYTES)
