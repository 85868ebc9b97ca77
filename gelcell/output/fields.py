"""The fields of a run for ParaView: XDMF of the region meshes, with the derived stresses and strains.

All files of a run go to a temporary directory first, which replaces the
output directory only when every file has been written (femtools.io): a run
that fails leaves no partial results behind.

Fields are written in the paper's dimensionless units (lengths L0,
velocities V0, stresses mu_s); ``summary.json`` has both those and SI units.
"""

from __future__ import annotations

import os



import ufl
from dolfinx import fem

import cell.forms as cell_forms
import gel.forms as gel_forms
from femtools.functions import NodalAverage, von_mises
from femtools.xdmf import NodalXDMF
from gelcell.post.fields import DeviceFields

__all__ = ["DerivedFields", "FieldSeries", "write_fields"]




class DerivedFields:
    """The fields written for ParaView and drawn in the figures, paper units, compiled once.

    gel: v_f, u_s, p, the network's von Mises stress and the von Mises
    measures of the three stress parts and their sum; cell: u_c, von Mises
    strain and stress (von Mises measures at the P2 nodes, each the mean over
    the cells around the node: ``femtools.functions.NodalAverage``, the same on
    any partition); fluid: V, P and, with finite kinematics, the mesh
    displacement to its current domain.  The stress and displacement units
    enter as Constants, so no parameter value makes anything compile again; ``update()`` recomputes every field from the
    (possibly changed) functions of ``fields``.
    """

    def __init__(self, fields: DeviceFields):
        self.fields = fields
        p = fields.params
        gm = fields.gel_mesh
        c = fields.gel_coefficients()
        u, v_f, pp = fields.displacement, fields.interstitial_velocity, fields.pore_pressure
        s_gel = fem.Constant(gm, float(p.stress_scale))
        Q2 = fem.FunctionSpace(gm, ("Lagrange", 2))
        phi_s = gel_forms.solid_fraction(u, c)
        scalars = {"von_mises_network": von_mises(gel_forms.network_stress(u, c))}
        parts = {"pressure": -pp * ufl.Identity(gm.geometry.dim), "brinkman": (1 - phi_s) * fields.fluid_stress(c),
                 "network": phi_s * gel_forms.network_stress(u, c),
                 "total": fields.gel_forms.total_stress(v_f, u, pp, c)}
        scalars.update({f"von_mises_{k}_part": von_mises(e) for k, e in parts.items()})
        self.fluid = {"V": fem.Function(fields.fluid_velocity.function_space, name="V"),
                      "P": fem.Function(fields.fluid_pressure.function_space, name="P")}
        if fields.fluid_mesh_displacement is not None:
            # finite kinematics: warp the fluid mesh by it to see the current domain
            self.fluid["mesh_displacement"] = fem.Function(fields.fluid_mesh_displacement.function_space,
                                                           name="mesh_displacement")
        self.gel = {"v_f": fem.Function(v_f.function_space, name="v_f"),
                    "u_s": fem.Function(u.function_space, name="u_s"),
                    "p": fem.Function(pp.function_space, name="p")}
        self._expressions = []
        # von Mises measures jump between cells: a node takes the mean of its cells, on any partition
        self._averages = {gm: NodalAverage(Q2)}
        for name, expr in scalars.items():
            self.gel[name] = fem.Function(Q2, name=name)
            self._expressions.append((self.gel[name],
                                      fem.Expression(s_gel * expr, Q2.element.interpolation_points())))
        self.cell = None
        if fields.cell_displacement is not None:
            uc, cm = fields.cell_displacement, fields.cell_mesh
            k = lambda v: fem.Constant(cm, float(v))  # noqa: E731
            Qc = fem.FunctionSpace(cm, ("Lagrange", 2))
            self._averages[cm] = NodalAverage(Qc)
            sc, dc = k(p.stress_scale), k(p.displacement_scale)
            sigma = cell_forms.cauchy_stress(uc, k(p.mu_c), k(p.lambda_c), dc, sc)
            self.cell = {"u_c": fem.Function(uc.function_space, name="u_c"),
                         "von_mises_strain": fem.Function(Qc, name="von_mises_strain"),
                         "von_mises_stress": fem.Function(Qc, name="von_mises_stress")}
            for name, expr in (("von_mises_strain", von_mises(cell_forms.green_lagrange(uc, dc))),
                               ("von_mises_stress", sc * von_mises(sigma))):
                self._expressions.append((self.cell[name], fem.Expression(expr, Qc.element.interpolation_points())))
        self.update()

    def update(self) -> None:
        f, p = self.fields, self.fields.params
        s, d = p.stress_scale, p.displacement_scale
        for dst, src, factor in ((self.fluid["V"], f.fluid_velocity, 1.0), (self.fluid["P"], f.fluid_pressure, s),
                                 (self.gel["v_f"], f.interstitial_velocity, 1.0), (self.gel["u_s"], f.displacement, d),
                                 (self.gel["p"], f.pore_pressure, s)):
            dst.x.array[:] = factor * src.x.array
        if f.fluid_mesh_displacement is not None:
            self.fluid["mesh_displacement"].x.array[:] = d * f.fluid_mesh_displacement.x.array
        if self.cell is not None:
            self.cell["u_c"].x.array[:] = d * f.cell_displacement.x.array
        for dst, expression in self._expressions:
            self._averages[dst.function_space.mesh](expression, dst)

    def groups(self) -> list[tuple[str, object, list]]:
        """``(file name, mesh, functions)`` of each XDMF file."""
        out = [("fluid.xdmf", self.fields.fluid_velocity.function_space.mesh, list(self.fluid.values())),
               ("gel.xdmf", self.fields.gel_mesh, list(self.gel.values()))]
        if self.cell is not None:
            out.append(("cell.xdmf", self.fields.cell_mesh, list(self.cell.values())))
        return out






class FieldSeries:
    """XDMF files (fluid, gel, cell) holding the derived fields at several times, for ParaView
    (``femtools.xdmf.NodalXDMF``: the files dolfinx writes, without its cost per field on curved
    meshes).  Each ``write`` leaves the files complete; nothing is held open between writes."""

    def __init__(self, directory: str, derived: DerivedFields):
        self.derived = derived
        self.files = [(name, NodalXDMF(os.path.join(directory, name), msh), functions)
                      for name, msh, functions in derived.groups()]

    @property
    def names(self) -> list[str]:
        return [name for name, _, _ in self.files]

    def write(self, t: float) -> None:
        """Write the derived fields as they are now, at time t."""
        for _, xf, functions in self.files:
            xf.write(functions, t)


def write_fields(directory: str, fields: DeviceFields, derived: DerivedFields | None = None) -> list[str]:
    """fluid.xdmf (V, P), gel.xdmf (v_f, p, u_s, von Mises ...), cell.xdmf (u_c, strain, stress).

    ``derived``: the :class:`DerivedFields` of ``fields`` if already built (e.g. shared with the figures).
    """
    series = FieldSeries(directory, derived or DerivedFields(fields))
    series.write(0.0)
    return series.names


