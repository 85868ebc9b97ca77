"""Building a geometry file's device in gmsh: gelcell's tags on its groups, and its P2 mesh.

:func:`build_file_model` (rank 0, inside :func:`gelcell.geometry.meshes.build_meshes`)
re-tags the checked groups with gelcell's facet and cell tags and meshes a
``.geo`` file with the sizes it gives, times ``mesh.size_factor``;
:func:`export_builtin` writes a built-in device as a geometry file named by
the convention.
"""

from __future__ import annotations

import os

from femtools.gmshimport import gmsh_session, import_gmsh
from gelcell.errors import ParameterError
from gelcell.geometry.builtin import builtin_cells
from gelcell.geometry.files.analyse import analyse
from gelcell.geometry.files.read import ELEMENT_TYPES
from gelcell.geometry.tags import Tag

__all__ = ["build_file_model", "convention_names", "export_builtin"]


def build_file_model(params) -> None:
    """Load the file into the current gmsh session (rank 0), tag it with gelcell's tags, mesh it (P2)."""
    gmsh = import_gmsh()
    path = os.path.abspath(params.geometry.file)
    fl = analyse(path)
    gmsh.open(path)
    gmsh.option.setNumber("General.Terminal", 0)
    is_mesh = path.lower().endswith(".msh")
    gmsh.model.removePhysicalGroups()
    for tag, (surfaces, name) in fl.surface_tags.items():
        gmsh.model.addPhysicalGroup(2, surfaces, tag)
        gmsh.model.setPhysicalName(2, tag, name)
    for tag, curves in fl.curve_tags.items():
        gmsh.model.addPhysicalGroup(1, curves, tag)
    if is_mesh:       # (a size factor other than 1 is refused by CaseParameters.validate)
        if 9 not in _types(gmsh):
            gmsh.model.mesh.setOrder(2)
    else:
        gmsh.option.setNumber("Mesh.MeshSizeFactor",
                              gmsh.option.getNumber("Mesh.MeshSizeFactor") * params.mesh.size_factor)
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        gmsh.model.mesh.clear()
        gmsh.model.mesh.generate(2)
        bad = [t for t in _types(gmsh) if t not in ELEMENT_TYPES]
        if bad:
            raise ParameterError(f"geometry file {path!r}: its mesh options make element type(s) {bad} (gmsh "
                                 f"numbers, e.g. 3 = quadrangle); gelcell takes triangles only (no Recombine)")
        gmsh.model.mesh.setOrder(2)
    gmsh.model.mesh.renumberNodes()


def _types(gmsh) -> list[int]:
    return [int(t) for t in gmsh.model.mesh.getElementTypes()]


def convention_names(params) -> dict[int, str]:
    """Facet and cell tags of a built-in device -> the names of the geometry-file convention."""
    cells = builtin_cells(params)
    inlet = "inlet:parabolic:1" if params.case == "shear" else "inlet:uniform:1"
    names = {int(Tag.FLUID): "fluid", int(Tag.GEL): "gel", int(Tag.INLET): inlet, int(Tag.OUTLET): "outlet",
             int(Tag.WALL): "wall", int(Tag.BOWL): "held", int(Tag.POST): "held",
             int(Tag.SYMMETRY_BOTTOM): "symmetry", int(Tag.SYMMETRY_TOP): "symmetry",
             int(Tag.GAMMA1): "interface_1" if params.case == "normal" else "interface",
             int(Tag.GAMMA3): "interface_2"}
    for c in cells:
        names[c.region_tag] = c.name
        names[c.facet_tag] = f"{c.name}_boundary"
    return names


def export_builtin(params, path: str) -> None:
    """Write the meshed built-in device of ``params`` as a .msh file named by the convention (serial).

    Loading it with ``--geometry`` gives the same mesh, hence the built-in
    device's results; it is also a starting point for a device of one's own.
    """
    from gelcell.geometry.builtin_model import build_model       # imports gmsh
    if params.case == "file":
        raise ParameterError("export_builtin: the case is already a geometry file")
    names = convention_names(params)
    with gmsh_session() as gmsh:
        build_model(params)
        # one group per convention name (the symmetry lines and the held walls merge)
        groups: dict = {}
        for dim, tag in gmsh.model.getPhysicalGroups():
            ents = list(gmsh.model.getEntitiesForPhysicalGroup(dim, tag))
            groups.setdefault((dim, names[int(tag)]), []).extend(ents)
            gmsh.model.removePhysicalName(gmsh.model.getPhysicalName(dim, tag))
        gmsh.model.removePhysicalGroups()
        for k, ((dim, name), ents) in enumerate(sorted(groups.items()), start=1):
            gmsh.model.addPhysicalGroup(dim, sorted(set(ents)), k)
            gmsh.model.setPhysicalName(dim, k, name)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(path)
