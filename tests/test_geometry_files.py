"""Geometry files: every convention error is refused before meshing, naming the group or entity, with nothing written.

Each case breaks the small valid device ``tests/geometry_files/small.geo`` in one way and runs
``gelcell run --geometry`` in-process: exit code 2 (bad input, ``gelcell.errors``), one message
naming the problem, and the output directory never created.
"""

from __future__ import annotations

import os

import pytest

from mpi4py import MPI

from gelcell.cli import main

COMM = MPI.COMM_WORLD

HERE = os.path.dirname(os.path.abspath(__file__))
SMALL = open(os.path.join(HERE, "geometry_files", "small.geo")).read()

SECOND_CELL = """
Point(20) = {X2, -0.3, 0, lcc}; Point(21) = {X2 + 0.05, -0.3, 0, lcc}; Point(22) = {X2 - 0.05, -0.3, 0, lcc};
Circle(20) = {21, 20, 22}; Circle(21) = {22, 20, 21};
Curve Loop(4) = {20, 21}; Plane Surface(4) = {4};
"""
POCKET = """
Point(30) = {2.5, 0, 0, lc}; Point(31) = {3, 0, 0, lc}; Point(32) = {3, 0.3, 0, lc}; Point(33) = {2.5, 0.3, 0, lc};
Line(30) = {30, 31}; Line(31) = {31, 32}; Line(32) = {32, 33}; Line(33) = {33, 30};
Curve Loop(5) = {30, 31, 32, 33}; Plane Surface(5) = {5};
"""
ISLAND = """
Point(40) = {2.5, 0, 0, lc}; Point(41) = {3.5, 0, 0, lc}; Point(42) = {3.5, 0.6, 0, lc}; Point(43) = {2.5, 0.6, 0, lc};
Line(40) = {40, 41}; Line(41) = {41, 42}; Line(42) = {42, 43}; Line(43) = {43, 40};
Point(44) = {2.8, 0.2, 0, lc}; Point(45) = {3.2, 0.2, 0, lc}; Point(46) = {3.2, 0.4, 0, lc}; Point(47) = {2.8, 0.4, 0, lc};
Line(44) = {44, 45}; Line(45) = {45, 46}; Line(46) = {46, 47}; Line(47) = {47, 44};
Curve Loop(6) = {40, 41, 42, 43}; Curve Loop(7) = {44, 45, 46, 47};
Plane Surface(6) = {6, 7}; Plane Surface(7) = {7};
"""

