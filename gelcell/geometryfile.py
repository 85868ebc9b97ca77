"""Devices from gmsh geometry files (``.geo`` or ``.msh``) with named physical groups.

The naming convention (docs/geometry-files.md) in short:

* surfaces: ``fluid``, ``gel``, and ``cell`` or ``cell_1``, ``cell_2``, ...
* curves: ``inlet`` / ``inlet_K`` with an optional profile and speed in V0
  units, ``inlet:parabolic:1`` (default) or ``inlet_2:uniform:0.5``;
  ``outlet`` (zero traction), ``wall`` (no slip), ``held`` (gel boundary
  with v_f = 0 and u_s = 0), ``symmetry`` (horizontal or vertical lines),
  ``interface`` / ``interface_K`` (fluid-gel interfaces, coupled as
  Gamma1, Gamma3, Gamma4, ...), optionally ``cell_boundary`` /
  ``cell_K_boundary`` (checked; the gel-cell interfaces are found from the
  surfaces).  ``outlet``, ``wall``, ``held`` and ``symmetry`` also take a
  ``_K`` suffix (merged).

:func:`read_geometry` reads the file's physical groups and topology (no
meshing), checks them (:func:`file_layout` raises one ``ParameterError``
listing every problem, naming the group or entity) and caches the result
per file version; :func:`build_file_model` (rank 0, inside
``gelcell.geometry.build_device``) re-tags the groups with gelcell's facet
and cell tags and meshes a ``.geo`` file with the sizes it gives, times
``mesh.size_factor``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re

import numpy as np

from femtools.gmshimport import gmsh_session, import_gmsh
from gelcell.parameters import ParameterError

__all__ = ["read_geometry", "file_layout", "build_file_model", "GeometryInfo", "SUFFIXES"]

SUFFIXES = (".geo", ".msh")
#: gmsh element types gelcell takes from a .msh file: points, 2- and 3-node lines, 3- and 6-node triangles
_ELEMENT_TYPES = {15: "point", 1: "2-node line", 8: "3-node line", 2: "3-node triangle", 9: "6-node triangle"}
_KINDS = ("inlet", "outlet", "wall", "held", "symmetry", "interface")
_SURFACE_RE = re.compile(r"^(fluid|gel|cell|cell_(\d+))$")
_CURVE_RE = re.compile(r"^(inlet|outlet|wall|held|symmetry|interface)(?:_(\d+))?(?::(\w+)(?::(.+))?)?$")
_CELL_BOUNDARY_RE = re.compile(r"^cell(?:_(\d+))?_boundary$")
_KNOWN = ["fluid", "gel", "cell", "cell_1", "inlet", "inlet_1", "inlet:parabolic:1", "inlet:uniform:1", "outlet",
          "wall", "held", "symmetry", "interface", "interface_1", "cell_boundary", "cell_1_boundary"]


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


def _key(path: str):
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
    if not isinstance(path, str) or not path:
        raise ParameterError(f"parameter 'geometry.file' = {path!r} must be the path of a .geo or .msh file")
    if not path.lower().endswith(SUFFIXES):
        raise ParameterError(f"parameter 'geometry.file' = {path!r}: a geometry file must end in .geo or .msh")
    if not os.path.isfile(path):
        raise ParameterError(f"parameter 'geometry.file' = {path!r}: no such file")
    key = _key(path)
    if key not in _CACHE:
        _CACHE[key] = _read_with_gmsh(os.path.abspath(path))
    return _CACHE[key]


# --------------------------------------------------------------------------- the convention
@dataclasses.dataclass
class _Parsed:
    surfaces: dict          # "fluid"/"gel" -> [surfaces]; cells: list of (name, [surfaces])
    cells: list
    curves: dict            # kind -> list of (group name, k, [curves], options)
    cell_boundaries: list   # (name, k, [curves])
    owner: dict             # curve -> group name


def _suggest(name: str) -> str:
    close = difflib.get_close_matches(name.split(":")[0], _KNOWN, n=1, cutoff=0.6)
    return f"; did you mean '{close[0]}'?" if close else ""


def _parse_groups(info: GeometryInfo, problems: list) -> _Parsed:
    surfaces = {"fluid": [], "gel": []}
    cells, curves, cell_boundaries = [], {k: [] for k in _KINDS}, []
    owner: dict = {}
    surface_owner: dict = {}
    for dim, name, ents in info.groups:
        text = name.strip()
        if dim == 2:
            m = _SURFACE_RE.match(text)
            if not m:
                problems.append(f"physical surface '{name}': unknown name (surfaces are 'fluid', 'gel', 'cell' "
                                f"or 'cell_1', 'cell_2', ...){_suggest(text)}")
                continue
            for s in ents:
                if s in surface_owner:
                    problems.append(f"surface {s} is in two physical groups: '{surface_owner[s]}' and '{name}'")
                surface_owner[s] = name
            if text in surfaces:
                surfaces[text] += ents
            else:
                cells.append((text, int(m.group(2)) if m.group(2) else 0, list(ents)))
        elif dim == 1:
            m = _CURVE_RE.match(text)
            mb = _CELL_BOUNDARY_RE.match(text)
            if not m and not mb:
                problems.append(f"physical curve '{name}': unknown name (curves are inlet[_K][:parabolic|uniform"
                                f"[:speed]], outlet, wall, held, symmetry, interface[_K], cell[_K]_boundary)"
                                f"{_suggest(text)}")
                continue
            for c in ents:
                if c in owner:
                    problems.append(f"curve {c} is in two physical groups: '{owner[c]}' and '{name}' (a curve "
                                    f"carries one condition)")
                owner[c] = name
            if mb:
                cell_boundaries.append((text, int(mb.group(1)) if mb.group(1) else 0, list(ents)))
                continue
            kind, k, profile, speed = m.group(1), m.group(2), m.group(3), m.group(4)
            options = {}
            if kind == "inlet":
                options["profile"] = profile or "parabolic"
                if options["profile"] not in ("parabolic", "uniform"):
                    problems.append(f"physical curve '{name}': inflow profile '{profile}' must be 'parabolic' or "
                                    f"'uniform'")
                try:
                    options["speed"] = float(speed) if speed is not None else 1.0
                    if not (math.isfinite(options["speed"]) and options["speed"] > 0):
                        raise ValueError
                except ValueError:
                    problems.append(f"physical curve '{name}': inflow speed '{speed}' must be a number > 0 "
                                    f"(in units of V0)")
                    options["speed"] = 1.0
            elif profile is not None:
                problems.append(f"physical curve '{name}': only inlets take options after ':'")
            curves[kind].append((text, int(k) if k else 0, list(ents), options))
        elif dim in (0,):
            continue          # named points are allowed and ignored
        else:
            problems.append(f"physical group '{name}' of dimension {dim}: gelcell devices are 2-D "
                            f"(surfaces and curves)")
    for key in ("fluid", "gel"):
        if not surfaces[key]:
            have = sorted({n for d, n, _ in info.groups if d == 2})
            problems.append(f"missing physical surface '{key}' (the file has surfaces {have}){_suggest(key)}")
    names = [c[0] for c in cells]
    if "cell" in names and len(cells) > 1:
        problems.append(f"physical surfaces {names}: use either one 'cell' or numbered 'cell_1', 'cell_2', ...")
    numbers = sorted(c[1] for c in cells)
    if len(cells) > 1 and numbers != list(range(1, len(cells) + 1)):
        problems.append(f"physical surfaces {names}: number the cells cell_1, cell_2, ... without gaps")
    for kind in ("inlet", "interface"):
        ks = [g[1] for g in curves[kind]]
        if len(ks) != len(set(ks)):
            problems.append(f"physical curves {[g[0] for g in curves[kind]]}: two {kind}s with the same number")
    cells.sort(key=lambda c: c[1])
    for kind in curves:
        curves[kind].sort(key=lambda g: g[1])
    return _Parsed(surfaces, cells, curves, cell_boundaries, owner)


def _symmetry_axis(c: int, p: np.ndarray, scale: float, name: str | None = None):
    """``(horizontal, None)`` for a straight axis-aligned symmetry curve, else ``(None, problem)``."""
    label = f"symmetry curve {c} {_where(p)}" + (f" ('{name}')" if name else "")
    if not _straight(p, scale):
        return None, f"{label} is not straight"
    horizontal = abs(p[0, 1] - p[-1, 1]) <= 1e-9 * scale
    vertical = abs(p[0, 0] - p[-1, 0]) <= 1e-9 * scale
    if not (horizontal or vertical):
        return None, f"{label} is neither horizontal nor vertical: gelcell supports axis-aligned symmetry lines only"
    return horizontal, None


def _straight(points: np.ndarray, scale: float) -> bool:
    a, b = points[0], points[-1]
    t = b - a
    L = np.linalg.norm(t)
    if L == 0:
        return False
    n = np.array([-t[1], t[0]]) / L
    return float(np.abs((points - a) @ n).max()) <= 1e-8 * max(scale, L)


def _inside(point, loops) -> bool:
    """Even-odd rule over all loops of a surface (holes included)."""
    from matplotlib.path import Path
    count = 0
    for loop in loops:
        if len(loop) > 2 and Path(loop).contains_point(point):
            count += 1
    return count % 2 == 1


def _polygon_area_centroid(loops) -> tuple[float, np.ndarray]:
    area, cx, cy = 0.0, 0.0, 0.0
    for loop in loops:
        x, y = loop[:, 0], loop[:, 1]
        x1, y1 = np.roll(x, -1), np.roll(y, -1)
        cr = x * y1 - x1 * y
        a = 0.5 * cr.sum()
        # orient every loop as a boundary of the surface: the outer loop counts positive, holes negative
        sign = 1.0 if a >= 0 else -1.0
        area += sign * a
        cx += sign * ((x + x1) * cr).sum() / 6.0
        cy += sign * ((y + y1) * cr).sum() / 6.0
    return abs(area), np.array([cx, cy]) / area if area else np.zeros(2)


def _components(surfaces: list, info: GeometryInfo) -> list[set]:
    """Connected groups of ``surfaces`` (sharing a curve)."""
    parent = {s: s for s in surfaces}

    def find(s):
        while parent[s] != s:
            parent[s] = parent[parent[s]]
            s = parent[s]
        return s
    for c, up in info.adjacent.items():
        mine = [s for s in up if s in parent]
        for s in mine[1:]:
            parent[find(s)] = find(mine[0])
    comps: dict = {}
    for s in surfaces:
        comps.setdefault(find(s), set()).add(s)
    return list(comps.values())


#: a gap between a cell and another cell or a gel boundary below this fraction of the cell's size is
#: taken as touching
TOUCH = 1e-3


def _distance(points: np.ndarray, polyline: np.ndarray) -> float:
    """Smallest distance from ``points`` to the segments of ``polyline``."""
    if len(polyline) == 0 or len(points) == 0:
        return math.inf
    if len(polyline) == 1:
        return float(np.linalg.norm(points - polyline[0], axis=1).min())
    a, b = polyline[:-1], polyline[1:]
    t = b - a
    ll = np.maximum((t * t).sum(axis=1), 1e-300)
    rel = points[:, None, :] - a[None, :, :]
    s = np.clip((rel * t[None]).sum(axis=2) / ll[None], 0.0, 1.0)
    proj = a[None] + s[..., None] * t[None]
    return float(np.linalg.norm(points[:, None, :] - proj, axis=2).min())


def _where(points: np.ndarray) -> str:
    m = points[len(points) // 2]
    return f"near ({m[0]:.4g}, {m[1]:.4g})"


@dataclasses.dataclass
class FileLayout:
    """The checked content of a geometry file in gelcell's terms."""

    curve_tags: dict        #: gelcell facet tag -> [curves]
    surface_tags: dict      #: gelcell cell tag -> ([surfaces], name)
    layout: object          #: gelcell.boundaries.DeviceLayout
    gel_depth: float        #: gel area / fluid-gel interface length
    enclosed_fluid: bool    #: some fluid region has no outlet (fixed only through an interface)


