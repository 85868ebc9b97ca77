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
import zipfile

from mpi4py import MPI

from gelcell.case import RunConfig
from gelcell.case.casefile import read_case_file
from gelcell.case.parameters import CASE_TABLES
from coupling.serialization import load_npz
from gelcell.coupled.defaults import partitioned_config
from gelcell.errors import ParameterError

__all__ = ["RUN_CONFIG", "CHECKPOINT", "read_interrupted", "check_checkpoint", "check_resume", "method_tables"]

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


def _checkpoint_problem(out: str, path: str, ranks: int) -> str | None:
    try:
        state = load_npz(path)
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        return (f"--resume {out}: the checkpoint {path} cannot be read ({type(exc).__name__}: {exc}): it is "
                f"damaged or truncated; remove {os.path.dirname(path)}/ and run again without --resume")
    if not isinstance(state, dict) or "format" not in state:
        return f"--resume {out}: {path} is not a checkpoint of a gelcell run"
    saved = state.get("ranks")
    if saved is not None and int(saved) != ranks:
        return (f"--resume {out}: the checkpoint was written on {int(saved)} MPI rank(s) and can only be resumed "
                f"on as many (mpirun -n {int(saved)} gelcell run --resume {out}); this run has {ranks}")
    return None


def check_checkpoint(out: str, comm: MPI.Comm = MPI.COMM_WORLD) -> None:
    """Raise ParameterError (on every rank) if the checkpoint of ``out`` cannot be resumed on ``comm``:
    unreadable or truncated, or written on another number of ranks (before anything is meshed)."""
    path = os.path.join(os.path.abspath(out) + ".partial", CHECKPOINT)
    problem = _checkpoint_problem(out, path, comm.size) if comm.rank == 0 else None
    problem = comm.bcast(problem, root=0)
    if problem is not None:
        raise ParameterError(problem)


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