# (id, [(old, new), ...], words the message must contain)
CASES = [
    ("misspelled group", [('Physical Curve("outlet")', 'Physical Curve("outlett")')],
     ["'outlett'", "did you mean 'outlet'"]),
    ("missing group", [('Physical Surface("gel") = {2};', "")], ["missing physical surface 'gel'"]),
    ("curve in two groups", [('Physical Curve("wall") = {3};', 'Physical Curve("wall") = {3, 2};')],
     ["curve 2 is in two physical groups", "'outlet'", "'wall'"]),
    ("interface sides do not share nodes",
     [("Curve Loop(2) = {5, 6, 7, 1};", "Line(8) = {1, 2}; Curve Loop(2) = {5, 6, 7, 8};"),
      ('Physical Curve("interface") = {1};', 'Physical Curve("interface") = {1, 8};')],
     ["interface 'interface'", "do not share nodes"]),
    ("cell overlaps another cell",
     [("//EXTRA", SECOND_CELL.replace("X2", "1.07")), ("Plane Surface(2) = {2, 3};", "Plane Surface(2) = {2, 3, 4};"),
      ('Physical Surface("cell") = {3};', 'Physical Surface("cell_1") = {3}; Physical Surface("cell_2") = {4};')],
     ["cell 'cell_2' overlaps cell 'cell_1'"]),
    ("cell touches another cell",
     [("//EXTRA", SECOND_CELL.replace("X2", "1.1")), ("Plane Surface(2) = {2, 3};", "Plane Surface(2) = {2, 3, 4};"),
      ('Physical Surface("cell") = {3};', 'Physical Surface("cell_1") = {3}; Physical Surface("cell_2") = {4};')],
     ["cell 'cell_2' touches cell 'cell_1'"]),
    ("cell touches a gel boundary", [("CY = -0.3;", "CY = -0.55;")], ["cell 'cell' touches the boundary 'held'"]),
    ("cell crosses a gel boundary", [("CY = -0.3;", "CY = -0.58;")], ["cell 'cell' overlaps a boundary of the gel"]),
    ("no outlet", [('Physical Curve("outlet") = {2};', ""), ('Physical Curve("wall") = {3};',
                                                            'Physical Curve("wall") = {3, 2};')],
     ["no physical curve 'outlet'", "pressure is undetermined"]),
    ("enclosed fluid", [("//EXTRA", POCKET), ('Physical Surface("fluid") = {1};', 'Physical Surface("fluid") = {1, 5};'),
                        ('Physical Curve("wall") = {3};', 'Physical Curve("wall") = {3, 30, 31, 32};'),
                        ('Physical Curve("outlet") = {2};', 'Physical Curve("outlet") = {2}; '
                                                            'Physical Curve("inlet_2") = {33};')],
     ["surface(s) [5]", "enclosed and nothing fixes its pressure"]),
    ("element order 3", [("//EXTRA", "Mesh.ElementOrder = 3;")], ["Mesh.ElementOrder = 3", "orders 1 and 2"]),
    ("quadrilaterals", [("//EXTRA", "Mesh.RecombineAll = 1;")], ["unsupported element type", "triangles"]),
    ("gel part held nowhere", [("//EXTRA", ISLAND), ('Physical Surface("gel") = {2};', 'Physical Surface("gel") = {2, 7};'),
                               ('Physical Surface("fluid") = {1};', 'Physical Surface("fluid") = {1, 6};'),
                               ('Physical Curve("wall") = {3};', 'Physical Curve("wall") = {3, 40, 41, 42, 43}; '
                                                                 'Physical Curve("interface_2") = {44, 45, 46, 47};'),
                               ('Physical Curve("interface")', 'Physical Curve("interface_1")')],
     ["the gel region of surface(s) [7]", "anchored nowhere"]),
    ("curve in no group", [('Physical Curve("wall") = {3};', "")], ["curve 3", "in no physical group"]),
    ("bad inflow profile", [('"inlet:uniform:0.5"', '"inlet:plug:0.5"')], ["'inlet:plug:0.5'", "'parabolic' or 'uniform'"]),
]


def _write(directory, edits, name="device.geo") -> str:
    """The edited file, written by rank 0 into a directory every rank sees."""
    text = SMALL
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    path = directory / name
    if COMM.rank == 0:
        path.write_text(text)
    COMM.Barrier()
    return str(path)


