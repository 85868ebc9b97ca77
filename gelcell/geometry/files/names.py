"""The naming convention of geometry files: physical groups by name (docs/geometry-files.md).

* surfaces (volumes in a 3D device): ``fluid``, ``gel``, and ``cell`` or ``cell_1``, ``cell_2``, ...
* curves (surfaces in 3D): ``inlet`` / ``inlet_K`` with an optional profile and speed in V0
  units, ``inlet:parabolic:1`` (default) or ``inlet_2:uniform:0.5``;
  ``outlet`` (zero traction), ``wall`` (no slip), ``held`` (gel boundary
  with v_f = 0 and u_s = 0), ``symmetry`` (horizontal or vertical lines; planes x, y or z = const),
  ``interface`` / ``interface_K`` (fluid-gel interfaces, coupled as
  Gamma1, Gamma3, Gamma4, ...), optionally ``cell_boundary`` /
  ``cell_K_boundary`` (checked; the gel-cell interfaces are found from the
  surfaces).  ``outlet``, ``wall``, ``held`` and ``symmetry`` also take a
  ``_K`` suffix (merged).

:func:`parse_groups` sorts a file's groups by these names; a name that is
not one of them is a problem with a suggestion of the nearest name.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re

from gelcell.geometry.files.read import GeometryInfo

__all__ = ["CURVE_KINDS", "WORDS", "ParsedGroups", "parse_groups", "suggest_name"]

#: dimension of the device -> the words of its regions and of their boundaries
WORDS = {2: ("surface", "curve"), 3: ("volume", "surface")}

#: the kinds of curve group: each names a boundary condition or an interface
CURVE_KINDS = ("inlet", "outlet", "wall", "held", "symmetry", "interface")
_SURFACE_RE = re.compile(r"^(fluid|gel|cell|cell_(\d+))$")
_CURVE_RE = re.compile(r"^(inlet|outlet|wall|held|symmetry|interface)(?:_(\d+))?(?::(\w+)(?::(.+))?)?$")
_CELL_BOUNDARY_RE = re.compile(r"^cell(?:_(\d+))?_boundary$")
_KNOWN = ["fluid", "gel", "cell", "cell_1", "inlet", "inlet_1", "inlet:parabolic:1", "inlet:uniform:1", "outlet",
          "wall", "held", "symmetry", "interface", "interface_1", "cell_boundary", "cell_1_boundary"]


@dataclasses.dataclass
class ParsedGroups:
    """A file's physical groups sorted by the convention."""

    surfaces: dict          #: "fluid"/"gel" -> [surfaces]
    cells: list             #: (name, K, [surfaces]) of every cell, by K
    curves: dict            #: kind -> [(group name, K, [curves], options)], by K
    cell_boundaries: list   #: (name, K, [curves])
    owner: dict             #: curve -> group name
    surface_owner: dict = dataclasses.field(default_factory=dict)   #: surface -> group name


def suggest_name(name: str) -> str:
    """"; did you mean 'X'?" for the convention's name nearest ``name`` (or "")."""
    close = difflib.get_close_matches(name.split(":")[0], _KNOWN, n=1, cutoff=0.6)
    return f"; did you mean '{close[0]}'?" if close else ""


def _surface_group(parsed: ParsedGroups, name: str, ents: list, problems: list, word: str = "surface") -> None:
    text = name.strip()
    m = _SURFACE_RE.match(text)
    if not m:
        problems.append(f"physical {word} '{name}': unknown name ({word}s are 'fluid', 'gel', 'cell' "
                        f"or 'cell_1', 'cell_2', ...){suggest_name(text)}")
        return
    for s in ents:
        if s in parsed.surface_owner:
            problems.append(f"{word} {s} is in two physical groups: '{parsed.surface_owner[s]}' and '{name}'")
        parsed.surface_owner[s] = name
    if text in parsed.surfaces:
        parsed.surfaces[text] += ents
    else:
        parsed.cells.append((text, int(m.group(2)) if m.group(2) else 0, list(ents)))


