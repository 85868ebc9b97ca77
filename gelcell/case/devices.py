"""The geometry of a case: the two built-in devices (model.md section 4), their cells, and a geometry file.

Lengths are in units of L0.  A built-in geometry checks its own lengths (``problems``), the gaps its
walls leave for the wall element size (``wall_problems``) and the placement of its cells
(``placement_problems``); a geometry file is checked by :mod:`gelcell.geometry` when it is read.
"""

from __future__ import annotations

import dataclasses
import math
import os

from gelcell.case.ranges import check_range, format_value, out_of_range, raise_problems, range_text
from gelcell.errors import ParameterError

__all__ = ["ShearGeometry", "NormalGeometry", "FileGeometry", "FileContents", "GEOMETRY_SUFFIXES", "WALLS"]

#: the floor and lid of a 3D device: no-slip walls (the gel bonded), or symmetry planes (the slab)
WALLS = ("noslip", "symmetric")


def _cells_tuple(value) -> tuple:
    """``cells`` as a tuple of float tuples (x, y, d), or (x, y, z, d) in 3D (from a TOML list or the command line)."""
    if value is None:
        return ()
    try:
        cells = tuple(tuple(float(v) for v in c) for c in value)
    except (TypeError, ValueError):
        raise ParameterError(f"parameter 'cells' = {value!r} must be a list of [x, y, d] "
                             f"(centre and diameter, units of L0; [x, y, z, d] in 3D)") from None
    for k, c in enumerate(cells):
        if len(c) not in (3, 4):
            raise ParameterError(f"parameter 'cells[{k}]' = {list(c)!r} must be [x, y, d] "
                                 f"(centre and diameter, units of L0; [x, y, z, d] in 3D)")
    return cells


def _cell_list_problems(cells, h_cell: float, clearance) -> list[str]:
    """Diameters > 0, each cell's clearance (gap to the gel's boundaries) and the gaps between cells.

    ``clearance(x, y, r)`` returns ``(gap, what)``: the smallest distance from
    the cell's circle to a gel boundary it must not touch, and that boundary's name.
    """
    p: list[str] = []
    for k, (_, _, d) in enumerate(cells):
        check_range(p, f"cells[{k}].d", d, 0.0)
    if p:
        return p
    why = (f"a cell must lie strictly inside the gel, with a gap of at least one cell element size "
           f"({format_value(h_cell)}) to the gel's boundaries and to the other cells so that the gap can be meshed")
    for k, (x, y, d) in enumerate(cells):
        gap, what = clearance(x, y, 0.5 * d)
        if gap < h_cell:
            near = "overlaps" if gap < 0 else "touches" if gap == 0 else f"comes within {format_value(gap)} of"
            p.append(f"parameter 'cells[{k}]' = [{format_value(x)}, {format_value(y)}, {format_value(d)}]: the cell "
                     f"{near} {what}: {why}")
    for i in range(len(cells)):
        for j in range(i + 1, len(cells)):
            (xi, yi, di), (xj, yj, dj) = cells[i], cells[j]
            gap = math.hypot(xi - xj, yi - yj) - 0.5 * (di + dj)
            if gap < h_cell:
                near = "overlap" if gap < 0 else "touch" if gap == 0 else f"are {format_value(gap)} apart"
                p.append(f"parameters 'cells[{i}]' and 'cells[{j}]': the cells {near}: {why}")
    return p


