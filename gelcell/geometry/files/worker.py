"""The gmsh side of reading and meshing a geometry file, run in a child process.

``python .../gelcell/geometry/files/worker.py`` reads one pickled request on
stdin and writes one pickled answer on its stdout (anything gmsh or the
file prints goes to stderr): ``("ok", payload)`` or ``("error", kind, text)``.
The parent side, with the time and memory bounds and the signals, is
:mod:`gelcell.geometry.files.child`.  Requests:

* ``{"op": "read", "path", "msh_version"}`` (``msh_version``: None for a
  ``.geo`` file; an MSH 2 file gets its topology from ``createTopology``): the physical groups and topology of the
  file (the fields of :class:`~gelcell.geometry.files.read.GeometryInfo`);
* ``{"op": "estimate", "path", "msh_version"}``: the triangles (tetrahedra in
  a file with volumes) of the file at ``--mesh-size 1`` (a ``.geo`` file's from coarse probe meshes, see
  :func:`reference_elements`), once the file is known to be valid (probe
  meshes of a broken file can crash gmsh);
* ``{"op": "mesh", "path", "msh_version", "dimension", "surface_tags", "curve_tags", "size_factor"}``:
  the file re-tagged with gelcell's tags (on its regions of ``dimension`` 2 or 3 and their
  boundaries) and meshed with curved P2 triangles or tetrahedra, as the arrays of
  :class:`femtools.mesh.ModelArrays`.

It imports gmsh and numpy only (no gelcell, no MPI, no dolfinx).
"""

from __future__ import annotations

import os
import pickle
import resource
import signal
import sys

import numpy as np

#: gmsh element types gelcell takes (the keys of gelcell.geometry.files.read.ELEMENT_TYPES: this
#: script imports nothing of gelcell, so that it starts fast): points, lines, triangles, tetrahedra
ELEMENT_TYPES = (15, 1, 8, 2, 9, 4, 11)

#: a probe mesh with at least this many triangles predicts the element count (see reference_elements)
PROBE_ELEMENTS = 1000
#: the size factors of the probe meshes, coarse to fine (times the file's own Mesh.MeshSizeFactor)
PROBE_SCALES = (1024, 256, 64, 16, 4, 1)


class Refused(Exception):
    """A file gelcell cannot use (reported as a ParameterError by the parent)."""


# --------------------------------------------------------------------------- the process
def _bound_the_process(request: dict) -> None:
    """End with the parent (SIGKILL when it dies), and bound this process's memory and output file sizes."""
    try:
        import ctypes
        ctypes.CDLL(None).prctl(1, int(signal.SIGKILL))      # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != request.get("parent", os.getppid()):
        os._exit(1)                                           # the parent is already gone
    memory = request.get("memory_bytes")
    if memory:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)             # a chatty file: its log is cut, not the run
    resource.setrlimit(resource.RLIMIT_FSIZE, (request.get("log_bytes", 8 << 20),) * 2)


def _session():
    import gmsh
    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    return gmsh


def _open(gmsh, path: str, msh_version: str | None) -> None:
    """Open the file; a mesh older than MSH 4 gets the topology MSH 4 stores (curve ends, adjacencies)."""
    try:
        gmsh.open(path)
    except Exception as exc:
        raise Refused(f"geometry file {path!r}: gmsh cannot read it: {exc}") from None
    gmsh.option.setNumber("General.Terminal", 0)
    if msh_version is not None and float(msh_version) < 4:
        gmsh.model.mesh.createTopology()


# --------------------------------------------------------------------------- read
def _samples(gmsh, curve: int, n: int = 64, from_mesh: bool = False, gdim: int = 2) -> np.ndarray:
    """Points (their first ``gdim`` coordinates) along a curve in order: from its parametrisation,
    or (``from_mesh``, a .msh file's discrete curve) its mesh nodes ordered by walking its line elements."""
    if not from_mesh:
        lo, hi = gmsh.model.getParametrizationBounds(1, curve)
        t = np.linspace(lo[0], hi[0], n)
        return np.asarray(gmsh.model.getValue(1, curve, t)).reshape(-1, 3)[:, :gdim]
    tags, coords, _ = gmsh.model.mesh.getNodes(1, curve, includeBoundary=True)
    x = np.asarray(coords).reshape(-1, 3)[:, :gdim]
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


def _loops(gmsh, surface: int, points: dict) -> list:
    """Closed boundary loops of a surface as point arrays (curves chained by their end points)."""
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


def _element_count(gmsh, dim: int = 2) -> int:
    return sum(len(t) for t in gmsh.model.mesh.getElements(dim)[1])


def _model_dimension(gmsh) -> int:
    """3 if the model has volumes, else 2."""
    return 3 if gmsh.model.getEntities(3) else 2


