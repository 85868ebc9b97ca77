"""Parameters of one device case: dimensionless groups, SI scales, geometry, mesh sizes.

One immutable :class:`CaseParameters` object describes a case completely.  It
is built from defaults, a TOML file or a dict (plus command-line overrides)
and is validated on construction, before any mesh is built: a parameter
outside its physical range raises one :class:`ParameterError` naming the
parameter, its value and the allowed range.

What is primary (stored) and what is derived (model.md sections 2 and 5):

* dimensionless groups ``phi_s0, lambda_s (= λ_s/μ_s), xi, beta, eta, ca`` are
  stored in :class:`Physics`;
* SI scales ``L0, mu, mu_s, pore_radius`` are stored in :class:`Dimensional`;
  the velocity scale is *derived* from the capillary-like number,
  ``V0 = Ca L0 μ_s / μ``, so changing ``Ca`` changes the flow speed at fixed
  moduli; ``λ_s [Pa] = lambda_s · μ_s``;
* the cell's Lamé moduli are stored in Pa (:class:`CellMaterial`, default
  Young's modulus 1 kPa, ν = 0.25, i.e. μ_c = λ_c = 400 Pa); they are also
  reported in units of μ_s (``mu_c``, ``lambda_c``) and as a multiple of the
  gel's drained modulus φ_s0 μ_s (``cell_moduli_multiple``, default 1);
* lengths of the geometry are in units of L0 (:class:`ShearGeometry`,
  :class:`NormalGeometry`); the cell offset ``e`` lives there too;
* element sizes (in units of L0) and the global ``size_factor`` are in
  :class:`MeshSizes`.

Units of the solvers.  Stresses in units of μ_s and displacements in units of
L0 are ~1e-7 and ~1e-6 at baseline; the solvers work in the stress unit
μ V0 / L0 = Ca μ_s and the displacement unit Ca L0.  ``stress_scale`` (= Ca,
in units of μ_s) and ``displacement_scale`` (= Ca, in units of L0) are these
units, so ``σ = stress_scale · σ_hat`` and ``u = displacement_scale · u_hat``.

Example::

    p = CaseParameters.default("shear").with_ca(1e-9).with_cell_moduli(10)
    p.V0                               # 1e-5 m/s
    p.to_report(0.5, "velocity")       # 0.5 V0 in µm/s
"""

from __future__ import annotations

import copy
import dataclasses
import math
import numbers
import os
import tomllib
import typing

__all__ = ["ParameterError", "Physics", "Dimensional", "CellMaterial", "ShearGeometry",
           "NormalGeometry", "FileGeometry", "MeshSizes", "CaseParameters", "CASES", "KINEMATICS", "REPORT_UNITS"]

CASES = ("shear", "normal")
#: every case: the built-in devices and a device from a geometry file (``[geometry] file``, ``--geometry``)
ALL_CASES = CASES + ("file",)
#: ``"finite"`` (default): total Lagrangian gel, moving fluid domain (docs/finite-strain.md);
#: ``"small"``: the equations on the undeformed domain, exact to the size of the strains
KINEMATICS = ("finite", "small")
#: splits of Gamma2 (gelcell.device): the cell takes the gel's displacement ("dirichlet"), the same
#: with the cell's stiffness condensed into the gel ("schur"), or the gel's force and springs ("robin")
GAMMA2 = ("dirichlet", "schur", "robin")
#: the default split: fewer iterations than "dirichlet" at every stiffness (docs/coupling.md)
DEFAULT_GAMMA2 = "schur"

#: Units in which results are reported (``to_report``) and their factor from SI.
REPORT_UNITS = {"length": ("µm", 1e6), "displacement": ("µm", 1e6),
                "velocity": ("µm/s", 1e6), "stress": ("mPa", 1e3),
                "pressure": ("mPa", 1e3), "time": ("s", 1.0)}


class ParameterError(ValueError):
    """A parameter outside its physical range (or an unknown/ill-typed input)."""


# --------------------------------------------------------------------------- helpers
def _fmt(x: float) -> str:
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        return repr(x)
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.6g}"


def _range_text(lo: float, hi: float, lo_closed: bool = False, hi_closed: bool = False) -> str:
    return f"{'[' if lo_closed else '('}{_fmt(lo)}, {_fmt(hi)}{']' if hi_closed else ')'}"


def _out_of_range(name: str, value, allowed: str, unit: str = "", why: str = "") -> str:
    u = f" {unit}" if unit else ""
    msg = f"parameter '{name}' = {_fmt(value)}{u} is outside its allowed range {allowed}{u}"
    return msg + (f": {why}" if why else "")


