"""Geometry files with volumes (3D devices, docs/geometry-files.md): the convention one dimension up.

References: the planar shear device with its circular cell, which the slab
file ``examples/devices/shear_slab_cylinder.geo`` (that device extruded over a
small height, floor and top symmetry planes, the cell a cylinder through the
height) equals to discretisation error (model.md section 10: its solution does
not depend on z), so slab - plane must shrink under refinement; and the
refusals of bad files, each naming the group before anything is meshed.
Small kinematics (the 3D finite-strain forms are checked per field).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from mpi4py import MPI

from femtools.functions import values_at_points
from gelcell.case import CaseParameters
from gelcell.case.devices import FileGeometry
from gelcell.geometry.describe import described
from gelcell.run.solve import solve_partitioned

COMM = MPI.COMM_WORLD
HERE = os.path.dirname(os.path.abspath(__file__))
SLAB = os.path.join(HERE, "..", "examples", "devices", "shear_slab_cylinder.geo")
#: the planar device as a file of the same sizes as the slab's floor
PLANE = os.path.join(HERE, "..", "examples", "devices", "shear.geo")
#: the slab's height in the file (its solution does not depend on it)
HEIGHT = 0.05
FIELDS = ("fluid_velocity", "interstitial_velocity", "displacement", "pore_pressure", "cell_displacement")


def file_case(path: str, mesh_size: float = 1.0) -> CaseParameters:
    p = CaseParameters.default("shear").replace(case="file", geometry=FileGeometry(file=path))
    return p.with_mesh_size(mesh_size).with_kinematics("small")


# --------------------------------------------------------------------------- slab = planar device
def _owned_nodes(f) -> tuple[np.ndarray, np.ndarray]:
    """Every rank's owned dof coordinates and values of ``f``, gathered on all ranks (coarse meshes only)."""
    V = f.function_space
    n, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
    x, values = V.tabulate_dof_coordinates()[:n], f.x.array[: n * bs].reshape(n, bs)
    return np.vstack(COMM.allgather(x)), np.vstack(COMM.allgather(values))


def _difference(slab, plane) -> dict[str, tuple[float, float]]:
    """Per field: the RMS over the planar device's nodes of |slab - plane| / RMS |plane|, the slab
    evaluated at mid-depth, and the same for the slab's z component."""
    out = {}
    for name in FIELDS:
        x, planar_values = _owned_nodes(getattr(plane, name))
        x[:, 2] = 0.5 * HEIGHT
        values = values_at_points(getattr(slab, name), x)
        # planar nodes on a curved boundary may lie outside the slab's tetrahedra (a coarse cell's many)
        inside = ~np.isnan(values[:, 0])
        assert inside.mean() > 0.5, (name, inside.mean())
        k = planar_values.shape[1]
        scale = np.sqrt(np.mean(np.sum(planar_values[inside] ** 2, axis=1)))
        in_plane = np.sqrt(np.mean(np.sum((values[inside, :k] - planar_values[inside]) ** 2, axis=1))) / scale
        normal = np.sqrt(np.mean(values[inside, k:] ** 2)) / scale if values.shape[1] > k else 0.0
        out[name] = (float(in_plane), float(normal))
    return out


def slab_minus_plane(mesh_size: float) -> dict[str, dict[str, tuple[float, float]]]:
    """:func:`_difference` of the slab file and the planar shear device with its cell, as the file
    ``examples/devices/shear.geo`` (``"file"``: the slab's floor mesh) and built in (``"builtin"``)."""
    slab = solve_partitioned(file_case(SLAB, mesh_size), verbose=False, checks=False).fields
    planar = {"file": file_case(PLANE, mesh_size),
              "builtin": CaseParameters.default("shear", with_cell=True).with_mesh_size(mesh_size)
              .with_kinematics("small")}
    return {key: _difference(slab, solve_partitioned(p, verbose=False, checks=False).fields)
            for key, p in planar.items()}


def test_slab_file_with_a_cylindrical_cell_equals_the_planar_device():
    """The slab file against the planar shear device with its circular cell, at size factors 6 and 4:
    slab - plane is the difference of two discretisations of one solution, so it shrinks in every
    field (the cell's displacement too), and the slab's z components are no larger than it.

    Asserted against the device as the file shear.geo, whose mesh is the floor of the slab's (so the
    difference is the 3D discretisation's alone).  Against the built-in device (printed) the planar
    meshes differ as well, and slab - plane is then that of the two planar meshes (built-in - file
    in 2D), which does not shrink monotonically from 6 to 4 in the fluid (it does from 4 to 2)."""
    coarse, fine = slab_minus_plane(6.0), slab_minus_plane(4.0)
    for key in coarse:
        for name in FIELDS:
            (c, cz), (f, fz) = coarse[key][name], fine[key][name]
            print(f"{key} {name}: slab - plane {c:.2e} -> {f:.2e}, z component {cz:.1e} -> {fz:.1e}")
    for name in FIELDS:
        (c, cz), (f, fz) = coarse["file"][name], fine["file"][name]
        assert f < c, name
        assert fz <= 2 * max(f, cz), name