def reference_elements(gmsh) -> float:
    """The number of cells (triangles; tetrahedra in a file with volumes) the file's own sizes make
    (``--mesh-size 1``), predicted without making them.

    Probe meshes are made at size factors 1024, 256, ... times the file's
    (each about 16 times finer than the one before) until one has
    :data:`PROBE_ELEMENTS` cells; the count of a mesh scales as the
    inverse square (2D) or cube (3D) of its size factor, so that probe predicts the count at
    factor 1 (a mesh of fewer cells at factor 1 is counted exactly).
    0 if no probe could be meshed.  The model is left unmeshed.
    """
    dim = _model_dimension(gmsh)
    base = gmsh.option.getNumber("Mesh.MeshSizeFactor")
    order = gmsh.option.getNumber("Mesh.ElementOrder")
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    estimate = 0.0
    try:
        for scale in PROBE_SCALES:
            gmsh.option.setNumber("Mesh.MeshSizeFactor", base * scale)
            gmsh.model.mesh.clear()
            try:
                gmsh.model.mesh.generate(dim)
            except Exception:
                continue               # too coarse for a small feature: try finer
            n = _element_count(gmsh, dim)
            estimate = float(n) * scale ** dim
            if n >= PROBE_ELEMENTS:
                break
    finally:
        gmsh.model.mesh.clear()
        gmsh.option.setNumber("Mesh.MeshSizeFactor", base)
        gmsh.option.setNumber("Mesh.ElementOrder", order)
    return estimate


# --------------------------------------------------------------------------- read: volumes (3D)
def _surface_samples(gmsh, surface: int, edge_points: dict, from_mesh: bool, n: int = 15) -> np.ndarray:
    """Points on a surface: its boundary curves' samples and an n x n grid of its parametrisation
    (the points inside its trimmed domain), or (``from_mesh``) its mesh nodes."""
    if from_mesh:
        _, coords, _ = gmsh.model.mesh.getNodes(2, surface, includeBoundary=True)
        return np.asarray(coords).reshape(-1, 3)
    edges = [edge_points[abs(c)] for _, c in gmsh.model.getBoundary([(2, surface)], combined=False, oriented=False)]
    inner = []
    try:
        lo, hi = gmsh.model.getParametrizationBounds(2, surface)
        u, v = np.meshgrid(np.linspace(lo[0], hi[0], n + 2)[1:-1], np.linspace(lo[1], hi[1], n + 2)[1:-1])
        for uv in np.column_stack([u.ravel(), v.ravel()]):
            if gmsh.model.isInside(2, surface, list(uv)):
                inner.append(np.asarray(gmsh.model.getValue(2, surface, list(uv)))[:3])
    except Exception:
        pass                           # a surface without a parametrisation: its boundary samples only
    return np.vstack(edges + ([np.asarray(inner)] if inner else []))


def _mesh_measures(gmsh, dim: int, tag: int):
    """Size (area, volume) and centroid of an entity from its linear mesh elements (a .msh file)."""
    types, _, nodes = gmsh.model.mesh.getElements(dim, tag)
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    index = {int(t): i for i, t in enumerate(node_tags)}
    x = np.asarray(coords).reshape(-1, 3)
    size, moment = 0.0, np.zeros(3)
    for et, nd in zip(types, nodes):
        k = gmsh.model.mesh.getElementProperties(et)[3]
        corners = x[[index[int(t)] for t in np.asarray(nd)]].reshape(-1, k, 3)[:, : dim + 1]
        edges = corners[:, 1:] - corners[:, :1]
        if dim == 3:
            m = np.abs(np.einsum("ij,ij->i", edges[:, 0], np.cross(edges[:, 1], edges[:, 2]))) / 6
        else:
            m = 0.5 * np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
        size += float(m.sum())
        moment += (m[:, None] * corners.mean(axis=1)).sum(axis=0)
    return size, (moment / size if size else moment)


def _measures(gmsh, dim: int, tag: int, from_mesh: bool):
    """Size and centroid of an entity: OpenCASCADE's, else its mesh's (a .msh file, or a probe mesh)."""
    if not from_mesh:
        try:
            return float(gmsh.model.occ.getMass(dim, tag)), np.asarray(gmsh.model.occ.getCenterOfMass(dim, tag))
        except Exception:
            pass                       # the built-in kernel: no masses
    return _mesh_measures(gmsh, dim, tag)


