"""Small stand-alone meshes for verifying the cell solver (not the device geometry).

All builders are collective: call them on every rank.  gmsh builds the model
on rank 0 only; the meshes have quadratic (curved, isoparametric) geometry
unless ``order=1``.  Facet tags are the module constants below.

* ``annulus(a, b, h)``: the ring a < r < b, full or a quarter (x, y > 0);
* ``disk(radius, h)``: a disk, full or its upper half (y > 0);
* ``block(length, height, n)``: a rectangle on a distorted triangle mesh;
* ``rectangle(length, height, h)``: a rectangle meshed by gmsh (P2 geometry by default);
* ``ball(radius, h)``: a ball of tetrahedra (the 3D cell), full or cut by planes through its centre;
* ``shell(a, b, h)``: the hollow sphere a < r < b, full or its octant x, y, z > 0.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import basix
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh

from femtools.gmshimport import import_gmsh
from femtools.mesh import model_to_mesh

gmsh = import_gmsh()

__all__ = ["INNER", "OUTER", "XAXIS", "YAXIS", "BOUNDARY", "FLAT", "PLANE_X", "PLANE_Y", "PLANE_Z",
           "LEFT", "RIGHT", "BOTTOM", "TOP", "annulus", "disk", "block", "rectangle", "ball", "shell"]

#: annulus: inner circle r = a, outer circle r = b, quarter edges on y = 0 and x = 0
INNER, OUTER, XAXIS, YAXIS = 1, 2, 3, 4
#: disk: its circle (or arc); FLAT: the half disk's diameter on y = 0
BOUNDARY, FLAT = 1, 2
#: block sides
LEFT, RIGHT, BOTTOM, TOP = 1, 2, 3, 4
#: 3D (ball, shell): the flat faces x = c_x, y = c_y, z = c_z through the centre (BOUNDARY,
#: INNER, OUTER are the spherical surfaces as in 2D)
PLANE_X, PLANE_Y, PLANE_Z = 5, 6, 7
_DOMAIN = 100


def _check_positive(**kwargs) -> None:
    for key, value in kwargs.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{key} must be a positive number, got {value!r}")


def _generate(comm: MPI.Comm, build, h: float, order: int, dim: int = 2, refine: int = 0):
    """Run ``build(occ)`` on rank 0 (it returns the domain's entities of dimension ``dim`` and
    ``model -> {tag: [boundary entities]}``), mesh, split ``refine`` times uniformly and convert."""
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    if int(refine) != refine or refine < 0:
        raise ValueError(f"refine must be a non-negative integer, got {refine!r}")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        if comm.rank == 0:
            gmsh.model.add("cell_test_mesh")
            occ = gmsh.model.occ
            domain, boundary = build(occ)
            occ.synchronize()
            gmsh.model.addPhysicalGroup(dim, domain, _DOMAIN)
            for tag, ids in boundary(gmsh.model).items():
                gmsh.model.addPhysicalGroup(dim - 1, ids, tag)
            gmsh.option.setNumber("Mesh.MeshSizeMin", h)
            gmsh.option.setNumber("Mesh.MeshSizeMax", h)
            gmsh.model.mesh.generate(dim)
            for _ in range(int(refine)):
                gmsh.model.mesh.refine()
            gmsh.model.mesh.setOrder(order)
        msh, _, facet_tags = model_to_mesh(gmsh.model, comm, 0, gdim=dim)
    finally:
        gmsh.finalize()
    if dim == 3:
        _check_not_inverted(msh, h)
    return msh, facet_tags


def _check_not_inverted(msh, h: float) -> None:
    """Raise ValueError if a (curved) tetrahedron has det J <= 0 at a P2 node or quadrature point.

    gmsh's curving of coarse tetrahedra onto a sphere seen from inside (a hollow sphere's
    inner face) can invert some; such a mesh gives wrong normals and integrals.
    """
    cell = basix.CellType.tetrahedron
    points = np.vstack([basix.create_lattice(cell, 2, basix.LatticeType.equispaced, True),
                        basix.make_quadrature(cell, 4)[0]])
    detj = fem.Expression(ufl.JacobianDeterminant(msh), points)
    cells = np.arange(msh.topology.index_map(3).size_local, dtype=np.int32)
    local = float(detj.eval(cells).min()) if cells.size else np.inf
    if msh.comm.allreduce(local, op=MPI.MIN) <= 0:
        raise ValueError(f"the curved mesh of size h={h} has inverted tetrahedra (det J <= 0); "
                         f"choose another h or order=1")


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


def _classify_faces(model, centre, radius_tag) -> dict[int, list[int]]:
    """Group the model's surfaces: a flat face by its normal axis (PLANE_X, _Y, _Z), a spherical
    face by ``radius_tag(r)`` of its distance r from ``centre``."""
    groups: dict[int, list[int]] = {}
    for _, f in model.getEntities(2):
        lo, hi = model.getParametrizationBounds(2, f)
        mid = 0.5 * (np.asarray(lo) + np.asarray(hi))
        if model.getType(2, f) == "Plane":
            axis = int(np.argmax(np.abs(model.getNormal(f, mid))))
            tag = (PLANE_X, PLANE_Y, PLANE_Z)[axis]
        else:
            tag = radius_tag(np.linalg.norm(np.asarray(model.getValue(2, f, mid)) - centre))
        groups.setdefault(tag, []).append(f)
    return groups


def _cut(occ, body, centre, size, planes):
    """Keep the part of ``body`` with x_i > centre_i for every axis i in ``planes``."""
    planes = sorted(set(int(p) for p in planes))
    if any(p not in (0, 1, 2) for p in planes):
        raise ValueError(f"planes must be axes 0, 1 or 2, got {planes!r}")
    if not planes:
        return body
    lo = [c if i in planes else c - size for i, c in enumerate(centre)]
    box = occ.addBox(*lo, *[size if i in planes else 2 * size for i in range(3)])
    return occ.intersect(body, [(3, box)])[0]


def ball(radius: float, h: float, centre=(0.0, 0.0, 0.0), planes=(), order: int = 2, refine: int = 0,
         comm: MPI.Comm = MPI.COMM_WORLD):
    """A ball of ``radius`` about ``centre`` (tetrahedra), the 3D counterpart of :func:`disk`.

    Args:
        planes: axes i (0, 1, 2) whose plane x_i = centre_i cuts the ball; the part
            x_i > centre_i is kept (a half, quarter or eighth ball on symmetry planes).
        refine: number of uniform splits of the mesh of size ``h`` (nested meshes
            of size h / 2^refine, their new boundary nodes on the sphere).

    Returns:
        ``(mesh, facet_tags)`` with tags BOUNDARY (the spherical surface, as Gamma2)
        and PLANE_X, PLANE_Y, PLANE_Z (the flat faces of the cut).
    """
    _check_positive(radius=radius, h=h)
    c = np.asarray(centre, dtype=float).reshape(3)

    def build(occ):
        body = _cut(occ, [(3, occ.addSphere(*c, radius))], c, 2 * radius, planes)
        return [t for _, t in body], lambda model: _classify_faces(model, c, lambda r: BOUNDARY)

    return _generate(comm, build, h, order, dim=3, refine=refine)


def shell(a: float, b: float, h: float, octant: bool = False, order: int = 2, refine: int = 0,
          comm: MPI.Comm = MPI.COMM_WORLD):
    """The hollow sphere ``a < r < b`` centred at the origin, the 3D counterpart of :func:`annulus`.

    Args:
        octant: only the eighth x, y, z > 0 (faces tagged PLANE_X, PLANE_Y, PLANE_Z).
        refine: number of uniform splits, as for :func:`ball`.

    Returns:
        ``(mesh, facet_tags)`` with tags INNER (r = a), OUTER (r = b) (and the planes).
    """
    _check_positive(a=a, b=b, h=h)
    if not a < b:
        raise ValueError(f"need a < b, got a={a}, b={b}")
    c = np.zeros(3)

    def build(occ):
        body, _ = occ.cut([(3, occ.addSphere(0, 0, 0, b))], [(3, occ.addSphere(0, 0, 0, a))])
        body = _cut(occ, body, c, 2 * b, (0, 1, 2) if octant else ())
        return [t for _, t in body], lambda model: _classify_faces(
            model, c, lambda r: INNER if abs(r - a) < abs(r - b) else OUTER)

    return _generate(comm, build, h, order, dim=3, refine=refine)


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