class _Cells:
    """The cells of a built-in geometry: ``cells`` if given, else its one cell (``cell_centre``, ``cell_diameter``).

    A 3D device (``chip_height`` set, model.md section 10) is the planar device
    extruded over z ∈ [0, chip_height], computed on z ∈ [0, chip_height/2] with a
    symmetry plane at mid-height; its cells are spheres centred at mid-height,
    given as (x, y, d) or (x, y, z, d) with z = chip_height/2.
    """

    def cell_list(self) -> list[tuple[float, float, float]]:
        """Centre in the (x, y) plane and diameter of every (whole) cell."""
        if self.cells:
            return [(c[0], c[1], c[-1]) for c in self.cells]
        return [(*self.cell_centre, self.cell_diameter)]

    def cell_list_3d(self) -> list[tuple[float, float, float, float]]:
        """Centre (x, y, z) and diameter of every cell of a 3D device (z = chip_height/2 unless given)."""
        z_mid = 0.5 * self.chip_height
        given = self.cells or ((),) * len(self.cell_list())
        return [(x, y, c[2] if len(c) == 4 else z_mid, d) for (x, y, d), c in zip(self.cell_list(), given)]

    @property
    def min_cell_diameter(self) -> float:
        return min(c[2] for c in self.cell_list())

    @property
    def dimension(self) -> int:
        """3 with a chip height (model.md section 10), else 2 (planar, plane strain)."""
        return 2 if self.chip_height is None else 3

    def chip_problems(self) -> list[str]:
        """``chip_height`` > 0 (or None: planar), ``walls`` one of :data:`WALLS`, 4-entry cells only in 3D."""
        p: list[str] = []
        if self.chip_height is not None:
            check_range(p, "chip_height", self.chip_height, 0.0, why="the chip's height H in units of L0 "
                        "(model.md section 10; the project's default for a 3D device is 0.4); "
                        "leave it out for the planar device")
        if self.walls not in WALLS:
            p.append(f"parameter 'walls' = {self.walls!r} is not one of {list(WALLS)} (noslip: the floor and "
                     f"lid are walls; symmetric: they are symmetry planes, the slab of model.md section 10)")
        elif self.chip_height is None and self.walls != "noslip":
            p.append(f"parameter 'walls' = {self.walls!r}: the floor and lid belong to a 3D device "
                     f"(give chip_height); the planar device has none")
        if self.chip_height is None:
            for k, c in enumerate(self.cells):
                if len(c) == 4:
                    p.append(f"parameter 'cells[{k}]' = {list(c)!r}: a cell [x, y, z, d] needs a 3D device "
                             f"(chip_height); a planar cell is [x, y, d]")
        return p

    def to_input_dict(self) -> dict:
        """The ``[geometry]`` table; a planar device's has no ``chip_height`` and ``walls`` (as before them)."""
        out = dataclasses.asdict(self)
        if self.chip_height is None:
            del out["chip_height"], out["walls"]
        return out

    def height_problems(self, h_cell: float) -> list[str]:
        """3D: each cell centred at mid-height, its sphere a gap ≥ ``h_cell`` off the floor and lid."""
        if self.chip_height is None:
            return []
        H, p = self.chip_height, []
        names = [f"cells[{k}]" for k in range(len(self.cells))] if self.cells else [None]
        for name, (_, _, z, d) in zip(names, self.cell_list_3d()):
            if abs(z - 0.5 * H) > 1e-12 * max(1.0, H):
                p.append(out_of_range(f"{name}.z", z, range_text(0.5 * H, 0.5 * H, True, True),
                                      why=f"a cell is centred at mid-height z = chip_height/2, where the half "
                                          f"height [0, {format_value(0.5 * H)}] computed has its symmetry plane"))
                continue
            d_max = H - 2 * h_cell
            if not d <= d_max:
                p.append(out_of_range(f"{name}.d" if name else "cell_diameter", d,
                                      range_text(0.0, d_max, hi_closed=True),
                                      why=f"the sphere would reach through the floor z = 0 and the lid "
                                          f"z = {format_value(H)}: it must keep a gap of at least one cell "
                                          f"element size ({format_value(h_cell)}) to them"))
        return p