def _check(problems: list, name: str, value, lo: float = -math.inf, hi: float = math.inf,
           lo_closed: bool = False, hi_closed: bool = False, unit: str = "", why: str = "",
           integer: bool = False) -> None:
    """Append a message to ``problems`` unless ``value`` is a real number in the range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or (
            integer and not float(value).is_integer()):
        kind = "an integer" if integer else "a number"
        problems.append(f"parameter '{name}' = {value!r} must be {kind} in "
                        f"{_range_text(lo, hi, lo_closed, hi_closed)}")
        return
    v = float(value)
    ok_lo = v >= lo if lo_closed else v > lo
    ok_hi = v <= hi if hi_closed else v < hi
    if not (ok_lo and ok_hi) or math.isnan(v):
        problems.append(_out_of_range(name, value, _range_text(lo, hi, lo_closed, hi_closed),
                                      unit, why))


def _raise(problems: list) -> None:
    if problems:
        raise ParameterError("\n".join(problems))


def _poisson(lmbda: float, mu: float) -> float:
    """Poisson ratio of a Lamé pair, ν = λ / (2 (λ + μ)) (also for plane strain)."""
    return lmbda / (2.0 * (lmbda + mu))


_NU_WHY = ("the Poisson ratio ν = λ/(2(λ+μ)) must lie in (-1, 0.5), i.e. μ > 0 and "
           "λ > -2μ/3 (positive bulk modulus)")


def _cells_tuple(value) -> tuple:
    """``cells`` as a tuple of (x, y, d) float triples (from a TOML list or the command line)."""
    if value is None:
        return ()
    try:
        cells = tuple(tuple(float(v) for v in c) for c in value)
    except (TypeError, ValueError):
        raise ParameterError(f"parameter 'cells' = {value!r} must be a list of [x, y, d] "
                             f"(centre and diameter, units of L0)") from None
    for k, c in enumerate(cells):
        if len(c) != 3:
            raise ParameterError(f"parameter 'cells[{k}]' = {list(c)!r} must be [x, y, d] "
                                 f"(centre and diameter, units of L0)")
    return cells


def _cell_list_problems(cells, h_cell: float, clearance) -> list[str]:
    """Diameters > 0, each cell's clearance (gap to the gel's boundaries) and the gaps between cells.

    ``clearance(x, y, r)`` returns ``(gap, what)``: the smallest distance from
    the cell's circle to a gel boundary it must not touch, and that boundary's name.
    """
    p: list[str] = []
    for k, (x, y, d) in enumerate(cells):
        _check(p, f"cells[{k}].d", d, 0.0)
    if p:
        return p
    why = (f"a cell must lie strictly inside the gel, with a gap of at least one cell element size "
           f"({_fmt(h_cell)}) to the gel's boundaries and to the other cells so that the gap can be meshed")
    for k, (x, y, d) in enumerate(cells):
        gap, what = clearance(x, y, 0.5 * d)
        if gap < h_cell:
            p.append(f"parameter 'cells[{k}]' = [{_fmt(x)}, {_fmt(y)}, {_fmt(d)}]: the cell "
                     f"{'overlaps' if gap < 0 else 'touches' if gap == 0 else 'comes within ' + _fmt(gap) + ' of'} "
                     f"{what}: {why}")
    for i in range(len(cells)):
        for j in range(i + 1, len(cells)):
            (xi, yi, di), (xj, yj, dj) = cells[i], cells[j]
            gap = math.hypot(xi - xj, yi - yj) - 0.5 * (di + dj)
            if gap < h_cell:
                p.append(f"parameters 'cells[{i}]' and 'cells[{j}]': the cells "
                         f"{'overlap' if gap < 0 else 'touch' if gap == 0 else 'are ' + _fmt(gap) + ' apart'}: {why}")
    return p


# --------------------------------------------------------------------------- blocks
@dataclasses.dataclass(frozen=True)
class Physics:
    """Dimensionless groups of model.md section 2 (Table 1 defaults)."""

    phi_s0: float = 0.01     #: solid volume fraction of the unloaded gel, (0, 1)
    lambda_s: float = 1.0    #: λ_s / μ_s of the network, > -2/3
    xi: float = 4.5e4        #: drag ξ̄ = ξ L0² / μ
    beta: float = 0.02       #: slip β̄ = μ β / L0
    eta: float = 0.02        #: interfacial permeability η̄ = μ η / L0
    ca: float = 3e-10        #: Ca = μ V0 / (L0 μ_s)

    def __post_init__(self):
        _raise(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        _check(p, "phi_s0", self.phi_s0, 0.0, 1.0)
        _check(p, "lambda_s", self.lambda_s, -2.0 / 3.0, why="λ_s/μ_s; " + _NU_WHY)
        for name in ("xi", "beta", "eta", "ca"):
            _check(p, name, getattr(self, name), 0.0)
        return p


@dataclasses.dataclass(frozen=True)
class Dimensional:
    """SI scales (model.md section 5).  V0 is derived: V0 = Ca L0 μ_s / μ."""

    L0: float = 250e-6           #: length scale [m]
    mu: float = 1e-3             #: perfusate viscosity [Pa s]
    mu_s: float = 40e3           #: network shear modulus μ_s [Pa] (stress scale)
    pore_radius: float = 2.5e-6  #: pore radius of the gel [m] (informative)

    def __post_init__(self):
        _raise(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        _check(p, "L0", self.L0, 0.0, unit="m")
        _check(p, "mu", self.mu, 0.0, unit="Pa s")
        _check(p, "mu_s", self.mu_s, 0.0, unit="Pa")
        _check(p, "pore_radius", self.pore_radius, 0.0, unit="m")
        return p


@dataclasses.dataclass(frozen=True)
class CellMaterial:
    """Lamé moduli of the neo-Hookean cell in Pa (primary values).

    Default: Young's modulus 1 kPa and ν = 0.25, i.e. μ_c = λ_c = 400 Pa
    = φ_s0 μ_s at baseline (model.md section 5).
    """

    mu_c: float = 400.0      #: shear modulus [Pa]
    lambda_c: float = 400.0  #: first Lamé parameter [Pa]

    @classmethod
    def from_young(cls, youngs_modulus: float, poisson_ratio: float) -> "CellMaterial":
        p: list[str] = []
        _check(p, "youngs_modulus", youngs_modulus, 0.0, unit="Pa")
        _check(p, "poisson_ratio", poisson_ratio, -1.0, 0.5)
        _raise(p)
        E, nu = float(youngs_modulus), float(poisson_ratio)
        return cls(mu_c=E / (2 * (1 + nu)), lambda_c=E * nu / ((1 + nu) * (1 - 2 * nu)))

    @property
    def youngs_modulus(self) -> float:
        """E = μ (3λ + 2μ) / (λ + μ) [Pa]."""
        return self.mu_c * (3 * self.lambda_c + 2 * self.mu_c) / (self.lambda_c + self.mu_c)

    @property
    def poisson_ratio(self) -> float:
        return _poisson(self.lambda_c, self.mu_c)

    def __post_init__(self):
        _raise(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        _check(p, "mu_c", self.mu_c, 0.0, unit="Pa")
        if not p:
            _check(p, "lambda_c", self.lambda_c, -2.0 * self.mu_c / 3.0, unit="Pa",
                   why="cell " + _NU_WHY)
        return p


class _Cells:
    """The cells of a built-in geometry: ``cells`` if given, else its one cell (``cell_centre``, ``cell_diameter``)."""

    def cell_list(self) -> list[tuple[float, float, float]]:
        """Centre and diameter of every (whole) cell."""
        if self.cells:
            return [tuple(c) for c in self.cells]
        return [(*self.cell_centre, self.cell_diameter)]

    @property
    def min_cell_diameter(self) -> float:
        return min(c[2] for c in self.cell_list())


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
        _raise(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        for name in ("upstream_length", "chamber_width", "downstream_length", "channel_height",
                     "cell_diameter"):
            _check(p, name, getattr(self, name), 0.0)
        _check(p, "half_angle", self.half_angle, 0.0, math.pi / 2, hi_closed=True, unit="rad")
        for name in ("e", "cell_offset_x"):
            _check(p, name, getattr(self, name))
        return p

    def placement_problems(self, h_cell: float) -> list[str]:
        """The cell must lie inside the gel with a gap ≥ ``h_cell`` to Γ1 and the bowl."""
        if self.cells:
            xb, yb = self.bowl_centre

            def clearance(x, y, r):
                return min((-y - r, "Γ1 (y = 0)"), (self.radius - math.hypot(x - xb, y - yb) - r, "the bowl"))
            return _cell_list_problems(self.cells, h_cell, clearance)
        r, R = 0.5 * self.cell_diameter, self.radius
        _, yb = self.bowl_centre
        gap = r + h_cell
        why = (f"the cell (diameter {_fmt(self.cell_diameter)}) must lie strictly inside the gel, "
               f"with a gap to Γ1 (y = 0) and to the bowl of at least one cell element size "
               f"({_fmt(h_cell)}) so that the gap can be meshed")
        if R - gap <= abs(self.cell_offset_x):
            return [_out_of_range("cell_offset_x", self.cell_offset_x,
                                  _range_text(-(R - gap), R - gap), why=why)]
        e_lo = gap
        e_hi = math.sqrt((R - gap) ** 2 - self.cell_offset_x ** 2) - yb
        if not e_lo < e_hi:
            return [f"parameter 'cell_diameter' = {_fmt(self.cell_diameter)} is too large for "
                    f"the chamber: {why}"]
        if not e_lo <= self.e <= e_hi:
            return [_out_of_range("e", self.e, _range_text(e_lo, e_hi, True, True), why=why)]
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
        _raise(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        for name in ("upstream_length", "gel_length", "downstream_length", "height",
                     "post_diameter", "cell_diameter"):
            _check(p, name, getattr(self, name), 0.0)
        for name in ("post_clearance", "e"):     # post_clearance: see wall_problems
            _check(p, name, getattr(self, name))
        return p

    def wall_problems(self, h_wall: float) -> list[str]:
        """Posts must not touch Γ1/Γ3, each other or the top symmetry line."""
        p: list[str] = []
        D, a, L, H = self.post_diameter, self.post_clearance, self.gel_length, self.height
        why = (f"the gap between a post and Γ1/Γ3 must be at least the wall element size "
               f"({_fmt(h_wall)}) so that it can be meshed")
        _check(p, "post_clearance", a, h_wall, lo_closed=True, why=why)
        if not p:
            a_max = 0.5 * (L - h_wall) - D
            if a > a_max:
                p.append(_out_of_range("post_clearance", a, _range_text(h_wall, a_max, True, True),
                                       why=f"the two posts (diameter {_fmt(D)}) would overlap or "
                                           f"leave a gap smaller than the wall element size "
                                           f"({_fmt(h_wall)}) in a gel of length {_fmt(L)}"))
        _check(p, "post_diameter", D, 0.0, 2 * (H - h_wall), hi_closed=True,
               why=f"a post must leave a gap of at least the wall element size ({_fmt(h_wall)}) "
                   f"to the symmetry line y = {_fmt(H)}")
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
                gaps = [(x - r, "Γ1 (x = 0)"), (self.gel_length - x - r, f"Γ3 (x = {_fmt(self.gel_length)})"),
                        (y - r, "the symmetry line y = 0")]
                if not on_line:
                    gaps.append((H - y - r, f"the symmetry line y = {_fmt(H)} (only a cell centred on it "
                                            f"may cross it)"))
                gaps += [(math.hypot(x - xp, y) - rp - r, "a post") for xp in self.post_centres]
                return min(gaps)
            return _cell_list_problems(self.cells, h_cell, clearance)
        r = 0.5 * self.cell_diameter
        why = (f"the cell (diameter {_fmt(self.cell_diameter)}) must lie strictly inside the gel, "
               f"with a gap to Γ1, Γ3 and the posts of at least one cell element size "
               f"({_fmt(h_cell)}) so that the gap can be meshed")
        if r + h_cell > self.height:
            return [_out_of_range("cell_diameter", self.cell_diameter,
                                  _range_text(0, 2 * (self.height - h_cell), hi_closed=True),
                                  why="the half cell would reach the symmetry line y = 0")]
        intervals = self.allowed_e(h_cell)
        if not intervals:
            return [f"parameter 'cell_diameter' = {_fmt(self.cell_diameter)} leaves no admissible "
                    f"cell position: {why}"]
        if not any(lo <= self.e <= hi for lo, hi in intervals):
            allowed = " ∪ ".join(_range_text(lo, hi, True, True) for lo, hi in intervals)
            return [_out_of_range("e", self.e, allowed, why=why)]
        return []


@dataclasses.dataclass(frozen=True)
class MeshSizes:
    """Element sizes in units of L0.  ``size_factor`` multiplies every size.

    * far field: ``h_fluid`` in the perfusate, ``h_gel`` in the gel;
    * cell: ``h_cell = π d / n_cell_edges`` on Γ2, inside the cell and in a
      band of width ``cell_band · d`` around it;
    * Brinkman layer δ = 1/sqrt(ξ φ_s0) (≈ 0.047 at baseline):
      ``h_layer = δ / layer_elements`` on Γ1/Γ3 and on the gel's no-slip walls
      (bowl, posts) and in a band of width ``layer_width · δ`` next to them;
    * beyond the bands the size grows linearly with distance, by ``growth``
      per unit distance, up to the far-field size.
    """

    size_factor: float = 1.0
    h_fluid: float = 0.04
    h_gel: float = 0.06
    n_cell_edges: int = 48
    layer_elements: float = 3.0
    layer_width: float = 1.0
    cell_band: float = 0.5
    growth: float = 0.25

    MIN_CELL_EDGES: typing.ClassVar[int] = 8

    def __post_init__(self):
        _raise(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        _check(p, "size_factor", self.size_factor, 0.0)
        for name in ("h_fluid", "h_gel", "layer_elements", "layer_width", "growth"):
            _check(p, name, getattr(self, name), 0.0)
        _check(p, "cell_band", self.cell_band, 0.0, lo_closed=True)
        _check(p, "n_cell_edges", self.n_cell_edges, self.MIN_CELL_EDGES, lo_closed=True,
               integer=True)
        if not p and self.n_cell_edges / self.size_factor < self.MIN_CELL_EDGES:
            p.append(_out_of_range(
                "size_factor", self.size_factor,
                _range_text(0, self.n_cell_edges / self.MIN_CELL_EDGES, hi_closed=True),
                why=f"it would leave fewer than {self.MIN_CELL_EDGES} edges around the cell"))
        return p


@dataclasses.dataclass(frozen=True)
class FileGeometry:
    """A device from a gmsh geometry file (``.geo`` or ``.msh``) named by docs/geometry-files.md.

    ``file`` is the path (a relative path in a TOML case file is relative to
    that file).  The file is read and checked on construction (no meshing):
    a naming or topology problem raises :class:`ParameterError` naming the
    group or entity.  Cells come from the file.
    """

    file: str = ""

    def __post_init__(self):
        _raise(self.problems())

    def problems(self) -> list[str]:
        from gelcell.geometryfile import analyse
        analyse(self.file)          # raises ParameterError naming the problem
        return []

    @property
    def layout(self):
        from gelcell.geometryfile import analyse
        return analyse(self.file)

    def cell_list(self) -> list[tuple[float, float, float]]:
        return [(*c.centre, c.diameter) for c in self.layout.layout.cells]

    @property
    def min_cell_diameter(self) -> float:
        cells = self.cell_list()
        return min(c[2] for c in cells) if cells else 0.06

    @property
    def e(self):
        return None

    def placement_problems(self, h_cell: float) -> list[str]:
        return []

    def wall_problems(self, h_wall: float) -> list[str]:
        return []


_BLOCKS = {"physics": Physics, "dimensional": Dimensional, "mesh": MeshSizes}
_GEOMETRY = {"shear": ShearGeometry, "normal": NormalGeometry, "file": FileGeometry}


def _field_names(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


# --------------------------------------------------------------------------- the case
@dataclasses.dataclass(frozen=True)
class CaseParameters:
    """Everything that defines one case; validated on construction.

    Args:
        case: ``"shear"`` or ``"normal"``.
        with_cell: whether the cell (and Γ2) is present.
        kinematics: ``"finite"`` (total Lagrangian gel and cell, the fluid
            domain following the gel's surface) or ``"small"`` (every field on
            its undeformed domain); ``[case] kinematics`` in a case file.
        physics, dimensional, cell, mesh: the blocks above (defaults if omitted).
        geometry: :class:`ShearGeometry` or :class:`NormalGeometry` matching
            ``case`` (default geometry of the case if omitted).
        coupling: raw ``[coupling]`` options, validated by the coupling library.
        time: raw ``[time]`` options of a time-dependent run, validated by
            :class:`gelcell.timesettings.TimeSettings`.
    """

    case: str = "shear"
    with_cell: bool = True
    kinematics: str = "finite"
    physics: Physics = dataclasses.field(default_factory=Physics)
    dimensional: Dimensional = dataclasses.field(default_factory=Dimensional)
    cell: CellMaterial = dataclasses.field(default_factory=CellMaterial)
    geometry: typing.Any = None
    mesh: MeshSizes = dataclasses.field(default_factory=MeshSizes)
    coupling: dict = dataclasses.field(default_factory=dict)
    time: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.case not in ALL_CASES:
            raise ParameterError(f"parameter 'case' = {self.case!r} is not one of {list(CASES)} "
                                 f"(or a geometry file)")
        if self.kinematics not in KINEMATICS:
            raise ParameterError(f"parameter 'kinematics' = {self.kinematics!r} is not one of {list(KINEMATICS)} "
                                 f"(finite: total Lagrangian gel and a moving fluid domain; small: every field on "
                                 f"its undeformed domain)")
        if self.geometry is None:
            if self.case == "file":
                raise ParameterError("a geometry-file case needs its file: [geometry] file or --geometry FILE")
            object.__setattr__(self, "geometry", _GEOMETRY[self.case]())
        if self.case == "file" and isinstance(self.geometry, FileGeometry):
            has_cells = bool(self.geometry.cell_list())
            if has_cells and not self.with_cell:
                raise ParameterError(f"parameter 'cell' = false: the cells of geometry file "
                                     f"{self.geometry.file!r} come from the file (remove them there)")
            object.__setattr__(self, "with_cell", has_cells)
        object.__setattr__(self, "coupling", copy.deepcopy(dict(self.coupling or {})))
        object.__setattr__(self, "time", copy.deepcopy(dict(self.time or {})))
        self.validate()

    # ----------------------------------------------------------- validation
    def validate(self) -> None:
        """Raise :class:`ParameterError` listing every parameter out of range."""
        if not isinstance(self.with_cell, bool):
            raise ParameterError(f"parameter 'cell' = {self.with_cell!r} must be true or false")
        expected = _GEOMETRY[self.case]
        if not isinstance(self.geometry, expected):
            raise ParameterError(f"the geometry of case {self.case!r} must be a {expected.__name__}, "
                                 f"got {type(self.geometry).__name__}")
        problems = (self.physics.problems() + self.dimensional.problems() + self.cell.problems()
                    + self.geometry.problems() + self.mesh.problems())
        _raise(problems)
        if self.case == "file" and self.geometry.file.lower().endswith(".msh") and self.mesh.size_factor != 1.0:
            raise ParameterError(f"parameter 'size_factor' = {self.mesh.size_factor:g} (--mesh-size): a .msh file "
                                 f"carries its own mesh; element sizes can be scaled for .geo files only (allowed: 1)")
        problems = self.geometry.wall_problems(self.element_sizes()["h_layer"])
        if self.with_cell:
            problems += self.geometry.placement_problems(self.element_sizes()["h_cell"])
        _raise(problems)

    # ----------------------------------------------------------- constructors
    @classmethod
    def default(cls, case: str = "shear", with_cell: bool = True) -> "CaseParameters":
        """Baseline parameters (model.md Table 1) of ``case``."""
        return cls(case=case, with_cell=with_cell)

    @classmethod
    def from_dict(cls, data: typing.Mapping, overrides: typing.Mapping | None = None,
                  source: str = "input", base_dir: str | None = None) -> "CaseParameters":
        """Build from the TOML layout (see ``examples/case_baseline_*.toml``).

        Tables: ``[case] name, cell, kinematics``; ``[physics]``; ``[dimensional]`` (may
        give ``V0`` instead of ``physics.ca``); ``[cell]`` with ``mu_c`` and
        ``lambda_c`` [Pa], or ``youngs_modulus`` [Pa] and ``poisson_ratio``,
        or ``moduli_multiple`` (× φ_s0 μ_s, with an optional
        ``poisson_ratio``, default 0.25); ``[geometry]`` (keys of the case's
        geometry class); ``[mesh]``; ``[coupling]`` and ``[time]`` (kept raw).

        ``overrides`` maps dotted keys (``"physics.ca"``, ``"geometry.e"``,
        ``"mesh.size_factor"``, ``"case.name"``, ``"case.cell"``) to values that
        replace those of ``data`` (also ``"case.kinematics"``); ``None`` values are ignored.  Unknown keys
        raise :class:`ParameterError` naming the key.
        """
        d = {k: (dict(v) if isinstance(v, typing.Mapping) else v) for k, v in dict(data).items()}
        for key, value in (overrides or {}).items():
            if value is None:
                continue
            table, _, name = key.partition(".")
            if not name:
                raise ParameterError(f"override key {key!r} must be 'table.key'")
            d.setdefault(table, {})
            if not isinstance(d[table], dict):
                raise ParameterError(f"'{table}' in {source} must be a table")
            d[table][name] = value
            if key == "physics.ca":
                d.get("dimensional", {}).pop("V0", None)
        known = {"case", "physics", "dimensional", "cell", "geometry", "mesh", "coupling", "time"}
        for table, value in d.items():
            if table not in known:
                raise ParameterError(f"unknown table or key '{table}' in {source} "
                                     f"(known: {sorted(known)})")
            if not isinstance(value, dict):
                raise ParameterError(f"'{table}' in {source} must be a table")

        def take(table: str, allowed: typing.Iterable[str]) -> dict:
            block = dict(d.get(table, {}))
            allowed = list(allowed)
            for k in block:
                if k not in allowed:
                    raise ParameterError(f"unknown key '{table}.{k}' in {source} (known: {allowed})")
            return block

        case_block = take("case", ["name", "cell", "kinematics"])
        geometry_block = d.get("geometry", {})
        if geometry_block.get("file") is not None:
            if case_block.get("name") not in (None, "file"):
                raise ParameterError(f"give either the device [case] name = {case_block['name']!r} or a geometry "
                                     f"file ([geometry] file / --geometry) in {source}, not both")
            for key in ("e", "cells", "cell_offset_x"):
                if key in geometry_block:
                    raise ParameterError(f"'geometry.{key}' places the cells of a built-in device; the cells of "
                                         f"geometry file {geometry_block['file']!r} come from the file")
            path = geometry_block["file"]
            if isinstance(path, str) and base_dir and not os.path.isabs(path):
                geometry_block["file"] = os.path.normpath(os.path.join(base_dir, path))
            case_block["name"] = "file"
            case_block.setdefault("cell", True)
        case = case_block.get("name", "shear")
        if case not in CASES and case != "file":
            raise ParameterError(f"parameter 'case' = {case!r} is not one of {list(CASES)}")
        if case == "file" and geometry_block.get("file") is None:
            raise ParameterError(f"case 'file' needs [geometry] file (a .geo or .msh path) in {source}")
        with_cell = case_block.get("cell", True)
        kinematics = case_block.get("kinematics", "finite")
        if kinematics not in KINEMATICS:
            raise ParameterError(f"parameter 'kinematics' = {kinematics!r} in {source} is not one of "
                                 f"{list(KINEMATICS)}")
        physics = take("physics", _field_names(Physics))
        dimensional = take("dimensional", _field_names(Dimensional) + ["V0"])
        V0 = dimensional.pop("V0", None)
        if V0 is not None:
            if "ca" in physics:
                raise ParameterError(f"give either 'physics.ca' or 'dimensional.V0' in {source}, "
                                     f"not both (V0 = Ca L0 μ_s / μ)")
            p: list[str] = []
            _check(p, "V0", V0, 0.0, unit="m/s")
            _raise(p)
            dim = Dimensional(**dimensional)
            _raise(dim.problems())
            physics["ca"] = dim.mu * V0 / (dim.L0 * dim.mu_s)
        geometry = take("geometry", _field_names(_GEOMETRY[case]))
        mesh = take("mesh", _field_names(MeshSizes))
        cell_block = take("cell", ["mu_c", "lambda_c", "youngs_modulus", "poisson_ratio",
                                   "moduli_multiple"])
        phys_obj = Physics(**physics)
        dim_obj = Dimensional(**dimensional)
        cell = cls._cell_from_block(cell_block, phys_obj, dim_obj, source)
        return cls(case=case, with_cell=with_cell, kinematics=kinematics, physics=phys_obj, dimensional=dim_obj,
                   cell=cell, geometry=_GEOMETRY[case](**geometry), mesh=MeshSizes(**mesh),
                   coupling=dict(d.get("coupling", {})), time=dict(d.get("time", {})))

    @staticmethod
    def _cell_from_block(block: dict, physics: Physics, dim: Dimensional,
                         source: str) -> CellMaterial:
        forms = [("mu_c" in block or "lambda_c" in block),
                 "youngs_modulus" in block, "moduli_multiple" in block]
        if sum(forms) > 1:
            raise ParameterError(f"give the cell moduli in {source} as one of: mu_c and lambda_c, "
                                 f"youngs_modulus and poisson_ratio, or moduli_multiple")
        if forms[0]:
            if "poisson_ratio" in block:
                raise ParameterError(f"'cell.poisson_ratio' in {source} goes with youngs_modulus "
                                     f"or moduli_multiple, not with mu_c/lambda_c")
            return CellMaterial(**block)
        nu = block.get("poisson_ratio", 0.25)
        if forms[1]:
            return CellMaterial.from_young(block["youngs_modulus"], nu)
        m = block.get("moduli_multiple", 1.0)
        p: list[str] = []
        _check(p, "moduli_multiple", m, 0.0)
        _check(p, "poisson_ratio", nu, -1.0, 0.5)
        _raise(p + physics.problems() + dim.problems())
        mu_c = m * physics.phi_s0 * dim.mu_s
        return CellMaterial(mu_c=mu_c, lambda_c=2 * mu_c * nu / (1 - 2 * nu))

    @classmethod
    def from_toml(cls, path: str | os.PathLike,
                  overrides: typing.Mapping | None = None) -> "CaseParameters":
        """Load a TOML case file (layout of :meth:`from_dict`)."""
        try:
            with open(path, "rb") as f:
                data = tomllib.load(f)
        except OSError as exc:
            raise ParameterError(f"cannot read case file {os.fspath(path)!r}: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ParameterError(f"case file {os.fspath(path)!r} is not valid TOML: {exc}") from None
        return cls.from_dict(data, overrides, source=os.fspath(path),
                             base_dir=os.path.dirname(os.path.abspath(os.fspath(path))))

    # ----------------------------------------------------------- variants
    def replace(self, **changes) -> "CaseParameters":
        """A validated copy with some top-level fields replaced."""
        return dataclasses.replace(self, **changes)

    def with_ca(self, value: float) -> "CaseParameters":
        """Change Ca (and hence the flow speed V0) at fixed moduli."""
        return self.replace(physics=dataclasses.replace(self.physics, ca=value))

    def with_kinematics(self, value: str) -> "CaseParameters":
        """The same case on the ``"finite"`` or the ``"small"`` kinematics path."""
        return self.replace(kinematics=value)

    def with_e(self, value: float) -> "CaseParameters":
        """Move the cell: centre (x_mid, -e) (shear) or (e, 0.5) (normal)."""
        if self.case == "file" or self.geometry.cells:
            raise ParameterError("parameter 'e' places the one cell of a built-in device; here the cells are "
                                 "given by the geometry file or the cells list")
        return self.replace(geometry=dataclasses.replace(self.geometry, e=value))

    def with_mesh_size(self, factor: float) -> "CaseParameters":
        """Multiply every element size by ``factor`` (2 = twice as coarse)."""
        return self.replace(mesh=dataclasses.replace(self.mesh, size_factor=factor))

    def with_cell_moduli(self, multiple: float) -> "CaseParameters":
        """Set μ_c = ``multiple`` · φ_s0 μ_s, keeping the cell's Poisson ratio (λ_c/μ_c)."""
        p: list[str] = []
        _check(p, "cell_moduli", multiple, 0.0, why="a multiple of the gel's drained modulus φ_s0 μ_s")
        _raise(p)
        mu_c = multiple * self.physics.phi_s0 * self.dimensional.mu_s
        ratio = self.cell.lambda_c / self.cell.mu_c
        return self.replace(cell=CellMaterial(mu_c=mu_c, lambda_c=ratio * mu_c))

    def with_gel_moduli(self, multiple: float) -> "CaseParameters":
        """Multiply μ_s and λ_s [Pa] by ``multiple`` at fixed V0 and fixed cell moduli [Pa].

        Hence Ca → Ca/multiple and μ_c/μ_s → (μ_c/μ_s)/multiple (model.md section 5 sweep).
        """
        p: list[str] = []
        _check(p, "gel_moduli", multiple, 0.0, why="a factor on μ_s and λ_s")
        _raise(p)
        return self.replace(
            physics=dataclasses.replace(self.physics, ca=self.physics.ca / multiple),
            dimensional=dataclasses.replace(self.dimensional, mu_s=self.dimensional.mu_s * multiple))

    # ----------------------------------------------------------- derived values
    @property
    def name(self) -> str:
        return self.case

    @property
    def label(self) -> str:
        """How runs and figures name the device: "shear flow", "normal flow" or "device FILE"."""
        if self.case == "file":
            return f"device {os.path.basename(self.geometry.file)}"
        return f"{self.case} flow"

    @property
    def e(self) -> float:
        return self.geometry.e

    @property
    def V0(self) -> float:
        """Velocity scale [m/s]: V0 = Ca L0 μ_s / μ."""
        d = self.dimensional
        return self.physics.ca * d.L0 * d.mu_s / d.mu

    @property
    def lambda_s_pa(self) -> float:
        """λ_s [Pa] = (λ_s/μ_s) μ_s."""
        return self.physics.lambda_s * self.dimensional.mu_s

    @property
    def mu_c(self) -> float:
        """Cell shear modulus in units of μ_s (μ̄_c)."""
        return self.cell.mu_c / self.dimensional.mu_s

    @property
    def lambda_c(self) -> float:
        """Cell λ_c in units of μ_s (λ̄_c)."""
        return self.cell.lambda_c / self.dimensional.mu_s

    @property
    def drained_modulus(self) -> float:
        """The gel's drained (measured) shear modulus φ_s0 μ_s [Pa]."""
        return self.physics.phi_s0 * self.dimensional.mu_s

    @property
    def cell_moduli_multiple(self) -> float:
        """μ_c / (φ_s0 μ_s): the cell's stiffness in multiples of the gel's drained modulus."""
        return self.cell.mu_c / self.drained_modulus

    @property
    def brinkman_layer(self) -> float:
        """Brinkman boundary-layer thickness δ = 1/sqrt(ξ φ_s0) in units of L0."""
        return 1.0 / math.sqrt(self.physics.xi * self.physics.phi_s0)

    @property
    def stress_scale(self) -> float:
        """Solver stress unit μ V0 / L0 in units of μ_s (= Ca)."""
        return self.physics.ca

    @property
    def displacement_scale(self) -> float:
        """Solver displacement unit Ca L0 in units of L0 (= Ca)."""
        return self.physics.ca

    def element_sizes(self) -> dict[str, float]:
        """Element sizes and band widths (units of L0) after ``size_factor``."""
        m, f = self.mesh, self.mesh.size_factor
        delta = self.brinkman_layer
        d = self.geometry.min_cell_diameter
        return {"h_fluid": f * m.h_fluid, "h_gel": f * m.h_gel,
                "h_cell": f * math.pi * d / m.n_cell_edges,
                "h_layer": f * delta / m.layer_elements,
                "cell_band": m.cell_band * d, "layer_band": m.layer_width * delta,
                "growth": m.growth}

    # ----------------------------------------------------------- unit conversions
    def scale(self, kind: str) -> float:
        """SI value of one dimensionless unit of ``kind``.

        ``length``/``displacement``: L0 [m]; ``velocity``: V0 [m/s];
        ``stress``/``pressure``: μ_s [Pa]; ``time``: L0/V0 [s].
        """
        d = self.dimensional
        scales = {"length": d.L0, "displacement": d.L0, "velocity": self.V0,
                  "stress": d.mu_s, "pressure": d.mu_s, "time": d.L0 / self.V0}
        try:
            return scales[kind]
        except KeyError:
            raise ValueError(f"unknown quantity kind {kind!r} (known: {sorted(scales)})") from None

    def to_si(self, value, kind: str):
        """Dimensionless (paper units) → SI (m, m/s, Pa, s)."""
        return value * self.scale(kind)

    def from_si(self, value, kind: str):
        """SI → dimensionless (paper units)."""
        return value / self.scale(kind)

    def to_report(self, value, kind: str):
        """Dimensionless → reporting units (µm, µm/s, mPa, s; see ``REPORT_UNITS``)."""
        return self.to_si(value, kind) * REPORT_UNITS[kind][1]

    def from_report(self, value, kind: str):
        """Reporting units (µm, µm/s, mPa, s) → dimensionless."""
        return self.from_si(value / REPORT_UNITS[kind][1], kind)

    # ----------------------------------------------------------- serialisation
    def to_input_dict(self) -> dict:
        """The TOML layout of this case; ``from_dict(to_input_dict())`` reproduces it."""
        return {"case": {"name": self.case, "cell": self.with_cell, "kinematics": self.kinematics},
                "physics": dataclasses.asdict(self.physics),
                "dimensional": dataclasses.asdict(self.dimensional),
                "cell": dataclasses.asdict(self.cell),
                "geometry": dataclasses.asdict(self.geometry),
                "mesh": dataclasses.asdict(self.mesh),
                "coupling": copy.deepcopy(self.coupling),
                "time": copy.deepcopy(self.time)}

    def to_dict(self) -> dict:
        """Everything for a summary: inputs plus dimensionless and SI blocks."""
        ph, d = self.physics, self.dimensional
        dimensionless = {
            "phi_s0": ph.phi_s0, "lambda_s": ph.lambda_s, "xi": ph.xi, "beta": ph.beta,
            "eta": ph.eta, "Ca": ph.ca, "mu_c": self.mu_c, "lambda_c": self.lambda_c, "e": self.e,
            "brinkman_layer": self.brinkman_layer, "stress_scale": self.stress_scale,
            "displacement_scale": self.displacement_scale,
            "cell_moduli_multiple_of_drained_gel_modulus": self.cell_moduli_multiple}
        si = {
            "L0_m": d.L0, "V0_m_per_s": self.V0, "mu_Pa_s": d.mu, "mu_s_Pa": d.mu_s,
            "lambda_s_Pa": self.lambda_s_pa, "drained_gel_modulus_Pa": self.drained_modulus,
            "mu_c_Pa": self.cell.mu_c, "lambda_c_Pa": self.cell.lambda_c,
            "cell_youngs_modulus_Pa": self.cell.youngs_modulus,
            "cell_poisson_ratio": self.cell.poisson_ratio, "pore_radius_m": d.pore_radius,
            "xi_Pa_s_per_m2": ph.xi * d.mu / d.L0 ** 2, "beta_m_per_Pa_s": ph.beta * d.L0 / d.mu,
            "eta_m_per_Pa_s": ph.eta * d.L0 / d.mu, "e_m": None if self.e is None else self.e * d.L0,
            "brinkman_layer_m": self.brinkman_layer * d.L0, "time_scale_s": d.L0 / self.V0,
            "solver_stress_unit_Pa": d.mu * self.V0 / d.L0,
            "solver_displacement_unit_m": ph.ca * d.L0}
        return {"case": self.case, "with_cell": self.with_cell, "kinematics": self.kinematics,
                "dimensionless": dimensionless, "si": si,
                "report_units": {k: v[0] for k, v in REPORT_UNITS.items()},
                "geometry": dataclasses.asdict(self.geometry),
                "mesh": {**dataclasses.asdict(self.mesh), "element_sizes": self.element_sizes()},
                "coupling": copy.deepcopy(self.coupling),
                "input": self.to_input_dict()}
