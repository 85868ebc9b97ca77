"""What the per-machine disk caches (:mod:`gelcell.geometry.meshcache`, :mod:`gelcell.coupled.priorcache`) share.

Entries are ``.npz`` files written atomically (a temporary file, then a
rename), so a concurrent reader sees the old entry or the whole new one;
reading touches an entry, and pruning keeps the most recently used ones.  A
cache never fails a run: a directory that cannot be written is skipped.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import tempfile
from typing import Any, Callable

import numpy as np

__all__ = ["cache_root", "enabled", "prune", "read_npz", "write_npz"]

_log = logging.getLogger(__name__)


def cache_root() -> str:
    """``$XDG_CACHE_HOME/gelcell``, else ``~/.cache/gelcell``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "gelcell")


def enabled(variable: str) -> bool:
    """False if the environment variable ``variable`` is ``0`` (the cache is off)."""
    return os.environ.get(variable, "1").strip() != "0"


def read_npz(path: str, parse: Callable[[Any], Any]) -> Any:
    """``parse(arrays)`` of the entry at ``path``, or None if there is none or it cannot be read or
    parsed (``parse`` raises for an entry that is not a complete one of its format).  A hit is
    marked recently used (kept by :func:`prune`)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            value = parse(data)
    except FileNotFoundError:
        return None
    except Exception as exc:           # a corrupt or foreign entry is a miss; the next store replaces it
        _log.debug("cache: ignoring unreadable entry %s: %s", path, exc)
        return None
    with contextlib.suppress(OSError):
        os.utime(path)
    return value


def write_npz(path: str, arrays: dict, compressed: bool) -> bool:
    """Write ``arrays`` to ``path`` atomically; False (and nothing written) if that fails."""
    directory = os.path.dirname(path)
    try:
        os.makedirs(directory, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".tmp-", suffix=".npz")
        try:
            with os.fdopen(fd, "wb") as f:
                (np.savez_compressed if compressed else np.savez)(f, **arrays)
            os.replace(tmp, path)
        finally:
            with contextlib.suppress(OSError):
                os.remove(tmp)        # left only if writing failed or was interrupted
    except OSError as exc:             # e.g. a read-only cache directory: the run goes on uncached
        _warn_once(directory, exc)
        return False
    return True


_WARNED: set[str] = set()


def _warn_once(directory: str, exc: OSError) -> None:
    """One warning per directory and process: the cache is skipped, the run goes on."""
    if directory not in _WARNED:
        _WARNED.add(directory)
        _log.warning("cache directory %s cannot be written (%s; check XDG_CACHE_HOME): going on without "
                     "this cache", directory, exc.strerror or exc)


def prune(directory: str, entry_name: re.Pattern, max_entries: int, max_bytes: float = float("inf")) -> None:
    """Keep the most recently used entries of ``directory`` (names matching ``entry_name``): at most
    ``max_entries`` of them, of at most ``max_bytes`` together.  Nothing else there is removed."""
    with contextlib.suppress(OSError):
        with os.scandir(directory) as it:
            found = sorted(((s.st_mtime, s.st_size, e.path) for e in it if entry_name.match(e.name)
                            for s in (e.stat(),)), reverse=True)
        total = 0
        for i, (_, size, path) in enumerate(found):
            total += size
            if i >= max_entries or total > max_bytes:
                with contextlib.suppress(OSError):
                    os.remove(path)
