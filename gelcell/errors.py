"""Every expected failure of gelcell: its one-line message and its exit code, in one place.

``gelcell`` (``gelcell.cli.main``) catches an exception, prints
``gelcell COMMAND: error: <message(exc)>`` on stderr (rank 0; no traceback
unless ``gelcell --debug``) and exits with ``exit_code(exc)``.  The mapping is
by exception type (:data:`EXIT_CODES`, first match wins):

| code | failure |
|---:|---|
| 0 | success |
| 1 | internal error (a bug: rerun with --debug and report it) |
| 2 | bad parameters, case file, ``[coupling]`` table or command-line option (``ParameterError``) |
| 3 | output directory refused or not writable (``OutputError``), or the disk is full (an ``OSError`` ENOSPC, EDQUOT) |
| 4 | model limits: Ca, cell/gel stiffness ratio, mesh too large, ``time.max_windows`` reached (``ModelLimitError``) |
| 5 | coupling diverged (``CouplingDivergedError``) |
| 6 | coupling did not converge in ``max_iterations`` (``CouplingNotConvergedError``) |
| 7 | singular system: a boundary condition is missing (``SingularSystemError``) |
| 8 | a field solver's Newton iteration failed (``NewtonError``) |
| 9 | some values of a sweep failed; the completed ones are written (``SweepError``) |
| 130 | interrupted by SIGINT (Ctrl-C) |
| 143 | interrupted by SIGTERM |

A coupling that diverged because a participant failed carries that failure as
its ``__cause__``: a singular system is reported as such (7); a Newton failure
is reported as the field's (8) unless the coupling residual grew more than
tenfold before it, in which case the coupling diverged (5) and the field failed
only under the growing interface loads.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import typing

from coupling.errors import CouplingDivergedError, CouplingNotConvergedError
from femtools.errors import NewtonError, OutputError, SingularSystemError

__all__ = ["GelcellError", "ModelLimitError", "SweepError", "Interrupted", "EXIT_CODES", "exit_code",
           "message", "root_cause", "disk_full", "install_signal_handlers", "OutputError", "SingularSystemError",
           "NewtonError", "ParameterError"]


class GelcellError(Exception):
    """Base class of gelcell's own expected failures."""


class ParameterError(ValueError):
    """A parameter outside its physical range (or an unknown/ill-typed input)."""


class ModelLimitError(GelcellError):
    """An input the model cannot answer: not representable, or too large for this machine."""


class SweepError(GelcellError):
    """Some values of a sweep failed; ``failures`` lists ``(value, message, exit code)``."""

    def __init__(self, text: str, failures: list):
        super().__init__(text)
        self.failures = failures


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived (raised by the handlers of :func:`install_signal_handlers`)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: (exception type, exit code), first match wins
EXIT_CODES: list[tuple[type, int]] = [
    (ParameterError, 2),
    (OutputError, 3),
    (ModelLimitError, 4),
    (CouplingDivergedError, 5),
    (CouplingNotConvergedError, 6),
    (SingularSystemError, 7),
    (NewtonError, 8),
    (SweepError, 9),
]
INTERNAL_ERROR = 1
#: A coupling whose residual grew by more than this factor before a field solver failed
#: diverged; below it the field failed under the load itself.
COUPLING_GROWTH = 10.0

_COUPLING_ADVICE = ("use the default --acceleration iqn-ils, or aitken (README: 'Choosing coupling "
                    "settings')")
_LOAD_ADVICE = ("the load is too large for this model: lower Ca (--ca; --gel-moduli X divides it by X) or the "
                "load; with --kinematics small, use the default --kinematics finite; for a time-dependent run, "
                "a smaller --dt")


def _coupling_growth(exc: CouplingDivergedError) -> float:
    """Largest growth of a data's residual norm from the first to the last coupling iteration."""
    windows = getattr(exc.result, "windows", None) or []
    records = windows[-1].records if windows else []
    if len(records) < 2:
        return 0.0
    first, last = records[0].residual_norms, records[-1].residual_norms
    return max((last[d] / first[d] for d in first if first[d] > 0 and d in last), default=0.0)


