"""The configuration of a run: the case, and how it is solved, coupled, stepped in time and written.

One :class:`RunConfig` holds everything ``gelcell run`` and ``gelcell sweep``
use.  It comes from three layers, and their precedence is decided here and
nowhere else (:func:`resolve`)::

    defaults  <  the case file's tables  <  the command line's keys

The command line arrives as dotted keys of the same tables (``physics.ca``,
``coupling.scheme``, ``solver.method``, ...; ``gelcell.cli`` maps each option
to its key), so every option has a case-file key.  The merge:

* a command-line key replaces the file's value; ``physics.ca`` also drops a
  ``dimensional.V0`` of the file (two ways of giving one value), a device
  (``case.name``) drops the file's ``geometry.file`` and a geometry file
  the file's ``case.name``;
* ``coupling.acceleration.type`` unlike the file's replaces the file's whole
  ``[coupling.acceleration]`` table, whose keys belong to another method;
* the multiples ``case.cell_moduli`` and ``case.gel_moduli`` act on the case
  the tables give (:meth:`CaseParameters.from_dict`); a written
  ``case.toml`` holds their result, not the multiples.

Tables (``examples/case_baseline_shear.toml``; docs/configuration.md):

* ``[case] [physics] [dimensional] [cell] [geometry] [mesh]``: the case
  (:class:`~gelcell.case.parameters.CaseParameters`);
* ``[solver] method`` (``"partitioned"`` or ``"monolithic"``), ``gamma2``
  (the split on Γ2: ``"schur"``, ``"dirichlet"`` or ``"robin"``), ``kind``
  (the field solvers' linear solves: ``"direct"``, ``"iterative"`` or
  ``"auto"``, :mod:`gelcell.coupled.solverchoice`) and ``[solver.petsc.FIELD]``
  (PETSc options of one field's solve, FIELD one of :data:`PETSC_FIELDS`);
* ``[coupling]``: the coupling library's table (docs/coupling.md); what it
  leaves out is the device's default (``gelcell.coupled.defaults``);
* ``[time]``: :class:`~gelcell.case.timesettings.TimeSettings`;
* ``[output] figures, progress, compare_no_cell``;
* ``[sweep] param, values, compare_kinematics`` (``gelcell sweep``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import typing

from gelcell.case.casefile import read_case_file
from gelcell.case.parameters import DEFAULT_GAMMA2, GAMMA2, CaseParameters
from gelcell.case.timesettings import TimeSettings
from gelcell.errors import ParameterError

__all__ = ["RunConfig", "SolverSettings", "SOLVER_KINDS", "PETSC_FIELDS",
           "OutputSettings", "SweepSettings", "resolve", "load_run_config",
           "merge_tables", "METHODS", "SWEEPS"]

METHODS = ("partitioned", "monolithic")
#: ``solver.kind``: the field solvers' linear solves (auto: by dimension and size, gelcell.coupled.solverchoice)
SOLVER_KINDS = ("direct", "iterative", "auto")
#: the fields of ``[solver.petsc.FIELD]`` (the fluid's options also reach its mesh motion)
PETSC_FIELDS = ("fluid", "gel", "cell")
#: the parameters ``gelcell sweep`` varies
SWEEPS = ("ca", "cell-moduli", "gel-moduli", "e")


def _flag(table: str, key: str, value) -> bool:
    if not isinstance(value, bool):
        raise ParameterError(f"parameter '{table}.{key}' = {value!r} must be true or false")
    return value


def _check_keys(table: str, block: typing.Mapping, known: typing.Iterable[str], source: str) -> None:
    known = list(known)
    for key in block:
        if key not in known:
            raise ParameterError(f"unknown key '{table}.{key}' in {source} (known: {known})")


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """``[solver]``: the partitioned coupling or the monolithic reference, the split on Γ2, and the
    field solvers' linear solves with their PETSc options per field."""

    method: str = "partitioned"
    gamma2: str = DEFAULT_GAMMA2
    kind: str = "direct"
    petsc: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ParameterError(f"parameter 'solver.method' = {self.method!r} is not one of {list(METHODS)}")
        if self.gamma2 not in GAMMA2:
            raise ParameterError(f"parameter 'solver.gamma2' = {self.gamma2!r} is not one of {list(GAMMA2)}")
        if self.kind not in SOLVER_KINDS:
            raise ParameterError(f"parameter 'solver.kind' = {self.kind!r} is not one of {list(SOLVER_KINDS)}")
        object.__setattr__(self, "petsc", _petsc_tables(self.petsc))
        if self.monolithic and self.petsc:
            raise ParameterError(f"parameter 'solver.petsc.{next(iter(self.petsc))}': PETSc options are for the "
                                 f"field solvers of the partitioned run, not the monolithic reference")

    @property
    def monolithic(self) -> bool:
        return self.method == "monolithic"