@dataclasses.dataclass(frozen=True)
class ShearGeometry(_Cells):
    """Shear-flow device (model.md section 4), lengths in units of L0.

    Channel ``x ∈ [0, upstream_length + chamber_width + downstream_length]``,
    ``y ∈ [0, channel_height]``.  The gel chamber hangs below the chord
    ``y = 0`` over the chamber width (Γ1); its wall (bowl) is a circular arc
    of half-angle ``half_angle``: radius ``R = chamber_width/2 / sin θ``,
    centre ``(x_mid, R cos θ)``.  Cell: circle of ``cell_diameter`` centred at
    ``(x_mid + cell_offset_x, -e)``.
    """

    upstream_length: float = 1.0
    chamber_width: float = 2.0
    downstream_length: float = 1.0
    channel_height: float = 0.2
    half_angle: float = math.pi / 3
    cell_diameter: float = 0.06
    e: float = 0.2
    cell_offset_x: float = 0.0
    #: several cells: ((x, y, d), ...) centres and diameters; empty: the one cell of e, cell_offset_x
    cells: tuple = ()
    #: 3D device: the chip's height H (z ∈ [0, H], model.md section 10); None: the planar device
    chip_height: float | None = None
    #: 3D device: the floor and lid are "noslip" walls or "symmetric" planes (the slab)
    walls: str = "noslip"

    @property
    def channel_length(self) -> float:
        return self.upstream_length + self.chamber_width + self.downstream_length

    @property
    def x_mid(self) -> float:
        """x of the chamber's middle (X = 2 at baseline)."""
        return self.upstream_length + 0.5 * self.chamber_width

    @property
    def radius(self) -> float:
        """Radius R of the bowl."""
        return 0.5 * self.chamber_width / math.sin(self.half_angle)

    @property
    def bowl_centre(self) -> tuple[float, float]:
        return self.x_mid, self.radius * math.cos(self.half_angle)

    @property
    def cell_centre(self) -> tuple[float, float]:
        return self.x_mid + self.cell_offset_x, -self.e

    def __post_init__(self):
        object.__setattr__(self, "cells", _cells_tuple(self.cells))
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        for name in ("upstream_length", "chamber_width", "downstream_length", "channel_height",
                     "cell_diameter"):
            check_range(p, name, getattr(self, name), 0.0)
        check_range(p, "half_angle", self.half_angle, 0.0, math.pi / 2, hi_closed=True, unit="rad")
        for name in ("e", "cell_offset_x"):
            check_range(p, name, getattr(self, name))
        return p + self.chip_problems()

    def placement_problems(self, h_cell: float) -> list[str]:
        """The cell must lie inside the gel with a gap ≥ ``h_cell`` to Γ1 and the bowl."""
        if self.cells:
            xb, yb = self.bowl_centre

            def clearance(x, y, r):
                return min((-y - r, "Γ1 (y = 0)"), (self.radius - math.hypot(x - xb, y - yb) - r, "the bowl"))
            return _cell_list_problems(self.cell_list(), h_cell, clearance)
        r, R = 0.5 * self.cell_diameter, self.radius
        _, yb = self.bowl_centre
        gap = r + h_cell
        why = (f"the cell (diameter {format_value(self.cell_diameter)}) must lie strictly inside the gel, "
               f"with a gap to Γ1 (y = 0) and to the bowl of at least one cell element size "
               f"({format_value(h_cell)}) so that the gap can be meshed")
        if R - gap <= abs(self.cell_offset_x):
            return [out_of_range("cell_offset_x", self.cell_offset_x,
                                  range_text(-(R - gap), R - gap), why=why)]
        e_lo = gap
        e_hi = math.sqrt((R - gap) ** 2 - self.cell_offset_x ** 2) - yb
        if not e_lo < e_hi:
            return [f"parameter 'cell_diameter' = {format_value(self.cell_diameter)} is too large for "
                    f"the chamber: {why}"]
        if not e_lo <= self.e <= e_hi:
            return [out_of_range("e", self.e, range_text(e_lo, e_hi, True, True), why=why)]
        return []

    def wall_problems(self, h_wall: float) -> list[str]:
        return []