def _analyse(info: GeometryInfo) -> FileLayout:
    from gelcell.boundaries import DeviceBoundaries, DeviceLayout, SegmentInflow
    from gelcell.geometry import (CellSpec, Tag, cell_region_tag, fluid_interface_name, fluid_interface_tag,
                                  gamma2_name, gamma2_tag, inlet_tag)
    problems: list[str] = []
    where = f"geometry file {info.path!r}"
    if info.max_dim > 2:
        raise ParameterError(f"{where}: it holds volumes (dimension 3); gelcell devices are 2-D")
    bad = [t for t in info.element_types if t not in _ELEMENT_TYPES]
    if bad:
        raise ParameterError(f"{where}: unsupported element type(s) {bad} (gmsh numbers); gelcell takes "
                             f"triangles of order 1 or 2 (types 2, 9) with lines of order 1 or 2 (1, 8)")
    if info.element_order not in (1, 2):
        raise ParameterError(f"{where}: Mesh.ElementOrder = {info.element_order}: gelcell meshes with "
                             f"order 2 (curved P2 triangles); orders 1 and 2 are accepted, not "
                             f"{info.element_order}")
    parsed = _parse_groups(info, problems)
    if problems:
        raise ParameterError(f"{where}:\n" + "\n".join(problems))
    fluid, gel = set(parsed.surfaces["fluid"]), set(parsed.surfaces["gel"])
    cell_of = {s: k for k, (_, _, ents) in enumerate(parsed.cells, start=1) for s in ents}
    region = {**{s: "fluid" for s in fluid}, **{s: "gel" for s in gel}}
    cell_names = {k: name for k, (name, _, _) in enumerate(parsed.cells, start=1)}
    unnamed = sorted(s for s in info.surface_polygons if s not in region and s not in cell_of)
    if unnamed:
        problems.append(f"surface(s) {unnamed} are in no physical group: name each 'fluid', 'gel' or a cell")
    kind_of = {}
    for kind, groups in parsed.curves.items():
        for name, k, ents, opts in groups:
            for c in ents:
                kind_of[c] = (kind, name)
    # ---- every curve by the surfaces it bounds
    gamma2: dict = {}
    cell_sym: dict = {}
    for c, up in sorted(info.adjacent.items()):
        up = [s for s in up if s in region or s in cell_of]
        if not up:
            continue
        sides = {region.get(s, "cell") for s in up}
        cells_here = sorted({cell_of[s] for s in up if s in cell_of})
        kind, gname = kind_of.get(c, (None, parsed.owner.get(c)))
        pts = info.curve_points[c]
        label = f"curve {c} {_where(pts)}"
        if len(cells_here) > 1:
            problems.append(f"cell '{cell_names[cells_here[0]]}' touches cell '{cell_names[cells_here[1]]}' "
                            f"along {label}: cells must be separated by gel")
            continue
        if cells_here:
            name = cell_names[cells_here[0]]
            if "fluid" in sides:
                problems.append(f"cell '{name}' touches the fluid along {label}: a cell must lie inside the gel")
            elif "gel" in sides:
                if kind is not None:
                    problems.append(f"cell '{name}' touches the gel boundary '{gname}' along {label}: a cell "
                                    f"must lie inside the gel")
                gamma2.setdefault(cells_here[0], []).append(c)
            elif kind == "symmetry":
                cell_sym.setdefault(cells_here[0], []).append(c)
            else:
                problems.append(f"cell '{name}': its boundary {label} is not in the gel" +
                                (f" (it is in '{gname}')" if gname else "") +
                                ": only a symmetry line may cut a cell")
            continue
        if sides == {"fluid", "gel"}:
            if kind != "interface":
                problems.append(f"{label} lies between the fluid and the gel but is "
                                + (f"in '{gname}'" if gname else "in no physical group")
                                + ": name it 'interface' (or 'interface_K')")
            continue
        if len(up) > 1:          # between two surfaces of one region: interior
            if kind is not None:
                problems.append(f"{label} of group '{gname}' lies inside the {sides.pop()}, not on its boundary")
            continue
        side = sides.pop()
        if kind == "interface":
            problems.append(f"interface '{gname}': {label} bounds only the {side}: the fluid and gel sides do "
                            f"not share nodes (draw one curve shared by both surfaces, e.g. with "
                            f"BooleanFragments or Coherence)")
        elif kind is None:
            allowed = "inlet, outlet, wall or symmetry" if side == "fluid" else "held or symmetry"
            problems.append(f"{label} bounds the {side} but is in no physical group: name it one of {allowed}"
                            + (f" (it is in '{gname}')" if gname else ""))
        elif side == "fluid" and kind == "held":
            problems.append(f"'{gname}': {label} bounds the fluid; 'held' is for gel boundaries (use 'wall')")
        elif side == "gel" and kind in ("inlet", "outlet", "wall"):
            problems.append(f"'{gname}': {label} bounds the gel; '{kind}' is for fluid boundaries (use 'held')")
    # curves of a group that bound nothing of the device
    for c, name in parsed.owner.items():
        if not [s for s in info.adjacent.get(c, []) if s in region or s in cell_of]:
            problems.append(f"curve {c} of group '{name}' bounds no fluid, gel or cell surface")
    if problems:
        raise ParameterError(f"{where}:\n" + "\n".join(problems))

    # ---- cells: touching and overlapping, their shape.  A gap below TOUCH x the cell's size counts
    # as touching (it could not be meshed); the samples of a curve are joined by straight segments.
    cell_specs = []
    others = {c: kind_of[c][1] for c in kind_of}
    n_cells = len(parsed.cells)
    boundary_pts = {}
    gel_loops = [lp for s in gel for lp in info.surface_polygons[s]]
    cell_loops = {k: [lp for s in ents for lp in info.surface_polygons[s]]
                  for k, (_, _, ents) in enumerate(parsed.cells, start=1)}
    for k in range(1, n_cells + 1):
        curves = gamma2.get(k, []) + cell_sym.get(k, [])
        boundary_pts[k] = np.vstack([info.curve_points[c] for c in curves]) if curves else np.zeros((0, 2))
    for k, (name, _, ents) in enumerate(parsed.cells, start=1):
        curves = gamma2.get(k, []) + cell_sym.get(k, [])
        size = float(np.ptp(boundary_pts[k], axis=0).max()) if len(boundary_pts[k]) else info.scale
        tol = TOUCH * size
        cut = bool(cell_sym.get(k))
        corners = {p for c in curves for p in info.curve_ends[c]}
        for c, gname in others.items():
            if c in cell_sym.get(k, []) or (cut and kind_of[c][0] == "symmetry"):
                continue
            shared = corners & set(info.curve_ends[c])
            gap = _distance(boundary_pts[k], info.curve_points[c])
            if shared or gap <= tol:
                problems.append(f"cell '{name}' touches the boundary '{gname}' {_where(info.curve_points[c])} "
                                f"(gap {gap:.3g}): a cell must lie inside the gel with a gap to its boundaries")
        # a cell crossing a gel boundary: points just outside its surface are not in the gel
        ring = np.vstack([info.curve_points[c] for c in gamma2.get(k, [])]) if gamma2.get(k) else np.zeros((0, 2))
        if len(ring):
            mid = ring.mean(axis=0)
            out = ring - mid
            out /= np.maximum(np.linalg.norm(out, axis=1), 1e-300)[:, None]
            probes = ring + 2 * tol * out
            # (probes in or next to another cell belong to the cell-cell checks below)
            near_other = lambda q: any(_inside(q, cell_loops[j]) or _distance(q[None, :], boundary_pts[j]) <= 4 * tol  # noqa: E731
                                       for j in cell_loops if j != k)
            sym_lines = [info.curve_points[c] for c in cell_sym.get(k, [])]
            near_line = lambda q: any(_distance(q[None, :], ln) <= 4 * tol for ln in sym_lines)  # noqa: E731
            if not all(_inside(q, gel_loops) or near_other(q) or near_line(q) for q in probes[::2]):
                problems.append(f"cell '{name}' overlaps a boundary of the gel (part of it lies outside the gel)")
        loops = [lp for s in ents for lp in info.surface_polygons[s]]
        area, centre = 0.0, np.zeros(2)
        for s in ents:
            a, cen = _polygon_area_centroid(info.surface_polygons[s])
            centre = (centre * area + cen * a) / (area + a) if area + a else centre
            area += a
        sym = []
        for c in cell_sym.get(k, []):
            p = info.curve_points[c]
            horizontal, problem = _symmetry_axis(c, p, info.scale)
            if problem:
                problems.append(problem)
                continue
            comp = 1 if horizontal else 0
            sym.append(comp)
            centre[comp] = p[0, comp]          # the whole (mirrored) cell is centred on the line
        # the nominal circle: centred on the centroid (on the symmetry line of a cut cell), through the
        # boundary point farthest from it (exact for a circular cell)
        radius = float(np.linalg.norm(boundary_pts[k] - centre, axis=1).max()) if len(boundary_pts[k]) else 0.0
        cell_specs.append(CellSpec(index=k, name=name, region_tag=cell_region_tag(k), facet_tag=gamma2_tag(k),
                                   interface=gamma2_name(k, n_cells), centre=(float(centre[0]), float(centre[1])),
                                   diameter=2.0 * radius, symmetry=tuple(sorted(set(sym)))))
        for j in range(1, k):
            other = parsed.cells[j - 1][0]
            deep = [p for p in boundary_pts[k][::2] if _inside(p, cell_loops[j])
                    and _distance(p[None, :], boundary_pts[j]) > tol]
            deep += [p for p in boundary_pts[j][::2] if _inside(p, cell_loops[k])
                     and _distance(p[None, :], boundary_pts[k]) > tol]
            if deep:
                problems.append(f"cell '{name}' overlaps cell '{other}'")
            elif _distance(boundary_pts[k], boundary_pts[j]) <= tol:
                problems.append(f"cell '{name}' touches cell '{other}'")
    # ---- fluid regions: something must fix the pressure
    outlets = {c for _, _, ents, _ in parsed.curves["outlet"] for c in ents}
    ifaces = {c for _, _, ents, _ in parsed.curves["interface"] for c in ents}
    if not outlets:
        problems.append("no physical curve 'outlet': the pressure is undetermined (give at least one outlet, "
                        "where the traction is zero)")
    enclosed = False
    for comp in _components(sorted(fluid), info):
        touching = {c for c, up in info.adjacent.items() if set(up) & comp}
        if not touching & outlets:
            enclosed = True
            if not touching & ifaces:
                problems.append(f"the fluid region of surface(s) {sorted(comp)} has no outlet and no fluid-gel "
                                f"interface: it is enclosed and nothing fixes its pressure")
    if not parsed.curves["inlet"]:
        problems.append("no physical curve 'inlet': nothing drives the flow")
    if not parsed.curves["held"]:
        problems.append("no physical curve 'held': the gel's network is anchored nowhere (name the gel boundaries "
                        "where v_f = 0 and u_s = 0 'held')")
    else:
        # every connected part of the gel must be anchored: a held curve, or symmetry lines in both directions
        held = {c for _, _, ents, _ in parsed.curves["held"] for c in ents}
        sym_dirs: dict = {}
        for _, _, ents, _ in parsed.curves["symmetry"]:
            for c in ents:
                p = info.curve_points[c]
                sym_dirs[c] = "h" if abs(p[0, 1] - p[-1, 1]) <= 1e-9 * info.scale else "v"
        for comp in _components(sorted(gel), info):
            touching = {c for c, up in info.adjacent.items() if set(up) & comp}
            if not touching & held and {sym_dirs[c] for c in touching if c in sym_dirs} != {"h", "v"}:
                problems.append(f"the gel region of surface(s) {sorted(comp)} touches no 'held' curve: its network "
                                f"is anchored nowhere (rigid-body motion)")
    if not parsed.curves["interface"]:
        problems.append("no physical curve 'interface': the fluid and the gel must share at least one interface")
    # ---- cell boundary groups given by the user must be the cell's boundary
    for name, k, ents in parsed.cell_boundaries:
        k = k or 1
        if k > n_cells:
            problems.append(f"physical curve '{name}': there is no cell {k}")
            continue
        expected = set(gamma2.get(k, []))        # a flat edge on a symmetry line is 'symmetry'
        if set(ents) != expected:
            problems.append(f"physical curve '{name}' = curves {sorted(ents)} is not the boundary of "
                            f"'{cell_names[k]}' (curves {sorted(expected)})")
    # ---- inlets: straight, with their inward normal
    inflow = []
    for j, (name, _, ents, opts) in enumerate(parsed.curves["inlet"], start=1):
        pts = np.vstack([info.curve_points[c] for c in ents])
        if len(ents) != 1 or not _straight(info.curve_points[ents[0]], info.scale):
            problems.append(f"inlet '{name}': an inlet must be one straight curve (it has {len(ents)} curve(s)"
                            f"{'' if len(ents) != 1 else ', not straight'})")
            continue
        a, b = pts[0], pts[-1]
        t = (b - a) / np.linalg.norm(b - a)
        n = np.array([-t[1], t[0]])
        mid = 0.5 * (a + b)
        surf = [s for s in info.adjacent[ents[0]] if s in fluid]
        loops = [lp for s in surf for lp in info.surface_polygons[s]]
        if not _inside(mid + 1e-4 * np.linalg.norm(b - a) * n, loops):
            n = -n
        inflow.append((inlet_tag(j), SegmentInflow(a, b, n, opts["speed"], opts["profile"]), name, opts))
    # ---- symmetry lines of the fluid and the gel
    sym_tags: dict = {}
    for name, _, ents, _ in parsed.curves["symmetry"]:
        for c in ents:
            p = info.curve_points[c]
            side = [region[s] for s in info.adjacent[c] if s in region]
            if not side:
                continue          # a cell's flat edge, handled above
            horizontal, problem = _symmetry_axis(c, p, info.scale, name)
            if problem:
                problems.append(problem)
                continue
            tag = {("fluid", True): Tag.SYMMETRY_BOTTOM, ("fluid", False): Tag.FLUID_SYMMETRY_X,
                   ("gel", True): Tag.GEL_SYMMETRY_Y, ("gel", False): Tag.GEL_SYMMETRY_X}[(side[0], horizontal)]
            sym_tags.setdefault(int(tag), []).append(c)
    if problems:
        raise ParameterError(f"{where}:\n" + "\n".join(problems))

    # ---- gelcell's tags
    curve_tags: dict = {}
    for tag, _, name, _ in inflow:
        curve_tags[tag] = [c for g in parsed.curves["inlet"] if g[0] == name for c in g[2]]
    for kind, tag in (("outlet", Tag.OUTLET), ("wall", Tag.WALL), ("held", Tag.BOWL)):
        ents = [c for g in parsed.curves[kind] for c in g[2]]
        if ents:
            curve_tags[int(tag)] = ents
    curve_tags.update(sym_tags)
    fluid_interfaces = {}
    for j, (name, _, ents, _) in enumerate(parsed.curves["interface"], start=1):
        curve_tags[fluid_interface_tag(j)] = list(ents)
        fluid_interfaces[fluid_interface_name(j)] = fluid_interface_tag(j)
    for k, curves in gamma2.items():
        curve_tags[gamma2_tag(k)] = list(curves)
    cell_sym_tags = {}
    for k, curves in cell_sym.items():
        for c in curves:
            p = info.curve_points[c]
            tag = int(Tag.SYMMETRY_TOP) if abs(p[0, 1] - p[-1, 1]) <= 1e-9 * info.scale else int(Tag.CELL_SYMMETRY_X)
            curve_tags.setdefault(tag, []).append(c)
            cell_sym_tags[tag] = 1 if tag == int(Tag.SYMMETRY_TOP) else 0
    surface_tags = {int(Tag.FLUID): (sorted(fluid), "fluid"), int(Tag.GEL): (sorted(gel), "gel")}
    for k, (name, _, ents) in enumerate(parsed.cells, start=1):
        surface_tags[cell_region_tag(k)] = (list(ents), name)
    present = set(curve_tags)
    boundaries = DeviceBoundaries(
        fluid_velocity=[([tag], g) for tag, g, _, _ in inflow] + ([([int(Tag.WALL)], (0.0, 0.0))]
                                                                  if int(Tag.WALL) in present else []),
        fluid_component=[([t], c, 0.0) for t, c in ((int(Tag.SYMMETRY_BOTTOM), 1), (int(Tag.FLUID_SYMMETRY_X), 0))
                         if t in present],
        gel_no_slip=[int(Tag.BOWL)],
        gel_symmetry=[([t], c) for t, c in ((int(Tag.GEL_SYMMETRY_Y), 1), (int(Tag.GEL_SYMMETRY_X), 0))
                      if t in present],
        cell_symmetry=[([t], c) for t, c in sorted(cell_sym_tags.items())],
        fluid_interfaces=fluid_interfaces,
        cell_interfaces={c.interface: c.facet_tag for c in cell_specs})
    xs = np.vstack([p for p in info.curve_points.values() if len(p)])
    width, height = np.ptp(xs[:, 0]), np.ptp(xs[:, 1])
    names = {tag: ("inlet " + name) for tag, _, name, _ in inflow}
    layout = DeviceLayout(boundaries=boundaries, cells=cell_specs, fluid_interfaces=fluid_interfaces,
                          wide=width > 2.5 * height, tag_names=names)
    gel_area = sum(_polygon_area_centroid(info.surface_polygons[s])[0] for s in gel)
    iface_len = sum(float(np.linalg.norm(np.diff(info.curve_points[c], axis=0), axis=1).sum())
                    for c in {c for _, _, ents, _ in parsed.curves["interface"] for c in ents})
    return FileLayout(curve_tags=curve_tags, surface_tags=surface_tags, layout=layout,
                      gel_depth=gel_area / iface_len, enclosed_fluid=enclosed)