def _petsc_tables(petsc) -> dict:
    """``[solver.petsc.FIELD]`` checked: FIELD one of PETSC_FIELDS, each a table of option = string/number/bool."""
    if not isinstance(petsc, typing.Mapping):
        raise ParameterError(f"parameter 'solver.petsc' = {petsc!r} must be a table of tables "
                             f"[solver.petsc.FIELD], FIELD one of {list(PETSC_FIELDS)}")
    out = {}
    for field, options in petsc.items():
        if field not in PETSC_FIELDS:
            raise ParameterError(f"unknown key 'solver.petsc.{field}' (known: {list(PETSC_FIELDS)})")
        if not isinstance(options, typing.Mapping) or not all(
                isinstance(v, (str, int, float, bool)) for v in options.values()):
            raise ParameterError(f"parameter 'solver.petsc.{field}' = {options!r} must be a table of PETSc options "
                                 f"(option = string, number or boolean, e.g. ksp_rtol = 1e-12)")
        out[field] = dict(options)
    return out


@dataclasses.dataclass(frozen=True)
class OutputSettings:
    """``[output]``: figures, the per-iteration progress, a comparison run without the cell."""

    figures: bool = True
    progress: bool = True
    compare_no_cell: bool = False

    def __post_init__(self):
        for f in dataclasses.fields(self):
            _flag("output", f.name, getattr(self, f.name))


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """``[sweep]``: the swept parameter and its values (``gelcell sweep``)."""

    param: str = "ca"
    values: tuple = ()
    compare_kinematics: bool = False

    def __post_init__(self):
        if self.param not in SWEEPS:
            raise ParameterError(f"parameter 'sweep.param' = {self.param!r} is not one of {list(SWEEPS)}")
        values = self.values if isinstance(self.values, (list, tuple)) else None
        if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                 and math.isfinite(v) for v in values):
            raise ParameterError(f"parameter 'sweep.values' = {self.values!r} must be a non-empty list of "
                                 f"finite numbers")
        object.__setattr__(self, "values", tuple(float(v) for v in values))
        _flag("sweep", "compare_kinematics", self.compare_kinematics)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything a run uses (see the module docstring); ``to_tables`` is its case-file layout."""

    case: CaseParameters
    solver: SolverSettings = SolverSettings()
    #: the ``[coupling]`` table as given (file and command line); the device fills in its defaults
    coupling: dict = dataclasses.field(default_factory=dict)
    time: TimeSettings = TimeSettings()
    output: OutputSettings = OutputSettings()
    sweep: SweepSettings | None = None

    def __post_init__(self):
        if self.output.compare_no_cell and self.time.transient:
            raise ParameterError("parameter 'output.compare_no_cell' (--compare-no-cell) is for steady runs, not "
                                 "with time.transient (--transient)")
        if self.output.compare_no_cell and self.case.case == "file" and self.case.with_cell:
            raise ParameterError("parameter 'output.compare_no_cell' (--compare-no-cell): the cells of a geometry "
                                 "file are part of its drawing; compare with a copy of the file without them")
        scheme = self.coupling.get("scheme")
        if isinstance(scheme, str) and scheme.endswith("explicit") and not self.time.transient \
                and not self.solver.monolithic:
            raise ParameterError(f"parameter 'coupling.scheme' = {scheme!r} exchanges once per time window: "
                                 f"add time.transient (--transient)")

    def replace(self, **changes) -> "RunConfig":
        return dataclasses.replace(self, **changes)

    def to_tables(self, coupling: typing.Mapping | None = None) -> dict:
        """The case-file tables of this configuration; ``coupling``: the table to write instead of
        :attr:`coupling` (the resolved one a run used)."""
        tables = self.case.to_input_dict()
        tables["solver"] = {k: v for k, v in dataclasses.asdict(self.solver).items() if v != {}}
        tables["coupling"] = copy.deepcopy(dict(self.coupling if coupling is None else coupling))
        tables["time"] = {k: v for k, v in self.time.to_dict().items() if v is not None}
        tables["output"] = dataclasses.asdict(self.output)
        if self.sweep is not None:
            tables["sweep"] = {**dataclasses.asdict(self.sweep), "values": list(self.sweep.values)}
        return tables


# --------------------------------------------------------------------------- the merge
def _set(tables: dict, key: str, value) -> None:
    """``tables[a][b][c] = value`` for the dotted ``key`` "a.b.c" (tables created as needed)."""
    *path, name = key.split(".")
    if not path:
        raise ParameterError(f"command-line key {key!r} must be 'table.key'")
    node = tables
    for part in path:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ParameterError(f"'{part}' in the case file must be a table (the command line sets {key})")
    node[name] = value


#: a command-line key that replaces another key of the file: (given key, table, key dropped)
_REPLACES = (("physics.ca", "dimensional", "V0"),          # two ways of giving one value
             ("geometry.file", "case", "name"),            # the device: a file instead of a built-in one
             ("case.name", "geometry", "file"))            # a built-in device instead of a file


def merge_tables(file_tables: typing.Mapping | None, command_line: typing.Mapping | None) -> dict:
    """The case file's tables with the command line's dotted keys on top (``None`` values: not given)."""
    tables = copy.deepcopy({k: (dict(v) if isinstance(v, typing.Mapping) else v)
                            for k, v in dict(file_tables or {}).items()})
    given = {k: v for k, v in dict(command_line or {}).items() if v is not None}
    acceleration = given.get("coupling.acceleration.type")
    if acceleration is not None:
        old = (tables.get("coupling") or {}).get("acceleration")
        if isinstance(old, typing.Mapping) and old.get("type", acceleration) != acceleration:
            tables["coupling"]["acceleration"] = {}
    for key, value in given.items():
        for given_key, table, dropped in _REPLACES:
            if key == given_key and isinstance(tables.get(table), dict):
                tables[table].pop(dropped, None)
        _set(tables, key, value)
    return tables


# --------------------------------------------------------------------------- the configuration
def _run_table(tables: dict, name: str, cls, source: str) -> typing.Any:
    block = tables.get(name) or {}
    _check_keys(name, block, [f.name for f in dataclasses.fields(cls)], source)
    return cls(**block)


def resolve(file_tables: typing.Mapping | None = None, command_line: typing.Mapping | None = None,
            source: str = "the command line", base_dir: str | None = None) -> RunConfig:
    """The run's configuration: defaults < ``file_tables`` (a case file's) < ``command_line`` (dotted keys).

    ``base_dir``: the directory relative paths of the case file are relative to
    (a geometry file, an inflow table).  Raises :class:`ParameterError` naming
    the first bad table, key or value; nothing is meshed.
    """
    tables = merge_tables(file_tables, command_line)
    case = CaseParameters.from_dict(tables, source=source, base_dir=base_dir)
    coupling = tables.get("coupling") or {}
    time_table = tables.get("time") or {}
    sweep = tables.get("sweep")
    return RunConfig(case=case, solver=_run_table(tables, "solver", SolverSettings, source),
                     coupling=copy.deepcopy(dict(coupling)),
                     time=TimeSettings.from_dict(time_table, source=source, base_dir=base_dir),
                     output=_run_table(tables, "output", OutputSettings, source),
                     sweep=None if sweep is None else _run_table(tables, "sweep", SweepSettings, source))


def load_run_config(path: str | os.PathLike | None, command_line: typing.Mapping | None = None) -> RunConfig:
    """:func:`resolve` of the case file at ``path`` (None: defaults) and the command line."""
    if path is None:
        return resolve({}, command_line)
    path = os.fspath(path)
    return resolve(read_case_file(path), command_line, source=path,
                   base_dir=os.path.dirname(os.path.abspath(path)))
