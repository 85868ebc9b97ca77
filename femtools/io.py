"""Output that is written whole or not at all, into directories gelcell made itself.

Safety rules of :func:`atomic_directory` (checked up front by
:func:`check_output_target`, which raises :class:`OutputError`):

* gelcell replaces only a directory it wrote itself, recognised by the
  marker file ``.gelcell-output`` (JSON: tool, version, command, time) in it,
  or an empty directory.  It refuses an empty path, the current directory
  or one containing it, an existing file, a symbolic link, a non-empty
  directory without the marker, and a parent it cannot write in.
* It refuses an output directory holding a file the run reads (``inputs``:
  its case file, geometry file, inflow table), which replacing it would delete.
* It refuses a name too long for the file system, counting the longest name
  made from it (``.tmp-<name>-XXXXXXXX``), before anything is solved.
* It refuses ``<path>.partial`` itself: that is an interrupted run's checkpoint.
* A time-dependent run holds an flock on its ``<path>.partial`` while it works
  in it (rank 0; :data:`LOCK_INFO` in it names the process): a second run on
  ``path`` is refused, naming the holder.
* New results go to a temporary sibling ``.tmp-<name>-*``.  When every rank
  has finished, the old directory is renamed aside (``.old-<name>-*``), the
  new one renamed in, and only then the old one deleted: a failure leaves
  either the old or the new results at the path, never a mixture.
* On an exception, SIGINT or SIGTERM (if a handler raises, see
  :func:`gelcell.errors.install_signal_handlers`) the temporary directory is
  deleted.  Signals that arrive while the directories are renamed are held
  until the rename is done.

The one exception to "nothing left behind" is ``partial=True`` (time-dependent
runs): the working directory is the fixed sibling ``<path>.partial``, which
holds the checkpoints, survives failures and signals, is reused by a resumed
run, and is promoted to ``<path>`` on success.

:func:`write_json` is the project's JSON writer: strict JSON (NaN and ±inf
as ``null``, never a bare ``NaN``), UTF-8, written atomically by rank 0.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import fcntl
import json
import logging
import os
import shlex
import shutil
import signal
import socket
import sys
import tempfile
import threading
import typing

from mpi4py import MPI

from femtools.errors import OutputError

__all__ = ["atomic_path", "write_json", "atomic_directory", "check_output_target", "OutputError",
           "MARKER", "PARTIAL_SUFFIX", "LOCK_INFO", "is_gelcell_output", "deferred_signals"]

log = logging.getLogger(__name__)

#: Name of the marker file in every output directory gelcell writes
MARKER = ".gelcell-output"
#: Suffix of the working directory of ``atomic_directory(..., partial=True)``
PARTIAL_SUFFIX = ".partial"
#: In ``<path>.partial`` while a run works in it (which holds an flock on that directory): who it is
LOCK_INFO = ".gelcell-lock"
_TOOL = "gelcell"


# --------------------------------------------------------------------------- marker
def _marker_info() -> dict:
    try:
        from importlib.metadata import version
        ver = version(_TOOL)
    except Exception:  # noqa: BLE001  (not installed: the marker still identifies the tool)
        ver = "unknown"
    return {"tool": _TOOL, "version": ver,
            "command": shlex.join([os.path.basename(sys.argv[0] or _TOOL)] + sys.argv[1:]),
            "created": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}


def _write_marker(directory: str) -> None:
    with open(os.path.join(directory, MARKER), "w", encoding="utf-8") as f:
        f.write(_json_text(_marker_info()))


def is_gelcell_output(path: str) -> bool:
    """True if ``path`` is a directory holding gelcell's marker file."""
    marker = os.path.join(path, MARKER)
    if os.path.islink(marker) or not os.path.isfile(marker):
        return False
    try:
        with open(marker, encoding="utf-8") as f:
            info = json.load(f)
    except (OSError, ValueError):
        return False
    return isinstance(info, dict) and info.get("tool") == _TOOL


