"""The statements of a ``.geo`` file that gelcell refuses, found before gmsh sees the file.

gmsh's ``.geo`` language can run commands and reach the file system
(``SystemCall "rm -rf ~";``, ``Include``, ``Save``, ...).  Users share
geometry files, so reading one must not execute anything:
:func:`check_geo_statements` scans the file's text (comments and strings
skipped) and raises one :class:`~gelcell.errors.ParameterError` naming every
refused statement and its line.  The refused statements, and why the rest
is safe, are listed in docs/geometry-files.md ("What a .geo file may
contain").  A ``.msh`` file is data: gmsh's MSH reader runs nothing.
"""

from __future__ import annotations

import re

from gelcell.errors import ParameterError

__all__ = ["REFUSED", "REFUSED_OPTION_CATEGORIES", "ALLOWED_GENERAL_OPTIONS", "geo_problems", "check_geo_statements"]

#: statement -> what it does (why it is refused)
REFUSED = {
    "SystemCall": "runs a shell command",
    "System": "runs a shell command",
    "NonBlockingSystemCall": "runs a shell command",
    "Shell": "runs a shell command",
    "OnelabRun": "runs an external program",
    "Include": "reads another file, which is not checked (paste its statements into this file)",
    "Merge": "reads another file",
    "MergeWithBoundingBox": "reads another file",
    "ShapeFromFile": "reads another file",
    "Save": "writes a file",
    "Print": "writes a file",
    "CreateDir": "creates a directory",
    "CreateDirectory": "creates a directory",
    "DeleteFile": "deletes a file",
    "RenameFile": "renames a file",
    "Plugin": "runs a post-processing plugin (plugins read and write files)",
    "SendToServer": "talks to an external program",
    "Exit": "ends the program",
}
#: option categories a file may not set: they name programs and files
REFUSED_OPTION_CATEGORIES = ("Solver", "Print", "PostProcessing", "View")
#: the only ``General.*`` options a file may set (the others name files, editors and programs)
ALLOWED_GENERAL_OPTIONS = ("Terminal", "Verbosity", "NumThreads", "ExpertMode")

_TOKEN = re.compile(r"""
    (?P<newline>\n)
  | (?P<space>[ \t\r\f\v]+)
  | (?P<line_comment>//[^\n]*)
  | (?P<block_comment>/\*.*?(\*/|\Z))
  | (?P<string>"(\\.|[^"\\])*("|\Z))
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<number>[0-9]*\.?[0-9]+([eE][-+]?[0-9]+)?)
  | (?P<other>.)
""", re.VERBOSE | re.DOTALL)


def _tokens(text: str) -> list[tuple[str, str, int]]:
    """``(kind, text, line)`` of every token but spaces and comments (a string is one token)."""
    out, line = [], 1
    for m in _TOKEN.finditer(text):
        kind, value = m.lastgroup, m.group()
        if kind not in ("newline", "space", "line_comment", "block_comment"):
            out.append((kind, value, line))
        line += value.count("\n")
    return out


def _closing(tokens: list, i: int) -> int:
    """Index of the ``)`` closing the ``(`` at ``tokens[i]`` (or the end)."""
    depth = 0
    for j in range(i, len(tokens)):
        if tokens[j][1] == "(":
            depth += 1
        elif tokens[j][1] == ")":
            depth -= 1
            if depth == 0:
                return j
    return len(tokens) - 1


def geo_problems(text: str) -> list[str]:
    """One line per refused statement of the ``.geo`` source ``text``: what it is, its line and why."""
    tokens, problems = _tokens(text), []
    for i, (kind, value, line) in enumerate(tokens):
        if kind != "name":
            continue
        after = tokens[i + 1][1] if i + 1 < len(tokens) else ""
        if value in REFUSED:
            problems.append(f"line {line}: '{value}' {REFUSED[value]}")
        elif value == "Printf" and after == "(":
            j = _closing(tokens, i + 1)
            if j + 1 < len(tokens) and tokens[j + 1][1] == ">":
                problems.append(f"line {line}: 'Printf(...) >' writes a file")
        elif after == "." and (i == 0 or tokens[i - 1][1] != "."):
            option = tokens[i + 2][1] if i + 2 < len(tokens) else ""
            if value in REFUSED_OPTION_CATEGORIES:
                problems.append(f"line {line}: option '{value}.{option}': the {value} options name programs "
                                f"and files")
            elif value == "General" and option not in ALLOWED_GENERAL_OPTIONS:
                problems.append(f"line {line}: option 'General.{option}': of the General options a geometry file "
                                f"may set only {', '.join(ALLOWED_GENERAL_OPTIONS)}")
    return problems


def check_geo_statements(path: str, text: str | None = None) -> None:
    """Raise :class:`ParameterError` naming every refused statement of the ``.geo`` file ``path``."""
    if text is None:
        with open(path, encoding="utf-8", errors="replace") as f:
            text = f.read()
    problems = geo_problems(text)
    if problems:
        raise ParameterError(f"geometry file {path!r} was not read: it holds statements that run commands or "
                             f"reach the file system, which gelcell refuses (see 'What a .geo file may contain' "
                             f"in docs/geometry-files.md)\n" + "\n".join(problems))
