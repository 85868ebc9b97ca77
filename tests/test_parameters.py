"""Case parameters: defaults, validation, unit conversions, sweeps, TOML and the CLI's errors."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys

import pytest

from mpi4py import MPI

from gelcell import cli
from gelcell.case import load_run_config
from gelcell.cli.commands import run_config
from gelcell.case import CaseParameters, CellMaterial, Dimensional, MeshSizes, Physics, ShearGeometry
from gelcell.errors import ParameterError

EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "examples")
SHEAR = CaseParameters.default("shear")
NORMAL = CaseParameters.default("normal")


# --------------------------------------------------------------------------- defaults
def test_baseline_values():
    p = SHEAR
    assert (p.physics.phi_s0, p.physics.lambda_s, p.physics.xi, p.physics.beta, p.physics.eta,
            p.physics.ca) == (0.01, 1.0, 4.5e4, 0.02, 0.02, 3e-10)
    assert (SHEAR.e, NORMAL.e) == (0.2, 1.2)
    assert p.V0 == pytest.approx(3e-6, rel=1e-14)                 # Ca L0 mu_s / mu
    assert p.lambda_s_pa == 40e3
    # cell: E = 1 kPa, nu = 0.25 -> mu_c = lambda_c = phi_s0 mu_s = 400 Pa = 0.01 mu_s
    assert (p.cell.mu_c, p.cell.lambda_c) == (400.0, 400.0)
    assert p.cell.youngs_modulus == pytest.approx(1000.0)
    assert p.cell.poisson_ratio == pytest.approx(0.25)
    assert p.mu_c == pytest.approx(0.01) and p.lambda_c == pytest.approx(0.01)
    assert p.cell_moduli_multiple == pytest.approx(1.0)
    assert p.brinkman_layer == pytest.approx(1 / math.sqrt(450))
    cm = CellMaterial.from_young(1000.0, 0.25)
    assert (cm.mu_c, cm.lambda_c) == pytest.approx((400.0, 400.0))


def test_default_element_sizes():
    h = SHEAR.element_sizes()
    assert h["h_cell"] == pytest.approx(math.pi * 0.06 / 48)
    assert h["h_layer"] == pytest.approx(SHEAR.brinkman_layer / 3)
    assert (h["h_fluid"], h["h_gel"]) == (0.04, 0.06)
    h2 = SHEAR.with_mesh_size(2.0).element_sizes()
    for k in ("h_cell", "h_layer", "h_fluid", "h_gel"):
        assert h2[k] == pytest.approx(2 * h[k])


# --------------------------------------------------------------------------- validation
def _error(make) -> str:
    with pytest.raises(ParameterError) as info:
        make()
    return str(info.value)


def test_message_format():
    msg = _error(lambda: SHEAR.replace(physics=Physics(phi_s0=1.5)))
    assert msg == "parameter 'phi_s0' = 1.5 is outside its allowed range (0, 1)"
    assert isinstance(ParameterError("x"), ValueError)


@pytest.mark.parametrize("name, value", [
    ("phi_s0", 0.0), ("phi_s0", 1.0), ("phi_s0", -0.1), ("phi_s0", float("nan")),
    ("lambda_s", -0.7), ("xi", 0.0), ("beta", -1.0), ("eta", 0.0), ("ca", 0.0), ("ca", -3e-10)])
def test_physics_out_of_range(name, value):
    msg = _error(lambda: Physics(**{name: value}) and SHEAR.replace(physics=Physics(**{name: value})))
    assert f"parameter '{name}' = " in msg and "allowed range" in msg


def test_lambda_bound_is_poisson_ratio():
    """λ > -2μ/3 <=> ν = λ/(2(λ+μ)) in (-1, 0.5) for μ > 0."""
    SHEAR.replace(physics=Physics(lambda_s=-0.66))            # ν = -0.97: allowed
    msg = _error(lambda: SHEAR.replace(physics=Physics(lambda_s=-2 / 3)))
    assert "'lambda_s'" in msg and "(-1, 0.5)" in msg
    SHEAR.replace(cell=CellMaterial(mu_c=300.0, lambda_c=-199.0))
    msg = _error(lambda: SHEAR.replace(cell=CellMaterial(mu_c=300.0, lambda_c=-200.0)))
    assert "parameter 'lambda_c' = -200 Pa is outside its allowed range (-200, inf) Pa" in msg


@pytest.mark.parametrize("name, value", [("L0", 0.0), ("mu", -1e-3), ("mu_s", 0.0),
                                         ("mu_s", -40e3), ("pore_radius", 0.0)])
def test_dimensional_out_of_range(name, value):
    msg = _error(lambda: SHEAR.replace(dimensional=Dimensional(**{name: value})))
    assert msg.startswith(f"parameter '{name}' = ")


@pytest.mark.parametrize("kwargs, name", [({"mu_c": 0.0}, "mu_c"), ({"mu_c": -400.0}, "mu_c"),
                                          ({"lambda_c": -300.0}, "lambda_c")])
def test_cell_moduli_out_of_range(kwargs, name):
    msg = _error(lambda: SHEAR.replace(cell=CellMaterial(**kwargs)))
    assert msg.startswith(f"parameter '{name}' = ")


@pytest.mark.parametrize("nu", [0.5, -1.0, 0.7])
def test_cell_poisson_ratio(nu):
    msg = _error(lambda: CellMaterial.from_young(1000.0, nu))
    assert msg.startswith("parameter 'poisson_ratio' = ") and "(-1, 0.5)" in msg
    msg = _error(lambda: CaseParameters.from_dict({"cell": {"youngs_modulus": 1e3, "poisson_ratio": nu}}))
    assert "'poisson_ratio'" in msg
    assert "'youngs_modulus'" in _error(lambda: CellMaterial.from_young(0.0, 0.25))


def test_velocity_scale_positive():
    msg = _error(lambda: CaseParameters.from_dict({"dimensional": {"V0": -1.0}}))
    assert msg.startswith("parameter 'V0' = -1 m/s")


@pytest.mark.parametrize("e", [-0.2, 0.0, 0.03, 0.033, 0.6, 5.0])
def test_shear_cell_not_inside_gel(e):
    """e = r: touching Γ1; e < r + h: gap below one element; e > depth - r - h: touching the bowl."""
    msg = _error(lambda: SHEAR.with_e(e))
    assert msg.startswith(f"parameter 'e' = {e:g} is outside its allowed range [0.033927, 0.543423]")
    assert "element size" in msg and "Γ1" in msg and "bowl" in msg


def test_shear_cell_gap_depends_on_element_size():
    e = 0.03 + 0.002                    # gap 0.002 to Γ1 < h_cell = 0.0039 at default size
    _error(lambda: SHEAR.with_e(e))
    SHEAR.replace(mesh=MeshSizes(size_factor=0.5), geometry=dataclasses.replace(SHEAR.geometry, e=e))
    SHEAR.with_e(0.54)                  # just inside the bowl
    assert "'cell_offset_x'" in _error(lambda: SHEAR.replace(
        geometry=dataclasses.replace(SHEAR.geometry, cell_offset_x=1.2)))


@pytest.mark.parametrize("e", [0.0, 0.03, -1.0, 2.37, 2.4, 3.0])
def test_normal_cell_touching_gamma1_gamma3(e):
    msg = _error(lambda: NORMAL.with_e(e))
    assert msg.startswith(f"parameter 'e' = {e:g} is outside its allowed range [0.033927, 2.36607]")
    assert "Γ1, Γ3 and the posts" in msg


def test_normal_cell_touching_post():
    """With posts reaching close to y = 0.5 a cell above a post is excluded."""
    g = dataclasses.replace(NORMAL.geometry, post_diameter=0.94, post_clearance=0.1, gel_length=2.8)
    xp = g.post_centres[0]
    msg = _error(lambda: NORMAL.replace(geometry=dataclasses.replace(g, e=xp)))
    assert msg.startswith(f"parameter 'e' = {xp:g} is outside its allowed range") and "∪" in msg
    NORMAL.replace(geometry=dataclasses.replace(g, e=0.5 * g.gel_length))


@pytest.mark.parametrize("changes, name", [
    ({"half_angle": 0.0}, "half_angle"), ({"half_angle": 2.0}, "half_angle"),
    ({"cell_diameter": 0.0}, "cell_diameter"), ({"cell_diameter": -0.06}, "cell_diameter"),
    ({"channel_height": 0.0}, "channel_height"), ({"chamber_width": -2.0}, "chamber_width"),
    ({"upstream_length": 0.0}, "upstream_length")])
def test_shear_geometry_out_of_range(changes, name):
    msg = _error(lambda: SHEAR.replace(geometry=dataclasses.replace(SHEAR.geometry, **changes)))
    assert msg.startswith(f"parameter '{name}' = ")


def test_half_angle_pi_over_2_allowed():
    p = SHEAR.replace(geometry=dataclasses.replace(SHEAR.geometry, half_angle=math.pi / 2))
    assert p.geometry.radius == pytest.approx(1.0)


@pytest.mark.parametrize("changes, name, text", [
    ({"post_clearance": 0.0}, "post_clearance", "Γ1/Γ3"),         # post touching Γ1 and Γ3
    ({"post_clearance": -0.1}, "post_clearance", "Γ1/Γ3"),        # post overlapping Γ1
    ({"post_clearance": 0.01}, "post_clearance", "wall element size"),
    ({"post_clearance": 0.8}, "post_clearance", "overlap"),       # posts overlap each other
    ({"post_diameter": 1.0}, "post_diameter", "y = 0.5"),         # post reaches the top line
    ({"post_diameter": 0.0}, "post_diameter", ""),
    ({"cell_diameter": 0.0}, "cell_diameter", ""),
    ({"cell_diameter": 1.2, "post_diameter": 0.2}, "cell_diameter", "y = 0"),
    ({"height": 0.0}, "height", ""), ({"gel_length": -1.0}, "gel_length", "")])
def test_normal_geometry_out_of_range(changes, name, text):
    msg = _error(lambda: NORMAL.replace(geometry=dataclasses.replace(NORMAL.geometry, **changes)))
    line = next(ln for ln in msg.splitlines() if ln.startswith(f"parameter '{name}' = "))
    assert text in line


@pytest.mark.parametrize("changes, name", [
    ({"size_factor": 0.0}, "size_factor"), ({"size_factor": -1.0}, "size_factor"),
    ({"size_factor": 7.0}, "size_factor"),            # fewer than 8 edges around the cell
    ({"h_fluid": 0.0}, "h_fluid"), ({"h_gel": -0.06}, "h_gel"),
    ({"n_cell_edges": 4}, "n_cell_edges"), ({"n_cell_edges": 48.5}, "n_cell_edges"),
    ({"layer_elements": 0.0}, "layer_elements"), ({"growth": 0.0}, "growth"),
    ({"cell_band": -1.0}, "cell_band")])
def test_mesh_out_of_range(changes, name):
    msg = _error(lambda: SHEAR.replace(mesh=dataclasses.replace(SHEAR.mesh, **changes)))
    assert msg.startswith(f"parameter '{name}' = ")


def test_cell_placement_ignored_without_cell():
    CaseParameters(case="shear", with_cell=False, geometry=ShearGeometry(e=5.0))
    _error(lambda: CaseParameters(case="shear", with_cell=True, geometry=ShearGeometry(e=5.0)))


def test_bad_case_and_types():
    assert "'case'" in _error(lambda: CaseParameters(case="channel"))
    assert "'cell'" in _error(lambda: CaseParameters(with_cell="yes"))
    assert CaseParameters().with_cell is True and CaseParameters().case == "shear"
    assert "NormalGeometry" in _error(lambda: CaseParameters(case="normal", geometry=ShearGeometry()))
    assert "must be a number" in _error(lambda: Physics(ca="fast") and SHEAR.replace(physics=Physics(ca="x")))


def test_all_problems_in_one_error():
    msg = _error(lambda: SHEAR.replace(physics=Physics(phi_s0=2.0, xi=-1.0)))
    assert len(msg.splitlines()) == 2 and "'phi_s0'" in msg and "'xi'" in msg


# --------------------------------------------------------------------------- conversions
def test_conversions_both_ways():
    p = SHEAR
    assert p.scale("length") == 250e-6 and p.scale("stress") == 40e3
    assert p.scale("velocity") == pytest.approx(3e-6) and p.scale("time") == pytest.approx(250 / 3)
    assert p.to_report(1.0, "velocity") == pytest.approx(3.0)            # µm/s
    assert p.to_report(0.04, "displacement") == pytest.approx(10.0)      # µm
    assert p.to_report(1e-7, "stress") == pytest.approx(4.0)             # 1e-7 μ_s = 4 mPa
    assert p.to_si(1e-7, "pressure") == pytest.approx(4e-3)              # Pa
    for kind in ("length", "displacement", "velocity", "stress", "pressure", "time"):
        assert p.from_si(p.to_si(0.37, kind), kind) == pytest.approx(0.37, rel=1e-14)
        assert p.from_report(p.to_report(0.37, kind), kind) == pytest.approx(0.37, rel=1e-14)
    assert p.from_report(3.0, "velocity") == pytest.approx(1.0)
    with pytest.raises(ValueError):
        p.scale("force")


def test_solver_scales():
    p = SHEAR
    assert p.stress_scale == p.physics.ca and p.displacement_scale == p.physics.ca
    d = p.to_dict()["si"]
    # stress unit μ V0 / L0 = Ca μ_s; displacement unit Ca L0
    assert d["solver_stress_unit_Pa"] == pytest.approx(p.stress_scale * p.dimensional.mu_s)
    assert d["solver_stress_unit_Pa"] == pytest.approx(1.2e-5)
    assert d["solver_displacement_unit_m"] == pytest.approx(p.displacement_scale * p.dimensional.L0)


def test_to_dict_blocks():
    d = NORMAL.to_dict()
    json.dumps(d)
    assert d["dimensionless"]["Ca"] == 3e-10 and d["dimensionless"]["e"] == 1.2
    assert d["dimensionless"]["mu_c"] == pytest.approx(0.01)
    assert d["si"]["V0_m_per_s"] == pytest.approx(3e-6) and d["si"]["mu_c_Pa"] == 400.0
    assert d["si"]["xi_Pa_s_per_m2"] == pytest.approx(4.5e4 * 1e-3 / (250e-6) ** 2)
    assert d["dimensionless"]["cell_moduli_multiple_of_drained_gel_modulus"] == pytest.approx(1.0)
    assert CaseParameters.from_dict(d["input"]) == NORMAL


# --------------------------------------------------------------------------- sweeps
def test_with_ca_changes_flow_speed_only():
    p = SHEAR.with_ca(1e-8)
    assert p.V0 == pytest.approx(1e-4) and p.dimensional == SHEAR.dimensional
    assert p.cell == SHEAR.cell and p.mu_c == SHEAR.mu_c


def test_with_cell_moduli():
    p = SHEAR.with_cell_moduli(10)
    assert p.cell.mu_c == pytest.approx(4000.0) and p.cell.lambda_c == pytest.approx(4000.0)
    assert p.cell.poisson_ratio == pytest.approx(0.25) and p.mu_c == pytest.approx(0.1)
    assert p.cell_moduli_multiple == pytest.approx(10) and p.V0 == SHEAR.V0
    assert "'cell_moduli'" in _error(lambda: SHEAR.with_cell_moduli(0.0))


@pytest.mark.parametrize("x", [0.1, 10.0])
def test_with_gel_moduli_at_fixed_flow_and_cell(x):
    p = SHEAR.with_gel_moduli(x)
    assert p.dimensional.mu_s == pytest.approx(40e3 * x) and p.lambda_s_pa == pytest.approx(40e3 * x)
    assert p.physics.lambda_s == SHEAR.physics.lambda_s
    assert p.V0 == pytest.approx(SHEAR.V0, rel=1e-14)                 # fixed dimensional flow
    assert p.cell == SHEAR.cell                                       # fixed cell moduli in Pa
    assert p.physics.ca == pytest.approx(SHEAR.physics.ca / x)
    assert p.mu_c == pytest.approx(SHEAR.mu_c / x)
    assert p.cell_moduli_multiple == pytest.approx(1 / x)
    assert "'gel_moduli'" in _error(lambda: SHEAR.with_gel_moduli(-1.0))


def test_with_e_and_mesh_size():
    assert NORMAL.with_e(0.4).geometry.cell_centre == (0.4, 0.5)
    assert SHEAR.with_e(0.3).geometry.cell_centre == (2.0, -0.3)
    assert SHEAR.with_mesh_size(0.5).mesh.size_factor == 0.5


# --------------------------------------------------------------------------- TOML
@pytest.mark.parametrize("case", ["shear", "normal"])
def test_examples_are_the_baseline(case):
    assert CaseParameters.from_toml(os.path.join(EXAMPLES, f"case_baseline_{case}.toml")) == \
        CaseParameters.default(case)


def test_toml_overrides_and_alternatives(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('[case]\nname = "normal"\ncell = false\n[dimensional]\nV0 = 6e-6\n'
                 '[cell]\nmoduli_multiple = 2.0\n[geometry]\ne = 0.4\n[coupling]\nscheme = "iqn"\n'
                 '[coupling.robin]\nalpha = 2.0\n')
    p = CaseParameters.from_toml(f)
    assert (p.case, p.with_cell, p.e) == ("normal", False, 0.4)
    assert p.physics.ca == pytest.approx(6e-10) and p.V0 == pytest.approx(6e-6)
    assert p.cell.mu_c == pytest.approx(800.0) and p.cell.poisson_ratio == pytest.approx(0.25)
    assert load_run_config(f).coupling == {"scheme": "iqn", "robin": {"alpha": 2.0}}
    q = load_run_config(f, {"physics.ca": 1e-9, "geometry.e": 2.0, "case.cell": True,
                            "mesh.size_factor": 2.0, "physics.xi": None}).case
    assert q.physics.ca == 1e-9 and q.e == 2.0 and q.with_cell and q.mesh.size_factor == 2.0
    y = CaseParameters.from_dict({"cell": {"youngs_modulus": 3000.0, "poisson_ratio": 0.3}})
    assert y.cell.youngs_modulus == pytest.approx(3000.0) and y.cell.poisson_ratio == pytest.approx(0.3)


@pytest.mark.parametrize("text, key", [
    ("[physics]\nphi = 0.01\n", "physics.phi"),
    ("[geometry]\npost_diameter = 0.4\n", "geometry.post_diameter"),    # a normal-only key in shear
    ("[mesh]\nsize = 2\n", "mesh.size"),
    ("[solver]\nrtol = 1e-8\n", "solver.rtol"),
    ("[tmie]\ndt = 1e-8\n", "tmie"),
    ("[case]\nname = 'shear'\ncells = true\n", "case.cells")])
def test_toml_unknown_key(tmp_path, text, key):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    msg = _error(lambda: load_run_config(f))
    assert f"unknown table or key '{key}'" in msg or f"unknown key '{key}'" in msg
    assert str(f) in msg


def test_toml_errors(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text("[physics\n")
    assert "not valid TOML" in _error(lambda: CaseParameters.from_toml(f))
    assert "cannot read" in _error(lambda: CaseParameters.from_toml(tmp_path / "missing.toml"))
    f.write_text("[physics]\nca = 1e-9\n[dimensional]\nV0 = 1e-6\n")
    assert "not both" in _error(lambda: CaseParameters.from_toml(f))
    f.write_text("[cell]\nmu_c = 100.0\nyoungs_modulus = 1000.0\n")
    assert "one of" in _error(lambda: CaseParameters.from_toml(f))
    f.write_text("[physics]\nphi_s0 = 1.5\n")
    assert _error(lambda: CaseParameters.from_toml(f)) == \
        "parameter 'phi_s0' = 1.5 is outside its allowed range (0, 1)"


# --------------------------------------------------------------------------- CLI
def test_cli_case_arguments(tmp_path):
    parser = cli.build_parser()
    args = parser.parse_args(["mesh", "normal", "--no-cell", "--e", "0.4", "--ca", "1e-9",
                              "--cell-moduli", "1", "--gel-moduli", "10", "--mesh-size", "2",
                              "--out", str(tmp_path)])
    p = run_config(args).case
    assert (p.case, p.with_cell, p.e, p.mesh.size_factor) == ("normal", False, 0.4, 2.0)
    assert p.cell.mu_c == pytest.approx(400.0) and p.dimensional.mu_s == pytest.approx(400e3)
    assert p.physics.ca == pytest.approx(1e-10) and p.V0 == pytest.approx(1e-5)
    args = parser.parse_args(["mesh", "--config", os.path.join(EXAMPLES, "case_baseline_normal.toml"),
                              "--e", "2.0", "--out", str(tmp_path)])
    assert run_config(args).case.e == 2.0


@pytest.mark.parametrize("argv, text", [
    (["mesh", "shear", "--e", "5"], "parameter 'e' = 5 is outside its allowed range"),
    (["mesh", "normal", "--mesh-size", "-1"], "parameter 'size_factor' = -1"),
    (["mesh", "shear", "--ca", "0"], "parameter 'ca' = 0"),
    (["mesh", "shear", "--cell-moduli", "-2"], "parameter 'cell_moduli' = -2"),
    (["mesh"], "give the device geometry")])
def test_cli_parameter_errors(tmp_path, capsys, argv, text):
    out = tmp_path / "never"
    assert cli.main(argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert (text in err) == (MPI.COMM_WORLD.rank == 0)          # printed once, by rank 0
    assert not out.exists()


@pytest.mark.skip_in_parallel
def test_cli_subprocess_help_and_error(tmp_path):
    def run(*a):
        return subprocess.run([sys.executable, "-m", "gelcell.cli", *a], capture_output=True, text=True, timeout=60)

    h = run("--help")
    assert h.returncode == 0 and "mesh" in h.stdout and "Gamma1" in h.stdout
    bad = run("mesh", "shear", "--e", "0.01", "--out", str(tmp_path / "x"))
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert "parameter 'e' = 0.01" in bad.stderr and "element size" in bad.stderr
