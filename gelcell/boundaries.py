"""Which boundary condition holds on which tagged boundary, for both device cases.

model.md section 3.  Shared by the partitioned solvers and the monolithic
reference, so that both solve the same problem.

Shear flow: parabolic inflow with maximum 1 at the inlet, zero traction at
the outlet, no slip on the channel walls; v_f = 0 and u_s = 0 on the bowl.
Normal flow: uniform inflow (1, 0), zero traction at the outlet; v_f = 0 and
u_s = 0 on the posts; symmetry (zero normal velocity and displacement, zero
tangential traction) on y = 0 and y = H.  The cell's flat edge on y = H is
a symmetry line too.  Gamma2 (steady): v_f = 0 on the gel side.

Several cells: each has its own Gamma2 (``Gamma2_k``, facet tag
``gamma2_tag(k)``).  A device from a geometry file (``params.case ==
"file"``) names its boundaries itself (docs/geometry-files.md);
:func:`device_layout` returns the cells, interfaces and conditions of any
case without meshing it.
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

from gelcell.geometry import CellSpec, Tag, cell_region_tag, gamma2_name, gamma2_tag

__all__ = ["DeviceBoundaries", "device_boundaries", "DeviceLayout", "device_layout", "builtin_cells",
           "ParabolicInflow", "SegmentInflow"]


@dataclasses.dataclass
class DeviceBoundaries:
    """Boundary conditions of a device case, by facet tag."""

    fluid_velocity: list[tuple[list[int], typing.Any]]       # full-vector Dirichlet (tags, value)
    fluid_component: list[tuple[list[int], int, float]]      # one-component Dirichlet (tags, comp, value)
    gel_no_slip: list[int]                                   # v_f = 0 and u_s = 0
    gel_symmetry: list[tuple[list[int], int]]                # v_f[c] = 0 and u_s[c] = 0
    cell_symmetry: list[tuple[list[int], int]]               # u_c[c] = 0
    fluid_interfaces: dict[str, int]                         # Gamma1, Gamma3
    cell_interfaces: dict[str, int]                          # Gamma2

    def fluid_dirichlet_tags(self) -> list[tuple[list[int], tuple[int, ...]]]:
        """Every fluid Dirichlet boundary with the velocity components it fixes."""
        out = [(tags, (0, 1)) for tags, _ in self.fluid_velocity]
        out += [(tags, (c,)) for tags, c, _ in self.fluid_component]
        return out


class ParabolicInflow:
    """V = (4 y (H - y) / H^2, 0): plane Poiseuille profile with maximum 1."""

    def __init__(self, height: float):
        self.height = float(height)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        H = self.height
        return np.vstack((4.0 * x[1] * (H - x[1]) / H**2, np.zeros_like(x[0])))


class SegmentInflow:
    """Inflow through a straight inlet from ``a`` to ``b``: ``speed`` times the inward unit ``normal``,
    times 4 s (1 - s) (parabolic, maximum ``speed``) or 1 (uniform), s the position along the segment."""

    def __init__(self, a, b, normal, speed: float, profile: str):
        self.a, self.b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
        self.normal, self.speed, self.profile = np.asarray(normal, float)[:2], float(speed), profile

    def __call__(self, x: np.ndarray) -> np.ndarray:
        t = self.b - self.a
        s = ((x[0] - self.a[0]) * t[0] + (x[1] - self.a[1]) * t[1]) / float(t @ t)
        shape = 4.0 * s * (1.0 - s) if self.profile == "parabolic" else np.ones_like(s)
        return np.vstack((self.speed * self.normal[0] * shape, self.speed * self.normal[1] * shape))


def builtin_cells(params) -> list[CellSpec]:
    """The cells of a built-in device (none without the cell)."""
    if not params.with_cell:
        return []
    cells = params.geometry.cell_list()
    n = len(cells)
    out = []
    for k, (x, y, d) in enumerate(cells, start=1):
        half = params.case == "normal" and params.geometry.on_symmetry_line(y)
        out.append(CellSpec(index=k, name="cell" if n == 1 else f"cell_{k}", region_tag=cell_region_tag(k),
                            facet_tag=gamma2_tag(k), interface=gamma2_name(k, n), centre=(x, y), diameter=d,
                            symmetry=(1,) if half else ()))
    return out


@dataclasses.dataclass
class DeviceLayout:
    """What the solvers and the reports need to know of a device besides its meshes."""

    boundaries: DeviceBoundaries
    cells: list[CellSpec]
    #: profile interfaces in order (Gamma1, Gamma3, ...): name -> facet tag
    fluid_interfaces: dict[str, int]
    #: display size of the figures: True for a device much wider than high
    wide: bool = False
    #: names of the facet tags in the file's convention (geometry files), for messages and counts
    tag_names: dict[int, str] = dataclasses.field(default_factory=dict)

    @property
    def cell_region_tags(self) -> list[int]:
        return [c.region_tag for c in self.cells]


def device_layout(params) -> DeviceLayout:
    """The layout of any case (built-in or geometry file), without meshing it."""
    if params.case == "file":
        from gelcell.geometryfile import file_layout
        return file_layout(params)
    cells = builtin_cells(params)
    b = device_boundaries(params.case, params.with_cell, getattr(params.geometry, "channel_height", 0.2), cells)
    return DeviceLayout(boundaries=b, cells=cells, fluid_interfaces=dict(b.fluid_interfaces),
                        wide=params.case == "normal")


def device_boundaries(case: str, with_cell: bool, channel_height: float = 0.2,
                      cells: list[CellSpec] | None = None) -> DeviceBoundaries:
    """The boundary conditions of the ``"shear"`` or ``"normal"`` device (``cells``: its cells, default one)."""
    if cells is None:
        cell_ifaces = {"Gamma2": int(Tag.GAMMA2)} if with_cell else {}
    else:
        cell_ifaces = {c.interface: c.facet_tag for c in cells} if with_cell else {}
    if case == "shear":
        return DeviceBoundaries(
            fluid_velocity=[([int(Tag.INLET)], ParabolicInflow(channel_height)),
                            ([int(Tag.WALL)], (0.0, 0.0))],
            fluid_component=[],
            gel_no_slip=[int(Tag.BOWL)],
            gel_symmetry=[],
            cell_symmetry=[],
            fluid_interfaces={"Gamma1": int(Tag.GAMMA1)},
            cell_interfaces=cell_ifaces)
    if case == "normal":
        sym = [int(Tag.SYMMETRY_BOTTOM), int(Tag.SYMMETRY_TOP)]
        return DeviceBoundaries(
            fluid_velocity=[([int(Tag.INLET)], (1.0, 0.0))],
            fluid_component=[(sym, 1, 0.0)],
            gel_no_slip=[int(Tag.POST)],
            gel_symmetry=[(sym, 1)],
            cell_symmetry=([([int(Tag.SYMMETRY_TOP)], 1)] if cells is None or any(c.symmetry for c in cells)
                           else []),
            fluid_interfaces={"Gamma1": int(Tag.GAMMA1), "Gamma3": int(Tag.GAMMA3)},
            cell_interfaces=cell_ifaces)
    raise ValueError(f"case must be 'shear' or 'normal', got {case!r}")