# --------------------------------------------------------------------------- the working directory's lock
def _holder(directory: str) -> str:
    """Who holds the lock of ``directory``, from its :data:`LOCK_INFO` (what is known of it)."""
    try:
        with open(os.path.join(directory, LOCK_INFO), encoding="utf-8") as f:
            info = json.load(f)
        return f"pid {info['pid']} on {info['host']}, since {info['created']}: {info['command']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "another gelcell process"


def _in_use(directory: str, shown: str) -> str:
    return (f"{shown!r} is in use by another gelcell run ({_holder(directory)}): two runs cannot share one "
            f"--out; wait until it has finished (or stop it), or choose another --out")


def _lock(directory: str) -> int | None:
    """An open descriptor of ``directory`` holding its exclusive flock, or None if another process holds it."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise
    return fd


def _lock_problem(directory: str, shown: str) -> str | None:
    """Why ``directory`` (an existing ``<path>.partial``) cannot be used now: another run holds it."""
    if not os.path.isdir(directory) or os.path.islink(directory):
        return None
    try:
        fd = _lock(directory)
    except OSError:
        return None                 # cannot be opened: the other checks say why
    if fd is None:
        return _in_use(directory, shown)
    os.close(fd)                    # releases the lock
    return None


def _release(fd: int, directory: str) -> None:
    """Remove the holder's :data:`LOCK_INFO` from ``directory`` (if it is still there), then unlock."""
    with contextlib.suppress(OSError):
        os.remove(os.path.join(directory, LOCK_INFO))
    os.close(fd)


# --------------------------------------------------------------------------- checks
def _target_problem(full: str, shown: str, empty_ok: bool) -> str | None:
    """Why the existing ``full`` may not be replaced (None if it may)."""
    if os.path.islink(full):
        return f"{shown!r} is a symbolic link: give the directory it points to, or another --out"
    if not os.path.lexists(full):
        return None
    if not os.path.isdir(full):
        return (f"{shown!r} is an existing file, not a directory: gelcell does not replace it; "
                f"choose another --out, or move the file yourself")
    if is_gelcell_output(full) or (empty_ok and not os.listdir(full)):
        return None
    return (f"{shown!r} already exists and holds files gelcell did not write (no {MARKER} marker): "
            f"gelcell replaces only its own output directories; choose a new --out, or move or "
            f"delete that directory yourself")


#: the longest name made from an output directory's: ``.old-<name>-`` and mkdtemp's 8 characters
_SIBLING_EXTRA = len(".old-") + len("-") + 8


