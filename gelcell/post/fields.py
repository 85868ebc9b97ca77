"""The solution of a device case as fields on the region meshes, from either method.

Both the partitioned run and the monolithic reference end here: the
monolithic fields are copied node by node onto the region meshes (the nodes
coincide), so every reported quantity is computed by the same code for both
(:mod:`gelcell.post.quantities`).  Fields are stored in the solvers' units
(velocity V0, stress s mu_s, displacement d L0, with s = d = Ca by default).
With finite kinematics the fluid fields live on the fluid's reference mesh
and ``fluid_mesh_displacement`` maps it to the current domain.
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem

import gel.forms as gel_forms
import gel.lagrangian as gel_lagrangian
from femtools.functions import integrate
from femtools.transfer import NodalTransfer
from gelcell.case import CaseParameters
from gelcell.geometry import DeviceLayout, device_layout

__all__ = ["DeviceFields", "fields_from_device", "fields_from_monolithic", "relative_differences"]


@dataclasses.dataclass
class DeviceFields:
    """Fields of a solved device case on the region meshes (solver units)."""

    params: CaseParameters
    fluid_velocity: fem.Function
    fluid_pressure: fem.Function
    interstitial_velocity: fem.Function
    displacement: fem.Function
    pore_pressure: fem.Function
    cell_displacement: fem.Function | None
    fluid_tags: typing.Any
    gel_tags: typing.Any
    cell_tags: typing.Any = None
    #: finite kinematics: the fluid mesh's displacement to the current domain (solver units, d L0)
    fluid_mesh_displacement: fem.Function | None = None
    #: the device's :class:`~gelcell.geometry.DeviceLayout` (cells, interfaces); None: from ``params``
    layout: DeviceLayout | None = None
    #: cell tags of the cell mesh (which cell each element belongs to); None: one cell
    cell_regions: typing.Any = None

    def __post_init__(self):
        if self.layout is None:
            self.layout = device_layout(self.params)

    @property
    def cells(self) -> list:
        """The :class:`~gelcell.geometry.CellSpec` of every cell (empty without cells)."""
        return list(self.layout.cells) if self.cell_displacement is not None else []

    @property
    def comm(self) -> MPI.Comm:
        return self.displacement.function_space.mesh.comm

    @property
    def gel_mesh(self):
        return self.displacement.function_space.mesh

    @property
    def cell_mesh(self):
        return None if self.cell_displacement is None else self.cell_displacement.function_space.mesh

    @property
    def gel_forms(self):
        """The gel's forms of this case's kinematics: ``gel.forms`` or ``gel.lagrangian``."""
        return gel_lagrangian if self.params.kinematics == "finite" else gel_forms

    def fluid_stress(self, c: gel_forms.GelCoefficients):
        """The interstitial fluid's viscous stress sigma_f / s of this case's kinematics (UFL)."""
        if self.params.kinematics == "finite":
            return gel_lagrangian.fluid_stress(self.interstitial_velocity, self.displacement, c)
        return gel_forms.fluid_stress(self.interstitial_velocity, c)

    def gel_coefficients(self) -> gel_forms.GelCoefficients:
        p, m = self.params, self.gel_mesh
        ph, s, d = p.physics, p.stress_scale, p.displacement_scale
        c = lambda v: fem.Constant(m, float(v))  # noqa: E731
        return gel_forms.GelCoefficients(phi_s0=c(ph.phi_s0), xi=c(ph.xi), lambda_s=c(ph.lambda_s),
                                         beta=c(ph.beta), eta=c(ph.eta), viscosity=c(ph.ca / s),
                                         stiffness=c(d / s), d=c(d))


def fields_from_device(device) -> DeviceFields:
    """The current fields of a partitioned :class:`gelcell.coupled.device.Device`."""
    fluid_mesh, fluid_tags = device.meshes.region("fluid")
    _, gel_tags = device.meshes.region("gel")
    cell_tags = device.meshes.region("cell")[1] if device.cell is not None else None
    gel = device.gel
    return DeviceFields(
        params=device.params, fluid_velocity=device.fluid.velocity, fluid_pressure=device.fluid.pressure,
        interstitial_velocity=gel.interstitial_velocity(), displacement=gel.displacement(),
        pore_pressure=gel.pore_pressure(),
        cell_displacement=None if device.cell is None else device.cell.displacement,
        fluid_tags=fluid_tags, gel_tags=gel_tags, cell_tags=cell_tags,
        fluid_mesh_displacement=getattr(device.fluid, "mesh_displacement", None),
        layout=device.meshes.layout, cell_regions=device.meshes.cell_tags)


def _region_spaces(msh):
    return (fem.VectorFunctionSpace(msh, ("Lagrange", 2)), fem.FunctionSpace(msh, ("Lagrange", 1)))


def fields_from_monolithic(solver, device_mesh, params: CaseParameters) -> DeviceFields:
    """Copy the monolithic solution onto the region meshes of ``device_mesh``."""
    fluid_mesh, fluid_tags = device_mesh.region("fluid")
    gel_mesh, gel_tags = device_mesh.region("gel")
    out = {}
    fluid_names = ("V", "P", "fluid_motion") if params.kinematics == "finite" else ("V", "P")
    for msh, names in ((fluid_mesh, fluid_names), (gel_mesh, ("v_f", "u", "p"))):
        Vv, Vs = _region_spaces(msh)
        for name in names:
            src = solver.field(name)
            dst = fem.Function(Vs if name in ("P", "p") else Vv, name=name)
            NodalTransfer(src.function_space, dst.function_space).apply(src, dst)
            out[name] = dst
    u_c, cell_tags = None, None
    if device_mesh.cells:
        cell_mesh, cell_tags = device_mesh.region("cell")
        Vv, _ = _region_spaces(cell_mesh)
        src = solver.field("u")
        u_c = NodalTransfer(src.function_space, Vv).apply(src, fem.Function(Vv, name="u_c"))
    return DeviceFields(params=params, fluid_velocity=out["V"], fluid_pressure=out["P"],
                        interstitial_velocity=out["v_f"], displacement=out["u"], pore_pressure=out["p"],
                        cell_displacement=u_c, fluid_tags=fluid_tags, gel_tags=gel_tags, cell_tags=cell_tags,
                        fluid_mesh_displacement=out.get("fluid_motion"), layout=device_mesh.layout,
                        cell_regions=device_mesh.cell_tags)


def _l2(f, comm) -> float:
    dx = ufl.Measure("dx", domain=f.function_space.mesh)
    return np.sqrt(integrate(ufl.inner(f, f), dx, comm))


def relative_differences(a: DeviceFields, b: DeviceFields) -> dict[str, float]:
    """Relative L2 differences ||a - b|| / ||b|| of every field (same meshes required)."""
    out = {}
    pairs = [("fluid_velocity", a.fluid_velocity, b.fluid_velocity),
             ("fluid_pressure", a.fluid_pressure, b.fluid_pressure),
             ("interstitial_velocity", a.interstitial_velocity, b.interstitial_velocity),
             ("displacement", a.displacement, b.displacement),
             ("pore_pressure", a.pore_pressure, b.pore_pressure)]
    if a.cell_displacement is not None and b.cell_displacement is not None:
        pairs.append(("cell_displacement", a.cell_displacement, b.cell_displacement))
    for name, fa, fb in pairs:
        diff = fem.Function(fb.function_space)
        NodalTransfer(fa.function_space, fb.function_space).apply(fa, diff)
        diff.x.array[:] -= fb.x.array
        ref = _l2(fb, fb.function_space.mesh.comm)
        out[name] = _l2(diff, fb.function_space.mesh.comm) / ref if ref > 0 else 0.0
    return out
