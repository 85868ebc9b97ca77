"""Reading a geometry file's physical groups and topology with gmsh (no meshing).

:func:`read_geometry` checks a ``.geo`` file's statements
(:mod:`~gelcell.geometry.files.screen`: nothing that reaches the shell or the
file system) or a ``.msh`` file's format version (:func:`msh_version`) before
gmsh sees it, then
opens it with gmsh in a child process (:mod:`~gelcell.geometry.files.child`:
stoppable by a signal, bounded in time and memory) and returns what the
analysis needs as plain data (:class:`GeometryInfo`, the same on every rank),
cached per file version (path, modification time, size).
"""

from __future__ import annotations

import dataclasses
import os

from gelcell.case import FileGeometry
from gelcell.errors import ParameterError
from gelcell.geometry.files.child import run_worker
from gelcell.geometry.files.screen import check_geo_statements

__all__ = ["GeometryInfo", "ELEMENT_TYPES", "read_geometry", "reference_elements", "estimated_elements",
           "file_version", "msh_version"]

#: gmsh element types gelcell takes from a .msh file: points, 2- and 3-node lines, 3- and 6-node triangles,
#: 4- and 10-node tetrahedra (a file with volumes)
ELEMENT_TYPES = {15: "point", 1: "2-node line", 8: "3-node line", 2: "3-node triangle", 9: "6-node triangle",
                 4: "4-node tetrahedron", 11: "10-node tetrahedron"}


@dataclasses.dataclass
class GeometryInfo:
    """What the checks and the layout need from a geometry file (plain data, the same on every rank).

    In a file with volumes (``dimension`` 3) the surfaces take the curves' part and the volumes
    the surfaces': ``adjacent`` is surface -> [volumes], ``curve_points`` surface -> (N, 3)
    points on it, ``curve_ends`` surface -> [its boundary curves], ``surface_polygons`` volume ->
    [] (the volumes); ``solid`` holds what only the 3D checks need: ``edge_points`` (curve ->
    (N, 3) samples), ``edge_facets`` (curve -> [surfaces]), ``sizes`` ((dim, tag) -> (area or
    volume, centroid)), ``gaps`` (volume of a ``cell*`` group -> {surface: distance}).
    """

    path: str
    groups: list            #: (dim, name, [entities])
    adjacent: dict          #: curve -> [surfaces it bounds]
    curve_points: dict      #: curve -> (N, 2) sample points along it, in order
    curve_ends: dict        #: curve -> [boundary point tags]
    surface_polygons: dict  #: surface -> list of closed (N, 2) loops
    element_types: list     #: gmsh element types present (.msh)
    max_dim: int
    element_order: int
    scale: float
    dimension: int = 2      #: 3 for a file with volumes
    solid: dict | None = None


# --------------------------------------------------------------------------- reading
_CACHE: dict = {}
_ESTIMATES: dict = {}


def file_version(path: str):
    st = os.stat(path)
    return (os.path.abspath(path), st.st_mtime_ns, st.st_size)


def msh_version(path: str) -> str:
    """The MSH format version of a ``.msh`` file, from its first lines; ParameterError if it is no MSH file
    or an MSH 1.0 one (which has no physical names, and so cannot follow the naming convention)."""
    with open(path, "rb") as f:
        lines = f.read(4096).splitlines()
    first = lines[0].strip() if lines else b""
    if first in (b"$NOD", b"$NOE"):
        raise ParameterError(f"geometry file {path!r} is in the MSH 1.0 format, which has no physical names, so "
                             f"its groups cannot be named by the convention (docs/geometry-files.md): write it "
                             f"as MSH 4.1 or 2.2 (e.g. gmsh FILE.geo -2 -format msh41)")
    if first != b"$MeshFormat" or len(lines) < 2 or not lines[1].split():
        raise ParameterError(f"geometry file {path!r} is not a MSH file (it does not begin with $MeshFormat)")
    version = lines[1].split()[0].decode("ascii", "replace")
    try:
        number = float(version)
    except ValueError:
        number = 0.0
    if not 2 <= number < 5:
        raise ParameterError(f"geometry file {path!r}: MSH format version {version!r} is not supported "
                             f"(gelcell reads MSH 2.x and 4.x)")
    return version


def _read_with_gmsh(path: str) -> GeometryInfo:
    """Check what must be checked before gmsh sees the file, then read it in a bounded child process."""
    version = None
    if path.lower().endswith(".geo"):
        check_geo_statements(path)
    else:
        version = msh_version(path)
    fields = run_worker({"op": "read", "path": path, "msh_version": version}, path, "reading")
    return GeometryInfo(path=path, **fields)


def reference_elements(path: str) -> float | None:
    """The triangles (tetrahedra: a file with volumes) of the file at ``--mesh-size 1`` (a ``.geo``
    file's predicted from coarse probe meshes: :func:`gelcell.geometry.files.worker.reference_elements`),
    cached per file version; None if gmsh crashed making the probes (the mesh itself is still bounded
    in its child process)."""
    read_geometry(path)
    key = file_version(path)
    if key not in _ESTIMATES:
        try:
            _ESTIMATES[key] = run_worker({"op": "estimate", "path": os.path.abspath(path),
                                           "msh_version": msh_version(path) if path.lower().endswith(".msh")
                                           else None}, path, "estimating")
        except ParameterError:
            _ESTIMATES[key] = None
    return _ESTIMATES[key]


def estimated_elements(path: str, size_factor: float) -> float | None:
    """The cells of the file's mesh at ``--mesh-size size_factor``: :func:`reference_elements` over the
    size factor squared (triangles) or cubed (tetrahedra); None where that is."""
    reference = reference_elements(path)
    return None if reference is None else reference / size_factor ** read_geometry(path).dimension


def read_geometry(path: str) -> GeometryInfo:
    """Physical groups and topology of a geometry file (cached per file version)."""
    FileGeometry(file=path)          # raises ParameterError for a bad path
    key = file_version(path)
    if key not in _CACHE:
        _CACHE[key] = _read_with_gmsh(os.path.abspath(path))
    return _CACHE[key]
