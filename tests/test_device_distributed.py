"""The device with its participants in separate process groups (``[coupling] distribute``).

The 2D shear device with a cell (mesh size 3), parallel- and serial-implicit,
distributed "fluid:1,gel+cell:1" on 2 ranks and "fluid:1,gel+cell:2" on 3
(the gel and the cell on 2 ranks of their own) against one process: the same
iterations, interface data and fields (to 1e-10).  ``gelcell run
--distribute`` on 2 ranks writes the outputs of the run without it (every
number of summary.json to 1e-10, the same files and field values), and so
does a time-dependent run, also when it is stopped and resumed.  Bad
``distribute`` values are refused before meshing, naming the key and the
allowed forms.
"""

from __future__ import annotations

import os
import subprocess
import sys

import h5py
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


@pytest.fixture(scope="module")
def one_process():
    return run_mpi("device_distributed.py", 1, ["single"])


@pytest.mark.parametrize("ranks, spec", [(2, "fluid:1,gel+cell:1"), (3, "fluid:1,gel+cell:2")],
                         ids=["1+1 ranks", "1+2 ranks"])
def test_distributed_device_gives_the_one_process_answer(one_process, ranks, spec):
    distributed = run_mpi("device_distributed.py", ranks, [spec])
    assert distributed["ranks"] == ranks
    for scheme in ("parallel", "serial"):
        one, two = one_process["schemes"][scheme], distributed["schemes"][scheme]
        assert one["converged"] and two["converged"]
        assert two["iterations"] == one["iterations"], scheme
        assert set(two["data"]) == set(one["data"])
        for name, values in one["data"].items():
            assert _relative(two["data"][name], values) <= 1e-10, (scheme, name)
        for name, norm in one["fields"].items():
            assert abs(two["fields"][name] - norm) <= 1e-10 * abs(norm), (scheme, name)


#: summary.json keys that differ between any two runs (timing, memory) or say how it was distributed
RUN_SPECIFIC = {"timing", "cost", "distribute"}
#: round-off-sized residuals (~1e-12, different in two runs of one case): compared to 1e-12 absolute
ROUND_OFF = ("residual_history", "interface_residuals")


def _summary_differences(a, b, path: str = "") -> list[str]:
    """Where two summary.json trees differ: other keys or strings, numbers beyond 1e-10 relative."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) - RUN_SPECIFIC != set(b) - RUN_SPECIFIC:
            return [f"{path}: keys {sorted(set(a) ^ set(b))}"]
        return [d for k in a if k not in RUN_SPECIFIC for d in _summary_differences(a[k], b[k], f"{path}/{k}")]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _summary_differences(x, y, f"{path}[{i}]")]
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (a, b))
    if not numbers:
        return [] if a == b else [f"{path}: {a!r} != {b!r}"]
    tol = 1e-12 if any(k in path for k in ROUND_OFF) else 1e-10 * abs(b)
    return [] if abs(a - b) <= tol else [f"{path}: {a!r} != {b!r}"]


def _h5_differences(one, two) -> list[str]:
    """Every dataset of two HDF5 files: the same shape, floats to 1e-10 of the largest value."""
    out = []
    with h5py.File(one, "r") as f, h5py.File(two, "r") as g:
        names = []
        f.visit(lambda n: names.append(n) if isinstance(f[n], h5py.Dataset) else None)
        for name in names:
            x, y = f[name][()], g[name][()]
            if x.shape != y.shape or np.abs(x - y).max(initial=0.0) > 1e-10 * np.abs(y).max(initial=1.0):
                out.append(f"{os.path.basename(one)}:{name}")
    return out


def test_cli_distributed_run_writes_the_outputs_of_the_run_without(tmp_path):
    args = ["run", "shear", "--mesh-size", "3", "--no-figures"]
    plain = run_mpi("cli_run.py", 2, args + ["--out", str(tmp_path / "plain")])
    spread = run_mpi("cli_run.py", 2, args + ["--distribute", "fluid:1,gel+cell:1", "--out", str(tmp_path / "spread")])
    assert plain["rc"] == spread["rc"] == 0 and spread["ranks"] == 2
    one, two = plain["summary"], spread["summary"]
    assert two["coupling"]["distribute"] == "fluid:1,gel+cell:1" and one["coupling"]["distribute"] is None
    assert one["coupling"]["converged"] and one["files"] == two["files"]
    assert _summary_differences(two, one) == []
    files = sorted(p.relative_to(tmp_path / "plain") for p in (tmp_path / "plain").rglob("*"))
    assert files == sorted(p.relative_to(tmp_path / "spread") for p in (tmp_path / "spread").rglob("*"))
    h5 = [f for f in files if f.suffix == ".h5"]
    assert len(h5) >= 4         # fluid, gel, cell and the Gamma1 profiles
    assert [d for f in h5 for d in _h5_differences(tmp_path / "spread" / f, tmp_path / "plain" / f)] == []


def test_distributed_time_dependent_run_and_its_resume_give_the_answer_without(tmp_path):
    """Adaptive BDF2 over half a consolidation time on 2 ranks: distributed equals every field on every
    rank, and a distributed run stopped in its 4th window and resumed from its checkpoint (each group
    saves and restores its own participants' states) equals the uninterrupted one, each to 1e-9 of the
    largest value of every physical column (the coupling tolerance, as tests/test_transient_cli.py)."""
    runs = run_mpi("transient_distributed.py", 2, [str(tmp_path)])
    assert runs["ranks"] == 2 and runs["checkpoint_windows"] >= 1
    physical = [c for c in runs["plain"] if c not in ("iterations", "residual")]
    for name, reference in (("distributed", "plain"), ("resumed", "distributed")):
        one, two = runs[reference], runs[name]
        assert len(two["t"]) == len(one["t"]) > runs["checkpoint_windows"] + 2, (name, two["t"], one["t"])
        for column in physical:
            a, b = np.asarray(two[column]), np.asarray(one[column])
            assert np.abs(a - b).max() <= 1e-9 * max(np.abs(b).max(), 1e-300), (name, column)


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
