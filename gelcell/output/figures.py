"""Figures of a device run: the fields gathered on rank 0, drawn by :mod:`gelcell.output.drawing`.

``figure_data`` gathers everything a figure shows into plain arrays (a
collective call); ``gelcell.output.drawing.render_device_figures`` draws them on rank 0
(:func:`collect_figures`).  A serial run may instead hand them to a
:class:`FigureWorker`: a separate Python process
started before the solve, which imports matplotlib while the run solves and
draws while the run writes its other files (XDMF, profiles, records), the
figures shared among forked processes, one per core, since the run then only waits.

3D devices (model.md section 10) are drawn as sections, with the 2D figures'
names: gel_velocity, gel_pressure, gel_displacement_von_mises,
cell_displacement and cell_traction_parts show the mid-height plane
z = H/2 (the paper's view; the mesh's own triangles there, the facets of the
symmetry plane), gamma1_profiles the mid-height line of Gamma1.  Two more
figures show the vertical plane y = y_cell through the (first) cell's centre
(without a cell: the default cell position), the plane that holds the flow
direction x and the height z, so the flow past the cell and the floor's
boundary layer are seen: gel_velocity_vertical.png (|v_f| and the in-plane
streamlines of (v_f,x, v_f,z)) and gel_displacement_von_mises_vertical.png;
the fields are evaluated at the points of a regular grid there
(:class:`PlaneSection`).
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import signal
import subprocess
import sys
import threading
import types

import numpy as np

from mpi4py import MPI

from dolfinx import fem, geometry

from femtools.functions import gather_owned_rows
from gelcell.output.fields import DerivedFields
from gelcell.post.fields import DeviceFields

__all__ = ["figure_data", "FigureWorker", "FigureWorkerError", "figure_worker", "collect_figures", "P1Gather",
           "MidHeightSection", "PlaneSection", "mid_height_section"]

#: the package's parent directory, so that the worker imports this very gelcell
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def figure_data(fields: DeviceFields, profiles: dict, summary: dict, overlay: dict | None = None,
                derived: DerivedFields | None = None) -> dict | None:
    """Everything the figures of a run show, as plain arrays and numbers on rank 0 (None elsewhere).

    Collective.  The fields are interpolated into P1 and gathered; the cells are
    described by name, centre and diameter only, so the data can be pickled
    and drawn by a process that has neither dolfinx nor MPI.
    """
    p = fields.params
    derived = derived or DerivedFields(fields)
    gel = derived.gel
    three_d = fields.gel_mesh.geometry.dim == 3
    on_gel = (mid_height_section(fields, fields.gel_mesh, fields.gel_tags) if three_d
              else P1Gather(fields.gel_mesh)).gather
    data = {"speed": on_gel(gel["v_f"]), "pressure": on_gel(gel["p"]), "disp": on_gel(gel["u_s"]),
            "vm": on_gel(gel["von_mises_network"]),
            "parts": {k: on_gel(gel[f"von_mises_{k}_part"]) for k in ("pressure", "brinkman", "network", "total")},
            "cell": None}
    if fields.cell_displacement is not None:
        on_cell = (mid_height_section(fields, fields.cell_mesh, fields.cell_tags) if three_d
                   else P1Gather(fields.cell_mesh))
        data["cell"] = on_cell.gather(derived.cell["u_c"])
    data["vertical"] = _vertical_data(fields, gel) if three_d else None
    if fields.comm.rank != 0:
        return None
    data.update(
        V=p.to_report(1.0, "velocity"), L=p.to_report(1.0, "length"), S=p.to_report(1.0, "stress"),
        label=p.label, wide=bool(fields.layout.wide), profiles=profiles["Gamma1"], overlay=overlay,
        section=f"mid-height plane z = {_mid_height(fields):.4g}" if three_d else None,
        # in 3D the cells as the mid-height plane cuts them: centre (x, y), the sphere's diameter
        cells=[types.SimpleNamespace(name=c.name, centre=tuple(float(v) for v in c.centre[:2]),
                                     diameter=float(c.diameter)) for c in fields.cells],
        cells_summary=summary.get("cells") or [{"centroid_displacement": summary["cell.centroid_displacement"]}])
    return data


class FigureWorkerError(RuntimeError):
    """The figure worker process failed (its last line of stderr is the message)."""


class FigureWorker:
    """A Python process that draws one run's figures (``python -m gelcell.output.drawing``).

    Start it before the solve: it imports matplotlib (~0.5 s) on the other
    core meanwhile.  ``submit(directory, data)`` sends the data of
    :func:`figure_data`; ``result()`` waits for the file names.  For serial
    runs only: under MPI both cores already solve.  ``GELCELL_FIGURE_WORKER=0``
    turns it off (see :func:`use_worker`).
    """

    def __init__(self):
        env = dict(os.environ, MPLBACKEND="Agg",
                   PYTHONPATH=os.pathsep.join(filter(None, [_ROOT, os.environ.get("PYTHONPATH")])))
        # a process group of its own: close() stops the processes it forks to draw, too
        self.proc = subprocess.Popen([sys.executable, "-m", "gelcell.output.drawing"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                     start_new_session=True)

    def submit(self, directory: str, data: dict) -> None:
        stdin, self.proc.stdin = self.proc.stdin, None     # sent whole: communicate() must not flush it
        # PETSc's signal handler aborts the run on SIGPIPE: a worker that died must give EPIPE instead
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
        try:
            pickle.dump((directory, data), stdin, protocol=pickle.HIGHEST_PROTOCOL)
        except OSError:                 # the worker is gone; result() reports why
            pass
        finally:
            try:
                stdin.close()
            except OSError:
                pass

    def result(self, timeout: float = 600.0) -> list[str]:
        """The names of the figures written; FigureWorkerError if the worker failed or timed out."""
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.close()
            raise FigureWorkerError(f"the figure worker did not finish within {timeout:.0f} s") from None
        if self.proc.returncode != 0:
            lines = err.decode(errors="replace").strip().splitlines()
            raise FigureWorkerError(f"the figure worker failed (exit {self.proc.returncode}): "
                                    f"{lines[-1] if lines else 'no message'}")
        try:
            names = json.loads(out.decode().strip().splitlines()[-1])
        except (ValueError, IndexError):
            raise FigureWorkerError("the figure worker returned no file names") from None
        return [str(n) for n in names]

    def close(self) -> None:
        """Stop the worker and the processes it forked if they still run (an interrupted or failed run)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                self.proc.kill()
        self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None and not stream.closed:
                stream.close()

    @staticmethod
    def use_worker(comm) -> bool:
        """A worker for serial runs from the main thread (it sets a signal) unless ``GELCELL_FIGURE_WORKER=0``."""
        return (comm.size == 1 and threading.current_thread() is threading.main_thread()
                and os.environ.get("GELCELL_FIGURE_WORKER", "1").strip() != "0")