# --------------------------------------------------------------------------- refused before meshing
SLAB_TEXT = open(SLAB).read()
#: a second cell: a cylinder drawn inside the gel but not fragmented with it (it shares no surface)
LOOSE_CELL = """
Cylinder(100) = {2.4, -0.3, 0, 0, 0, h, d/2};
Physical Volume("cell_2") = {100};
"""

# (id, [(old, new), ...], words the message must contain)
CASES = [
    ("outlet unnamed", [('Physical Surface("outlet") = outlet();', "")],
     ["surface 10 near (4, 0.1, 0.025) bounds the fluid but is in no physical group"]),
    ("no outlet", [('Physical Surface("outlet") = outlet();', ""),
                   ('Physical Surface("wall") = walls();', 'Physical Surface("wall") = {walls(), outlet()};')],
     ["no physical surface 'outlet'", "the pressure is undetermined"]),
    ("misspelled surface", [('Physical Surface("outlet")', 'Physical Surface("outlett")')],
     ["'outlett'", "did you mean 'outlet'"]),
    ("missing volume", [('Physical Volume("gel") = gel();', "")], ["missing physical volume 'gel'"]),
    ("a 2D name on a surface", [('Physical Surface("held")', 'Physical Surface("gel")')],
     ["physical surface 'gel': unknown name"]),
    ("a cell with no interface", [('Physical Volume("cell")', 'Physical Volume("cell_1")'), ("//END", LOOSE_CELL)],
     ["cell 'cell_2'", "is not in the gel"]),
    ("a symmetry plane at an angle",
     [('Physical Surface("held") = bowl();', 'Physical Surface("symmetry_2") = bowl();')],
     ["is not planar", "symmetry planes x, y or z = const only"]),
    ("an unknown inflow profile", [('"inlet:parabolic:1"', '"inlet:poiseuille:1"')],
     ["physical surface 'inlet:poiseuille:1'", "must be 'parabolic' or 'uniform'"]),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_3d_file_is_refused_before_meshing(case, cli_stderr, shared_tmp_path, monkeypatch):
    """Each case breaks the slab file one way: exit 2, the message names the group or volume, nothing
    written, and gmsh never asked to mesh (nor to make the probe meshes of the estimate)."""
    from gelcell.cli import main
    from gelcell.geometry.files import build, read

    def no_meshing(*args, **kwargs):
        raise AssertionError("the file was meshed")
    monkeypatch.setattr(build, "run_worker", no_meshing)
    monkeypatch.setattr(read, "reference_elements", no_meshing)
    _, edits, words = case
    text = SLAB_TEXT + "\n//END\n"
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    path = str(shared_tmp_path / "device.geo")
    if COMM.rank == 0:
        with open(path, "w") as f:
            f.write(text)
    COMM.Barrier()
    out = shared_tmp_path / "out"
    code = main(["run", "--geometry", path, "--quiet", "--no-figures", "--kinematics", "small", "--out", str(out)])
    err = cli_stderr()
    assert code == 2, err
    assert "gelcell run: error:" in err and "device.geo" in err
    for word in words:
        assert word in err, (word, err)
    COMM.Barrier()
    assert sorted(os.listdir(shared_tmp_path)) == ["device.geo"]


def test_slab_file_reads_its_convention():
    """The slab file: its volumes become the regions, its floor and top the fluid's, the gel's and the
    cell's z symmetry planes, its cell a cylinder of the 2D cell's centre and diameter, its inlet
    the planar device's profile 4 y (W - y) / W^2, uniform in z (walls at y = 0, W; symmetry in z)."""
    p = described(file_case(SLAB))
    assert p.geometry.dimension == 3 and p.with_cell
    from gelcell.geometry.describe import device_layout
    layout = device_layout(p)
    (cell,) = layout.cells
    assert cell.centre == pytest.approx((2.0, -0.2, 0.5 * HEIGHT), abs=1e-9)
    assert cell.diameter == pytest.approx(0.06, rel=1e-9) and cell.symmetry == (2,)
    b = layout.boundaries
    assert b.dim == 3 and [c for _, c, _ in b.fluid_component] == [2]
    assert [c for _, c in b.gel_symmetry] == [2] and [c for _, c in b.cell_symmetry] == [2]
    inflow = b.fluid_velocity[0][1]
    y, z = np.meshgrid(np.linspace(0, 0.2, 5), np.linspace(0, HEIGHT, 3))
    x = np.vstack([np.zeros(y.size), y.ravel(), z.ravel()])
    assert np.allclose(inflow(x), [4 * x[1] * (0.2 - x[1]) / 0.04, 0 * x[1], 0 * x[1]], atol=1e-14)


# --------------------------------------------------------------------------- a chip's lower half
CHIP = os.path.join(HERE, "geometry_files", "chip3d.geo")


def test_parabolic_inlet_of_a_half_channel_is_the_duct_series():
    """The chip file's inlet (walls y = 0, W and the floor z = 0, the symmetry plane z = 0.2 above):
    the profile of the whole duct W x 0.4 on its lower half, which is the built-in 3D device's
    ChipInflow("duct") (the rectangular-duct series, maximum 1 on the centre line), and its sphere."""
    from gelcell.geometry.describe import device_layout
    from gelcell.geometry.layout import ChipInflow
    layout = device_layout(described(file_case(CHIP)))
    inflow = layout.boundaries.fluid_velocity[0][1]
    y, z = np.meshgrid(np.linspace(0, 0.2, 9), np.linspace(0, 0.2, 7))
    x = np.vstack([np.zeros(y.size), y.ravel(), z.ravel()])
    assert np.allclose(inflow(x), ChipInflow("duct", 0.2, 0.4)(x), rtol=0, atol=1e-13)
    (cell,) = layout.cells
    assert cell.centre == pytest.approx((1.0, -0.15, 0.1), abs=1e-9) and cell.symmetry == ()
    assert cell.diameter == pytest.approx(0.06, rel=1e-6)


def test_chip_file_partitioned_equals_monolithic():
    """A 3D file device with a duct inflow, a bonded floor, a mid-height symmetry plane and a
    spherical cell: the partitioned fields (coupled to 1e-10) equal the monolithic reference's
    (the same discrete problem) to 1e-6 relative."""
    from gelcell.post.fields import relative_differences
    from gelcell.run.solve import solve_monolithic
    p = file_case(CHIP)
    part = solve_partitioned(p, verbose=False, checks=False)
    mono = solve_monolithic(p, checks=False)
    differences = relative_differences(part.fields, mono.fields)
    print(", ".join(f"{k} {v:.1e}" for k, v in differences.items()))
    assert part.summary["coupling"]["converged"]
    assert max(differences.values()) <= 1e-6, differences
    assert len(part.summary["cell"]["centroid_displacement"]) == 3


def test_same_3d_file_device_on_one_and_two_ranks():
    """The chip file: the summary's quantities and the coupling iterations on 1 and 2 ranks."""
    from mpi_run import run_mpi
    args = [CHIP, "1", "small"]
    serial, parallel = run_mpi("file_summary.py", 1, args), run_mpi("file_summary.py", 2, args)
    assert serial["iterations"] == parallel["iterations"]
    for key, value in serial.items():
        assert parallel[key] == pytest.approx(value, rel=1e-8, abs=1e-14), key


def test_a_too_fine_3d_file_is_refused_before_meshing():
    """A file with volumes: the probe count scales as the inverse cube of --mesh-size and the memory by
    the 3D law, so a fine size is refused with a --mesh-size that fits (checked: it passes)."""
    from gelcell.geometry.files.read import reference_elements
    from gelcell.errors import ModelLimitError
    from gelcell.post.validity import check_file_mesh_size, estimate_file_mesh
    coarse, fine = (estimate_file_mesh(described(file_case(SLAB, s))) for s in (2.0, 1.0))
    assert coarse["dimension"] == 3 and fine["elements"] == pytest.approx(8 * coarse["elements"], rel=1e-12)
    assert fine["elements"] == pytest.approx(reference_elements(SLAB), rel=1e-12)
    memory = int(2 * fine["memory_bytes"])          # a machine on which mesh-size 1 fits, 0.25 not
    with pytest.raises(ModelLimitError, match=r"--mesh-size 0.25 would make about") as refused:
        check_file_mesh_size(described(file_case(SLAB, 0.25)), memory=memory)
    suggested = float(str(refused.value).split("choose --mesh-size ")[1].split()[0])
    assert 0.25 < suggested <= 1.0
    check_file_mesh_size(described(file_case(SLAB, suggested)), memory=memory)