def _name_problem(full: str, shown: str, existing: str) -> str | None:
    """Why a name made from ``full`` is too long for the file system (None if none is).

    Checked: every directory still to be created, the directory itself and the
    names gelcell derives from it (``.tmp-<name>-*``, ``.old-<name>-*``,
    ``<name>.partial``), against the limits of the file system of ``existing``.
    """
    try:
        name_max = os.pathconf(existing, "PC_NAME_MAX")
        path_max = os.pathconf(existing, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    extra = max(_SIBLING_EXTRA, len(PARTIAL_SUFFIX))
    length = len(os.fsencode(os.path.basename(full)))
    if length + extra > name_max:
        name = os.path.basename(full)
        return (f"the name of the output directory {name[:24] + '...' + name[-8:]!r} is too long ({length} "
                f"bytes): gelcell writes "
                f"'.tmp-<name>-XXXXXXXX' and '<name>{PARTIAL_SUFFIX}' next to it, {length + extra} bytes, and "
                f"the file system allows {name_max}; choose a name of at most {name_max - extra} bytes")
    part = full
    while part != existing and part != os.path.dirname(part):
        if len(os.fsencode(os.path.basename(part))) > name_max:
            return (f"cannot create the output directory: the directory name {os.path.basename(part)[:24] + '...'!r} "
                    f"is too long ({len(os.fsencode(os.path.basename(part)))} bytes; the file system allows "
                    f"{name_max}); choose a shorter --out")
        part = os.path.dirname(part)
    if len(os.fsencode(full)) + _SIBLING_EXTRA + 64 > path_max:
        return (f"the output directory {shown!r} is too long a path ({len(os.fsencode(full))} bytes; "
                f"the file system allows {path_max} for a file in it); choose a shorter --out")
    return None


def _run_of_partial(full: str) -> str | None:
    """The output directory whose time-dependent run works in ``full`` (None if ``full`` is not one)."""
    if not full.endswith(PARTIAL_SUFFIX) or len(full) == len(PARTIAL_SUFFIX) or not is_gelcell_output(full):
        return None
    return full[:-len(PARTIAL_SUFFIX)]


def _input_problem(full: str, shown: str, partial: bool, inputs) -> str | None:
    """Why replacing ``full`` (or promoting ``full.partial``) would delete one of the run's ``inputs``."""
    replaced = [os.path.realpath(full)] + ([os.path.realpath(full + PARTIAL_SUFFIX)] if partial else [])
    for what, name in inputs:
        if not name:
            continue
        real = os.path.realpath(os.fspath(name))
        for directory in replaced:
            if os.path.commonpath([real, directory]) == directory:
                inside = shown if directory == replaced[0] else shown.rstrip(os.sep) + PARTIAL_SUFFIX
                return (f"the output directory {inside!r} contains an input of this run, {os.fspath(name)!r} "
                        f"({what}): gelcell replaces its output directory as a whole, which would delete "
                        f"it; move the input out of {inside!r} or choose another --out")
    return None


def _refusal(path, partial: bool, inputs=()) -> str | None:
    """Why ``path`` may not be used as an output directory (None if it may)."""
    if path is None or not os.fspath(path).strip():
        return ("the output directory is an empty string: give a directory, e.g. --out results/run1 "
                "(is a shell variable such as $OUT unset?)")
    shown = os.fspath(path)
    full = os.path.abspath(shown)
    cwd = os.getcwd()
    if os.path.commonpath([full, cwd]) == full:
        return (f"the output directory {shown!r} is the current directory or contains it: gelcell "
                f"replaces its output directory as a whole; give a new subdirectory, "
                f"e.g. --out {os.path.join(shown, 'results')}")
    if _run_of_partial(full) is not None:
        run = shown.rstrip(os.sep)[:-len(PARTIAL_SUFFIX)]
        return (f"{shown!r} is the working directory (checkpoint) of the interrupted time-dependent run "
                f"whose --out was {run!r}: gelcell does not replace it; continue that run with "
                f"'gelcell run --resume {run}', or delete {shown!r} yourself, or choose another --out")
    problem = _input_problem(full, shown, partial, inputs)
    if problem is not None:
        return problem
    # a time-dependent run working in path.partial/ (it replaces path when it ends)
    problem = _lock_problem(full + PARTIAL_SUFFIX, shown.rstrip(os.sep) + PARTIAL_SUFFIX)
    if problem is None:
        problem = _target_problem(full, shown, empty_ok=True)
    if problem is None and partial:
        # the checkpoint directory of an interrupted run is reused only if gelcell made it
        problem = _target_problem(full + PARTIAL_SUFFIX, shown.rstrip(os.sep) + PARTIAL_SUFFIX, empty_ok=False)
    if problem is not None:
        return problem
    existing = os.path.dirname(full)
    while not os.path.lexists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        return f"cannot create {shown!r}: {existing!r} is a file, not a directory; choose another --out"
    problem = _name_problem(full, shown, existing)
    if problem is not None:
        return problem
    try:        # the real test of writability (os.access is always true for root)
        os.rmdir(tempfile.mkdtemp(prefix=".gelcell-probe-", dir=existing))
    except OSError as exc:
        return (f"cannot write the output directory {shown!r}: {existing!r} is not writable "
                f"({exc.strerror}); choose an --out in a writable directory")
    return None


def _on_rank0(comm: MPI.Comm, action: typing.Callable[[], typing.Any]):
    """Run ``action`` on rank 0; return its result (or raise its OutputError) on every rank."""
    result, error = None, None
    if comm.rank == 0:
        try:
            result = action()
        except OSError as exc:
            error = f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc)
    result, error = comm.bcast((result, error), root=0)
    if error is not None:
        raise OutputError(error)
    return result