@contextlib.contextmanager
def figure_worker(wanted: bool, comm):
    """A started :class:`FigureWorker` if ``wanted`` and :meth:`FigureWorker.use_worker` (else None),
    stopped when the block is left, however it is left."""
    worker = FigureWorker() if wanted and FigureWorker.use_worker(comm) else None
    try:
        yield worker
    finally:
        if worker is not None:
            worker.close()


class P1Gather:
    """Vertex coordinates and cells of a mesh gathered on rank 0 once, and field values at the vertices.

    ``gather(f)`` interpolates a Function (any Lagrange space on this mesh,
    scalar or vector; no form compilation) into P1 and returns
    ``(x, cells, values)`` on rank 0 and ``None`` elsewhere: ``x`` (n, gdim),
    ``cells`` the triangles (2D) or tetrahedra (3D) as vertex rows.
    """

    def __init__(self, msh):
        self.msh, self.comm = msh, msh.comm
        self._spaces: dict[bool, fem.FunctionSpace] = {}
        Q = self._space(False)
        imap = Q.dofmap.index_map
        n_owned = imap.size_local
        self._n_owned, self._start, self._n = n_owned, imap.local_range[0], imap.size_global
        tdim = msh.topology.dim
        x = Q.tabulate_dof_coordinates()[:n_owned, :msh.geometry.dim]
        gidx = imap.local_to_global(np.arange(n_owned + imap.num_ghosts, dtype=np.int32))
        n_cells = msh.topology.index_map(tdim).size_local
        tri = gidx[Q.dofmap.list.array.reshape(-1, tdim + 1)[:n_cells]]
        self.x = gather_owned_rows(self.comm, self._start, x, self._n)
        triangles = self.comm.gather(tri, root=0)
        self.triangles = np.vstack(triangles) if self.comm.rank == 0 else None

    def _space(self, vector: bool) -> fem.FunctionSpace:
        if vector not in self._spaces:
            element = ("Lagrange", 1)
            self._spaces[vector] = (fem.VectorFunctionSpace(self.msh, element) if vector
                                    else fem.FunctionSpace(self.msh, element))
        return self._spaces[vector]

    def gather(self, f: fem.Function):
        Q = self._space(bool(f.ufl_shape))
        g = fem.Function(Q)
        g.interpolate(f)
        bs = Q.dofmap.index_map_bs
        V = gather_owned_rows(self.comm, self._start, g.x.array.reshape(-1, bs)[:self._n_owned], self._n)
        if self.comm.rank != 0:
            return None
        return self.x, self.triangles, (V[:, 0] if bs == 1 else V)


