"""Which boundary condition holds on which tagged boundary, for both device cases.

model.md section 3.  Shared by the partitioned solvers and the monolithic
reference, so that both solve the same problem.

Shear flow: parabolic inflow with maximum 1 at the inlet, zero traction at
the outlet, no slip on the channel walls; v_f = 0 and u_s = 0 on the bowl.
Normal flow: uniform inflow (1, 0), zero traction at the outlet; v_f = 0 and
u_s = 0 on the posts; symmetry (zero normal velocity and displacement, zero
tangential traction) on y = 0 and y = H.  The cell's flat edge on y = H is
a symmetry line too.  Gamma2 (steady): v_f = 0 on the gel side.
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

from gelcell.geometry import Tag

__all__ = ["DeviceBoundaries", "device_boundaries"]


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


def device_boundaries(case: str, with_cell: bool, channel_height: float = 0.2) -> DeviceBoundaries:
    """The boundary conditions of the ``"shear"`` or ``"normal"`` device."""
    cell_ifaces = {"Gamma2": int(Tag.GAMMA2)} if with_cell else {}
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
            cell_symmetry=[([int(Tag.SYMMETRY_TOP)], 1)],
            fluid_interfaces={"Gamma1": int(Tag.GAMMA1), "Gamma3": int(Tag.GAMMA3)},
            cell_interfaces=cell_ifaces)
    raise ValueError(f"case must be 'shear' or 'normal', got {case!r}")