_ANALYSED: dict = {}


def analyse(path: str) -> FileLayout:
    """The checked layout of a geometry file (cached per file version); raises ParameterError."""
    info = read_geometry(path)
    key = _key(path)
    if key not in _ANALYSED:
        _ANALYSED[key] = _analyse(info)
    return _ANALYSED[key]


def file_layout(params):
    """The :class:`gelcell.boundaries.DeviceLayout` of a geometry-file case."""
    return analyse(params.geometry.file).layout


def build_file_model(params) -> None:
    """Load the file into the current gmsh session (rank 0), tag it with gelcell's tags, mesh it (P2)."""
    gmsh = import_gmsh()
    path = os.path.abspath(params.geometry.file)
    fl = analyse(path)
    gmsh.open(path)
    gmsh.option.setNumber("General.Terminal", 0)
    is_mesh = path.lower().endswith(".msh")
    gmsh.model.removePhysicalGroups()
    for tag, (surfaces, name) in fl.surface_tags.items():
        gmsh.model.addPhysicalGroup(2, surfaces, tag)
        gmsh.model.setPhysicalName(2, tag, name)
    for tag, curves in fl.curve_tags.items():
        gmsh.model.addPhysicalGroup(1, curves, tag)
    if is_mesh:       # (a size factor other than 1 is refused by CaseParameters.validate)
        if 9 not in _types(gmsh):
            gmsh.model.mesh.setOrder(2)
    else:
        gmsh.option.setNumber("Mesh.MeshSizeFactor",
                              gmsh.option.getNumber("Mesh.MeshSizeFactor") * params.mesh.size_factor)
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        gmsh.model.mesh.clear()
        gmsh.model.mesh.generate(2)
        bad = [t for t in _types(gmsh) if t not in _ELEMENT_TYPES]
        if bad:
            raise ParameterError(f"geometry file {path!r}: its mesh options make element type(s) {bad} (gmsh "
                                 f"numbers, e.g. 3 = quadrangle); gelcell takes triangles only (no Recombine)")
        gmsh.model.mesh.setOrder(2)
    gmsh.model.mesh.renumberNodes()


