"""Resuming an interrupted time-dependent run: its configuration and checkpoint in ``DIR.partial/``.

A run writes ``DIR.partial/case.toml`` (its whole configuration) when it
starts and ``DIR.partial/checkpoint.npz`` after every window; ``--resume
DIR`` continues it from there.  What the command line gives at a resume
must agree with the stored configuration: the case (any case option or a
``--config``), the time settings (any time option) and the method (solver
and coupling options); the output options may differ.
"""

from __future__ import annotations

import json
import os
import typing

from gelcell.case import RunConfig
from gelcell.case.casefile import read_case_file
from gelcell.case.parameters import CASE_TABLES
from gelcell.coupled.defaults import partitioned_config
from gelcell.errors import ParameterError

__all__ = ["RUN_CONFIG", "CHECKPOINT", "read_interrupted", "check_resume", "method_tables"]

#: the configuration of the run in ``DIR.partial/`` (and, once it is done, in ``DIR/``)
RUN_CONFIG = "case.toml"
CHECKPOINT = "checkpoint.npz"
#: the groups of tables a resume compares, and the tables of each
_GROUPS = {"case": CASE_TABLES, "time settings": ("time",), "method": ("solver", "coupling")}


def read_interrupted(out: str) -> dict:
    """The configuration tables of the interrupted run whose ``--out`` was ``out``; ParameterError if none."""
    partial = os.path.abspath(out) + ".partial"
    path = os.path.join(partial, RUN_CONFIG)
    if not os.path.isfile(os.path.join(partial, CHECKPOINT)) or not os.path.isfile(path):
        raise ParameterError(f"--resume {out}: nothing to resume, {partial}/ holds no checkpoint of an "
                             f"interrupted time-dependent run")
    return read_case_file(path)


def method_tables(config: RunConfig) -> dict:
    """``[solver]`` and the resolved ``[coupling]`` of a time-dependent run (what its method is)."""
    coupling = None if config.solver.monolithic else partitioned_config(
        config.case, config.coupling, transient=True, gamma2=config.solver.gamma2)
    return config.to_tables(coupling=coupling)


def _normalised(tables: dict, names: typing.Iterable[str]) -> dict:
    return json.loads(json.dumps({n: tables.get(n) or {} for n in names}, default=str, sort_keys=True))


def check_resume(stored: RunConfig, given: RunConfig, groups: typing.Iterable[str], out: str) -> None:
    """Raise ParameterError if ``given`` (the command line) differs from ``stored`` in one of ``groups``."""
    mine, theirs = method_tables(stored), method_tables(given)
    for group in groups:
        names = _GROUPS[group]
        a, b = _normalised(theirs, names), _normalised(mine, names)
        if a == b:
            continue
        keys = sorted(f"{t}.{k}" for t in names for k in set(a[t]) | set(b[t]) if a[t].get(k) != b[t].get(k))
        raise ParameterError(f"--resume {out}: the checkpoint belongs to another run: its {group} "
                             f"differ{'s' if group == 'method' else ''} from the command line's"
                             f"{' (' + ', '.join(keys) + ')' if keys else ''}; resume with the "
                             f"interrupted run's options, or only '--resume {out}'")
