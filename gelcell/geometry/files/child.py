"""Reading and meshing a user's geometry file in a child process, where a signal and a bound can stop gmsh.

gmsh parses a ``.geo`` file and meshes it in C++ with SIGINT and SIGTERM at
their default actions for the interpreter, so a file that keeps gmsh busy
(a ``For`` loop of 2e9 iterations, a size field far too fine) could not be
stopped but by SIGKILL.  :func:`run_worker` therefore runs the gmsh work of
:mod:`gelcell.geometry.files.worker` in a child process (the script alone:
no gelcell import, no MPI, so it starts in 0.3 s and works on any rank of
an ``mpirun``) and waits for it:

* SIGINT or SIGTERM (the CLI's :class:`~gelcell.errors.Interrupted`) ends the
  child at once (SIGKILL) and goes on as the run's interruption (exit 130/143);
  the child also gets SIGKILL if this process dies;
* a time bound (:func:`time_limit`: ``$GELCELL_GMSH_TIME_LIMIT`` seconds,
  default :data:`DEFAULT_TIME_LIMIT`) and a memory bound (the address space of
  the child: :data:`MEMORY_SHARE` of this machine's memory) end it with a
  :class:`~gelcell.errors.ModelLimitError` (exit 4);
* gmsh's own errors, and a crash of gmsh, are a
  :class:`~gelcell.errors.ParameterError` naming the file (exit 2).
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import tempfile

from gelcell.errors import ModelLimitError, ParameterError
from gelcell.machine import MEMORY_SHARE, machine_memory

__all__ = ["DEFAULT_TIME_LIMIT", "time_limit", "memory_limit", "run_worker"]

#: seconds gmsh may take to read or to mesh a geometry file, unless ``$GELCELL_GMSH_TIME_LIMIT`` says otherwise
DEFAULT_TIME_LIMIT = 900.0
#: environment variables of an MPI launcher, not passed to the child (it is no MPI process)
_MPI_PREFIXES = ("OMPI_", "PMIX_", "PMI_", "HYDRA_", "MPICH_", "I_MPI_")
#: the child's script (run by path: it imports no gelcell module)
_WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "worker.py")
#: how much of the child's stderr (gmsh's messages) is kept for the error line
_LOG_TAIL = 4096


def time_limit() -> float:
    """``$GELCELL_GMSH_TIME_LIMIT`` (seconds > 0), else :data:`DEFAULT_TIME_LIMIT`."""
    text = os.environ.get("GELCELL_GMSH_TIME_LIMIT")
    if not text:
        return DEFAULT_TIME_LIMIT
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise ParameterError(f"GELCELL_GMSH_TIME_LIMIT = {text!r} must be a number of seconds > 0")
    return value


def memory_limit() -> int:
    """The address space the child may use: MEMORY_SHARE of this machine's memory (at least 1 GiB)."""
    return max(int(MEMORY_SHARE * machine_memory()), 1 << 30)


def _tail(log) -> str:
    log.seek(0, os.SEEK_END)
    size = log.tell()
    log.seek(max(0, size - _LOG_TAIL))
    lines = [ln.strip() for ln in log.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    return lines[-1] if lines else ""


def _environment() -> dict:
    return {k: v for k, v in os.environ.items() if not k.startswith(_MPI_PREFIXES)}


def run_worker(request: dict, path: str, doing: str):
    """The payload of the worker's answer to ``request``, or the error it reports.

    Args:
        request: the worker's request (see :mod:`gelcell.geometry.files.worker`).
        path: the geometry file, for the messages.
        doing: what the child does, for the messages ("reading", "meshing").
    """
    limit, memory = time_limit(), memory_limit()
    request = dict(request, parent=os.getpid(), memory_bytes=memory)
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen([sys.executable, _WORKER], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=log, env=_environment())
        try:
            out, _ = proc.communicate(pickle.dumps(request), timeout=limit)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            advice = ("a larger --mesh-size, coarser sizes in the file" if doing == "meshing" else
                      "does the file loop for long, or mesh itself?")
            raise ModelLimitError(f"geometry file {path!r}: gmsh was still {doing} it after {limit:g} s, the "
                                  f"limit ($GELCELL_GMSH_TIME_LIMIT seconds, default {DEFAULT_TIME_LIMIT:g}): "
                                  f"{advice}; or raise the limit") from None
        except BaseException:          # SIGINT/SIGTERM (Interrupted) or any other failure: gmsh stops now
            proc.kill()
            proc.wait()
            raise
        gmsh_said = _tail(log)
    answer = None
    if proc.returncode == 0 and out:
        try:
            answer = pickle.loads(out)
        except Exception:
            answer = None
    if answer is None:
        return _crashed(proc.returncode, gmsh_said, path, doing, memory)
    if answer[0] == "ok":
        return answer[1]
    kind, text = answer[1], answer[2]
    if kind == "ParameterError":
        raise ParameterError(text)
    if kind == "MemoryError":
        _out_of_memory(path, doing, memory)
    raise ParameterError(f"geometry file {path!r}: gmsh failed {doing} it: {text or gmsh_said}")


def _out_of_memory(path: str, doing: str, memory: int):
    raise ModelLimitError(f"geometry file {path!r}: gmsh ran out of memory {doing} it (it may use "
                          f"{memory / 2**30:.3g} GiB, {MEMORY_SHARE:.0%} of this machine's memory): choose a "
                          f"larger --mesh-size or coarsen the file's sizes")


def _crashed(returncode: int, gmsh_said: str, path: str, doing: str, memory: int):
    said = gmsh_said.lower()
    if any(w in said for w in ("bad_alloc", "memoryerror", "out of memory", "cannot allocate")):
        _out_of_memory(path, doing, memory)
    if returncode < 0:
        try:
            how = f"was killed by {signal.Signals(-returncode).name}"
        except ValueError:
            how = f"was killed by signal {-returncode}"
    else:
        how = f"exited with status {returncode}"
    raise ParameterError(f"geometry file {path!r}: gmsh {how} while {doing} it"
                         + (f" ({gmsh_said})" if gmsh_said else ""))
