"""A disk cache of the meshed built-in devices, so that a warm run neither imports gmsh nor meshes.

Importing gmsh (it loads libgmsh) and meshing a built-in device are paid by
every process otherwise.  An entry holds the raw arrays of the meshed gmsh
model (:class:`femtools.mesh.ModelArrays`), not dolfinx meshes: the meshes
(and their partition on any number of ranks) are built from them exactly as
from a fresh gmsh model, so a hit gives the same meshes as a miss.

* Key: the sha256 of everything the mesh depends on (:func:`cache_key`):
  the case, the geometry, the element sizes, the mesh block, the gmsh and
  dolfinx versions, :data:`MESH_FORMAT` (the version of what the meshing
  code produces: bump it with a change of ``gelcell.geometry.builtin_model``
  or ``femtools.mesh`` that changes a mesh) and :data:`CACHE_FORMAT` (the
  entry's layout).  Editing a docstring or a comment keeps the entries.
* Where: ``$GELCELL_CACHE_DIR``, else ``$XDG_CACHE_HOME/gelcell/meshes``, else
  ``~/.cache/gelcell/meshes``.  ``GELCELL_MESH_CACHE=0`` turns it off.
* Only the built-in devices (``shear``, ``normal``) are cached: a geometry
  file's content and the options it sets are not part of any key.
* Size: an entry is a few 100 kB (compressed) at the default sizes; the
  :data:`MAX_ENTRIES` most recently used entries are kept (a hit touches its
  entry), so entries of edited code or old parameters do not pile up.

Only rank 0 calls :func:`load` and :func:`store`.  The cache never fails a run:
an entry that cannot be read is a miss (and is overwritten), a directory that
cannot be written is skipped.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.util
import json
import os
import re

import numpy as np

from femtools.mesh import ModelArrays
from gelcell import diskcache
from gelcell.case import CaseParameters

__all__ = ["CACHE_FORMAT", "MESH_FORMAT", "CACHED_CASES", "MAX_ENTRIES", "cache_dir", "cache_key", "cache_path",
           "enabled", "load", "store"]

#: version of the entry layout below; bump it when that changes
CACHE_FORMAT = 1
#: cases whose mesh is cached (a geometry file's content is not keyed: it is meshed every time)
CACHED_CASES = ("shear", "normal")
#: entries kept when a new one is written: the most recently used ones
MAX_ENTRIES = 100
#: version of the meshes the code makes from a case (geometry, tags, size fields, extraction):
#: bump it when a change of the meshing code changes a mesh
MESH_FORMAT = 1
#: the name of an entry (pruning removes nothing else from a directory the user chose)
_ENTRY_NAME = re.compile(r"^(%s)-[0-9a-f]{64}\.npz$" % "|".join(CACHED_CASES))


def enabled() -> bool:
    """False if ``GELCELL_MESH_CACHE=0`` (always mesh)."""
    return diskcache.enabled("GELCELL_MESH_CACHE")


def cache_dir() -> str:
    """``$GELCELL_CACHE_DIR``, else ``$XDG_CACHE_HOME/gelcell/meshes``, else ``~/.cache/gelcell/meshes``."""
    return os.environ.get("GELCELL_CACHE_DIR") or os.path.join(diskcache.cache_root(), "meshes")


def _gmsh_version() -> str:
    """The gmsh API version, read from gmsh.py's text: importing gmsh is what a hit avoids."""
    spec = importlib.util.find_spec("gmsh")
    if spec is None or spec.origin is None:
        return "none"
    with open(spec.origin, encoding="utf-8", errors="replace") as f:
        found = re.search(r'^GMSH_API_VERSION\s*=\s*"([^"]*)"', f.read(), re.MULTILINE)
    return found.group(1) if found else "unknown"


@functools.lru_cache(maxsize=None)
def _environment() -> dict:
    """The part of the key shared by every case of this process: the formats and the versions."""
    import dolfinx
    return {"format": CACHE_FORMAT, "mesh_format": MESH_FORMAT, "gmsh": _gmsh_version(),
            "dolfinx": dolfinx.__version__}


def cache_key(params: CaseParameters) -> str:
    """sha256 (hex) of a canonical JSON of everything the gmsh model of ``params`` depends on.

    Physics values enter only through the element sizes (the Brinkman layer);
    e.g. Ca does not change the key.
    """
    data = {"case": params.case, "with_cell": params.with_cell, "geometry": repr(params.geometry),
            "element_sizes": params.element_sizes(), "mesh": dataclasses.asdict(params.mesh),
            **_environment()}
    text = json.dumps(data, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def cache_path(params: CaseParameters) -> str:
    """The entry file of ``params``: ``<cache_dir>/<case>-<key>.npz``."""
    return os.path.join(cache_dir(), f"{params.case}-{cache_key(params)}.npz")


def _cached(params: CaseParameters) -> bool:
    return enabled() and params.case in CACHED_CASES


def _to_npz(arrays: ModelArrays) -> dict:
    """Flat array dict of an entry: element types in their order, then per type topology and markers."""
    types = list(arrays.topology)
    out = {"format": np.array(CACHE_FORMAT), "x": arrays.x, "types": np.array(types, dtype=np.int64),
           "dims": np.array([arrays.dims[k] for k in types], dtype=np.int64)}
    for k in types:
        out[f"topology_{k}"] = arrays.topology[k]
        out[f"markers_{k}"] = arrays.markers[k]
    return out


def _from_npz(data) -> ModelArrays:
    """Inverse of :func:`_to_npz`; ValueError if the entry is not a complete one of this format."""
    if int(data["format"]) != CACHE_FORMAT:
        raise ValueError(f"entry format {int(data['format'])}, expected {CACHE_FORMAT}")
    types = [int(k) for k in data["types"]]
    arrays = ModelArrays(x=data["x"], topology={k: data[f"topology_{k}"] for k in types},
                         markers={k: data[f"markers_{k}"] for k in types},
                         dims=dict(zip(types, (int(d) for d in data["dims"]))))
    n = arrays.x.shape[0]
    if arrays.x.ndim != 2 or arrays.x.shape[1] != 3 or not types:
        raise ValueError("bad node array or no elements")
    for k in types:
        top, mark = arrays.topology[k], arrays.markers[k]
        if top.ndim != 2 or mark.shape != (top.shape[0],) or (top.size and int(top.max()) >= n):
            raise ValueError(f"inconsistent arrays of element type {k}")
    return arrays


def load(params: CaseParameters) -> ModelArrays | None:
    """The cached arrays of the device of ``params``, or None (not cached, disabled, or unreadable)."""
    if not _cached(params):
        return None
    return diskcache.read_npz(cache_path(params), _from_npz)


def store(params: CaseParameters, arrays: ModelArrays) -> None:
    """Write the entry of ``params`` atomically (temporary file + rename); skip it if that fails."""
    if not _cached(params):
        return
    path = cache_path(params)
    # compressed: 2.4x smaller, +4 ms to read
    if diskcache.write_npz(path, _to_npz(arrays), compressed=True):
        _prune(os.path.dirname(path))


def _prune(directory: str) -> None:
    """Remove all but the :data:`MAX_ENTRIES` most recently used entries of ``directory``."""
    diskcache.prune(directory, _ENTRY_NAME, MAX_ENTRIES)
