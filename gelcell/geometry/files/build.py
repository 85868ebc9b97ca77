"""Building a geometry file's device in gmsh: gelcell's tags on its groups, and its P2 mesh.

:func:`mesh_file` (rank 0, inside :func:`gelcell.geometry.meshes.build_meshes`)
re-tags the checked groups with gelcell's facet and cell tags and meshes a
``.geo`` file with the sizes it gives, times ``mesh.size_factor``, in a
child process (:mod:`~gelcell.geometry.files.child`);
:func:`export_builtin` writes a built-in device as a geometry file named by
the convention.
"""

from __future__ import annotations

import os

from femtools.gmshimport import gmsh_session
from gelcell.errors import ParameterError
from gelcell.geometry.builtin import builtin_cells
from gelcell.geometry.files.analyse import analyse
from gelcell.geometry.files.child import run_worker
from gelcell.geometry.files.read import msh_version
from gelcell.geometry.tags import Tag

__all__ = ["mesh_file", "convention_names", "export_builtin"]


def mesh_file(params) -> dict:
    """The arrays of :class:`femtools.mesh.ModelArrays` of the file's device, meshed in a child process.

    The file is checked (:func:`~gelcell.geometry.files.analyse.analyse`), re-tagged with gelcell's
    tags and meshed with curved P2 triangles or tetrahedra (a ``.geo`` file with its sizes times
    ``mesh.size_factor``) by :func:`gelcell.geometry.files.worker.mesh`.
    """
    path = os.path.abspath(params.geometry.file)
    fl = analyse(path)
    version = msh_version(path) if path.lower().endswith(".msh") else None
    request = {"op": "mesh", "path": path, "msh_version": version, "dimension": fl.dimension,
               "surface_tags": fl.surface_tags,
               "curve_tags": fl.curve_tags, "size_factor": params.mesh.size_factor}
    return run_worker(request, path, "meshing")


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