def check_output_target(path, comm: MPI.Comm = MPI.COMM_WORLD, partial: bool = False,
                        inputs: typing.Iterable[tuple[str, typing.Any]] = ()) -> str:
    """Raise :class:`OutputError` unless ``path`` may be written by :func:`atomic_directory`.

    Call it before any meshing or solving.  ``inputs`` are ``(what, path)`` of
    the files the run reads (e.g. ``("--config", "case.toml")``): none may lie
    in the directories the run replaces.  Returns the absolute path.
    """
    inputs = list(inputs)
    problem = _on_rank0(comm, lambda: _refusal(path, partial, inputs))
    if problem is not None:
        raise OutputError(problem)
    return os.path.abspath(os.fspath(path))


# --------------------------------------------------------------------------- signals
@contextlib.contextmanager
def deferred_signals(signals: typing.Iterable[int] = (signal.SIGINT, signal.SIGTERM)):
    """Hold ``signals`` inside the block; deliver them (to the previous handlers) after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {s: signal.getsignal(s) for s in signals}
    for s, handler in previous.items():
        if handler is not None:          # None: a handler installed outside Python; leave it
            signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for s, handler in previous.items():
            if handler is not None:
                signal.signal(s, handler)
        for s in dict.fromkeys(pending):
            signal.raise_signal(s)


# --------------------------------------------------------------------------- directories
def _promote(work: str, full: str, partial: bool) -> None:
    """Replace ``full`` by ``work``: old aside, new in, old deleted (rank 0)."""
    problem = _target_problem(full, full, empty_ok=True)   # it may have changed during the run
    if problem is not None:
        raise OSError(f"{problem}; the new results are kept in {work}")
    os.chmod(work, 0o755)                   # mkdtemp makes it private
    parent, name = os.path.split(full)
    old = None
    try:
        if os.path.lexists(full):
            old = tempfile.mkdtemp(prefix=f".old-{name}-", dir=parent)
            os.replace(full, old)            # onto the empty placeholder: atomic
        os.replace(work, full)
    except OSError as exc:
        if old is not None and not os.path.lexists(full):
            os.replace(old, full)            # put the previous results back
        elif old is not None:
            os.rmdir(old)
        if not partial:
            shutil.rmtree(work, ignore_errors=True)
        raise OSError(f"could not move the new results into {full!r} ({exc.strerror or exc}); "
                      f"the previous contents of {full!r} are unchanged") from exc
    if old is not None:
        try:
            shutil.rmtree(old)
        except OSError as exc:
            log.warning("the previous results were moved to %s but could not be deleted (%s); "
                        "delete it yourself", old, exc)


def _prepare(full: str, partial: bool, held: list) -> tuple[str, str | None]:
    """Create the working directory with its marker (rank 0); return its path and why it cannot be used.

    ``partial``: the working directory ``full.partial`` is locked (its descriptor
    appended to ``held``) and its :data:`LOCK_INFO` names this process.
    """
    parent = os.path.dirname(full)
    os.makedirs(parent, exist_ok=True)
    if not partial:
        work = tempfile.mkdtemp(prefix=f".tmp-{os.path.basename(full)}-", dir=parent)
        _write_marker(work)
        return work, None
    work = full + PARTIAL_SUFFIX
    for _ in range(3):                  # another run may rename it (promote) between mkdir and flock
        with contextlib.suppress(FileExistsError):
            os.mkdir(work)
        fd = _lock(work)
        if fd is None:
            return work, _in_use(work, work)
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(work))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    else:
        return work, f"{work!r} was replaced by another gelcell run three times while this one started; retry"
    held.append(fd)
    try:
        if not is_gelcell_output(work):
            _write_marker(work)
        info = {**_marker_info(), "pid": os.getpid(), "host": socket.gethostname()}
        with open(os.path.join(work, LOCK_INFO), "w", encoding="utf-8") as f:
            f.write(_json_text(info))
    except BaseException:
        _release(held.pop(), work)
        raise
    return work, None


@contextlib.contextmanager
def atomic_directory(path, comm: MPI.Comm = MPI.COMM_WORLD, partial: bool = False):
    """Yield a working directory that replaces ``path`` as a whole when the block succeeds.

    ``path`` is checked first (:func:`check_output_target`).  The working
    directory carries the marker.  On success on every rank the old ``path`` is
    renamed aside, the working directory renamed to ``path`` and the old one
    deleted.  On an exception (incl. KeyboardInterrupt or a raising SIGTERM
    handler) on any rank the working directory is deleted and ``path`` is
    unchanged, except with ``partial=True``: the working directory is then
    ``path + ".partial"`` (reused as it is if it exists, so a resumed run
    continues from its checkpoints) and is kept on failure.
    """
    full = check_output_target(path, comm, partial)
    held: list[int] = []            # rank 0: the descriptor holding the lock of full.partial
    work, problem = _on_rank0(comm, lambda: _prepare(full, partial, held))
    if problem is not None:
        raise OutputError(problem)
    ok = False
    try:
        yield work
        ok = True
    finally:
        with deferred_signals():
            try:
                ok = comm.allreduce(ok, op=MPI.LAND)
                if held:
                    with contextlib.suppress(OSError):
                        os.remove(os.path.join(work, LOCK_INFO))     # not into the results
                if ok:
                    _on_rank0(comm, lambda: _promote(work, full, partial))
                elif not partial and comm.rank == 0:
                    shutil.rmtree(work, ignore_errors=True)
            finally:
                for fd in held:
                    os.close(fd)            # releases the lock


@contextlib.contextmanager
def _commit(tmp: str, path: str, comm: MPI.Comm):
    """Move the file ``tmp`` to ``path`` if the block succeeded on every rank, else delete it.

    Collective: when it returns, ``path`` is there for every rank; rank 0's
    OSError (moving or removing) is raised on every rank.
    """
    ok = False
    try:
        yield
        ok = True
    finally:
        ok = comm.allreduce(ok, op=MPI.LAND)
        failed = None
        if comm.rank == 0:
            try:
                if ok:
                    os.chmod(tmp, 0o644)         # mkstemp makes it private
                    os.replace(tmp, path)
                elif os.path.exists(tmp):
                    os.remove(tmp)
            except OSError as exc:
                failed = (exc.errno, exc.strerror or str(exc), exc.filename or tmp)
        failed = comm.bcast(failed, root=0)
        if failed is not None and ok:
            raise OSError(*failed)


@contextlib.contextmanager
def atomic_path(path: str, comm: MPI.Comm = MPI.COMM_WORLD):
    """Yield a temporary path next to ``path``; rename it to ``path`` on success.

    Rank 0 chooses the name; every rank may write to it (e.g. XDMF/HDF5 in
    parallel).  On an exception the temporary file is removed and ``path``
    is left untouched.
    """
    path = os.path.abspath(path)
    tmp = None
    if comm.rank == 0:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(path),
                                   dir=os.path.dirname(path))
        os.close(fd)
    tmp = comm.bcast(tmp, root=0)
    with _commit(tmp, path, comm):
        yield tmp


def _json_text(data: typing.Any) -> str:
    """``data`` as strict JSON text (UTF-8 characters kept, indented, newline-terminated).

    Converted by :func:`coupling.serialization.to_jsonable`: numpy scalars and
    arrays become Python numbers and lists, NaN and ±inf ``null``; anything
    else that is not JSON raises a TypeError naming its key path.
    """
    from coupling.serialization import to_jsonable     # the coupling package imports scipy: only when needed
    return json.dumps(to_jsonable(data), indent=2, ensure_ascii=False, allow_nan=False) + "\n"


def write_json(path: str, data: typing.Any, comm: MPI.Comm = MPI.COMM_WORLD) -> None:
    """Write ``data`` to ``path`` as strict JSON (:func:`_json_text`), atomically, by rank 0 (collective).

    Only rank 0's ``data`` is written.  A TypeError (``data`` holds something
    that is not JSON) is raised on every rank, before any file is created.
    """
    text, error = None, None
    if comm.rank == 0:
        try:
            text = _json_text(data)
        except TypeError as exc:
            error = f"{path}: {exc}"
    error = comm.bcast(error, root=0)
    if error is not None:
        raise TypeError(error)
    with atomic_path(path, comm) as tmp:
        if comm.rank == 0:
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(text)
