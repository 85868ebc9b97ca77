"""Small stand-alone meshes for verifying the cell solver (not the device geometry).

All builders are collective: call them on every rank.  gmsh builds the model
on rank 0 only; the meshes have quadratic (curved, isoparametric) geometry
unless ``order=1``.  Facet tags are the module constants below.

* ``annulus(a, b, h)``: the ring a < r < b, full or a quarter (x, y > 0);
* ``disk(radius, h)``: a disk, full or its upper half (y > 0);
* ``block(length, height, n)``: a rectangle on a distorted triangle mesh;
* ``rectangle(length, height, h)``: a rectangle meshed by gmsh (P2 geometry by default).
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

from dolfinx import mesh as dmesh

from femtools.gmshimport import import_gmsh
from femtools.mesh import model_to_mesh

gmsh = import_gmsh()

__all__ = ["INNER", "OUTER", "XAXIS", "YAXIS", "BOUNDARY", "FLAT",
           "LEFT", "RIGHT", "BOTTOM", "TOP", "annulus", "disk", "block", "rectangle"]

#: annulus: inner circle r = a, outer circle r = b, quarter edges on y = 0 and x = 0
INNER, OUTER, XAXIS, YAXIS = 1, 2, 3, 4
#: disk: its circle (or arc); FLAT: the half disk's diameter on y = 0
BOUNDARY, FLAT = 1, 2
#: block sides
LEFT, RIGHT, BOTTOM, TOP = 1, 2, 3, 4
_DOMAIN = 100


def _check_positive(**kwargs) -> None:
    for key, value in kwargs.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{key} must be a positive number, got {value!r}")


def _generate(comm: MPI.Comm, build, h: float, order: int):
    """Run ``build(occ)`` on rank 0 (it returns ``{tag: [curves]}``), mesh and convert."""
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        if comm.rank == 0:
            gmsh.model.add("cell_test_mesh")
            occ = gmsh.model.occ
            surfaces, curves = build(occ)
            occ.synchronize()
            gmsh.model.addPhysicalGroup(2, surfaces, _DOMAIN)
            for tag, ids in curves(gmsh.model).items():
                gmsh.model.addPhysicalGroup(1, ids, tag)
            gmsh.option.setNumber("Mesh.MeshSizeMin", h)
            gmsh.option.setNumber("Mesh.MeshSizeMax", h)
            gmsh.model.mesh.generate(2)
            gmsh.model.mesh.setOrder(order)
        msh, _, facet_tags = model_to_mesh(gmsh.model, comm, 0, gdim=2)
    finally:
        gmsh.finalize()
    return msh, facet_tags


def _classify(model, rule) -> dict[int, list[int]]:
    """Group the model's curves by ``rule(x_centre, y_centre, length)`` -> tag."""
    groups: dict[int, list[int]] = {}
    for _, c in model.getEntities(1):
        x, y, _ = model.occ.getCenterOfMass(1, c)
        groups.setdefault(rule(x, y, model.occ.getMass(1, c)), []).append(c)
    return groups


def annulus(a: float, b: float, h: float, quarter: bool = False, order: int = 2,
            comm: MPI.Comm = MPI.COMM_WORLD):
    """The ring ``a < r < b`` centred at the origin.

    Args:
        a, b: inner and outer radius (0 < a < b).
        h: uniform mesh size.
        quarter: only the quarter x > 0, y > 0 (edges tagged XAXIS, YAXIS).
        order: geometry order (2: curved isoparametric cells).

    Returns:
        ``(mesh, facet_tags)`` with tags INNER, OUTER (and XAXIS, YAXIS).
    """
    _check_positive(a=a, b=b, h=h)
    if not a < b:
        raise ValueError(f"need a < b, got a={a}, b={b}")

    def build(occ):
        ring, _ = occ.cut([(2, occ.addDisk(0, 0, 0, b, b))], [(2, occ.addDisk(0, 0, 0, a, a))])
        if quarter:
            ring, _ = occ.intersect(ring, [(2, occ.addRectangle(0, 0, 0, 2 * b, 2 * b))])
        surfaces = [t for _, t in ring]

        def curves(model):
            def rule(x, y, length):
                if quarter and abs(y) < 1e-12 * b:
                    return XAXIS
                if quarter and abs(x) < 1e-12 * b:
                    return YAXIS
                # the arcs' lengths tell them apart: (pi/2) r or 2 pi r
                r = length / (0.5 * np.pi if quarter else 2 * np.pi)
                return INNER if abs(r - a) < abs(r - b) else OUTER
            return _classify(model, rule)
        return surfaces, curves

    return _generate(comm, build, h, order)


