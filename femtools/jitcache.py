"""Loading FFCx's compiled forms from its cache by file name, without listing the cache.

FFCx 0.5 finds a cached module with a fresh ``importlib.machinery.FileFinder``
on the cache directory, and a fresh finder lists the whole directory
(``os.listdir``) to look up one name.  The cache holds every form ever
compiled on the machine (thousands of files on a development machine), so
every form a run loads pays for a listing of all of them, and more as the
cache grows (docs/femtools-costs.md).

:func:`install` wraps ``ffcx.codegeneration.jit.get_cached_module``: a module
whose compilation has finished (FFCx's ``<name>.c.cached`` marker exists) is
loaded from ``<name><extension suffix>`` directly; anything else (a first
compilation, a compilation in progress in another process, a marker without
its library) goes to FFCx's own function, which waits for a compilation in
progress in another process for at least :data:`WAIT_FOR_OTHER_COMPILATION`
seconds (FFCx's default, 10 s, is shorter than one 3D form's compilation on a
loaded machine: a process that found the form half-compiled by another, as
the parallel test workers do on an empty cache, would fail).

:func:`install` also makes sure that dolfinx's default cache directory
(``$XDG_CACHE_HOME/fenics``, else ``~/.cache/fenics``) can be written: if
it cannot (``XDG_CACHE_HOME`` names a file, a read-only mount, ...), the
forms are compiled into ``$TMPDIR/gelcell-fenics-<uid>`` (or a fresh
temporary directory) instead, with one warning; a run never fails on it.

:func:`install` also makes UFL order Constants by their creation count, as it
orders Coefficients (:func:`sort_constants_by_count`): UFL sorts the operands
of a sum by comparing terminals, Constants by their text, ``"...(), 10)"``
before ``"...(), 9)"``, so the same form built after a different number of
Constants had another operand order, another signature, and was compiled
again (the same gel's Jacobian twice in one test, or once more in every
``mpirun`` subprocess).
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import importlib.util
import logging
import os
import stat
import tempfile

__all__ = ["install", "installed", "sort_constants_by_count", "writable_directory"]

_ORIGINAL = "_gelcell_original_get_cached_module"
#: seconds to wait for another process's compilation of a form before FFCx gives up
WAIT_FOR_OTHER_COMPILATION = 600
_log = logging.getLogger(__name__)


def writable_directory(path: str) -> bool:
    """Whether ``path`` is (or can be made) a directory that this process can create files in."""
    try:
        os.makedirs(path, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".probe-")
        os.close(fd)
        os.remove(probe)
    except OSError:
        return False
    return True


def _private_fallback() -> str:
    """``$TMPDIR/gelcell-fenics-<uid>`` if it is this user's own directory, else a new temporary one."""
    path = os.path.join(tempfile.gettempdir(), f"gelcell-fenics-{os.getuid()}")
    with contextlib.suppress(OSError):
        os.mkdir(path, 0o700)
    with contextlib.suppress(OSError):
        info = os.lstat(path)
        if stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and writable_directory(path):
            return path
    return tempfile.mkdtemp(prefix="gelcell-fenics-")


def _usable_cache_dir() -> None:
    """Point dolfinx's default JIT cache at a writable directory (see the module docstring)."""
    try:
        from dolfinx import jit as dolfinx_jit
    except ImportError:
        return
    default = getattr(dolfinx_jit, "DOLFINX_DEFAULT_JIT_PARAMETERS", {}).get("cache_dir")
    if not default or writable_directory(os.fspath(default[0])):
        return
    fallback = _private_fallback()
    dolfinx_jit.DOLFINX_DEFAULT_JIT_PARAMETERS["cache_dir"] = (type(default[0])(fallback), *default[1:])
    from mpi4py import MPI
    if MPI.COMM_WORLD.rank == 0:
        _log.warning("the form compiler's cache %s cannot be written (check XDG_CACHE_HOME): compiling "
                     "into %s instead", default[0], fallback)


def _load(path: str, module_name: str, object_names):
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return [getattr(module.lib, name) for name in object_names], module


def _cached_library(cache_dir: str, module_name: str) -> str | None:
    """The compiled library of ``module_name`` if FFCx marked its compilation as finished."""
    if not os.path.exists(os.path.join(cache_dir, module_name + ".c.cached")):
        return None
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:       # the order FileFinder tries them in
        path = os.path.join(cache_dir, module_name + suffix)
        if os.path.exists(path):
            return path
    return None


def _cmp_constant(a, b) -> int:
    """-1, 0, 1 as ``a`` was created before, as, or after ``b`` (ufl.sorting's convention)."""
    x, y = a.count(), b.count()
    return -1 if x < y else (0 if x == y else 1)


def sort_constants_by_count() -> None:
    """Let UFL's canonical operand order compare Constants by creation count, not by text.

    The relative order of creation is a property of the form (UFL compares Coefficients so), and the
    form signature renumbers the counts: the signature no longer depends on how many Constants the
    process had made before.
    """
    from ufl import sorting
    from ufl.constant import Constant
    sorting._terminal_cmps[Constant._ufl_typecode_] = _cmp_constant


def install() -> bool:
    """Wrap FFCx's cache look-up (once per process); False if this FFCx has no such function."""
    try:
        from ffcx.codegeneration import jit
    except ImportError:
        return False
    original = getattr(jit, "get_cached_module", None)
    if original is None:
        return False
    if hasattr(jit, _ORIGINAL):
        return True
    sort_constants_by_count()
    _usable_cache_dir()

    def get_cached_module(module_name, object_names, cache_dir, timeout):
        path = _cached_library(str(cache_dir), module_name)
        if path is not None:
            return _load(path, module_name, object_names)
        return original(module_name, object_names, cache_dir, max(timeout, WAIT_FOR_OTHER_COMPILATION))

    get_cached_module.__doc__ = original.__doc__
    setattr(jit, _ORIGINAL, original)
    jit.get_cached_module = get_cached_module
    return True


def installed() -> bool:
    """Whether :func:`install` has wrapped FFCx's look-up in this process."""
    try:
        from ffcx.codegeneration import jit
    except ImportError:
        return False
    return hasattr(jit, _ORIGINAL)