def _inlet_options(name: str, profile: str | None, speed: str | None, problems: list, word: str = "curve") -> dict:
    """The profile and speed (units of V0) of ``inlet[_K]:profile:speed``."""
    options = {"profile": profile or "parabolic"}
    if options["profile"] not in ("parabolic", "uniform"):
        problems.append(f"physical {word} '{name}': inflow profile '{profile}' must be 'parabolic' or 'uniform'")
    try:
        options["speed"] = float(speed) if speed is not None else 1.0
        if not (math.isfinite(options["speed"]) and options["speed"] > 0):
            raise ValueError
    except ValueError:
        problems.append(f"physical {word} '{name}': inflow speed '{speed}' must be a number > 0 (in units of V0)")
        options["speed"] = 1.0
    return options


def _curve_group(parsed: ParsedGroups, name: str, ents: list, problems: list, word: str = "curve") -> None:
    text = name.strip()
    m, mb = _CURVE_RE.match(text), _CELL_BOUNDARY_RE.match(text)
    if not m and not mb:
        problems.append(f"physical {word} '{name}': unknown name ({word}s are inlet[_K][:parabolic|uniform"
                        f"[:speed]], outlet, wall, held, symmetry, interface[_K], cell[_K]_boundary)"
                        f"{suggest_name(text)}")
        return
    for c in ents:
        if c in parsed.owner:
            problems.append(f"{word} {c} is in two physical groups: '{parsed.owner[c]}' and '{name}' (a {word} "
                            f"carries one condition)")
        parsed.owner[c] = name
    if mb:
        parsed.cell_boundaries.append((text, int(mb.group(1)) if mb.group(1) else 0, list(ents)))
        return
    kind, k, profile, speed = m.group(1), m.group(2), m.group(3), m.group(4)
    options = {}
    if kind == "inlet":
        options = _inlet_options(name, profile, speed, problems, word)
    elif profile is not None:
        problems.append(f"physical {word} '{name}': only inlets take options after ':'")
    parsed.curves[kind].append((text, int(k) if k else 0, list(ents), options))


def _numbering_problems(info: GeometryInfo, parsed: ParsedGroups, problems: list) -> None:
    """The fluid and the gel are present; cells and numbered groups are numbered 1, 2, ... once each."""
    region, facet = WORDS[info.dimension]
    for key in ("fluid", "gel"):
        if not parsed.surfaces[key]:
            have = sorted({n for d, n, _ in info.groups if d == info.dimension})
            problems.append(f"missing physical {region} '{key}' (the file has {region}s {have}){suggest_name(key)}")
    cells = parsed.cells
    names = [c[0] for c in cells]
    if "cell" in names and len(cells) > 1:
        problems.append(f"physical {region}s {names}: use either one 'cell' or numbered 'cell_1', 'cell_2', ...")
    if len(cells) > 1 and sorted(c[1] for c in cells) != list(range(1, len(cells) + 1)):
        problems.append(f"physical {region}s {names}: number the cells cell_1, cell_2, ... without gaps")
    for kind in ("inlet", "interface"):
        ks = [g[1] for g in parsed.curves[kind]]
        if len(ks) != len(set(ks)):
            problems.append(f"physical {facet}s {[g[0] for g in parsed.curves[kind]]}: two {kind}s with the same "
                            f"number")


def parse_groups(info: GeometryInfo, problems: list) -> ParsedGroups:
    """The groups of ``info`` by the convention; what does not follow it is appended to ``problems``."""
    parsed = ParsedGroups(surfaces={"fluid": [], "gel": []}, cells=[], curves={k: [] for k in CURVE_KINDS},
                          cell_boundaries=[], owner={})
    top = info.dimension
    region, facet = WORDS[top]
    for dim, name, ents in info.groups:
        if dim == top:
            _surface_group(parsed, name, ents, problems, region)
        elif dim == top - 1:
            _curve_group(parsed, name, ents, problems, facet)
        elif dim == 1 and (_CURVE_RE.match(name.strip()) or _SURFACE_RE.match(name.strip())):
            problems.append(f"physical curve '{name}': a device with volumes carries its conditions on "
                            f"surfaces and its regions are volumes (named points and other curves are ignored)")
        # named points (and, in 3D, curves of other names) are allowed and ignored
    _numbering_problems(info, parsed, problems)
    parsed.cells.sort(key=lambda c: c[1])
    for kind in parsed.curves:
        parsed.curves[kind].sort(key=lambda g: g[1])
    return parsed