class MidHeightSection:
    """The mid-height plane z = H/2 of a 3D region mesh: its symmetry-plane facets (Tag.SYMMETRY_MID).

    ``gather(f)`` returns ``(x, triangles, values)`` on rank 0 (None elsewhere)
    as :class:`P1Gather` does for a planar mesh: ``x`` (n, 2) the (x, y) of
    the vertices on the plane, ``values`` the field's P1 interpolant there
    (its vertex values), all its components (v_z = u_z = 0 on the plane by
    symmetry).  Only the plane's vertices are gathered: each rank sends those
    of its owned facets there, with the owners' values.
    """

    def __init__(self, msh, facet_tags):
        from gelcell.geometry import Tag
        self.msh, self.comm = msh, msh.comm
        self._spaces: dict[bool, fem.FunctionSpace] = {}
        Q = self._space(False)
        fdim = msh.topology.dim - 1
        msh.topology.create_connectivity(fdim, fdim + 1)
        msh.topology.create_connectivity(fdim + 1, fdim)
        f_to_c, c_to_f = msh.topology.connectivity(fdim, fdim + 1), msh.topology.connectivity(fdim + 1, fdim)
        n_owned = msh.topology.index_map(fdim).size_local
        facets = facet_tags.indices[(facet_tags.values == int(Tag.SYMMETRY_MID)) & (facet_tags.indices < n_owned)]
        if self.comm.allreduce(len(facets), op=MPI.SUM) == 0:
            raise ValueError("no mid-height symmetry plane (SYMMETRY_MID facets) in a 3D mesh to draw")
        closure = Q.dofmap.dof_layout.entity_closure_dofs
        local = np.empty((len(facets), fdim + 1), dtype=np.int32)
        for i, f in enumerate(facets):
            c = f_to_c.links(f)[0]
            k = int(np.flatnonzero(c_to_f.links(c) == f)[0])
            local[i] = Q.dofmap.cell_dofs(c)[closure(fdim, k)]
        self.dofs, corner = np.unique(local, return_inverse=True)
        global_dofs = Q.dofmap.index_map.local_to_global(self.dofs.astype(np.int32)).astype(np.int64)
        x = Q.tabulate_dof_coordinates()[self.dofs, :2]
        parts = self.comm.gather((global_dofs, x, global_dofs[corner.reshape(local.shape)]), root=0)
        if self.comm.rank == 0:
            self.used = np.unique(np.concatenate([g for g, _, _ in parts]))
            self._rows = [np.searchsorted(self.used, g) for g, _, _ in parts]
            self.x = np.zeros((self.used.size, 2))
            for rows, (_, xr, _) in zip(self._rows, parts):
                self.x[rows] = xr
            self.triangles = np.searchsorted(self.used, np.vstack([t for _, _, t in parts]))

    def _space(self, vector: bool) -> fem.FunctionSpace:
        if vector not in self._spaces:
            self._spaces[vector] = (fem.VectorFunctionSpace(self.msh, ("Lagrange", 1)) if vector
                                    else fem.FunctionSpace(self.msh, ("Lagrange", 1)))
        return self._spaces[vector]

    def gather(self, f: fem.Function):
        Q = self._space(bool(f.ufl_shape))
        g = fem.Function(Q)
        g.interpolate(f)
        g.x.scatter_forward()           # the ghosts hold their owners' values: every rank sends the same
        bs = Q.dofmap.index_map_bs
        parts = self.comm.gather(g.x.array.reshape(-1, bs)[self.dofs], root=0)
        if self.comm.rank != 0:
            return None
        out = np.zeros((self.used.size, bs))
        for rows, values in zip(self._rows, parts):
            out[rows] = values
        return self.x, self.triangles, (out[:, 0] if bs == 1 else out)


