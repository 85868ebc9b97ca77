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

import dataclasses
import math
import os
import typing

from gelcell.case.casefile import read_case_file
from gelcell.case.devices import FileGeometry, NormalGeometry, ShearGeometry
from gelcell.case.materials import CellMaterial, Dimensional, Physics
from gelcell.case.meshsizes import MeshSizes
from gelcell.case.ranges import check_range, format_value, out_of_range, raise_problems, range_text
from gelcell.errors import ParameterError

__all__ = ["CaseParameters", "CASES", "ALL_CASES", "KINEMATICS", "GAMMA2", "DEFAULT_GAMMA2", "REPORT_UNITS",
           "CASE_TABLES", "RUN_TABLES"]

CASES = ("shear", "normal")
#: every case: the built-in devices and a device from a geometry file (``[geometry] file``, ``--geometry``)
ALL_CASES = CASES + ("file",)
#: ``"finite"`` (default): total Lagrangian gel, moving fluid domain (docs/finite-strain.md);
#: ``"small"``: the equations on the undeformed domain, exact to the size of the strains
KINEMATICS = ("finite", "small")
#: splits of Gamma2 (gelcell.coupled): the cell takes the gel's displacement ("dirichlet"), the same
#: with the cell's stiffness condensed into the gel ("schur"), or the gel's force and springs ("robin")
GAMMA2 = ("dirichlet", "schur", "robin")
#: the default split: fewer iterations than "dirichlet" at every stiffness (docs/coupling.md)
DEFAULT_GAMMA2 = "schur"

#: Units in which results are reported (``to_report``) and their factor from SI.
REPORT_UNITS = {"length": ("µm", 1e6), "displacement": ("µm", 1e6),
                "velocity": ("µm/s", 1e6), "stress": ("mPa", 1e3),
                "pressure": ("mPa", 1e3), "time": ("s", 1.0)}


