"""The devices: tags, built-in layouts, geometry files, and their meshes with a disk cache.

What needs no mesh (tags, layouts, a geometry file's contents) is importable
without dolfinx or gmsh; the meshes are built by
:func:`gelcell.geometry.meshes.build_meshes`.
"""

from gelcell.geometry.describe import described, device_layout
from gelcell.geometry.layout import CellSpec, DeviceBoundaries, DeviceLayout
from gelcell.geometry.tags import INTERFACES, REGIONS, Tag, tag_name, tag_value

__all__ = ["Tag", "REGIONS", "INTERFACES", "tag_name", "tag_value", "CellSpec", "DeviceBoundaries", "DeviceLayout",
           "device_layout", "described"]
