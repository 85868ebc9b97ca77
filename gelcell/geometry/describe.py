"""What a case's device is, without meshing it: its layout, and what its geometry file holds."""

from __future__ import annotations

import dataclasses

from gelcell.case import CaseParameters, FileContents
from gelcell.geometry.builtin import builtin_layout
from gelcell.geometry.files.analyse import analyse
from gelcell.geometry.layout import DeviceLayout

__all__ = ["device_layout", "described"]


def device_layout(params: CaseParameters) -> DeviceLayout:
    """The layout of any case (built-in or geometry file), without meshing it."""
    if params.case == "file":
        return analyse(params.geometry.file).layout
    return builtin_layout(params)


def described(params: CaseParameters) -> CaseParameters:
    """The case with what its geometry file holds (its cells, the gel's depth); other cases as they are.

    The file is read and checked once per file version (no meshing); a
    naming or topology problem raises :class:`~gelcell.errors.ParameterError`
    naming the group or entity.  ``with_cell`` becomes whether the file has cells.
    """
    if params.case != "file" or params.geometry.contents is not None:
        return params
    found = analyse(params.geometry.file)
    contents = FileContents(cells=tuple((c.centre[0], c.centre[1], c.diameter) for c in found.layout.cells),
                            gel_depth=found.gel_depth, enclosed_fluid=found.enclosed_fluid,
                            dimension=found.dimension)
    return params.replace(geometry=dataclasses.replace(params.geometry, contents=contents))
