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
from gelcell.geometry.meshes import build_meshes

__all__ = ["DeviceFields", "WorldFields", "fields_from_device", "fields_from_monolithic", "relative_differences"]


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
    """The current fields of a partitioned :class:`gelcell.coupled.device.Device`.

    A distributed device (``distribute``) has each field on its group's
    ranks only: its fields are then copies on region meshes of the world
    communicator (:class:`WorldFields`), on every rank as without it.
    """
    if device.distribution is not None:
        return WorldFields(device).fields
    return _device_fields(device.params, _field_functions(device), device.meshes)


#: the functions of a device's fields: ``name: (region, owner field, function of the device)``
_FIELD_FUNCTIONS = {
    "fluid_velocity": ("fluid", "fluid", lambda d: d.fluid.velocity),
    "fluid_pressure": ("fluid", "fluid", lambda d: d.fluid.pressure),
    "fluid_mesh_displacement": ("fluid", "fluid", lambda d: getattr(d.fluid, "mesh_displacement", None)),
    "interstitial_velocity": ("gel", "gel", lambda d: d.gel.interstitial_velocity()),
    "displacement": ("gel", "gel", lambda d: d.gel.displacement()),
    "pore_pressure": ("gel", "gel", lambda d: d.gel.pore_pressure()),
    "cell_displacement": ("cell", "cell", lambda d: d.cell.displacement),
}


def _has(device, owner: str) -> bool:
    """Whether the device has the fields of solver ``owner`` (the cell's only with a cell)."""
    return owner != "cell" or device.params.with_cell


def _field_functions(device) -> dict[str, fem.Function | None]:
    """``{name: function}`` of the fields of :data:`_FIELD_FUNCTIONS` on this rank (None where not)."""
    return {name: get(device) if _has(device, owner) and device.is_local(owner) else None
            for name, (_, owner, get) in _FIELD_FUNCTIONS.items()}


def _device_fields(params: CaseParameters, functions: dict, meshes) -> DeviceFields:
    """The :class:`DeviceFields` of ``functions`` (:func:`_field_functions`) with the tags of ``meshes``."""
    return DeviceFields(
        params=params, **functions, fluid_tags=meshes.region("fluid")[1], gel_tags=meshes.region("gel")[1],
        cell_tags=meshes.region("cell")[1] if functions["cell_displacement"] is not None else None,
        layout=meshes.layout, cell_regions=meshes.cell_tags)


class WorldFields:
    """The fields of a distributed device, copied onto region meshes of its world communicator.

    Each field's solver runs on its process group only, on the group's own
    region meshes.  This builds the region meshes once more on the world
    communicator (the mesh cache makes it cheap: they come from the same
    gmsh mesh, so their nodes coincide with the groups') and copies each
    field from its group node by node (:class:`~femtools.transfer.NodalTransfer`
    over the world communicator), as the monolithic reference's fields are
    copied onto the region meshes.  The post-processing then runs on
    :attr:`fields` on every rank, unchanged.  Collective on the world
    communicator.

    Args:
        device: a :class:`gelcell.coupled.device.Device` built with ``distribute``.
        meshes: its region meshes on ``device.comm`` (default: built here).
    """

    def __init__(self, device, meshes=None):
        self.device = device
        self.meshes = meshes or build_meshes(device.params, device.comm, whole=False)
        local = _field_functions(device)
        self._copies: dict[str, tuple[NodalTransfer, fem.Function]] = {}
        spaces: dict = {}
        world = dict.fromkeys(local)
        for name, (region, owner, _) in _FIELD_FUNCTIONS.items():
            # the element of the field (None if this device has no such field), known on every rank
            if not _has(device, owner):
                continue
            element = device._from_field(owner, lambda f=local[name]: None if f is None else f.ufl_element())
            if element is None:
                continue
            if (region, element) not in spaces:
                spaces[region, element] = fem.FunctionSpace(self.meshes.region(region)[0], element)
            V, src = spaces[region, element], local[name]
            # one transfer per field: the group's fields of one element may have different dof orders
            transfer = NodalTransfer(None if src is None else src.function_space, V, comm=device.comm)
            world[name] = fem.Function(V, name=name)
            self._copies[name] = (transfer, world[name])
        self.fields = _device_fields(device.params, world, self.meshes)
        self.update()

    def update(self) -> DeviceFields:
        """Copy the device's current fields into :attr:`fields` (collective); returns them."""
        local = _field_functions(self.device)
        for name, (transfer, dst) in self._copies.items():
            transfer.apply(local[name], dst)
        return self.fields


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
