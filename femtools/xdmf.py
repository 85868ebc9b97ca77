"""XDMF time series of Lagrange fields at the geometry nodes of a (curved) mesh, for ParaView.

The files are those dolfinx's ``XDMFFile.write_function`` writes: the mesh
(written by dolfinx itself), and per field a temporal collection whose
attributes hold the field at the mesh's geometry nodes, vectors padded to three
components, in ``<stem>.h5:/Function/<name>/<time>``.

Why not ``write_function``: on a mesh of degree 2 (the device meshes, whose
curved edges are P2) dolfinx 0.5's call is slow whatever the field, far slower
than on the same mesh with straight edges, and a run makes one call per field
and frame (docs/femtools-costs.md).  Here a field in the coordinate element's space is a reordering of its dof
values (the geometry nodes are its dofs); any other Lagrange field is first
interpolated into that space on its own mesh (no form compilation).  The values
are gathered on rank 0 in the global node order of the mesh dataset and
appended with h5py, and rank 0 rewrites the XML file after each time.
"""

from __future__ import annotations

import os
import xml.sax.saxutils

import numpy as np

from dolfinx import fem, io

from femtools.functions import LAGRANGE_FAMILIES, gather_owned_rows

__all__ = ["NodalXDMF"]

_TEMPORAL = """    <Grid Name="{name}" GridType="Collection" CollectionType="Temporal">
{steps}    </Grid>
"""
_STEP = """      <Grid Name="{name}" GridType="Uniform">
        <xi:include xpointer="xpointer(/Xdmf/Domain/Grid[@GridType='Uniform'][1]/*[self::Topology or self::Geometry])" />
        <Time Value="{time}" />
        <Attribute Name="{name}" AttributeType="{kind}" Center="Node">
          <DataItem Dimensions="{rows} {columns}" Format="HDF">{h5}:{dataset}</DataItem>
        </Attribute>
      </Grid>
"""


class NodalXDMF:
    """One XDMF file (``path``, with ``<stem>.h5`` beside it) of fields on ``msh`` at several times.

    ``write(functions, t)`` is collective; every function must live on ``msh``,
    in a Lagrange space (scalar or vector), and have a name unique in the file.
    """

    def __init__(self, path: str, msh):
        self.path, self.msh, self.comm = path, msh, msh.comm
        stem = os.path.splitext(path)[0]
        self.h5_path, self.h5_name = stem + ".h5", os.path.basename(stem) + ".h5"
        with io.XDMFFile(self.comm, path, "w") as xf:
            xf.write_mesh(msh)
        imap = msh.geometry.index_map()
        self._n_owned, self._start, self._n = imap.size_local, imap.local_range[0], imap.size_global
        self._node_spaces: dict[int, fem.FunctionSpace] = {}
        self._node_dofs: dict[int, np.ndarray] = {}
        self._steps: dict[str, list[str]] = {}
        self._head = None
        if self.comm.rank == 0:
            with open(path) as f:
                text = f.read()
            self._head = text[:text.rindex("  </Domain>")]

    # -- nodal values --------------------------------------------------------
    def _node_space(self, bs: int) -> fem.FunctionSpace:
        """The coordinate element's Lagrange space with block size ``bs`` (its dofs are the geometry nodes)."""
        if bs not in self._node_spaces:
            degree = self.msh.geometry.cmap.degree
            self._node_spaces[bs] = (fem.FunctionSpace(self.msh, ("Lagrange", degree)) if bs == 1 else
                                     fem.VectorFunctionSpace(self.msh, ("Lagrange", degree), dim=bs))
        return self._node_spaces[bs]

    def _dofs_of_nodes(self, V: fem.FunctionSpace) -> np.ndarray:
        """The dof of ``V`` (the coordinate element's space) at each owned geometry node."""
        key = id(V)
        if key not in self._node_dofs:
            geometry = self.msh.geometry.dofmap.array
            dofs = V.dofmap.list.array
            if geometry.size != dofs.size:
                raise ValueError(f"{V}: not the mesh's coordinate element space")
            of_node = np.empty(self.msh.geometry.x.shape[0], dtype=np.int64)
            of_node[geometry] = dofs
            self._node_dofs[key] = (V, of_node[:self._n_owned])     # V kept alive: id() stays unique
        return self._node_dofs[key][1]

    def _is_node_space(self, V: fem.FunctionSpace) -> bool:
        """Whether ``V`` is a (collapsed) Lagrange space of the coordinate element's degree."""
        e = V.ufl_element()        # a MixedElement reports "Mixed"
        return (e.family() in LAGRANGE_FAMILIES and e.degree() == self.msh.geometry.cmap.degree
                and not V.component())

    def nodal_values(self, f: fem.Function) -> np.ndarray:
        """(owned geometry nodes, components) values of ``f``, vectors padded to 3 components."""
        V = f.function_space
        if V.mesh is not self.msh:
            raise ValueError(f"{f.name}: not a function on this file's mesh")
        bs = V.dofmap.index_map_bs
        if bs > 3:
            raise ValueError(f"{f.name}: only scalar and vector fields are written, not {bs} components")
        if not self._is_node_space(V):
            g = fem.Function(self._node_space(bs))
            g.interpolate(f)
            V, f = g.function_space, g
        values = f.x.array.reshape(-1, bs)[self._dofs_of_nodes(V)]
        columns = 1 if bs == 1 else 3
        if columns > bs:
            values = np.hstack([values, np.zeros((values.shape[0], columns - bs))])
        return values

    # -- writing ---------------------------------------------------------------
    def write(self, functions, t: float) -> None:
        """Append ``functions`` at time ``t`` (collective); the XML is rewritten whole."""
        parts = [gather_owned_rows(self.comm, self._start, self.nodal_values(f), self._n) for f in functions]
        error = None
        if self.comm.rank == 0:
            try:
                self._append(functions, parts, float(t))
            except Exception as exc:       # every rank must learn of it, or the others hang later
                error = f"{self.path}: {exc}"
        error = self.comm.bcast(error, root=0)
        if error is not None:
            raise OSError(error)

    def _append(self, functions, parts, t: float) -> None:
        import h5py

        time_text = repr(t)[:-2] if repr(t).endswith(".0") else repr(t)     # 0 as dolfinx writes it, not 0.0
        time_key = time_text.replace(".", "_")
        with h5py.File(self.h5_path, "a") as h5:
            for f, data in zip(functions, parts):
                columns = data.shape[1]
                dataset = f"/Function/{f.name}/{time_key}"
                h5.create_dataset(dataset, data=data)
                kind = "Scalar" if columns == 1 else "Vector"
                self._steps.setdefault(f.name, []).append(_STEP.format(
                    name=xml.sax.saxutils.escape(f.name), time=time_text, kind=kind, rows=self._n,
                    columns=columns, h5=self.h5_name, dataset=dataset))
        grids = "".join(_TEMPORAL.format(name=xml.sax.saxutils.escape(name), steps="".join(steps))
                        for name, steps in self._steps.items())
        tmp = self.path + ".tmp"
        with open(tmp, "w") as out:
            out.write(self._head + grids + "  </Domain>\n</Xdmf>\n")
        os.replace(tmp, self.path)