def _types(gmsh) -> list[int]:
    return [int(t) for t in gmsh.model.mesh.getElementTypes()]


def convention_names(params) -> dict[int, str]:
    """Facet and cell tags of a built-in device -> the names of the geometry-file convention."""
    from gelcell.boundaries import builtin_cells
    from gelcell.geometry import Tag
    cells = builtin_cells(params)
    inlet = "inlet:parabolic:1" if params.case == "shear" else "inlet:uniform:1"
    names = {int(Tag.FLUID): "fluid", int(Tag.GEL): "gel", int(Tag.INLET): inlet, int(Tag.OUTLET): "outlet",
             int(Tag.WALL): "wall", int(Tag.BOWL): "held", int(Tag.POST): "held",
             int(Tag.SYMMETRY_BOTTOM): "symmetry", int(Tag.SYMMETRY_TOP): "symmetry",
             int(Tag.GAMMA1): "interface_1" if params.case == "normal" else "interface",
             int(Tag.GAMMA3): "interface_2"}
    for c in cells:
        names[c.region_tag] = c.name
        names[c.facet_tag] = f"{c.name}_boundary"
    return names


def export_builtin(params, path: str) -> None:
    """Write the meshed built-in device of ``params`` as a .msh file named by the convention (serial).

    Loading it with ``--geometry`` gives the same mesh, hence the built-in
    device's results; it is also a starting point for a device of one's own.
    """
    from gelcell.geometry import _build_model
    if params.case == "file":
        raise ParameterError("export_builtin: the case is already a geometry file")
    names = convention_names(params)
    with gmsh_session() as gmsh:
        _build_model(params)
        # one group per convention name (the symmetry lines and the held walls merge)
        groups: dict = {}
        for dim, tag in gmsh.model.getPhysicalGroups():
            ents = list(gmsh.model.getEntitiesForPhysicalGroup(dim, tag))
            groups.setdefault((dim, names[int(tag)]), []).extend(ents)
            gmsh.model.removePhysicalName(gmsh.model.getPhysicalName(dim, tag))
        gmsh.model.removePhysicalGroups()
        for k, ((dim, name), ents) in enumerate(sorted(groups.items()), start=1):
            gmsh.model.addPhysicalGroup(dim, sorted(set(ents)), k)
            gmsh.model.setPhysicalName(dim, k, name)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(path)