def _gaps(groups: list, facet_points: dict, facets_of: dict) -> dict:
    """For every volume of a ``cell*`` group: surface -> the smallest distance between the samples of
    the volume's boundary and those of that surface (the surfaces not bounding it): a sampled
    estimate (a touching cell shares a curve or a point with the surface, which the checks find)."""
    gaps = {}
    cells = {v for dim, name, ents in groups if dim == 3 and name.strip().startswith("cell") for v in ents}
    for v in sorted(cells):
        own = set(facets_of[v])
        pts = np.vstack([facet_points[s] for s in own])
        gaps[v] = {s: float(np.linalg.norm(pts[:, None, :] - q[None, :, :], axis=2).min())
                   for s, q in facet_points.items() if s not in own and len(q)}
    return gaps


def _read_volumes(gmsh, groups: list, is_mesh: bool) -> dict:
    """The GeometryInfo fields of a file with volumes: its surfaces play the 2D curves' part and its
    volumes the 2D surfaces' (adjacency, samples, boundary entities), plus what the 3D checks need."""
    edge_points, edge_facets = {}, {}
    for _, c in gmsh.model.getEntities(1):
        edge_points[c] = _samples(gmsh, c, from_mesh=is_mesh, gdim=3)
        edge_facets[c] = [int(s) for s in gmsh.model.getAdjacencies(1, c)[0]]
    adjacent, points, edges, sizes = {}, {}, {}, {}
    probe = False
    for _, s in gmsh.model.getEntities(2):
        up, down = gmsh.model.getAdjacencies(2, s)
        adjacent[s] = [int(v) for v in up]
        edges[s] = [int(c) for c in down]
        points[s] = _surface_samples(gmsh, s, edge_points, is_mesh)
    for dim in (2, 3):
        for _, t in gmsh.model.getEntities(dim):
            try:
                sizes[(dim, t)] = _measures(gmsh, dim, t, is_mesh or probe)
            except Exception:
                probe = True           # no OpenCASCADE masses: a coarse mesh measures the rest
                gmsh.option.setNumber("Mesh.MeshSizeFactor", 8 * gmsh.option.getNumber("Mesh.MeshSizeFactor"))
                gmsh.model.mesh.generate(3)
                sizes[(dim, t)] = _mesh_measures(gmsh, dim, t)
    if probe:
        gmsh.model.mesh.clear()
    facets_of = {v: [abs(t) for _, t in gmsh.model.getBoundary([(3, v)], combined=False, oriented=False)]
                 for _, v in gmsh.model.getEntities(3)}
    return dict(adjacent=adjacent, curve_points=points, curve_ends=edges,
                surface_polygons={v: [] for _, v in gmsh.model.getEntities(3)},
                solid=dict(edge_points=edge_points, edge_facets=edge_facets, sizes=sizes, facets_of=facets_of,
                           gaps=_gaps(groups, points, facets_of)))


def read(request: dict) -> dict:
    """The fields of a GeometryInfo (``path`` excepted) of the file of ``request``."""
    gmsh = _session()
    path = request["path"]
    _open(gmsh, path, request.get("msh_version"))
    is_mesh = path.lower().endswith(".msh")
    entities = gmsh.model.getEntities()
    max_dim = max((d for d, _ in entities), default=-1)
    groups = []
    for dim, tag in gmsh.model.getPhysicalGroups():
        name = gmsh.model.getPhysicalName(dim, tag) or str(tag)
        groups.append((dim, name, [int(e) for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag)]))
    types = [int(t) for t in gmsh.model.mesh.getElementTypes()] if is_mesh else []
    order = int(gmsh.option.getNumber("Mesh.ElementOrder"))
    if gmsh.option.getNumber("Mesh.RecombineAll"):
        types.append(3)     # quadrilaterals requested
    common = dict(groups=groups, element_types=sorted(set(types)), max_dim=max_dim, element_order=order)
    if max_dim == 3:
        fields = _read_volumes(gmsh, groups, is_mesh)
        allpts = np.vstack([p for p in fields["curve_points"].values() if len(p)])
        return dict(common, **fields, dimension=3, scale=float(np.ptp(allpts, axis=0).max()) or 1.0)
    adjacent, points, ends = {}, {}, {}
    for _, c in gmsh.model.getEntities(1):
        up, down = gmsh.model.getAdjacencies(1, c)
        adjacent[c] = [int(s) for s in up]
        ends[c] = [int(p) for p in down]
        points[c] = _samples(gmsh, c, from_mesh=is_mesh)
    polygons = {s: _loops(gmsh, s, points) for _, s in gmsh.model.getEntities(2)}
    allpts = np.vstack([p for p in points.values() if len(p)]) if points else np.zeros((1, 2))
    scale = float(np.ptp(allpts, axis=0).max()) or 1.0
    return dict(common, adjacent=adjacent, curve_points=points, curve_ends=ends, surface_polygons=polygons,
                scale=scale)


