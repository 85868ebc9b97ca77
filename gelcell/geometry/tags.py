"""The tags of regions and boundaries that every part of gelcell uses, and their names.

A device with one cell, one inlet and one or two fluid-gel interfaces uses
:class:`Tag`; further cells, inlets and interfaces are numbered by
:func:`cell_region_tag`, :func:`gamma2_tag`, :func:`inlet_tag` and
:func:`fluid_interface_tag`, so that the first of each keeps its
:class:`Tag` value.
"""

from __future__ import annotations

import enum

__all__ = ["Tag", "REGIONS", "INTERFACES", "REGION_TAGS", "FACET_TAGS", "cell_region_tag", "gamma2_tag",
           "gamma2_name", "fluid_interface_name", "fluid_interface_tag", "inlet_tag", "tag_name", "tag_value"]


class Tag(enum.IntEnum):
    """Cell tags (regions) and facet tags (boundaries, interfaces) used by every module."""

    FLUID = 1
    GEL = 2
    CELL = 3
    INLET = 11
    OUTLET = 12
    WALL = 13             #: channel no-slip walls (shear geometry)
    SYMMETRY_BOTTOM = 14  #: y = 0 (normal geometry)
    SYMMETRY_TOP = 15     #: y = height (normal geometry), incl. the cell's flat edge
    GAMMA1 = 21           #: fluid–gel interface (upstream one in the normal geometry)
    GAMMA2 = 22           #: gel–cell interface
    GAMMA3 = 23           #: downstream fluid–gel interface (normal geometry)
    BOWL = 31             #: wall of the shear chamber
    POST = 32             #: posts (holes in the gel, normal geometry)
    FLUID_SYMMETRY_X = 16  #: geometry files: symmetry line x = const of the fluid (V_x = 0)
    GEL_SYMMETRY_Y = 17    #: geometry files: symmetry line y = const of the gel
    GEL_SYMMETRY_X = 18    #: geometry files: symmetry line x = const of the gel
    CELL_SYMMETRY_X = 19   #: geometry files: symmetry line x = const of a cell
    FLOOR = 41             #: 3D devices: the floor z = 0 (a wall, or a symmetry plane in the slab)
    SYMMETRY_MID = 42      #: 3D devices: the mid-height symmetry plane z = H/2, incl. the cells' flat faces
    FLUID_SYMMETRY_Z = 43  #: 3D geometry files: symmetry plane z = const of the fluid (V_z = 0)
    GEL_SYMMETRY_Z = 44    #: 3D geometry files: symmetry plane z = const of the gel
    CELL_SYMMETRY_Z = 45   #: 3D geometry files: symmetry plane z = const of a cell


#: region name -> cell tag
REGIONS = {"fluid": Tag.FLUID, "gel": Tag.GEL, "cell": Tag.CELL}


#: interface name -> (facet tag, (region, region))
INTERFACES = {"Gamma1": (Tag.GAMMA1, ("fluid", "gel")),
              "Gamma2": (Tag.GAMMA2, ("gel", "cell")),
              "Gamma3": (Tag.GAMMA3, ("fluid", "gel"))}


REGION_TAGS = (Tag.FLUID, Tag.GEL, Tag.CELL)


FACET_TAGS = tuple(t for t in Tag if t not in REGION_TAGS)


# --------------------------------------------------------------------------- numbering of several cells,
# interfaces and inlets: the first one keeps the tag of the single-cell devices (Tag.CELL, Tag.GAMMA2,
# Tag.GAMMA1, Tag.INLET), so a device with one of each is numbered exactly as before
def cell_region_tag(k: int) -> int:
    """Cell (surface) tag of cell ``k`` (1-based)."""
    return int(Tag.CELL) if k == 1 else 300 + k


def gamma2_tag(k: int) -> int:
    """Facet tag of the gel-cell interface of cell ``k`` (1-based)."""
    return int(Tag.GAMMA2) if k == 1 else 2200 + k


def gamma2_name(k: int, n: int) -> str:
    """Coupling name of cell ``k``'s interface among ``n`` cells: ``Gamma2`` alone, else ``Gamma2_k``."""
    return "Gamma2" if n == 1 else f"Gamma2_{k}"


def fluid_interface_name(k: int) -> str:
    """Coupling name of the ``k``-th fluid-gel interface: Gamma1, Gamma3, Gamma4, ..."""
    return "Gamma1" if k == 1 else f"Gamma{k + 1}"


def fluid_interface_tag(k: int) -> int:
    """Facet tag of the ``k``-th fluid-gel interface: 21, 23, then 2000 + k."""
    return {1: int(Tag.GAMMA1), 2: int(Tag.GAMMA3)}.get(k, 2000 + k)


def inlet_tag(k: int) -> int:
    """Facet tag of inlet ``k``: 11, then 1100 + k."""
    return int(Tag.INLET) if k == 1 else 1100 + k


def tag_name(value: int) -> str:
    """A printable name of a cell or facet tag value (the enum's, or a numbered one)."""
    value = int(value)
    try:
        return Tag(value).name
    except ValueError:
        pass
    for lo, name in ((2200, "GAMMA2_{}"), (2000, "GAMMA{}"), (1100, "INLET_{}"), (300, "CELL_{}")):
        if lo < value < lo + 100:
            k = value - lo
            return name.format(k + 1 if name == "GAMMA{}" else k)
    return str(value)


def tag_value(name: str) -> int:
    """The tag value of a :func:`tag_name` (inverse)."""
    if name in Tag.__members__:
        return int(Tag[name])
    for prefix, make in (("GAMMA2_", gamma2_tag), ("INLET_", inlet_tag), ("CELL_", cell_region_tag),
                         ("GAMMA", lambda k: fluid_interface_tag(k - 1))):
        if name.startswith(prefix) and name[len(prefix):].isdigit():
            return make(int(name[len(prefix):]))
    return int(name)
