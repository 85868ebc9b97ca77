"""The checks of a geometry file that hold in 2D and 3D alike, and the result of the analysis.

:class:`Analysis` runs the steps of :func:`gelcell.geometry.files.analyse.analyse` on a file's
regions (surfaces, or volumes in 3D) and their boundaries (curves, or surfaces): every entity in
its group, the conditions on the right side, the interfaces shared, the pressure fixed, the
network anchored; its planar forms of the inlets and the symmetry lines are replaced for volumes
by :mod:`~gelcell.geometry.files.analyse3d`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gelcell.errors import ParameterError
from gelcell.geometry.files.names import WORDS, ParsedGroups
from gelcell.geometry.files.read import GeometryInfo
from gelcell.geometry.files.shapes import connected_surfaces, is_inside, is_straight, symmetry_axis, where
from gelcell.geometry.layout import DeviceLayout, SegmentInflow
from gelcell.geometry.tags import Tag, fluid_interface_name, fluid_interface_tag, gamma2_tag, inlet_tag

__all__ = ["FileLayout", "Analysis", "check_mesh_kind", "boundary_tags"]


@dataclasses.dataclass
class FileLayout:
    """The checked content of a geometry file in gelcell's terms."""

    curve_tags: dict        #: gelcell facet tag -> [curves]
    surface_tags: dict      #: gelcell cell tag -> ([surfaces], name)
    layout: DeviceLayout    #: conditions, cells, interfaces
    gel_depth: float        #: gel area / fluid-gel interface length
    enclosed_fluid: bool    #: some fluid region has no outlet (fixed only through an interface)
    dimension: int = 2      #: 3: a device of volumes (surface_tags then holds volumes, curve_tags surfaces)


def check_mesh_kind(info: GeometryInfo, source: str) -> None:
    """A planar file of triangles or a file with volumes of tetrahedra, of order 1 or 2."""
    allowed = {2: (1, 8, 2, 9, 15), 3: (1, 8, 2, 9, 4, 11, 15)}[info.dimension]
    bad = [t for t in info.element_types if t not in allowed]
    if bad:
        raise ParameterError(f"{source}: unsupported element type(s) {bad} (gmsh numbers); gelcell takes "
                             f"triangles of order 1 or 2 (types 2, 9) with lines of order 1 or 2 (1, 8), and "
                             f"in a file with volumes tetrahedra of order 1 or 2 (4, 11)")
    if info.element_order not in (1, 2):
        raise ParameterError(f"{source}: Mesh.ElementOrder = {info.element_order}: gelcell meshes with "
                             f"order 2 (curved P2 triangles); orders 1 and 2 are accepted, not "
                             f"{info.element_order}")


