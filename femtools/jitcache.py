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
its library) goes to FFCx's own function, unchanged.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os

__all__ = ["install", "installed"]

_ORIGINAL = "_gelcell_original_get_cached_module"


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

    def get_cached_module(module_name, object_names, cache_dir, timeout):
        path = _cached_library(str(cache_dir), module_name)
        if path is not None:
            return _load(path, module_name, object_names)
        return original(module_name, object_names, cache_dir, timeout)

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