def root_cause(exc: BaseException) -> BaseException:
    """The failure to report: a participant's failure behind a coupling divergence, if it is the cause."""
    cause = exc.__cause__ if isinstance(exc, CouplingDivergedError) else None
    if isinstance(cause, SingularSystemError):
        return cause
    if isinstance(cause, NewtonError) and _coupling_growth(exc) <= COUPLING_GROWTH:
        return cause
    return exc


def disk_full(exc: BaseException) -> bool:
    """True if ``exc`` is a write that failed because the file system is full (or the quota used up)."""
    if not isinstance(exc, OSError):
        return False
    return exc.errno in (errno.ENOSPC, errno.EDQUOT) or os.strerror(errno.ENOSPC) in str(exc)


def exit_code(exc: BaseException) -> int:
    """The exit status of ``gelcell`` for ``exc`` (see the table in the module docstring)."""
    if isinstance(exc, KeyboardInterrupt):
        return 128 + getattr(exc, "signum", signal.SIGINT)
    exc = root_cause(exc)
    if disk_full(exc):
        return dict(EXIT_CODES)[OutputError]
    for kind, code in EXIT_CODES:
        if isinstance(exc, kind):
            return code
    return INTERNAL_ERROR


def _one_line(text: str) -> str:
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


def message(exc: BaseException) -> str:
    """One line naming the cause of ``exc`` and what to do."""
    if isinstance(exc, KeyboardInterrupt):
        name = signal.Signals(getattr(exc, "signum", signal.SIGINT)).name
        return (f"interrupted by {name}: stopped before the results were complete; temporary files "
                f"were removed and the output directory is unchanged")
    cause = root_cause(exc)
    if isinstance(cause, NewtonError):
        return f"{cause.solver}: Newton's method failed ({cause.reason}): {_LOAD_ADVICE}"
    if isinstance(cause, CouplingDivergedError):
        inner = cause.__cause__
        if inner is None:
            head = str(cause).split("; residual norms of")[0]
            return _one_line(f"{head}: {_COUPLING_ADVICE}")
        failed = getattr(inner, "solver", None) or type(inner).__name__
        detail = getattr(inner, "reason", None) or _one_line(inner)
        return _one_line(f"coupling diverged: its residual grew x{_coupling_growth(cause):.3g} in "
                         f"{cause.result.iterations} iterations, then the {failed} solver failed ({detail}): "
                         f"{_COUPLING_ADVICE}")
    if isinstance(cause, CouplingNotConvergedError):
        head = str(cause).split("; its history")[0]
        return _one_line(f"{head}: raise max_iterations in the [coupling] table of a --config file, "
                         f"or {_COUPLING_ADVICE}")
    if disk_full(cause):
        where = f" writing {cause.filename}" if getattr(cause, "filename", None) else ""
        return _one_line(f"the disk is full ({os.strerror(cause.errno or errno.ENOSPC)}){where}: free space "
                         f"there or choose an --out on another file system; an interrupted time-dependent run "
                         f"continues from its last checkpoint with --resume DIR")
    if any(isinstance(cause, kind) for kind, _ in EXIT_CODES):
        return _one_line(cause)
    return _one_line(f"internal error: {type(exc).__name__}: {exc} (rerun with gelcell --debug ... for "
                     f"the traceback, and please report it)")


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


@contextlib.contextmanager
def install_signal_handlers(signals: typing.Iterable[int] = (signal.SIGINT, signal.SIGTERM)):
    """Inside the block SIGINT and SIGTERM raise :class:`Interrupted`, so that context managers
    (``femtools.io.atomic_directory``) unwind and remove their temporary files.

    gmsh, which resets SIGINT, is imported later if at all (not on a mesh-cache hit), always
    through ``femtools.gmshimport.import_gmsh``, which keeps these handlers."""
    previous = {s: signal.getsignal(s) for s in signals}
    for s in signals:
        signal.signal(s, _raise_interrupted)
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)

