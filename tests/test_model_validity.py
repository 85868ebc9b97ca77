"""Inputs the model cannot answer are refused before solving, or flagged after (issue 12 item 3)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from mpi4py import MPI

from gelcell.errors import ModelLimitError
from gelcell.geometry.meshes import build_meshes
from gelcell.case import CaseParameters
from gelcell.post.validity import (MAX_CELL_STRAIN, MAX_DISPLACEMENT_GRADIENT, check_mesh_size, check_representable,
                                   estimate_mesh, model_warnings, representable_ca)


def test_representable_ca_from_float64():
    lo, hi = representable_ca()
    assert 1e-147 < lo < 1e-145 and 1e145 < hi < 1e147
    # the squares of Ca-sized quantities (von Mises measures, norms) leave float64 outside it:
    strain_per_ca = 5e3                       # the cell's strain / Ca at baseline
    assert (1e-300 * strain_per_ca) ** 2 == 0.0 and (lo * strain_per_ca) ** 2 > sys.float_info.min
    for ca in (1e300, 1e-300, 1e-150):
        with pytest.raises(ModelLimitError, match="cannot be represented"):
            check_representable(CaseParameters.default("shear").with_ca(ca))
    for ca in (3e-10, 1e-8, 1e-100, 1.0):
        check_representable(CaseParameters.default("shear").with_ca(ca))


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_element_estimate_matches_the_mesh(case):
    params = CaseParameters.default(case).with_mesh_size(3)
    counts = build_meshes(params, MPI.COMM_WORLD, whole=False).counts()
    actual = sum(counts[r]["cells"] for r in ("fluid", "gel", "cell"))
    assert 0.75 < estimate_mesh(params)["elements"] / actual < 1.25


def test_mesh_too_large_for_the_machine_is_refused_with_a_size_that_fits():
    params = CaseParameters.default("shear").with_mesh_size(1e-4)
    with pytest.raises(ModelLimitError, match=r"about 5.8e\+11 elements, which need about .* GiB") as info:
        check_mesh_size(params)
    suggested = float(str(info.value).split("choose --mesh-size ")[1].split()[0])
    check_mesh_size(params.with_mesh_size(suggested))
    # the limit follows the memory: a machine with 0.5 GiB cannot hold the default mesh (0.7 GB)
    with pytest.raises(ModelLimitError):
        check_mesh_size(CaseParameters.default("shear"), memory=2**29)


def test_model_warnings_above_the_thresholds():
    assert model_warnings({"max_displacement_gradient": 1e-6, "max_cell_strain": 1e-6}) == []
    assert model_warnings({"max_displacement_gradient": 1e-6, "max_cell_strain": None}) == []
    warnings = model_warnings({"max_displacement_gradient": 2 * MAX_DISPLACEMENT_GRADIENT,
                               "max_cell_strain": 2 * MAX_CELL_STRAIN})
    assert len(warnings) == 2 and "displacement gradient" in warnings[0] and "strain" in warnings[1]


@pytest.mark.skip_in_parallel
def test_large_strain_run_is_flagged(tmp_path):
    """--ca 5e-5: a 38 % displacement gradient used to pass silently (the monolithic reference is the
    cheaper solve here; both methods report through the same summary)."""
    out = tmp_path / "big"
    proc = subprocess.run([sys.executable, "-m", "gelcell.cli", "run", "shear", "--ca", "5e-5", "--monolithic",
                           "--mesh-size", "3", "--no-figures", "--quiet", "--out", str(out)],
                          capture_output=True, text=True,
                          env=dict(os.environ, MPLBACKEND="Agg"), timeout=600)
    assert proc.returncode == 0, proc.stderr
    warned = [line for line in proc.stderr.splitlines() if line.startswith("gelcell: warning: ")]
    assert len(warned) == 2, proc.stderr
    model = json.loads((out / "summary.json").read_text())["model"]
    assert model["max_displacement_gradient"] > 0.3 and model["max_cell_strain"] > 0.15
    assert [f"gelcell: warning: {w}" for w in model["warnings"]] == warned
