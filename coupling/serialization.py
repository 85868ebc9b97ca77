"""Nested Python/numpy structures in files: ``.npz`` without pickle, and strict JSON.

:func:`save_npz` stores arrays as npz members and everything else (dicts with
string keys, lists, tuples, numbers, strings, booleans, ``None``) as a JSON
document in the member ``__meta__`` in which arrays appear as
``{"__array__": key}``; :func:`load_npz` reads it back with
``allow_pickle=False``.

:func:`to_jsonable` turns results (numpy scalars and arrays, NaN/Inf) into
plain Python that ``json.dump(..., allow_nan=False)`` accepts; every JSON file
the project writes goes through it.
"""

from __future__ import annotations

import io
import json
import os
from typing import Any

import numpy as np

__all__ = ["save_npz", "load_npz", "to_jsonable", "write_bytes", "encode_text", "decode_text"]

_META = "__meta__"


def _encode(obj: Any, arrays: dict[str, np.ndarray], where: str) -> Any:
    if isinstance(obj, np.ndarray):
        if obj.dtype == object:
            raise TypeError(f"{where}: object arrays cannot be saved")
        key = f"a{len(arrays)}"
        arrays[key] = obj
        return {"__array__": key}
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj)
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, dict):
        items = []
        for k, v in obj.items():
            if not isinstance(k, str):
                raise TypeError(f"{where}: dict keys must be strings, got {k!r}")
            items.append([k, _encode(v, arrays, f"{where}[{k!r}]")])
        return {"__dict__": items}
    if isinstance(obj, tuple):
        return {"__tuple__": [_encode(v, arrays, f"{where}[{i}]") for i, v in enumerate(obj)]}
    if isinstance(obj, list):
        return [_encode(v, arrays, f"{where}[{i}]") for i, v in enumerate(obj)]
    raise TypeError(f"{where}: cannot save an object of type {type(obj).__name__} (allowed: numpy "
                    f"arrays, dicts with string keys, lists, tuples, numbers, strings, None)")


def _decode(obj: Any, arrays: Any) -> Any:
    if isinstance(obj, list):
        return [_decode(v, arrays) for v in obj]
    if isinstance(obj, dict):
        if "__array__" in obj:
            return np.array(arrays[obj["__array__"]])
        if "__tuple__" in obj:
            return tuple(_decode(v, arrays) for v in obj["__tuple__"])
        if "__dict__" in obj:
            return {k: _decode(v, arrays) for k, v in obj["__dict__"]}
        raise ValueError(f"corrupt npz metadata entry {obj!r}")
    return obj


def encode_text(obj: Any) -> str:
    """``obj`` (no arrays) as the JSON text :func:`save_npz` would store it; :func:`decode_text` reads it.

    For a part of a structure saved often and changed rarely (a run's window records in every
    checkpoint): encoded once, it is stored as one string."""
    arrays: dict[str, np.ndarray] = {}
    meta = _encode(obj, arrays, "text")
    if arrays:
        raise TypeError("encode_text: arrays cannot be encoded as text (use save_npz)")
    return json.dumps(meta)


def decode_text(text: str) -> Any:
    """The object of an :func:`encode_text` text."""
    return _decode(json.loads(text), {})


def save_npz(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` to ``path`` (exactly that name; no suffix is added).

    The archive is built in memory and written in one piece: a failed write
    (a full disk) raises its OSError and removes the incomplete file.
    """
    arrays: dict[str, np.ndarray] = {}
    meta = _encode(obj, arrays, "state")
    buffer = io.BytesIO()
    np.savez(buffer, **{_META: np.array(json.dumps(meta))}, **arrays)
    write_bytes(path, buffer.getbuffer())


def write_bytes(path: str | os.PathLike, data) -> None:
    """Write ``data`` to ``path``; if that fails, remove the incomplete file and raise the OSError."""
    path = os.fspath(path)
    try:
        with open(path, "wb") as fh:
            fh.write(data)
    except OSError:
        try:
            os.remove(path)
        except OSError:
            pass
        raise


def load_npz(path: str | os.PathLike) -> Any:
    """Read an object written by :func:`save_npz`."""
    with np.load(os.fspath(path), allow_pickle=False) as archive:
        if _META not in archive.files:
            raise ValueError(f"{path}: not a coupling npz file (no {_META} member)")
        meta = json.loads(str(archive[_META]))
        arrays = {name: archive[name] for name in archive.files if name != _META}
    return _decode(meta, arrays)


def to_jsonable(obj: Any) -> Any:
    """``obj`` as plain Python for strict JSON (``json.dump(..., allow_nan=False)``), recursively.

    * numpy arrays become (nested) lists, numpy scalars ``bool``, ``int`` or ``float``;
    * NaN, +inf and -inf (Python or numpy floats) become ``None``;
    * dicts keep their values' order with ``str(key)`` keys; tuples and lists become lists;
    * strings and ``None`` are returned unchanged;
    * anything else raises a TypeError naming where it is, e.g. ``['runs'][2]['solver']``.

    Example::

        json.dumps(to_jsonable({1: np.float64("nan"), "x": np.arange(2)}), allow_nan=False)
        # '{"1": null, "x": [0, 1]}'
    """
    try:
        return _plain(obj)
    except _NotJSON as exc:
        where = "".join(f"[{key!r}]" for key in reversed(exc.path)) or "the value"
        raise TypeError(f"{where}: an object of type {type(exc.obj).__name__} cannot be written as JSON "
                        f"(allowed: dicts, lists, tuples, numpy arrays, numbers, strings, booleans, "
                        f"None)") from None


class _NotJSON(Exception):
    """An object :func:`to_jsonable` cannot convert; ``path`` collects its keys, innermost first."""

    def __init__(self, obj: Any):
        super().__init__()
        self.obj, self.path = obj, []


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        out = {}
        for key, value in obj.items():
            try:
                out[str(key)] = _plain(value)
            except _NotJSON as exc:
                exc.path.append(key)
                raise
        return out
    if isinstance(obj, (list, tuple)):
        items = []
        for i, value in enumerate(obj):
            try:
                items.append(_plain(value))
            except _NotJSON as exc:
                exc.path.append(i)
                raise
        return items
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if np.isfinite(value) else None
    if obj is None or isinstance(obj, str):
        return obj
    raise _NotJSON(obj)
