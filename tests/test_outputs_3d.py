"""The outputs of a 3D device run (model.md section 10): Gamma1 profiles, figures as sections, XDMF.

One coarse 3D shear device with its cell (small strain, partitioned to the
coupling tolerance), checked against what the geometry and the boundary
conditions of section 10 make exact:

* profiles: the rows are Gamma1's nodes on the mid-height line (y = 0,
  z = H/2, in x order), where the symmetry conditions make v_f,z = u_s,z = 0;
  the slab's (walls = "symmetric", no cell) mid-height profile is the planar
  device's: as close to the converged 2D profile as the 2D one of the same
  mesh size;
* figures: the mid-height section covers the gel's planar area (the circular
  segment of the bowl less the cell's disc) up to the polygonal arc; the
  vertical section through the cell sees the bonded floor (v_f = 0) and the
  cell's half disc; every promised PNG is written;
* XDMF: a valid 3D file (10-node tetrahedra, XYZ geometry, three-component
  vectors), whose values at the floor's and the symmetry plane's nodes obey
  their conditions, and whose u_s at every node is the solution's.

Every check reduces over MPI (``./scripts/pytest-2-ranks tests/test_outputs_3d.py``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest
import scipy.spatial

from mpi4py import MPI

from gelcell.post.quantities import gamma_profiles
from device3d_cases import HEIGHT, MESH, partitioned

COMM = MPI.COMM_WORLD


def device_3d(case: str = "shear", walls: str = "noslip", mesh: float = MESH, height: float = HEIGHT,
              with_cell: bool = True, kinematics: str = "small"):
    """The 3D device of ``case`` solved by the partitioned scheme (shared, tests/device3d_cases.py), and its fields."""
    run = partitioned(case, walls, mesh, height, with_cell, kinematics)
    return run.solver, run.fields


@pytest.fixture(scope="module")
def shear():
    return device_3d("shear")[1]


def test_gamma1_profile_is_the_mid_height_line(shear):
    prof = gamma_profiles(shear, "Gamma1")
    assert set(prof) == {"X", "Y", "Z", "v_fx", "v_fy", "v_fz", "u_sx", "u_sy", "u_sz"}
    g = shear.params.geometry
    # Gamma1 of the shear device is the chord y = 0 over the chamber: x_mid -+ chamber_width/2
    assert np.abs(prof["Y"]).max() < 1e-12 and np.abs(prof["Z"] - 0.5 * HEIGHT).max() < 1e-12
    assert np.all(np.diff(prof["X"]) > 0)
    assert prof["X"][0] == pytest.approx(g.x_mid - 0.5 * g.chamber_width, abs=1e-12)
    assert prof["X"][-1] == pytest.approx(g.x_mid + 0.5 * g.chamber_width, abs=1e-12)
    # every Gamma1 node at z = H/2 is a row (the P2 nodes of the chord's edges: an odd number)
    assert len(prof["X"]) % 2 == 1 and len(prof["X"]) >= 9
    # the symmetry plane: zero normal velocity and displacement, exactly (Dirichlet conditions)
    assert np.abs(prof["v_fz"]).max() == 0.0 and np.abs(prof["u_sz"]).max() == 0.0
    # and the flow crosses Gamma1 and drags the network along x (the planar device's signs)
    assert prof["v_fx"].max() > 0 and prof["u_sx"].max() > 0


def _planar_profile(case: str, mesh: float) -> dict:
    return gamma_profiles(partitioned(case, mesh=mesh, height=None, with_cell=False).fields, "Gamma1")


def test_slab_profile_is_the_planar_one():
    """The slab of section 10 without a cell does not depend on z: its mid-height Gamma1 profile is the 2D one.

    Reference: the planar device at mesh size 1.5; the slab (size 6, tetrahedra) must be as close to it as the
    planar device of the same size 6 (triangles), within a factor 2 (the meshes differ: the tetrahedra are not
    the triangles extruded).  Measured ratios 1.03 (v_fx), 1.04 (v_fy), 1.49 (u_sx), 1.30 (u_sy).
    """
    slab = gamma_profiles(device_3d("shear", walls="symmetric", with_cell=False)[1], "Gamma1")
    fine, same_size = _planar_profile("shear", 1.5), _planar_profile("shear", MESH)
    assert np.abs(slab["v_fz"]).max() == 0.0 and np.abs(slab["u_sz"]).max() == 0.0
    def error(prof, key):
        return np.abs(np.interp(fine["X"], prof["X"], prof[key]) - fine[key]).max()
    for key in ("v_fx", "v_fy", "u_sx", "u_sy"):
        assert error(slab, key) <= 2 * error(same_size, key), (key, error(slab, key), error(same_size, key))


def test_profile_files_have_the_3d_columns(shear, shared_tmp_path):
    from gelcell.output.profiles import write_profiles
    prof = write_profiles(str(shared_tmp_path), shear, COMM)["Gamma1"]
    COMM.Barrier()
    with h5py.File(shared_tmp_path / "gamma1_profiles.h5", "r") as h5:
        assert set(h5) == set(prof) and "z = 0.2" in h5.attrs["section"]
        for key, values in prof.items():
            assert np.array_equal(h5[key][:], values), key
    with open(shared_tmp_path / "gamma1_profiles.csv") as f:
        header, first = f.readline().strip().split(","), f.readline().strip().split(",")
    assert header == list(prof) and float(first[header.index("X")]) == pytest.approx(prof["X"][0], rel=1e-11)


def _bowl_area(g) -> float:
    """The circular segment below the chord y = 0: R^2 (theta - sin theta cos theta)."""
    R, t = g.radius, g.half_angle
    return R**2 * (t - math.sin(t) * math.cos(t))


def _area(x, tri) -> float:
    a, b, c = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    return float(0.5 * np.abs(np.cross(b - a, c - a)).sum())


@pytest.fixture(scope="module")
def figures(shear, tmp_path_factory):
    """figure_data of the shear device and the PNGs drawn from it (rank 0; None elsewhere)."""
    from gelcell.output.figures import figure_data
    profiles = {"Gamma1": gamma_profiles(shear, "Gamma1")}
    summary = {"cells": [{"centroid_displacement": [0.0, 0.0, 0.0]}]}     # the arrows' origin only
    data = figure_data(shear, profiles, summary)
    if COMM.rank != 0:
        return None, None
    from gelcell.output.drawing import render_device_figures
    directory = tmp_path_factory.mktemp("figures")
    return data, (directory, render_device_figures(str(directory), data))


def test_figures_are_the_2d_set_and_two_vertical_sections(figures):
    data, drawn = figures
    if COMM.rank != 0:
        return
    directory, names = drawn
    assert names == ["gel_velocity.png", "gel_pressure.png", "gel_displacement_von_mises.png",
                     "gamma1_profiles.png", "cell_displacement.png", "cell_traction_parts.png",
                     "gel_velocity_vertical.png", "gel_displacement_von_mises_vertical.png"]
    from PIL import Image
    for name in names:
        image = np.asarray(Image.open(directory / name).convert("L"))
        assert image.shape[0] > 200 and image.shape[1] > 400, name
        assert image.std() > 10, name         # not blank


def test_mid_height_section_covers_the_gel(figures, shear):
    data, _ = figures
    if COMM.rank != 0:
        return
    g = shear.params.geometry
    x, tri, v = data["speed"]
    assert x.shape[1] == 2 and v.shape[1] == 3
    # the bowl's segment less the cell's disc; the section's straight edges cut the arcs by their sagitta
    # (h^2/8R, edges h <~ 0.15 on the coarse mesh: under 0.3 % of the area)
    expected = _bowl_area(g) - math.pi * (0.5 * g.cell_diameter) ** 2
    assert _area(x, tri) == pytest.approx(expected, rel=3e-3)
    assert _area(x, tri) < expected
    # the plane of symmetry: v_f,z = u_s,z = 0 at its vertices (to the round-off of the P2 -> P1 interpolation)
    u = data["disp"][2]
    assert np.abs(v[:, 2]).max() <= 1e-12 * np.abs(v).max() and np.abs(u[:, 2]).max() <= 1e-12 * np.abs(u).max()
    # the cell's section at mid-height is its equator: its vertices within the disc of its diameter
    xc, _, uc = data["cell"]
    r = np.linalg.norm(xc - np.asarray(data["cells"][0].centre), axis=1)
    assert r.max() == pytest.approx(0.5 * g.cell_diameter, rel=1e-6) and uc.shape[1] == 3


def test_vertical_section_through_the_cell(figures, shear):
    data, _ = figures
    if COMM.rank != 0:
        return
    vert = data["vertical"]
    g = shear.params.geometry
    assert vert["y"] == pytest.approx(g.cell_centre[1]) and vert["components"] == (0, 2)
    x, tri, v = vert["speed"]
    # the window lies in the gel but for the cell: its half disc (radius d/2 about (x_c, H/2)) is missing
    window = np.ptp(x[:, 0]) * np.ptp(x[:, 1])
    half_disc = 0.5 * math.pi * (0.5 * g.cell_diameter) ** 2
    assert np.ptp(x[:, 1]) == pytest.approx(0.5 * HEIGHT, rel=1e-6)
    spacing = np.ptp(x[:, 0]) / (len(np.unique(x[:, 0])) - 1)
    # up to the grid's squares the cell's half circle cuts: its length x 2 spacings
    missing = window - _area(x, tri)
    assert abs(missing - half_disc) <= 2 * spacing * math.pi * 0.5 * g.cell_diameter
    # the bonded floor: v_f = 0 there (the lowest row of the grid, 1e-9 above it)
    speed = np.linalg.norm(v, axis=1)
    floor = x[:, 1] < x[:, 1].min() + 1e-12
    assert speed[floor].max() < 1e-6 * speed.max()
    assert vert["cells"][0].centre == pytest.approx((g.cell_centre[0], 0.5 * HEIGHT))


def test_xdmf_of_the_3d_fields(shear, shared_tmp_path):
    from gelcell.output.fields import write_fields
    names = write_fields(str(shared_tmp_path), shear)
    assert names == ["fluid.xdmf", "gel.xdmf", "cell.xdmf"]
    COMM.Barrier()
    d = shear.params.displacement_scale
    u = shear.displacement
    V = u.function_space
    n_owned = V.dofmap.index_map.size_local
    owned_x = V.tabulate_dof_coordinates()[:n_owned]
    owned_u = d * u.x.array[:3 * n_owned].reshape(-1, 3)
    n_cells = COMM.allreduce(shear.gel_mesh.topology.index_map(3).size_local, op=MPI.SUM)
    root = ET.parse(shared_tmp_path / "gel.xdmf").getroot()
    topology = root.find(".//Topology")
    assert topology.get("TopologyType") == "Tetrahedron_10" and int(topology.get("NumberOfElements")) == n_cells
    assert root.find(".//Geometry").get("GeometryType") == "XYZ"
    attributes = {a.get("Name"): a for a in root.iter("Attribute")}
    for name, kind in (("v_f", "Vector"), ("u_s", "Vector"), ("p", "Scalar"), ("von_mises_network", "Scalar")):
        assert attributes[name].get("AttributeType") == kind
    with h5py.File(shared_tmp_path / "gel.h5", "r") as h5:
        x = h5["Mesh/mesh/geometry"][:]
        u_file, v_file = h5["Function/u_s/0"][:], h5["Function/v_f/0"][:]
    assert x.shape[1] == 3 and u_file.shape == (x.shape[0], 3) and v_file.shape == (x.shape[0], 3)
    # the file's u_s at each node is the solution's (every rank checks its own nodes)
    dist, index = scipy.spatial.cKDTree(x).query(owned_x)
    assert COMM.allreduce(float(dist.max(initial=0.0)), op=MPI.MAX) < 1e-12
    err = float(np.abs(u_file[index] - owned_u).max(initial=0.0))
    assert COMM.allreduce(err, op=MPI.MAX) <= 1e-14 * np.abs(u_file).max()
    # the conditions of section 10 in the file: the bonded floor (v_f = u_s = 0), the symmetry plane (z parts 0)
    floor, mid = np.abs(x[:, 2]) < 1e-12, np.abs(x[:, 2] - 0.5 * HEIGHT) < 1e-12
    assert floor.any() and mid.any()
    assert np.abs(u_file[floor]).max() == 0.0 and np.abs(v_file[floor]).max() == 0.0
    assert np.abs(u_file[mid, 2]).max() == 0.0 and np.abs(v_file[mid, 2]).max() == 0.0
    for name in ("fluid", "cell"):
        root = ET.parse(shared_tmp_path / f"{name}.xdmf").getroot()
        assert root.find(".//Topology").get("TopologyType").startswith("Tetrahedron")
        with h5py.File(shared_tmp_path / f"{name}.h5", "r") as h5:
            vector = h5["Function/V/0" if name == "fluid" else "Function/u_c/0"][:]
        assert vector.shape[1] == 3


def test_sections_reproduce_a_linear_field(shear):
    """Both sections give f = x + 2y + 3z exactly (a P2 field reproduces it on the curved mesh): the mid-height
    facets at their vertices, and the grid of the plane z = H/2 (the fallback for meshes without the
    symmetry plane) at its points, which cover the same area up to the grid's boundary band."""
    from dolfinx import fem
    from gelcell.output.figures import MidHeightSection, PlaneSection
    msh = shear.gel_mesh
    f = fem.Function(fem.FunctionSpace(msh, ("Lagrange", 2)))
    f.interpolate(lambda x: x[0] + 2 * x[1] + 3 * x[2])
    g = shear.params.geometry
    spacing = 0.01
    exact = MidHeightSection(msh, shear.gel_tags).gather(f)
    plane = PlaneSection(msh, 2, 0.5 * HEIGHT, None, spacing)
    grid = plane.gather(f)
    if COMM.rank != 0:
        return
    assert abs(plane.offset - 0.5 * HEIGHT) < 1e-8         # moved inside the mesh's bounding box
    for (x, _, values), z in ((exact, 0.5 * HEIGHT), (grid, plane.offset)):
        assert np.abs(values - (x[:, 0] + 2 * x[:, 1] + 3 * z)).max() < 1e-12
    area = _bowl_area(g) - math.pi * (0.5 * g.cell_diameter) ** 2
    perimeter = 2 * g.radius * g.half_angle + 2 * g.radius * math.sin(g.half_angle) + math.pi * g.cell_diameter
    assert abs(_area(grid[0], grid[1]) - area) <= 2 * spacing * perimeter
