"""What a case is and how it is run, as plain validated data (no dolfinx, no gmsh).

:class:`CaseParameters` is the device and its materials; :class:`RunConfig`
adds how it is solved, coupled, stepped in time and written, resolved from
defaults, a case file and the command line (:func:`resolve`).  Everything
here is checked on construction: a bad value raises one
:class:`~gelcell.errors.ParameterError` naming it and its allowed range.
"""

from gelcell.case.config import (METHODS, PETSC_FIELDS, SOLVER_KINDS, SWEEPS, OutputSettings, RunConfig,
                                 SolverSettings, SweepSettings, load_run_config, merge_tables, resolve)
from gelcell.case.devices import WALLS, FileContents, FileGeometry, NormalGeometry, ShearGeometry
from gelcell.case.inflow import Waveform, parse_inflow
from gelcell.case.materials import CellMaterial, Dimensional, Physics
from gelcell.case.meshsizes import MeshSizes
from gelcell.case.parameters import (ALL_CASES, CASES, DEFAULT_GAMMA2, GAMMA2, KINEMATICS, REPORT_UNITS,
                                     CaseParameters)
from gelcell.case.timesettings import TimeSettings, time_scales

__all__ = ["CaseParameters", "Physics", "Dimensional", "CellMaterial", "ShearGeometry", "NormalGeometry",
           "FileGeometry", "FileContents", "MeshSizes", "TimeSettings", "time_scales", "Waveform", "parse_inflow",
           "RunConfig", "SolverSettings", "OutputSettings", "SweepSettings", "resolve", "load_run_config",
           "merge_tables", "CASES", "ALL_CASES", "KINEMATICS", "GAMMA2", "DEFAULT_GAMMA2", "REPORT_UNITS",
           "METHODS", "SWEEPS", "SOLVER_KINDS", "PETSC_FIELDS", "WALLS"]
