"""The user's commands end to end: `gelcell run`, `--monolithic`, `gelcell sweep`, bad input."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

pytestmark = pytest.mark.skipif("OMPI_COMM_WORLD_SIZE" in os.environ,
                                reason="runs the CLI as subprocesses: done by the serial pytest run")


def gelcell(*args, check=True):
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, "-m", "gelcell.cli", *args], capture_output=True, text=True,
                          env=env, timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f"gelcell {' '.join(args)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def test_help():
    out = gelcell("--help").stdout
    for command in ("mesh", "run", "sweep", "study"):
        assert command in out


def test_run_writes_every_promised_file(tmp_path):
    out = tmp_path / "shear"
    proc = gelcell("run", "shear", "--mesh-size", "3", "--compare-no-cell", "--quiet", "--out", str(out))
    assert "max |v_f| in the gel" in proc.stdout and "µm/s" in proc.stdout
    expected = ["summary.json", "summary_no_cell.json", "fluid.xdmf", "fluid.h5", "gel.xdmf", "gel.h5",
                "cell.xdmf", "cell.h5", "gamma1_profiles.h5", "gamma1_profiles.csv",
                "coupling/coupling-convergence.csv", "coupling/coupling-iterations.json",
                "gel_velocity.png", "gel_pressure.png", "gel_displacement_von_mises.png", "gamma1_profiles.png",
                "cell_displacement.png", "cell_traction_parts.png"]
    for name in expected:
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert s["case"] == "shear" and s["cell"] is True and s["coupling"]["converged"]
    assert s["model"]["warnings"] == [] and 0 < s["model"]["max_cell_strain"] < 1e-5
    assert json.loads((out / "summary_no_cell.json").read_text())["cell"] is False
    # the profiles: sorted along Gamma1 = the chord y = 0, x in [1, 3]; h5 and csv agree
    with h5py.File(out / "gamma1_profiles.h5") as h5:
        X, usx = h5["X"][:], h5["u_sx"][:]
        assert np.all(np.diff(X) > 0) and X[0] == pytest.approx(1.0) and X[-1] == pytest.approx(3.0)
        assert np.allclose(h5["Y"][:], 0.0, atol=1e-12)
    rows = list(csv.DictReader(open(out / "gamma1_profiles.csv")))
    assert np.allclose([float(r["u_sx"]) for r in rows], usx, rtol=1e-10)
    # the ends of Gamma1 sit on the fixed bowl: no network displacement there
    assert abs(usx[0]) < 1e-12 and abs(usx[-1]) < 1e-12


def test_run_monolithic(tmp_path):
    out = tmp_path / "mono"
    gelcell("run", "normal", "--mesh-size", "3", "--monolithic", "--no-figures", "--out", str(out))
    s = json.loads((out / "summary.json").read_text())
    assert s["method"] == "monolithic" and s["coupling"] is None
    assert s["monolithic"]["newton_iterations"] <= 5
    worst = max(v for r in s["interface_residuals"].values() for v in r.values())
    assert worst < 1e-8, s["interface_residuals"]
    assert (out / "gamma3_profiles.csv").is_file()


def test_sweep_of_cell_moduli(tmp_path):
    """A stiffer cell deforms less: its strain falls as its moduli rise (same loads)."""
    out = tmp_path / "sweep"
    gelcell("sweep", "shear", "--param", "cell-moduli", "--values", "0.1", "1", "10", "--mesh-size", "3",
            "--quiet", "--out", str(out))
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [float(r["cell-moduli"]) for r in rows] == [0.1, 1.0, 10.0]
    strain = [float(r["cell_von_mises_strain_max"]) for r in rows]
    assert strain[0] > strain[1] > strain[2]
    assert (out / "sweep.png").is_file() and (out / "sweep.json").is_file()
    assert all(r["converged"] == "True" for r in rows)


@pytest.mark.parametrize("args, name", [
    (["--ca", "-1"], "ca"),
    (["--e", "5"], "e"),
    (["--mesh-size", "0"], "size_factor"),
    (["--cell-moduli", "-2"], "cell_moduli"),
])
def test_bad_parameters_stop_before_meshing(tmp_path, args, name):
    out = tmp_path / "bad"
    proc = gelcell("run", "shear", *args, "--out", str(out), check=False)
    assert proc.returncode == 2
    assert name in proc.stderr and "allowed" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()


def test_run_with_the_linearized_prior(tmp_path):
    """--jacobian-prior linearized: the same case in a few iterations (docs/coupling.md: 4-5 at any
    stiffness); with --monolithic or a non-IQN acceleration it is refused before meshing."""
    out = tmp_path / "prior"
    gelcell("run", "normal", "--mesh-size", "3", "--jacobian-prior", "linearized", "--no-figures", "--quiet",
            "--out", str(out))
    s = json.loads((out / "summary.json").read_text())
    assert s["coupling"]["converged"] and s["coupling"]["iterations"] <= 6
    for extra in (["--monolithic"], ["--acceleration", "aitken"]):
        bad = tmp_path / "bad"
        proc = gelcell("run", "normal", "--jacobian-prior", "linearized", *extra, "--out", str(bad), check=False)
        assert proc.returncode == 2 and "jacobian" in proc.stderr.replace("-", "_"), proc.stderr
        assert "Traceback" not in proc.stderr and not bad.exists()
