"""The device with its participants in separate process groups (``[coupling] distribute``).

The 2D shear device with a cell (mesh size 3), parallel- and serial-implicit,
distributed "fluid:1,gel+cell:1" on 2 ranks against one process: the same
iterations, interface data and fields (to 1e-10).  Bad ``distribute`` values
are refused before meshing, naming the key and the allowed forms.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from mpi4py import MPI

import gelcell.coupled.device as device_module
from gelcell.case import CaseParameters
from gelcell.coupled.defaults import partitioned_config
from gelcell.errors import ParameterError
from mpi_run import run_mpi

ALLOWED = "expected 'name[+name...][:ranks],...'"


def _relative(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def test_distributed_device_gives_the_one_process_answer():
    single = run_mpi("device_distributed.py", 1, ["single"])
    distributed = run_mpi("device_distributed.py", 2, ["distributed"])
    assert distributed["ranks"] == 2
    for scheme in ("parallel", "serial"):
        one, two = single["schemes"][scheme], distributed["schemes"][scheme]
        assert one["converged"] and two["converged"]
        assert two["iterations"] == one["iterations"], scheme
        assert set(two["data"]) == set(one["data"])
        for name, values in one["data"].items():
            assert _relative(two["data"][name], values) <= 1e-10, (scheme, name)
        for name, norm in one["fields"].items():
            assert abs(two["fields"][name] - norm) <= 1e-10 * abs(norm), (scheme, name)


@pytest.mark.parametrize("spec, message", [
    ("fluid:x,gel+cell", "rank count 'x'"),
    ("fluid,gel", r"participants \['cell'\] are in no group"),
    ("fluid,gel+cell+solid", r"unknown participants \['solid'\]"),
    ("fluid+gel,gel+cell", r"names \['gel'\] more than once"),
])
def test_bad_distribute_is_refused_naming_the_key(spec, message):
    params = CaseParameters.default("shear", True).with_mesh_size(3)
    with pytest.raises(ParameterError, match=message) as info:
        partitioned_config(params, {"distribute": spec})
    assert "coupling.distribute" in str(info.value) and ALLOWED in str(info.value)


def test_distribute_that_does_not_fit_the_ranks_stops_before_meshing(monkeypatch):
    def no_meshing(*args, **kwargs):
        raise AssertionError("meshed before the distribute setting was checked")
    monkeypatch.setattr(device_module, "build_meshes", no_meshing)
    params = CaseParameters.default("shear", True).with_mesh_size(3)
    with pytest.raises(ParameterError, match=r"coupling.distribute = 'fluid:1,gel\+cell:2' needs 3 ranks"):
        device_module.Device(params, MPI.COMM_SELF, distribute="fluid:1,gel+cell:2")


@pytest.mark.skipif("OMPI_COMM_WORLD_SIZE" in os.environ, reason="runs the CLI as a subprocess")
def test_cli_refuses_bad_distribute_before_meshing(tmp_path):
    out = tmp_path / "bad"
    proc = subprocess.run([sys.executable, "-m", "gelcell.cli", "run", "shear", "--distribute", "fluid:0,gel+cell",
                           "--out", str(out)], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 2
    assert "coupling.distribute" in proc.stderr and ALLOWED in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()