class Analysis:
    """The steps of :func:`analyse` on one file; each appends what it finds wrong to ``problems``."""

    def __init__(self, info: GeometryInfo, parsed: ParsedGroups, source: str):
        self.info, self.parsed, self.source = info, parsed, source
        self.problems: list[str] = []
        self.fluid, self.gel = set(parsed.surfaces["fluid"]), set(parsed.surfaces["gel"])
        self.cell_of = {s: k for k, (_, _, ents) in enumerate(parsed.cells, start=1) for s in ents}
        self.region = {**{s: "fluid" for s in self.fluid}, **{s: "gel" for s in self.gel}}
        self.cell_names = {k: name for k, (name, _, _) in enumerate(parsed.cells, start=1)}
        self.kind_of = {c: (kind, name) for kind, groups in parsed.curves.items()
                        for name, _, ents, _ in groups for c in ents}
        self.gamma2: dict = {}       # cell -> its curves in the gel
        self.cut: dict = {}          # cell -> its curves on symmetry lines
        #: the words of the regions and of their boundaries: surface and curve (2D), volume and surface (3D)
        self.region_word, self.facet_word = WORDS[info.dimension]

    def stop_if_wrong(self) -> None:
        if self.problems:
            raise ParameterError(f"{self.source}:\n" + "\n".join(self.problems))

    def curves_of(self, kind: str) -> set:
        return {c for _, _, ents, _ in self.parsed.curves[kind] for c in ents}

    # -- every surface and curve has its group -------------------------------------------------------
    def unnamed_surfaces(self) -> None:
        unnamed = sorted(s for s in self.info.surface_polygons if s not in self.region and s not in self.cell_of)
        if unnamed:
            self.problems.append(f"{self.region_word}(s) {unnamed} are in no physical group: name each 'fluid', "
                                 f"'gel' or a cell")

    def classify_curves(self) -> None:
        """Every curve by the surfaces it bounds: a cell's, an interface, or a region's boundary."""
        for c, up in sorted(self.info.adjacent.items()):
            up = [s for s in up if s in self.region or s in self.cell_of]
            if not up:
                continue
            kind, gname = self.kind_of.get(c, (None, self.parsed.owner.get(c)))
            label = f"{self.facet_word} {c} {where(self.info.curve_points[c])}"
            cells_here = sorted({self.cell_of[s] for s in up if s in self.cell_of})
            if cells_here:
                self._cell_curve(c, up, cells_here, kind, gname, label)
            else:
                self._region_curve(up, kind, gname, label)
        for c, name in self.parsed.owner.items():
            if not [s for s in self.info.adjacent.get(c, []) if s in self.region or s in self.cell_of]:
                self.problems.append(f"{self.facet_word} {c} of group '{name}' bounds no fluid, gel or cell "
                                     f"{self.region_word}")

    def _cell_curve(self, c: int, up: list, cells_here: list, kind, gname, label: str) -> None:
        sides = {self.region.get(s, "cell") for s in up}
        if len(cells_here) > 1:
            self.problems.append(f"cell '{self.cell_names[cells_here[0]]}' touches cell "
                                 f"'{self.cell_names[cells_here[1]]}' along {label}: cells must be separated by gel")
            return
        k = cells_here[0]
        name = self.cell_names[k]
        if "fluid" in sides:
            self.problems.append(f"cell '{name}' touches the fluid along {label}: a cell must lie inside the gel")
        elif "gel" in sides:
            if kind is not None:
                self.problems.append(f"cell '{name}' touches the gel boundary '{gname}' along {label}: a cell "
                                     f"must lie inside the gel")
            self.gamma2.setdefault(k, []).append(c)
        elif kind == "symmetry":
            self.cut.setdefault(k, []).append(c)
        else:
            self.problems.append(f"cell '{name}': its boundary {label} is not in the gel"
                                 + (f" (it is in '{gname}')" if gname else "")
                                 + f": only a symmetry {'plane' if self.info.dimension == 3 else 'line'} may "
                                   f"cut a cell")

    def _region_curve(self, up: list, kind, gname, label: str) -> None:
        sides = {self.region[s] for s in up}
        if sides == {"fluid", "gel"}:
            if kind != "interface":
                self.problems.append(f"{label} lies between the fluid and the gel but is "
                                     + (f"in '{gname}'" if gname else "in no physical group")
                                     + ": name it 'interface' (or 'interface_K')")
            return
        side = sides.pop()
        if len(up) > 1:          # between two surfaces of one region: interior
            if kind is not None:
                self.problems.append(f"{label} of group '{gname}' lies inside the {side}, not on its boundary")
        elif kind == "interface":
            self.problems.append(f"interface '{gname}': {label} bounds only the {side}: the fluid and gel sides "
                                 f"do not share nodes (draw one {self.facet_word} shared by both "
                                 f"{self.region_word}s, e.g. with BooleanFragments or Coherence)")
        elif kind is None:
            allowed = "inlet, outlet, wall or symmetry" if side == "fluid" else "held or symmetry"
            self.problems.append(f"{label} bounds the {side} but is in no physical group: name it one of "
                                 f"{allowed}" + (f" (it is in '{gname}')" if gname else ""))
        elif side == "fluid" and kind == "held":
            self.problems.append(f"'{gname}': {label} bounds the fluid; 'held' is for gel boundaries (use 'wall')")
        elif side == "gel" and kind in ("inlet", "outlet", "wall"):
            self.problems.append(f"'{gname}': {label} bounds the gel; '{kind}' is for fluid boundaries "
                                 f"(use 'held')")

    # -- the problem is well posed -------------------------------------------------------------------
    def pressure_fixed(self) -> bool:
        """Every fluid region has an outlet or an interface; returns whether some fluid is enclosed."""
        outlets, ifaces = self.curves_of("outlet"), self.curves_of("interface")
        if not outlets:
            self.problems.append(f"no physical {self.facet_word} 'outlet': the pressure is undetermined (give at "
                                 f"least one outlet, where the traction is zero)")
        enclosed = False
        for comp in connected_surfaces(sorted(self.fluid), self.info):
            touching = {c for c, up in self.info.adjacent.items() if set(up) & comp}
            if not touching & outlets:
                enclosed = True
                if not touching & ifaces:
                    self.problems.append(f"the fluid region of {self.region_word}(s) {sorted(comp)} has no outlet "
                                         f"and no fluid-gel interface: it is enclosed and nothing fixes its pressure")
        return enclosed

    def network_anchored(self) -> None:
        """An inlet and an interface exist; every part of the gel is held, or on symmetry lines both ways."""
        facet = self.facet_word
        if not self.parsed.curves["inlet"]:
            self.problems.append(f"no physical {facet} 'inlet': nothing drives the flow")
        if not self.parsed.curves["held"]:
            self.problems.append(f"no physical {facet} 'held': the gel's network is anchored nowhere (name the gel "
                                 f"boundaries where v_f = 0 and u_s = 0 'held')")
        else:
            held = self.curves_of("held")
            directions = {c: self.symmetry_normal(c) for c in self.curves_of("symmetry")}
            for comp in connected_surfaces(sorted(self.gel), self.info):
                touching = {c for c, up in self.info.adjacent.items() if set(up) & comp}
                normals = {directions[c] for c in touching if c in directions}
                if not touching & held and not set(range(self.info.dimension)) <= normals:
                    self.problems.append(f"the gel region of {self.region_word}(s) {sorted(comp)} touches no "
                                         f"'held' {facet}: its network is anchored nowhere (rigid-body motion)")
        if not self.parsed.curves["interface"]:
            self.problems.append(f"no physical {facet} 'interface': the fluid and the gel must share at least one "
                                 f"interface")

    def symmetry_normal(self, c: int):
        """The axis normal to an axis-aligned straight symmetry curve (0: x = const, 1: y = const), else None."""
        p, scale = self.info.curve_points[c], self.info.scale
        return 1 if abs(p[0, 1] - p[-1, 1]) <= 1e-9 * scale else 0

    def cell_boundary_groups(self) -> None:
        """A ``cell[_K]_boundary`` group given by the user must be that cell's boundary."""
        for name, k, ents in self.parsed.cell_boundaries:
            k = k or 1
            if k > len(self.parsed.cells):
                self.problems.append(f"physical {self.facet_word} '{name}': there is no cell {k}")
                continue
            expected = set(self.gamma2.get(k, []))        # a flat edge on a symmetry line is 'symmetry'
            if set(ents) != expected:
                self.problems.append(f"physical {self.facet_word} '{name}' = {self.facet_word}s {sorted(ents)} is "
                                     f"not the boundary of '{self.cell_names[k]}' ({self.facet_word}s "
                                     f"{sorted(expected)})")

    # -- conditions ------------------------------------------------------------------------------------
    def inlets(self) -> list:
        """``(tag, SegmentInflow, group name, options)`` of every inlet: straight, with its inward normal."""
        info, inflow = self.info, []
        for j, (name, _, ents, opts) in enumerate(self.parsed.curves["inlet"], start=1):
            if len(ents) != 1 or not is_straight(info.curve_points[ents[0]], info.scale):
                self.problems.append(f"inlet '{name}': an inlet must be one straight curve (it has {len(ents)} "
                                     f"curve(s){'' if len(ents) != 1 else ', not straight'})")
                continue
            pts = info.curve_points[ents[0]]
            a, b = pts[0], pts[-1]
            t = (b - a) / np.linalg.norm(b - a)
            n = np.array([-t[1], t[0]])
            loops = [lp for s in info.adjacent[ents[0]] if s in self.fluid for lp in info.surface_polygons[s]]
            if not is_inside(0.5 * (a + b) + 1e-4 * np.linalg.norm(b - a) * n, loops):
                n = -n
            inflow.append((inlet_tag(j), SegmentInflow(a, b, n, opts["speed"], opts["profile"]), name, opts))
        return inflow

    def symmetry_tags(self) -> dict:
        """Facet tag -> curves of the fluid's and the gel's symmetry lines (by region and direction)."""
        tags: dict = {}
        for name, _, ents, _ in self.parsed.curves["symmetry"]:
            for c in ents:
                side = [self.region[s] for s in self.info.adjacent[c] if s in self.region]
                if not side:
                    continue          # a cell's flat edge, handled with the cells
                horizontal, problem = symmetry_axis(c, self.info.curve_points[c], self.info.scale, name)
                if problem:
                    self.problems.append(problem)
                    continue
                tag = {("fluid", True): Tag.SYMMETRY_BOTTOM, ("fluid", False): Tag.FLUID_SYMMETRY_X,
                       ("gel", True): Tag.GEL_SYMMETRY_Y, ("gel", False): Tag.GEL_SYMMETRY_X}[(side[0], horizontal)]
                tags.setdefault(int(tag), []).append(c)
        return tags

    def cell_symmetry_tags(self, curve_tags: dict) -> dict:
        """The cells' flat edges into ``curve_tags``; returns facet tag -> the component fixed there."""
        fixed = {}
        for curves in self.cut.values():
            for c in curves:
                p = self.info.curve_points[c]
                horizontal = abs(p[0, 1] - p[-1, 1]) <= 1e-9 * self.info.scale
                tag = int(Tag.SYMMETRY_TOP) if horizontal else int(Tag.CELL_SYMMETRY_X)
                curve_tags.setdefault(tag, []).append(c)
                fixed[tag] = 1 if horizontal else 0
        return fixed


def boundary_tags(a: Analysis, inflow: list, sym_tags: dict) -> tuple[dict, dict]:
    """gelcell's facet tag -> curves, and the fluid interfaces' coupling names -> tags."""
    parsed, curve_tags = a.parsed, {}
    for tag, _, name, _ in inflow:
        curve_tags[tag] = [c for g in parsed.curves["inlet"] if g[0] == name for c in g[2]]
    for kind, tag in (("outlet", Tag.OUTLET), ("wall", Tag.WALL), ("held", Tag.BOWL)):
        ents = [c for g in parsed.curves[kind] for c in g[2]]
        if ents:
            curve_tags[int(tag)] = ents
    curve_tags.update(sym_tags)
    fluid_interfaces = {}
    for j, (_, _, ents, _) in enumerate(parsed.curves["interface"], start=1):
        curve_tags[fluid_interface_tag(j)] = list(ents)
        fluid_interfaces[fluid_interface_name(j)] = fluid_interface_tag(j)
    for k, curves in a.gamma2.items():
        curve_tags[gamma2_tag(k)] = list(curves)
    return curve_tags, fluid_interfaces
