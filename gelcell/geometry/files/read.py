"""Reading a geometry file's physical groups and topology with gmsh (no meshing).

:func:`read_geometry` opens a ``.geo`` or ``.msh`` file in a gmsh session
and returns what the analysis needs as plain data (:class:`GeometryInfo`,
the same on every rank), cached per file version (path, modification time,
size).
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from femtools.gmshimport import gmsh_session, import_gmsh
from gelcell.case import FileGeometry
from gelcell.errors import ParameterError
from gelcell.geometry.files.screen import check_geo_statements

__all__ = ["GeometryInfo", "ELEMENT_TYPES", "read_geometry", "file_version"]

#: gmsh element types gelcell takes from a .msh file: points, 2- and 3-node lines, 3- and 6-node triangles
ELEMENT_TYPES = {15: "point", 1: "2-node line", 8: "3-node line", 2: "3-node triangle", 9: "6-node triangle"}


@dataclasses.dataclass
class GeometryInfo:
    """What the checks and the layout need from a geometry file (plain data, the same on every rank)."""

    path: str
    groups: list            #: (dim, name, [entities])
    adjacent: dict          #: curve -> [surfaces it bounds]
    curve_points: dict      #: curve -> (N, 2) sample points along it, in order
    curve_ends: dict        #: curve -> [boundary point tags]
    surface_polygons: dict  #: surface -> list of closed (N, 2) loops
    element_types: list     #: gmsh element types present (.msh)
    max_dim: int
    element_order: int
    scale: float


# --------------------------------------------------------------------------- reading
_CACHE: dict = {}


def file_version(path: str):
    st = os.stat(path)
    return (os.path.abspath(path), st.st_mtime_ns, st.st_size)


def _samples(curve: int, n: int = 64, from_mesh: bool = False) -> np.ndarray:
    """Points along a curve in order: from its parametrisation, or (``from_mesh``, a .msh file's
    discrete curve) its mesh nodes ordered by walking its line elements."""
    gmsh = import_gmsh()
    if not from_mesh:
        lo, hi = gmsh.model.getParametrizationBounds(1, curve)
        t = np.linspace(lo[0], hi[0], n)
        return np.asarray(gmsh.model.getValue(1, curve, t)).reshape(-1, 3)[:, :2]
    tags, coords, _ = gmsh.model.mesh.getNodes(1, curve, includeBoundary=True)
    x = np.asarray(coords).reshape(-1, 3)[:, :2]
    if x.shape[0] < 2:
        return x
    # order the nodes by walking the curve's line elements
    types, _, nodes = gmsh.model.mesh.getElements(1, curve)
    index = {int(t): i for i, t in enumerate(tags)}
    edges = []
    for et, nd in zip(types, nodes):
        k = 3 if et == 8 else 2
        nd = np.asarray(nd).reshape(-1, k)
        edges += [(index[int(a)], index[int(b)]) for a, b in nd[:, :2]]
    if not edges:
        return x
    nxt: dict = {}
    for a, b in edges:
        nxt.setdefault(a, []).append(b)
        nxt.setdefault(b, []).append(a)
    start = next((v for v, w in nxt.items() if len(w) == 1), edges[0][0])
    order, prev, cur = [start], None, start
    while True:
        cand = [w for w in nxt[cur] if w != prev and w not in order[-2:]]
        if not cand or len(order) > len(nxt):
            break
        prev, cur = cur, cand[0]
        if cur == start:
            break
        order.append(cur)
    return x[order]


def _loops(surface: int, points: dict) -> list:
    """Closed boundary loops of a surface as point arrays (curves chained by their end points)."""
    gmsh = import_gmsh()
    pieces = []
    for _, c in gmsh.model.getBoundary([(2, surface)], combined=False, oriented=False):
        pieces.append(points[abs(c)])
    loops, tol = [], None
    while pieces:
        loop = list(pieces.pop(0))
        tol = tol or 1e-7 * max(1.0, float(np.abs(loop).max()))
        for _ in range(len(pieces) + 1):
            if np.linalg.norm(np.asarray(loop[0]) - loop[-1]) <= tol and len(loop) > 2:
                break
            for i, p in enumerate(pieces):
                if np.linalg.norm(p[0] - loop[-1]) <= tol:
                    loop += list(p[1:])
                elif np.linalg.norm(p[-1] - loop[-1]) <= tol:
                    loop += list(p[::-1][1:])
                else:
                    continue
                pieces.pop(i)
                break
            else:
                break
        loops.append(np.asarray(loop))
    return loops


def _read_with_gmsh(path: str) -> GeometryInfo:
    with gmsh_session() as gmsh:
        try:
            gmsh.open(path)
        except Exception as exc:
            raise ParameterError(f"geometry file {path!r}: gmsh cannot read it: {exc}") from None
        is_mesh = path.lower().endswith(".msh")
        entities = gmsh.model.getEntities()
        max_dim = max((d for d, _ in entities), default=-1)
        groups = []
        for dim, tag in gmsh.model.getPhysicalGroups():
            name = gmsh.model.getPhysicalName(dim, tag) or str(tag)
            groups.append((dim, name, [int(e) for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag)]))
        adjacent, points, ends = {}, {}, {}
        for _, c in gmsh.model.getEntities(1):
            up, down = gmsh.model.getAdjacencies(1, c)
            adjacent[c] = [int(s) for s in up]
            ends[c] = [int(p) for p in down]
            points[c] = _samples(c, from_mesh=is_mesh)
        polygons = {s: _loops(s, points) for _, s in gmsh.model.getEntities(2)}
        types = [int(t) for t in gmsh.model.mesh.getElementTypes()] if is_mesh else []
        order = int(gmsh.option.getNumber("Mesh.ElementOrder"))
        if gmsh.option.getNumber("Mesh.RecombineAll"):
            types.append(3)     # quadrilaterals requested
        allpts = np.vstack([p for p in points.values() if len(p)]) if points else np.zeros((1, 2))
        scale = float(np.ptp(allpts, axis=0).max()) or 1.0
        return GeometryInfo(path=path, groups=groups, adjacent=adjacent, curve_points=points, curve_ends=ends,
                            surface_polygons=polygons, element_types=sorted(set(types)), max_dim=max_dim,
                            element_order=order, scale=scale)


def read_geometry(path: str) -> GeometryInfo:
    """Physical groups and topology of a geometry file (cached per file version)."""
    FileGeometry(file=path)          # raises ParameterError for a bad path
    if path.lower().endswith(".geo"):
        check_geo_statements(path)   # before gmsh sees it: nothing that runs commands or touches files
    key = file_version(path)
    if key not in _CACHE:
        _CACHE[key] = _read_with_gmsh(os.path.abspath(path))
    return _CACHE[key]