def estimate(request: dict) -> float:
    """The triangles of the file at ``--mesh-size 1``: a ``.msh`` file's own, a ``.geo`` file's predicted."""
    gmsh = _session()
    path = request["path"]
    _open(gmsh, path, request.get("msh_version"))
    if path.lower().endswith(".msh"):
        return float(_element_count(gmsh, _model_dimension(gmsh)))
    return reference_elements(gmsh)


# --------------------------------------------------------------------------- mesh
def _types(gmsh) -> list[int]:
    return [int(t) for t in gmsh.model.mesh.getElementTypes()]


def _arrays(model) -> dict:
    """The arrays of :class:`femtools.mesh.ModelArrays` of the meshed ``model``, as
    ``dolfinx.io.gmshio.extract_geometry`` and ``extract_topology_and_markers`` (0.5.2) make them."""
    topologies: dict = {}
    for dim, tag in model.getPhysicalGroups():
        for entity in model.getEntitiesForPhysicalGroup(dim, tag):
            entity_types, entity_tags, entity_topologies = model.mesh.getElements(dim, tag=entity)
            if len(entity_types) != 1:
                raise Refused(f"physical group {tag} of dimension {dim}: entity {entity} holds "
                              f"{len(entity_types)} element types (one expected)")
            num_nodes = model.mesh.getElementProperties(entity_types[0])[3]
            topology = entity_topologies[0].reshape(-1, num_nodes) - 1
            marker = np.full_like(entity_tags[0], tag)
            k = int(entity_types[0])
            if k in topologies:
                topologies[k] = (np.concatenate((topologies[k][0], topology), axis=0),
                                 np.hstack([topologies[k][1], marker]))
            else:
                topologies[k] = (topology, marker)
    indices, points, _ = model.mesh.getNodes()
    points = points.reshape(-1, 3)
    indices -= 1
    perm_sort = np.argsort(indices)
    if not np.all(indices[perm_sort] == np.arange(len(indices))):
        raise Refused("the mesh's node numbers are not contiguous")
    return dict(x=points[perm_sort], topology={k: v[0] for k, v in topologies.items()},
                markers={k: v[1] for k, v in topologies.items()},
                dims={k: int(model.mesh.getElementProperties(k)[1]) for k in topologies})


def mesh(request: dict) -> dict:
    """The file re-tagged with gelcell's tags and meshed (P2), as ModelArrays' fields."""
    gmsh = _session()
    path = request["path"]
    _open(gmsh, path, request.get("msh_version"))
    is_mesh = path.lower().endswith(".msh")
    dim = request.get("dimension", 2)      # of the regions; their boundaries are one lower
    gmsh.model.removePhysicalGroups()
    for tag, (surfaces, name) in request["surface_tags"].items():
        gmsh.model.addPhysicalGroup(dim, surfaces, tag)
        gmsh.model.setPhysicalName(dim, tag, name)
    for tag, curves in request["curve_tags"].items():
        gmsh.model.addPhysicalGroup(dim - 1, curves, tag)
    if is_mesh:       # (a size factor other than 1 is refused by CaseParameters.validate)
        if (11 if dim == 3 else 9) not in _types(gmsh):
            gmsh.model.mesh.setOrder(2)
    else:
        gmsh.option.setNumber("Mesh.MeshSizeFactor",
                              gmsh.option.getNumber("Mesh.MeshSizeFactor") * request["size_factor"])
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        gmsh.model.mesh.clear()
        gmsh.model.mesh.generate(dim)
        bad = [t for t in _types(gmsh) if t not in ELEMENT_TYPES]
        if bad:
            raise Refused(f"geometry file {path!r}: its mesh options make element type(s) {bad} (gmsh "
                          f"numbers, e.g. 3 = quadrangle, 6 = prism); gelcell takes triangles and "
                          f"tetrahedra only (no Recombine)")
        gmsh.model.mesh.setOrder(2)
    gmsh.model.mesh.renumberNodes()
    return _arrays(gmsh.model)


OPERATIONS = {"read": read, "estimate": estimate, "mesh": mesh}


def main() -> None:
    answer_file = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                  # what gmsh or the file prints goes to stderr
    request = pickle.load(sys.stdin.buffer)
    _bound_the_process(request)
    try:
        answer = ("ok", OPERATIONS[request["op"]](request))
    except Refused as exc:
        answer = ("error", "ParameterError", str(exc))
    except MemoryError:
        answer = ("error", "MemoryError", "out of memory")
    except Exception as exc:       # gmsh's own errors: reported by the parent, naming the file
        answer = ("error", "gmsh", f"{exc}")
    pickle.dump(answer, answer_file)
    answer_file.close()
    sys.stdout.flush()
    os._exit(0)                    # no gmsh finalize or atexit work: the answer is out


if __name__ == "__main__":
    main()