class PlaneSection:
    """Fields of a 3D mesh on a regular grid of the plane x_normal = ``offset``, for figures.

    ``normal``: 1 (the vertical plane y = offset, grid axes x and z) or 2 (the
    horizontal plane z = offset, axes x and y).  The grid spans ``first_range``
    along its first axis (x; None: the mesh's extent) and the mesh's extent
    along the second, with spacing about ``spacing``; points on the domain's
    bounding box are moved inside by 1e-9 of the mesh's size.  Each rank
    evaluates the points in its owned cells (bounding-box tree), rank 0 keeps
    each point's value from the lowest rank that found it.  ``gather(f)``
    returns ``(x, triangles, values)`` on rank 0: ``x`` (n, 2) the in-plane
    coordinates of the grid points inside the mesh, ``triangles`` the grid's
    triangles with all three corners inside, ``values`` the field's values
    (all components).
    """

    def __init__(self, msh, normal: int, offset: float, first_range: tuple[float, float] | None, spacing: float):
        comm, tdim = msh.comm, msh.topology.dim
        self.comm, self.msh = comm, msh
        lo, hi = _bounds(msh)
        eps = 1e-9 * float(np.max(hi - lo))
        a, b = {1: (0, 2), 2: (0, 1)}[normal]
        first_range = first_range or (lo[a], hi[a])
        a0, a1 = max(first_range[0], lo[a] + eps), min(first_range[1], hi[a] - eps)
        b0, b1 = lo[b] + eps, hi[b] - eps
        na, nb = (max(2, int(np.ceil(extent / spacing)) + 1) for extent in (a1 - a0, b1 - b0))
        ga, gb = np.meshgrid(np.linspace(a0, a1, na), np.linspace(b0, b1, nb))
        self.shape = gb.shape
        points = np.zeros((ga.size, 3))
        points[:, a], points[:, b] = ga.ravel(), gb.ravel()
        #: the plane's position, moved inside the bounding box
        self.offset = float(np.clip(offset, lo[normal] + eps, hi[normal] - eps))
        points[:, normal] = self.offset
        owned = np.arange(msh.topology.index_map(tdim).size_local, dtype=np.int32)
        tree = geometry.BoundingBoxTree(msh, tdim, owned)
        colliding = geometry.compute_colliding_cells(msh, geometry.compute_collisions(tree, points), points)
        found = np.array([len(colliding.links(i)) > 0 for i in range(len(points))], dtype=bool)
        self.index = np.flatnonzero(found)
        self.cells = np.array([colliding.links(i)[0] for i in self.index], dtype=np.int32)
        self.points = points
        gathered = comm.gather(self.index, root=0)
        if comm.rank == 0:
            # each point from the lowest rank that has it
            self.source = np.full(len(points), -1, dtype=np.int64)
            for rank in reversed(range(comm.size)):
                self.source[gathered[rank]] = rank
            self.gathered_index = gathered
            inside = self.source >= 0
            self.used = np.flatnonzero(inside)
            renumber = np.full(len(points), -1, dtype=np.int64)
            renumber[self.used] = np.arange(len(self.used))
            self.x = np.column_stack([ga.ravel(), gb.ravel()])[self.used]
            self.triangles = renumber[_grid_triangles(*self.shape, inside)]

    def gather(self, f: fem.Function):
        bs = f.function_space.dofmap.index_map_bs
        values = (f.eval(self.points[self.index], self.cells) if len(self.index)
                  else np.empty((0, bs))).reshape(-1, bs)
        parts = self.comm.gather(values, root=0)
        if self.comm.rank != 0:
            return None
        out = np.zeros((len(self.points), bs))
        for rank, (index, vals) in enumerate(zip(self.gathered_index, parts)):
            mine = self.source[index] == rank
            out[index[mine]] = vals[mine]
        out = out[self.used]
        return self.x, self.triangles, (out[:, 0] if bs == 1 else out)


def mid_height_section(fields: DeviceFields, msh, facet_tags):
    """The mid-height plane of a 3D region mesh: its SYMMETRY_MID facets (:class:`MidHeightSection`), or, a
    mesh without them (a geometry file of the whole height), a grid of the plane z = H/2
    (:class:`PlaneSection`, spacing 1/400 of the mesh's larger planar extent, at most a sixth of the
    smallest cell's radius)."""
    from gelcell.geometry import Tag
    has_plane = msh.comm.allreduce(bool(np.any(facet_tags.values == int(Tag.SYMMETRY_MID))), op=MPI.LOR)
    if has_plane:
        return MidHeightSection(msh, facet_tags)
    lo, hi = _bounds(msh)
    extent = float(np.max(hi[:2] - lo[:2]))
    spacing = min([extent / 400] + [float(c.diameter) / 12 for c in fields.cells])
    return PlaneSection(msh, 2, _mid_height(fields), None, spacing)


