"""Case files: TOML read with bounds, and written back (``DIR/case.toml``) so that a run can be repeated.

:func:`read_case_file` refuses what is not a small regular UTF-8 TOML file
with one :class:`~gelcell.errors.ParameterError` naming the file (the bytes
are read by :func:`read_bounded`, which the inflow tables share);
:func:`toml_text` writes nested tables of strings, numbers, booleans and
lists (a ``None`` value is left out: TOML has none), which ``tomllib``
reads back to the same values (floats are written with ``repr``, exact).
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
import tomllib
import typing

from gelcell.errors import ParameterError

__all__ = ["read_case_file", "read_bounded", "toml_text", "MAX_CASE_FILE_BYTES"]

#: a case file is a few kB; anything larger is not one
MAX_CASE_FILE_BYTES = 1 << 20
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def read_bounded(path: str, what: str, limit: int) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes; ParameterError otherwise."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise ParameterError(f"cannot read {what} {path!r}: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise ParameterError(f"{what} {path!r} is not a regular file")
    if info.st_size > limit:
        raise ParameterError(f"{what} {path!r} has {info.st_size} bytes, more than the {limit} allowed")
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as exc:
        raise ParameterError(f"cannot read {what} {path!r}: {exc.strerror}") from None
    if len(data) > limit:
        raise ParameterError(f"{what} {path!r} has more than the {limit} bytes allowed")
    return data


def read_case_file(path: str | os.PathLike) -> dict:
    """The tables of a TOML case file (a regular UTF-8 file of at most :data:`MAX_CASE_FILE_BYTES`)."""
    path = os.fspath(path)
    data = read_bounded(path, "case file", MAX_CASE_FILE_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterError(f"case file {path!r} is not UTF-8 text (byte {exc.start}): a case file is "
                             f"TOML") from None
    if "\x00" in text:
        raise ParameterError(f"case file {path!r} holds NUL bytes: a case file is TOML text")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"case file {path!r} is not valid TOML: {exc}") from None


def _key(name: str) -> str:
    return name if _BARE_KEY.match(name) else json.dumps(name, ensure_ascii=False)


def _value(value: typing.Any, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)      # a JSON string is a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v, f"{where}[{i}]") for i, v in enumerate(value)) + "]"
    if isinstance(value, dict):
        items = [f"{_key(k)} = {_value(v, f'{where}.{k}')}" for k, v in value.items() if v is not None]
        return "{" + ", ".join(items) + "}"
    raise TypeError(f"{where}: cannot write a {type(value).__name__} to TOML")


def _table(lines: list[str], name: str, table: typing.Mapping, where: str) -> None:
    scalars = {k: v for k, v in table.items() if v is not None and not isinstance(v, dict)}
    tables = {k: v for k, v in table.items() if isinstance(v, dict)}
    if name and (scalars or not tables):
        lines.append(f"\n[{name}]")
    lines += [f"{_key(k)} = {_value(v, f'{where}.{k}')}" for k, v in scalars.items()]
    for k, v in tables.items():
        _table(lines, f"{name}.{_key(k)}" if name else _key(k), v, f"{where}.{k}")


def toml_text(tables: typing.Mapping[str, typing.Mapping], header: str = "") -> str:
    """TOML text of ``{table: {key: value, ...}, ...}`` (nested dicts become sub-tables)."""
    lines = [f"# {line}" for line in header.splitlines()]
    _table(lines, "", dict(tables), "case")
    return "\n".join(lines).lstrip("\n") + "\n"