@dataclasses.dataclass(frozen=True)
class NormalGeometry(_Cells):
    """Normal-flow device (model.md section 4), lower half of one unit, lengths in L0.

    Upstream fluid ``x ∈ [-upstream_length, 0]``, gel ``x ∈ [0, gel_length]``
    (Γ1 at x = 0, Γ3 at x = gel_length), downstream fluid up to
    ``gel_length + downstream_length``; ``y ∈ [0, height]``.  Two posts of
    diameter ``post_diameter`` centred on y = 0 at ``x = a + D/2`` and
    ``gel_length - a - D/2`` (``a = post_clearance``) are holes in the gel.
    Cell: circle of ``cell_diameter`` centred at ``(e, height)`` (its lower
    half is in the domain).
    """

    upstream_length: float = 1.0
    gel_length: float = 2.4
    downstream_length: float = 1.0
    height: float = 0.5
    post_diameter: float = 0.4
    post_clearance: float = 0.2
    cell_diameter: float = 0.06
    e: float = 1.2
    #: several cells: ((x, y, d), ...); a cell centred on y = height is cut by the symmetry line
    #: (its lower half is in the domain); empty: the one cell of e
    cells: tuple = ()
    #: 3D device: the chip's height H (z ∈ [0, H], model.md section 10); None: the planar device
    chip_height: float | None = None
    #: 3D device: the floor and lid are "noslip" walls or "symmetric" planes (the slab)
    walls: str = "noslip"

    def on_symmetry_line(self, y: float) -> bool:
        """Whether a cell centred at height ``y`` is cut by the symmetry line y = height (half a cell)."""
        return abs(y - self.height) <= 1e-12 * max(1.0, self.height)

    @property
    def post_centres(self) -> tuple[float, float]:
        r = 0.5 * self.post_diameter
        return self.post_clearance + r, self.gel_length - self.post_clearance - r

    @property
    def cell_centre(self) -> tuple[float, float]:
        return self.e, self.height

    def __post_init__(self):
        object.__setattr__(self, "cells", _cells_tuple(self.cells))
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        for name in ("upstream_length", "gel_length", "downstream_length", "height",
                     "post_diameter", "cell_diameter"):
            check_range(p, name, getattr(self, name), 0.0)
        for name in ("post_clearance", "e"):     # post_clearance: see wall_problems
            check_range(p, name, getattr(self, name))
        return p + self.chip_problems()

    def wall_problems(self, h_wall: float) -> list[str]:
        """Posts must not touch Γ1/Γ3, each other or the top symmetry line."""
        p: list[str] = []
        D, a, L, H = self.post_diameter, self.post_clearance, self.gel_length, self.height
        why = (f"the gap between a post and Γ1/Γ3 must be at least the wall element size "
               f"({format_value(h_wall)}) so that it can be meshed")
        check_range(p, "post_clearance", a, h_wall, lo_closed=True, why=why)
        if not p:
            a_max = 0.5 * (L - h_wall) - D
            if a > a_max:
                p.append(out_of_range("post_clearance", a, range_text(h_wall, a_max, True, True),
                                       why=f"the two posts (diameter {format_value(D)}) would overlap or "
                                           f"leave a gap smaller than the wall element size "
                                           f"({format_value(h_wall)}) in a gel of length {format_value(L)}"))
        check_range(p, "post_diameter", D, 0.0, 2 * (H - h_wall), hi_closed=True,
               why=f"a post must leave a gap of at least the wall element size ({format_value(h_wall)}) "
                   f"to the symmetry line y = {format_value(H)}")
        return p

    def allowed_e(self, h_cell: float) -> list[tuple[float, float]]:
        """Intervals of ``e`` for which the cell keeps a gap ≥ ``h_cell`` to Γ1, Γ3 and the posts."""
        r, H = 0.5 * self.cell_diameter, self.height
        gap = r + h_cell
        intervals = [(gap, self.gel_length - gap)] if gap < self.gel_length - gap else []
        for xp in self.post_centres:
            reach2 = (0.5 * self.post_diameter + gap) ** 2 - H ** 2
            if reach2 <= 0:
                continue
            w = math.sqrt(reach2)
            cut = []
            for lo, hi in intervals:
                if lo < xp - w:
                    cut.append((lo, min(hi, xp - w)))
                if hi > xp + w:
                    cut.append((max(lo, xp + w), hi))
            intervals = cut
        return intervals

    def placement_problems(self, h_cell: float) -> list[str]:
        if self.cells:
            H, rp = self.height, 0.5 * self.post_diameter

            def clearance(x, y, r):
                on_line = self.on_symmetry_line(y)
                gaps = [(x - r, "Γ1 (x = 0)"), (self.gel_length - x - r, f"Γ3 (x = {format_value(self.gel_length)})"),
                        (y - r, "the symmetry line y = 0")]
                if not on_line:
                    gaps.append((H - y - r, f"the symmetry line y = {format_value(H)} (only a cell centred on it "
                                            f"may cross it)"))
                gaps += [(math.hypot(x - xp, y) - rp - r, "a post") for xp in self.post_centres]
                return min(gaps)
            return _cell_list_problems(self.cell_list(), h_cell, clearance)
        r = 0.5 * self.cell_diameter
        why = (f"the cell (diameter {format_value(self.cell_diameter)}) must lie strictly inside the gel, "
               f"with a gap to Γ1, Γ3 and the posts of at least one cell element size "
               f"({format_value(h_cell)}) so that the gap can be meshed")
        if r + h_cell > self.height:
            return [out_of_range("cell_diameter", self.cell_diameter,
                                  range_text(0, 2 * (self.height - h_cell), hi_closed=True),
                                  why="the half cell would reach the symmetry line y = 0")]
        intervals = self.allowed_e(h_cell)
        if not intervals:
            return [f"parameter 'cell_diameter' = {format_value(self.cell_diameter)} leaves no admissible "
                    f"cell position: {why}"]
        if not any(lo <= self.e <= hi for lo, hi in intervals):
            allowed = " ∪ ".join(range_text(lo, hi, True, True) for lo, hi in intervals)
            return [out_of_range("e", self.e, allowed, why=why)]
        return []