#: the tables of a case file that define the case (this module), and those of how it is run
#: (:mod:`gelcell.case.config`)
CASE_TABLES = ("case", "physics", "dimensional", "cell", "geometry", "mesh")
RUN_TABLES = ("solver", "coupling", "time", "output", "sweep")
_GEOMETRY = {"shear": ShearGeometry, "normal": NormalGeometry, "file": FileGeometry}
#: A built-in device's cell element size (π d / n_cell_edges) must be at least this share of the far-field
#: size min(h_fluid, h_gel) (both scale with size_factor): far below it gmsh cannot grade the mesh from the cell
#: to the far field, and it aborts the process (a cell of diameter 1e-9 L0 is below its geometric tolerance).
MIN_CELL_SIZE_RATIO = 1e-3


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
    """

    case: str = "shear"
    with_cell: bool = True
    kinematics: str = "finite"
    physics: Physics = dataclasses.field(default_factory=Physics)
    dimensional: Dimensional = dataclasses.field(default_factory=Dimensional)
    cell: CellMaterial = dataclasses.field(default_factory=CellMaterial)
    geometry: typing.Any = None
    mesh: MeshSizes = dataclasses.field(default_factory=MeshSizes)

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
        if self.case == "file" and isinstance(self.geometry, FileGeometry) and self.geometry.contents is not None:
            has_cells = bool(self.geometry.contents.cells)
            if has_cells and not self.with_cell:
                raise ParameterError(f"parameter 'cell' = false: the cells of geometry file "
                                     f"{self.geometry.file!r} come from the file (remove them there)")
            object.__setattr__(self, "with_cell", has_cells)
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
        raise_problems(problems)
        if self.case == "file" and self.geometry.file.lower().endswith(".msh") and self.mesh.size_factor != 1.0:
            raise ParameterError(f"parameter 'size_factor' = {self.mesh.size_factor:g} (--mesh-size): a .msh file "
                                 f"carries its own mesh; element sizes can be scaled for .geo files only (allowed: 1)")
        if self.case == "file":
            return                  # its walls and cells are checked when the file is read (gelcell.geometry)
        problems = self.geometry.wall_problems(self.element_sizes()["h_layer"])
        if self.with_cell:
            problems += self._cell_size_problems()
            raise_problems(problems)
            problems += self.geometry.placement_problems(self.element_sizes()["h_cell"])
            problems += self.geometry.height_problems(self.element_sizes()["h_cell"])
        raise_problems(problems)

    def _cell_size_problems(self) -> list[str]:
        """Every cell of a built-in device large enough for its mesh: π d / n_cell_edges at least
        MIN_CELL_SIZE_RATIO x min(h_fluid, h_gel)."""
        m = self.mesh
        far = min(m.h_fluid, m.h_gel)
        d_min = MIN_CELL_SIZE_RATIO * far * m.n_cell_edges / math.pi
        why = (f"a cell's element size π d / n_cell_edges (n_cell_edges = {m.n_cell_edges}) must be at least "
               f"{MIN_CELL_SIZE_RATIO:g} x the far-field element size min(h_fluid, h_gel) = {format_value(far)}, "
               f"so that gmsh can grade the mesh from the cell to the far field")
        cells = self.geometry.cell_list()
        names = [f"cells[{k}].d" for k in range(len(cells))] if self.geometry.cells else ["cell_diameter"]
        return [out_of_range(name, d, range_text(d_min, math.inf, lo_closed=True), why=why)
                for name, (_, _, d) in zip(names, cells) if not d >= d_min]

    # ----------------------------------------------------------- constructors
    @classmethod
    def default(cls, case: str = "shear", with_cell: bool = True) -> "CaseParameters":
        """Baseline parameters (model.md Table 1) of ``case``."""
        return cls(case=case, with_cell=with_cell)

    @classmethod
    def from_dict(cls, data: typing.Mapping, source: str = "input", base_dir: str | None = None) -> "CaseParameters":
        """Build from the tables of a case file (see ``examples/case_baseline_*.toml``).

        Tables: ``[case] name, cell, kinematics`` and two multiples applied to the
        case the other tables give, in this order: ``cell_moduli`` (μ_c =
        multiple × φ_s0 μ_s, the cell's Poisson ratio kept) and ``gel_moduli``
        (μ_s, λ_s × multiple at fixed V0 and cell moduli, so Ca → Ca / multiple);
        ``[physics]``; ``[dimensional]`` (may
        give ``V0`` instead of ``physics.ca``); ``[cell]`` with ``mu_c`` and
        ``lambda_c`` [Pa], or ``youngs_modulus`` [Pa] and ``poisson_ratio``,
        or ``moduli_multiple`` (× φ_s0 μ_s, with an optional
        ``poisson_ratio``, default 0.25); ``[geometry]`` (keys of the case's
        geometry class, or ``file``); ``[mesh]``.  The tables of how a case is
        run (:data:`RUN_TABLES`) are read by :class:`gelcell.case.RunConfig`,
        not here.  Unknown tables and keys raise :class:`ParameterError` naming them.
        """
        d = _known_tables(data, source)
        case_block = _take(d, "case", ["name", "cell", "kinematics", "cell_moduli", "gel_moduli"], source)
        geometry_block = dict(d.get("geometry", {}))
        if geometry_block.get("file") is not None:
            _file_case(case_block, geometry_block, source, base_dir)
        case = case_block.get("name", "shear")
        if case not in ALL_CASES:
            raise ParameterError(f"parameter 'case' = {case!r} is not one of {list(CASES)}")
        if case == "file" and geometry_block.get("file") is None:
            raise ParameterError(f"case 'file' needs [geometry] file (a .geo or .msh path) in {source}")
        kinematics = case_block.get("kinematics", "finite")
        if kinematics not in KINEMATICS:
            raise ParameterError(f"parameter 'kinematics' = {kinematics!r} in {source} is not one of "
                                 f"{list(KINEMATICS)}")
        physics, dimensional = _physics_blocks(d, source)
        unknown = [k for k in geometry_block if k not in _field_names(_GEOMETRY[case])]
        if unknown:
            raise ParameterError(f"unknown key 'geometry.{unknown[0]}' in {source} "
                                 f"(known: {_field_names(_GEOMETRY[case])})")
        mesh = _take(d, "mesh", _field_names(MeshSizes), source)
        cell_block = _take(d, "cell", ["mu_c", "lambda_c", "youngs_modulus", "poisson_ratio", "moduli_multiple"],
                           source)
        made = cls(case=case, with_cell=case_block.get("cell", True), kinematics=kinematics, physics=physics,
                   dimensional=dimensional, cell=_cell_from_block(cell_block, physics, dimensional, source),
                   geometry=_GEOMETRY[case](**geometry_block), mesh=MeshSizes(**mesh))
        if case_block.get("cell_moduli") is not None:
            made = made.with_cell_moduli(case_block["cell_moduli"])
        if case_block.get("gel_moduli") is not None:
            made = made.with_gel_moduli(case_block["gel_moduli"])
        return made

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "CaseParameters":
        """The case of a TOML case file (layout of :meth:`from_dict`)."""
        return cls.from_dict(read_case_file(path), source=os.fspath(path),
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
        check_range(p, "cell_moduli", multiple, 0.0, why="a multiple of the gel's drained modulus φ_s0 μ_s")
        raise_problems(p)
        mu_c = multiple * self.physics.phi_s0 * self.dimensional.mu_s
        ratio = self.cell.lambda_c / self.cell.mu_c
        return self.replace(cell=CellMaterial(mu_c=mu_c, lambda_c=ratio * mu_c))

    def with_gel_moduli(self, multiple: float) -> "CaseParameters":
        """Multiply μ_s and λ_s [Pa] by ``multiple`` at fixed V0 and fixed cell moduli [Pa].

        Hence Ca → Ca/multiple and μ_c/μ_s → (μ_c/μ_s)/multiple (model.md section 5 sweep).
        """
        p: list[str] = []
        check_range(p, "gel_moduli", multiple, 0.0, why="a factor on μ_s and λ_s")
        raise_problems(p)
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
        g = self.geometry
        return {"case": {"name": self.case, "cell": self.with_cell, "kinematics": self.kinematics},
                "physics": dataclasses.asdict(self.physics),
                "dimensional": dataclasses.asdict(self.dimensional),
                "cell": dataclasses.asdict(self.cell),
                "geometry": g.to_input_dict(),
                "mesh": dataclasses.asdict(self.mesh)}

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
                "geometry": self.to_input_dict()["geometry"],
                "mesh": {**dataclasses.asdict(self.mesh), "element_sizes": self.element_sizes()},
                "input": self.to_input_dict()}


# --------------------------------------------------------------------------- reading the tables
def _known_tables(data: typing.Mapping, source: str) -> dict:
    """The tables of ``data`` (copied), each a table of a known name."""
    d = {k: (dict(v) if isinstance(v, typing.Mapping) else v) for k, v in dict(data).items()}
    known = CASE_TABLES + RUN_TABLES
    for table, value in d.items():
        if table not in known:
            raise ParameterError(f"unknown table or key '{table}' in {source} (known: {sorted(known)})")
        if not isinstance(value, dict):
            raise ParameterError(f"'{table}' in {source} must be a table")
    return d


def _take(d: dict, table: str, allowed: typing.Iterable[str], source: str) -> dict:
    """Table ``table`` of ``d`` (a copy), whose keys must be among ``allowed``."""
    block = dict(d.get(table, {}))
    allowed = list(allowed)
    for k in block:
        if k not in allowed:
            raise ParameterError(f"unknown key '{table}.{k}' in {source} (known: {allowed})")
    return block


def _file_case(case_block: dict, geometry_block: dict, source: str, base_dir: str | None) -> None:
    """A ``[geometry] file``: the case is ``file``; its path relative to the case file's directory."""
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


def _physics_blocks(d: dict, source: str) -> tuple[Physics, Dimensional]:
    """``[physics]`` and ``[dimensional]``; a ``dimensional.V0`` gives Ca = μ V0 / (L0 μ_s)."""
    physics = _take(d, "physics", _field_names(Physics), source)
    dimensional = _take(d, "dimensional", _field_names(Dimensional) + ["V0"], source)
    V0 = dimensional.pop("V0", None)
    if V0 is not None:
        if "ca" in physics:
            raise ParameterError(f"give either 'physics.ca' or 'dimensional.V0' in {source}, "
                                 f"not both (V0 = Ca L0 μ_s / μ)")
        p: list[str] = []
        check_range(p, "V0", V0, 0.0, unit="m/s")
        raise_problems(p)
        dim = Dimensional(**dimensional)
        physics["ca"] = dim.mu * V0 / (dim.L0 * dim.mu_s)
    return Physics(**physics), Dimensional(**dimensional)


def _cell_from_block(block: dict, physics: Physics, dim: Dimensional, source: str) -> CellMaterial:
    """The cell's moduli from ``[cell]``: Lamé moduli, Young's modulus and ν, or a multiple of φ_s0 μ_s."""
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
    check_range(p, "moduli_multiple", m, 0.0)
    check_range(p, "poisson_ratio", nu, -1.0, 0.5)
    raise_problems(p + physics.problems() + dim.problems())
    mu_c = m * physics.phi_s0 * dim.mu_s
    return CellMaterial(mu_c=mu_c, lambda_c=2 * mu_c * nu / (1 - 2 * nu))
