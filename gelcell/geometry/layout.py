"""What the solvers and the reports need to know of a device besides its meshes: conditions and cells.

:class:`DeviceBoundaries` says which boundary condition holds on which
tagged boundary (model.md section 3), shared by the partitioned solvers and
the monolithic reference so that both solve the same problem; Gamma2
(steady): v_f = 0 on the gel side.  :class:`DeviceLayout` adds the cells
(:class:`CellSpec`) and the fluid-gel interfaces.  The built-in devices'
layouts come from :mod:`gelcell.geometry.builtin`, a geometry file's from
:mod:`gelcell.geometry.files` (docs/geometry-files.md).
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

__all__ = ["DeviceBoundaries", "DeviceLayout", "CellSpec", "ParabolicInflow", "SegmentInflow"]


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


@dataclasses.dataclass(frozen=True)
class CellSpec:
    """One cell of a device: its tags, its coupling interface and its nominal shape.

    ``centre`` and ``diameter`` are those of the whole cell (a circle of the
    same area for a cell of another shape); ``symmetry`` lists the components
    fixed on its flat edges (a half cell on a symmetry line: its centroid
    moves along the line).
    """

    index: int                 #: 1-based
    name: str                  #: "cell" (single cell) or "cell_k"
    region_tag: int
    facet_tag: int             #: its Gamma2
    interface: str             #: coupling name of its Gamma2
    centre: tuple[float, float]
    diameter: float
    symmetry: tuple[int, ...] = ()