#: what a geometry file may be called
GEOMETRY_SUFFIXES = (".geo", ".msh")
#: the default cell diameter of the element sizes when a device has no cell
_NO_CELL_DIAMETER = 0.06


@dataclasses.dataclass(frozen=True)
class FileContents:
    """What a case needs to know of its geometry file's content: read by :mod:`gelcell.geometry`."""

    cells: tuple = ()              #: ((x, y, d), ...): centre and diameter of each cell, units of L0
    gel_depth: float = 0.0         #: the gel's area over the fluid-gel interfaces' length
    enclosed_fluid: bool = False   #: some fluid region has no outlet (fixed only through an interface)
    dimension: int = 2             #: 3: the file's regions are volumes (a 3D device)


@dataclasses.dataclass(frozen=True)
class FileGeometry:
    """A device from a gmsh geometry file (``.geo`` or ``.msh``) named by docs/geometry-files.md.

    ``file`` is the path (a relative path in a TOML case file is relative to
    that file); here only the path is checked.  The file is read, checked
    and described by ``gelcell.geometry.described`` before anything is
    meshed, which fills in ``contents`` (its cells come from the file).
    """

    file: str = ""
    contents: FileContents | None = dataclasses.field(default=None, compare=False, repr=False)

    def __post_init__(self):
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        path = self.file
        if not isinstance(path, str) or not path:
            return [f"parameter 'geometry.file' = {path!r} must be the path of a .geo or .msh file"]
        if not path.lower().endswith(GEOMETRY_SUFFIXES):
            return [f"parameter 'geometry.file' = {path!r}: a geometry file must end in .geo or .msh"]
        if not os.path.isfile(path):
            return [f"parameter 'geometry.file' = {path!r}: no such file"]
        return []

    def cell_list(self) -> list[tuple[float, float, float]]:
        if self.contents is None:
            raise RuntimeError(f"geometry file {self.file!r} has not been read yet (gelcell.geometry.described)")
        return [tuple(c) for c in self.contents.cells]

    @property
    def min_cell_diameter(self) -> float:
        cells = self.cell_list()
        return min(c[2] for c in cells) if cells else _NO_CELL_DIAMETER

    @property
    def dimension(self) -> int:
        """2 for a planar file, 3 for one of volumes (known once the file is read)."""
        return 2 if self.contents is None else self.contents.dimension

    @property
    def e(self):
        return None

    def to_input_dict(self) -> dict:
        return {"file": self.file}