def _grid_triangles(nz: int, nx: int, inside: np.ndarray) -> np.ndarray:
    """The two triangles of every square of an (nz, nx) grid (row-major points), the ones whose corners are all
    ``inside``."""
    k = np.arange(nz * nx).reshape(nz, nx)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel()
    tri = np.vstack([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return tri[inside[tri].all(axis=1)]


def _vertical_data(fields: DeviceFields, gel: dict) -> dict | None:
    """The gel's fields on the vertical plane y = y_cell through the first cell's centre (rank 0; None elsewhere).

    The window: x within 2.5 H (at least 5 cell radii) of the cell's centre, the mesh's z extent; the grid's
    spacing the smaller of a sixth of the cell's radius and 1/300 of the window's width.
    """
    p, msh = fields.params, fields.gel_mesh
    height = p.geometry.chip_height or 2 * _mid_height(fields)
    if fields.cells:
        centre, diameter = np.asarray(fields.cells[0].centre, dtype=float), float(fields.cells[0].diameter)
    else:
        x, y, d = (p.geometry.cell_list() or [_middle(msh) + (0.06,)])[0]
        centre, diameter = np.array([x, y, 0.5 * height]), float(d)
    r = 0.5 * diameter
    half = max(1.25 * height, 5 * r)
    spacing = min(r / 6, 2 * half / 300)
    section = PlaneSection(msh, 1, float(centre[1]), (centre[0] - half, centre[0] + half), spacing)
    out = {"speed": section.gather(gel["v_f"]), "disp": section.gather(gel["u_s"]),
           "vm": section.gather(gel["von_mises_network"])}
    if fields.comm.rank != 0:
        return None
    # the cells the plane cuts, as the circles it cuts them in
    cut = [(c, 0.25 * float(c.diameter)**2 - (float(c.centre[1]) - float(centre[1]))**2) for c in fields.cells]
    out.update(y=float(centre[1]), components=(0, 2),
               cells=[types.SimpleNamespace(name=c.name, centre=(float(c.centre[0]), float(c.centre[2])),
                                            diameter=2 * float(np.sqrt(r2))) for c, r2 in cut if r2 > 0])
    return out


def _mid_height(fields: DeviceFields) -> float:
    """z = H/2, the plane the 3D figures show; a geometry file without chip_height: the top of a half-height
    mesh (it has the SYMMETRY_MID plane), else the middle of the gel's z extent."""
    from gelcell.geometry import Tag
    H = fields.params.geometry.chip_height
    if H is not None:
        return 0.5 * float(H)
    msh = fields.gel_mesh
    lo, hi = _bounds(msh)
    half = msh.comm.allreduce(bool(np.any(fields.gel_tags.values == int(Tag.SYMMETRY_MID))), op=MPI.LOR)
    return float(hi[2]) if half else 0.5 * float(lo[2] + hi[2])


def _bounds(msh) -> tuple[np.ndarray, np.ndarray]:
    """The corners (lo, hi) of a mesh's bounding box (every rank)."""
    x, comm = msh.geometry.x, msh.comm
    lo = np.array([comm.allreduce(float(x[:, k].min()) if len(x) else np.inf, op=MPI.MIN) for k in range(3)])
    hi = np.array([comm.allreduce(float(x[:, k].max()) if len(x) else -np.inf, op=MPI.MAX) for k in range(3)])
    return lo, hi


def _middle(msh) -> tuple[float, float]:
    """The (x, y) centre of a mesh's bounding box (every rank)."""
    lo, hi = _bounds(msh)
    return tuple(0.5 * (lo[:2] + hi[:2]))


def collect_figures(tmp: str, data: dict, worker: FigureWorker | None) -> list[str]:
    """The figures drawn by ``worker``, or here if there is none or it failed (rank 0's data)."""
    if worker is not None:
        try:
            return worker.result()
        except FigureWorkerError as exc:
            print(f"gelcell: warning: {exc}; drawing the figures in this process", file=sys.stderr, flush=True)
    from gelcell.output.drawing import render_device_figures      # imports matplotlib
    return render_device_figures(tmp, data)