@pytest.mark.parametrize("edits,words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_broken_file_is_refused_before_meshing(shared_tmp_path, cli_stderr, edits, words):
    path = _write(shared_tmp_path, edits)
    out = shared_tmp_path / "out"
    code = main(["run", "--geometry", path, "--quiet", "--no-figures", "--out", str(out)])
    err = cli_stderr()
    assert code == 2, err
    assert "gelcell run: error:" in err and os.path.basename(path) in err
    for word in words:
        assert word in err, (word, err)
    COMM.Barrier()
    assert sorted(os.listdir(shared_tmp_path)) == ["device.geo"]   # nothing written, not even a temporary


def test_valid_file_reads_its_convention():
    """The unbroken file: its groups become gelcell's conditions, its cell a CellSpec."""
    from gelcell.geometry.layout import SegmentInflow
    from gelcell.case import CaseParameters
    p = CaseParameters.from_dict({"geometry": {"file": os.path.join(HERE, "geometry_files", "small.geo")}})
    assert p.case == "file" and p.with_cell
    from gelcell.geometry.describe import device_layout
    layout = device_layout(p)
    (cell,) = layout.cells
    assert cell.name == "cell" and cell.interface == "Gamma2"
    assert cell.centre == pytest.approx((1.0, -0.3), abs=1e-12) and cell.diameter == pytest.approx(0.1, rel=1e-12)
    assert layout.fluid_interfaces == {"Gamma1": 21}
    profile = [v for t, v in layout.boundaries.fluid_velocity if isinstance(v, SegmentInflow)][0]
    import numpy as np
    # uniform inflow of 0.5 V0 into the channel (+x) on the inlet x = 0
    values = profile(np.array([[0.0, 0.0], [0.05, 0.25], [0.0, 0.0]]))
    assert np.allclose(values, [[0.5, 0.5], [0.0, 0.0]])


def test_cells_of_a_builtin_device_are_checked_before_meshing(cli_stderr, shared_tmp_path):
    out = shared_tmp_path / "out"
    code = main(["run", "shear", "--cells", "2.0,-0.3,0.06", "2.05,-0.3,0.06", "--out", str(out)])
    err = cli_stderr()
    assert code == 2 and "'cells[0]' and 'cells[1]'" in err and "overlap" in err, err
    code = main(["run", "shear", "--cells", "2.0,-0.01,0.06", "--out", str(out)])
    err = cli_stderr()
    assert code == 2 and "cells[0]" in err and "Γ1" in err, err
    assert not out.exists()


@pytest.mark.parametrize("how", ["--cells", "case file"])
def test_a_cell_too_small_for_the_mesh_is_refused_before_gmsh(cli_stderr, shared_tmp_path, how):
    """Issue 28 item 3: a cell of diameter 1e-9 aborted gmsh (exit 134, a C++ backtrace): one
    ParameterError names the parameter and its allowed range."""
    out = shared_tmp_path / "out"
    if how == "--cells":
        args, name = ["--cells", "2.0,-0.2,1e-9"], "'cells[0].d'"
    else:
        case = shared_tmp_path / "tiny.toml"
        if COMM.rank == 0:
            case.write_text("[geometry]\ncell_diameter = 1e-9\n")
        COMM.Barrier()
        args, name = ["--config", str(case)], "'cell_diameter'"
    code = main(["run", "shear", *args, "--mesh-size", "3", "--quiet", "--no-figures", "--out", str(out)])
    err = cli_stderr()
    assert code == 2, err
    assert f"parameter {name} = 1e-09 is outside its allowed range [0.000611155, inf)" in err, err
    assert "π d / n_cell_edges" in err and err.count("error:") == 1, err
    assert not out.exists()


@pytest.mark.skip_in_parallel
def test_case_file_names_the_geometry_relative_to_itself(tmp_path):
    from gelcell.case import CaseParameters
    from gelcell.errors import ParameterError
    (tmp_path / "dev").mkdir()
    (tmp_path / "dev" / "chip.geo").write_text(SMALL)
    (tmp_path / "case.toml").write_text('[geometry]\nfile = "dev/chip.geo"\n[physics]\nca = 1e-9\n')
    p = CaseParameters.from_toml(tmp_path / "case.toml")
    assert p.case == "file" and p.geometry.file == str(tmp_path / "dev" / "chip.geo") and p.physics.ca == 1e-9
    assert CaseParameters.from_dict(p.to_input_dict()).geometry.file == p.geometry.file     # round trip
    (tmp_path / "both.toml").write_text('[case]\nname = "shear"\n[geometry]\nfile = "dev/chip.geo"\n')
    with pytest.raises(ParameterError, match="either the device"):
        CaseParameters.from_toml(tmp_path / "both.toml")
    (tmp_path / "cells.toml").write_text('[case]\nname = "shear"\n[geometry]\ncells = [[1.9, -0.2, 0.06], '
                                        '[2.1, -0.3, 0.05]]\n')
    q = CaseParameters.from_toml(tmp_path / "cells.toml")
    assert q.geometry.cell_list() == [(1.9, -0.2, 0.06), (2.1, -0.3, 0.05)]
    with pytest.raises(ParameterError, match="e"):
        q.with_e(0.3)


HOSTILE = [
    ("SystemCall", 'SystemCall "touch {pwned}";', "'SystemCall' runs a shell command"),
    ("Shell", 'System "touch {pwned}";', "'System' runs a shell command"),
    ("OnelabRun", 'OnelabRun("x", "touch {pwned}");', "'OnelabRun' runs an external program"),
    ("Include", 'Include\n  "{pwned}.geo";', "'Include' reads another file"),
    ("Save", 'Save "{pwned}.msh";', "'Save' writes a file"),
    ("Printf to a file", 'Printf("x = %g", 1) > "{pwned}";', "'Printf(...) >' writes a file"),
    ("Solver option", 'Solver.Executable0 = "/bin/sh";', "option 'Solver.Executable0'"),
]


@pytest.mark.parametrize("statement,words", [c[1:] for c in HOSTILE], ids=[c[0] for c in HOSTILE])
def test_geo_statements_that_reach_the_shell_or_files_are_refused_before_gmsh(shared_tmp_path, cli_stderr,
                                                                              statement, words):
    """Issue 28 item 1: the statement and its line are named, exit 2, nothing run, nothing written."""
    pwned = shared_tmp_path / "pwned"
    lines = SMALL.count("\n")
    path = _write(shared_tmp_path, [(SMALL, SMALL + "// comment: SystemCall \"x\";\n"
                                     + statement.format(pwned=pwned) + "\n")])
    out = shared_tmp_path / "out"
    code = main(["run", "--geometry", path, "--quiet", "--no-figures", "--out", str(out)])
    err = cli_stderr()
    assert code == 2, err
    assert f"line {lines + 2}: {words}" in err and "run commands or reach the file system" in err, err
    assert err.count("line ") == 1, err              # the comment's SystemCall is no statement
    COMM.Barrier()
    assert sorted(os.listdir(shared_tmp_path)) == ["device.geo"]   # nothing run, nothing written


def test_allowed_statements_are_not_refused():
    from gelcell.geometry.files.screen import geo_problems
    text = ('Physical Surface("Save") = {1}; /* Include "x"; */ Printf("fine %g", 1);\n'
            'Mesh.MeshSizeFactor = 2; General.Terminal = 1; Field[1].CurvesList = {1}; Delete Physicals;\n')
    assert geo_problems(text) == []
    for name in ("shear.geo", "shear_three_cells.geo", "three_channel_chip.geo"):
        assert geo_problems(open(os.path.join(HERE, "..", "examples", "devices", name)).read()) == []


HANG = "\nFor i In {1:2e9}\n  x = i;\nEndFor\n"       # keeps gmsh's parser busy for hours


def _workers_of(pid: int) -> list[int]:
    """The gmsh child processes (gelcell/geometry/files/worker.py) whose parent is ``pid``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmdline = f.read()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"gelcell/geometry/files/worker.py" in cmdline:
            found.append(int(entry))
    return found


@pytest.mark.skip_in_parallel
def test_a_geo_file_that_keeps_gmsh_busy_is_stopped_by_sigterm(tmp_path):
    """Issue 28 item 2: gmsh parses the file in a child process: SIGTERM ends the run (143) within seconds."""
    import signal
    import subprocess
    import sys
    import time
    path = tmp_path / "hang.geo"
    path.write_text(SMALL + HANG)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "gelcell.cli", "run", "--geometry", str(path), "--quiet",
                             "--no-figures", "--out", str(out)], stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, MPLBACKEND="Agg"))
    deadline = time.monotonic() + 60
    while not _workers_of(proc.pid) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    workers = _workers_of(proc.pid)
    assert workers, "gmsh's child process never started"
    time.sleep(1.0)                                  # gmsh is in the loop now
    sent = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - sent < 5
    assert proc.returncode == 143, err
    assert "gelcell run: error: interrupted by SIGTERM" in err
    assert not any(os.path.exists(f"/proc/{w}") and _workers_of(proc.pid) for w in workers)
    time.sleep(0.2)
    assert not [w for w in workers if os.path.exists(f"/proc/{w}/cmdline")
                and b"worker" in open(f"/proc/{w}/cmdline", "rb").read()], "gmsh's child outlived the run"
    assert sorted(os.listdir(tmp_path)) == ["hang.geo"]


def test_a_geo_file_that_keeps_gmsh_busy_meets_the_time_limit(shared_tmp_path, cli_stderr, monkeypatch):
    """The time bound ($GELCELL_GMSH_TIME_LIMIT) ends it with a model limit (exit 4), nothing written."""
    path = _write(shared_tmp_path, [(SMALL, SMALL + HANG)])
    monkeypatch.setenv("GELCELL_GMSH_TIME_LIMIT", "1.5")
    code = main(["run", "--geometry", path, "--quiet", "--no-figures", "--out", str(shared_tmp_path / "out")])
    err = cli_stderr()
    assert code == 4, err
    assert "gmsh was still reading it after 1.5 s" in err and "GELCELL_GMSH_TIME_LIMIT" in err, err
    COMM.Barrier()
    assert sorted(os.listdir(shared_tmp_path)) == ["device.geo"]


def test_a_too_fine_geo_file_is_refused_before_meshing(shared_tmp_path, cli_stderr):
    """Issue 28 item 2: the element count is estimated from the file's sizes (coarse probe meshes) and
    refused like a built-in device's (exit 4, with a --mesh-size that fits)."""
    from gelcell.case import CaseParameters
    from gelcell.geometry import described
    from gelcell.geometry.files.read import reference_elements
    from gelcell.post.validity import check_file_mesh_size
    shear = os.path.join(HERE, "..", "examples", "devices", "shear.geo")
    out = shared_tmp_path / "out"
    code = main(["run", "--geometry", shear, "--mesh-size", "1e-4", "--quiet", "--no-figures", "--out", str(out)])
    err = cli_stderr()
    assert code == 4, err
    assert "--mesh-size 0.0001 would make about" in err and "geometry file shear.geo" in err, err
    suggested = float(err.split("choose --mesh-size ")[1].split()[0])
    params = described(CaseParameters.from_dict({"geometry": {"file": shear}, "mesh": {"size_factor": suggested}}))
    check_file_mesh_size(params)
    assert not out.exists()
    # the estimate against the mesh of --mesh-size 1 (about 7.2e3 triangles)
    assert 0.8 < reference_elements(shear) / 7.2e3 < 1.25


def _msh_files(directory) -> dict:
    """The coarse built-in shear device written as MSH 4.1, 2.2 and 1.0 files (rank 0)."""
    from gelcell.case import CaseParameters
    from gelcell.geometry.files.build import export_builtin
    paths = {v: str(directory / f"shear_{v}.msh") for v in ("4.1", "2.2", "1.0")}
    if COMM.rank == 0:
        export_builtin(CaseParameters.default("shear").with_mesh_size(3), paths["4.1"])
        from femtools.gmshimport import gmsh_session
        for v in ("2.2", "1.0"):
            with gmsh_session() as gmsh:
                gmsh.open(paths["4.1"])
                gmsh.option.setNumber("Mesh.MshFileVersion", float(v))
                gmsh.write(paths[v])
    COMM.Barrier()
    return paths


def test_msh_2_files_are_read_like_msh_4_and_msh_1_is_refused_naming_it(shared_tmp_path, cli_stderr):
    """Issue 28 item 4: an MSH 2.2 file ended in 'internal error: KeyError: 2' (no curve ends or
    adjacencies in MSH 2: gmsh's createTopology makes them); MSH 1.0 has no physical names."""
    import numpy as np
    from gelcell.case import CaseParameters
    from gelcell.geometry.meshes import build_meshes
    paths = _msh_files(shared_tmp_path)
    counts, nodes = {}, {}
    for v in ("4.1", "2.2"):
        meshes = build_meshes(CaseParameters.from_dict({"geometry": {"file": paths[v]}}), COMM)
        counts[v] = meshes.counts()
        geometry = meshes.whole[0].geometry
        owned = geometry.x[:geometry.index_map().size_local, :2]
        nodes[v] = COMM.allreduce(owned.sum(axis=0), op=MPI.SUM)
    assert counts["2.2"] == counts["4.1"]
    assert np.allclose(nodes["2.2"], nodes["4.1"])
    out = shared_tmp_path / "out"
    code = main(["run", "--geometry", paths["1.0"], "--quiet", "--no-figures", "--out", str(out)])
    err = cli_stderr()
    assert code == 2 and "is in the MSH 1.0 format, which has no physical names" in err, err
    assert not out.exists()