def disk(radius: float, h: float, centre=(0.0, 0.0), half: bool = False, order: int = 2,
         comm: MPI.Comm = MPI.COMM_WORLD):
    """A disk of ``radius`` about ``centre``; with ``half`` only its part y > centre_y.

    Returns:
        ``(mesh, facet_tags)`` with tags BOUNDARY (the circle or arc) and FLAT
        (the diameter of the half disk).
    """
    _check_positive(radius=radius, h=h)
    cx, cy = float(centre[0]), float(centre[1])

    def build(occ):
        body = [(2, occ.addDisk(cx, cy, 0, radius, radius))]
        if half:
            body, _ = occ.intersect(body, [(2, occ.addRectangle(cx - 2 * radius, cy, 0,
                                                                4 * radius, 2 * radius))])
        surfaces = [t for _, t in body]

        def curves(model):
            return _classify(model, lambda x, y, length:
                             FLAT if half and abs(y - cy) < 1e-12 * (1 + abs(cy)) else BOUNDARY)
        return surfaces, curves

    return _generate(comm, build, h, order)


def rectangle(length: float, height: float, h: float, order: int = 2, comm: MPI.Comm = MPI.COMM_WORLD):
    """``[0, length] x [0, height]`` meshed by gmsh with size ``h``; tags LEFT, RIGHT, BOTTOM, TOP."""
    _check_positive(length=length, height=height, h=h)

    def build(occ):
        surfaces = [occ.addRectangle(0, 0, 0, length, height)]

        def curves(model):
            def rule(x, y, _):
                if abs(x) < 1e-12 * length:
                    return LEFT
                if abs(x - length) < 1e-12 * length:
                    return RIGHT
                return BOTTOM if abs(y) < 1e-12 * height else TOP
            return _classify(model, rule)
        return surfaces, curves

    return _generate(comm, build, h, order)


def block(length: float, height: float, n: int, distortion: float = 0.15,
          comm: MPI.Comm = MPI.COMM_WORLD):
    """Rectangle ``[0, length] x [0, height]`` on ``n`` x ``n`` crossed-diagonal cells, distorted.

    Interior vertices are displaced by up to ``distortion`` times the cell size
    in each direction, by a deterministic function of their position (the
    same on every rank and for every partition); boundary vertices stay put.

    Returns:
        ``(mesh, facet_tags)`` with tags LEFT, RIGHT, BOTTOM, TOP.
    """
    _check_positive(length=length, height=height, n=n)
    if not 0 <= distortion < 0.25:
        # two neighbours moving 0.25 h towards each other flatten a crossed-diagonal triangle
        raise ValueError(f"distortion must lie in [0, 0.25), got {distortion}")
    msh = dmesh.create_rectangle(comm, [np.zeros(2), np.array([length, height])], [n, n],
                                 dmesh.CellType.triangle, diagonal=dmesh.DiagonalType.crossed)
    x = msh.geometry.x
    hx, hy = length / n, height / n
    inside = ((x[:, 0] > 1e-10 * length) & (x[:, 0] < length * (1 - 1e-10))
              & (x[:, 1] > 1e-10 * height) & (x[:, 1] < height * (1 - 1e-10)))
    # a pseudo-random but position-determined shift in (-1/2, 1/2)
    xi = np.sin(12.9898 * x[:, 0] / hx + 78.233 * x[:, 1] / hy) * 43758.5453
    eta = np.sin(39.3468 * x[:, 0] / hx + 11.135 * x[:, 1] / hy) * 24634.6345
    shift = np.column_stack([xi - np.floor(xi) - 0.5, eta - np.floor(eta) - 0.5])
    x[inside, 0] += 2 * distortion * hx * shift[inside, 0]
    x[inside, 1] += 2 * distortion * hy * shift[inside, 1]
    tdim = msh.topology.dim
    sides = {LEFT: lambda p: np.isclose(p[0], 0.0), RIGHT: lambda p: np.isclose(p[0], length),
             BOTTOM: lambda p: np.isclose(p[1], 0.0), TOP: lambda p: np.isclose(p[1], height)}
    indices, values = [], []
    for tag, marker in sides.items():
        f = dmesh.locate_entities_boundary(msh, tdim - 1, marker)
        indices.append(f)
        values.append(np.full(f.size, tag, dtype=np.int32))
    indices = np.hstack(indices).astype(np.int32)
    values = np.hstack(values)
    # corner facets do not exist (a facet lies on one side only), so indices are unique
    order = np.argsort(indices)
    return msh, dmesh.meshtags(msh, tdim - 1, indices[order], values[order])
