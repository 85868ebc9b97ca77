"""Every expected failure ends with one line on stderr and its own exit code (issue 12 item 2).

The command-line tests run gelcell as a subprocess (serial only); most of them
fail before anything is meshed.  The mapping itself (gelcell.errors) is tested
in-process.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
import types

import pytest

from coupling.errors import CouplingDivergedError, CouplingNotConvergedError
from femtools.errors import NewtonError, OutputError, SingularSystemError
from gelcell.errors import (EXIT_CODES, Interrupted, ModelLimitError, SweepError, exit_code, message,
                            root_cause)
from gelcell.errors import ParameterError

serial_cli = pytest.mark.skip_in_parallel


def gelcell(*args, cwd=None):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "gelcell.cli", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=600)


def error_line(proc, command: str) -> str:
    """The one line on stderr (warnings aside), checked to be gelcell's error line."""
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 1 and lines[0].startswith(f"gelcell {command}: error: "), proc.stderr
    return lines[0]


# ------------------------------------------------------------------ before meshing
@serial_cli
@pytest.mark.parametrize("args, code, words", [
    (["run", "--config", "{typo}", "--out", "o"], 2, ["[coupling]", "max_iteratons", "max_iterations"]),
    (["study", "--quick", "--max-iterations", "0", "--out", "o"], 2, ["--max-iterations", "at least 1"]),
    (["sweep", "shear", "--param", "ca", "--values", "1e-9", "2e-9", "1e-9", "--out", "o"], 2,
     ["ca=1e-09", "more than once"]),
    (["run", "shear", "--ca", "1e300", "--out", "o"], 4, ["Ca = 1e+300", "cannot be represented", "1.5e-146"]),
    (["run", "shear", "--ca", "1e-300", "--out", "o"], 4, ["Ca = 1e-300", "cannot be represented"]),
    (["run", "shear", "--mesh-size", "1e-4", "--out", "o"], 4, ["elements", "GiB", "--mesh-size 0."]),
    (["mesh", "normal", "--mesh-size", "1e-4", "--out", "o"], 4, ["elements", "GiB"]),
], ids=["coupling-typo", "study-max-iterations", "sweep-duplicates", "ca-overflow", "ca-underflow",
        "mesh-too-large", "mesh-command-too-large"])
def test_refused_before_meshing(tmp_path, args, code, words):
    typo = tmp_path / "typo.toml"
    typo.write_text('[case]\nname = "shear"\n[coupling]\nmax_iteratons = 5\n')
    proc = gelcell(*[a.format(typo=typo) for a in args], cwd=tmp_path)
    assert proc.returncode == code, proc.stderr
    line = error_line(proc, args[0])
    for word in words:
        assert word in line
    assert proc.stdout == "" and not (tmp_path / "o").exists()


@serial_cli
def test_debug_adds_the_traceback(tmp_path):
    proc = gelcell("--debug", "run", "shear", "--ca", "1e300", "--out", "o", cwd=tmp_path)
    assert proc.returncode == 4
    assert "Traceback" in proc.stderr and "ModelLimitError" in proc.stderr
    assert proc.stderr.rstrip().splitlines()[-1].startswith("gelcell run: error: Ca = 1e+300")


# ------------------------------------------------------------------ while solving
@serial_cli
@pytest.mark.parametrize("args, code, words", [
    (["--config", "{diverging}", "--acceleration", "none", "--gamma2", "dirichlet"], 5,
     ["coupling diverged", "Gamma2/force", "--acceleration iqn-ils"]),
    (["--config", "{few}"], 6, ["did not converge in 2 iterations", "raise max_iterations"]),
    (["--ca", "1e-3"], 8, ["gel: Newton's method failed", "lower Ca", "--gel-moduli X divides it"]),
], ids=["diverged", "not-converged", "newton"])
def test_solver_failures(tmp_path, args, code, words):
    cases = {"few": "max_iterations = 2", "diverging": "divergence_factor = 100"}   # stop early
    for name, line in cases.items():
        (tmp_path / f"{name}.toml").write_text(f'[case]\nname = "shear"\n[coupling]\n{line}\n')
    args = [a.format(**{k: tmp_path / f"{k}.toml" for k in cases}) for a in args]
    case = [] if "--config" in args else ["shear"]
    proc = gelcell("run", *case, *args, "--mesh-size", "3", "--no-figures", "--quiet", "--out", "o",
                   cwd=tmp_path)
    assert proc.returncode == code, proc.stderr
    line = error_line(proc, "run")
    for word in words:
        assert word in line
    assert sorted(os.listdir(tmp_path)) == ["diverging.toml", "few.toml"]   # nothing written or left over


@serial_cli
def test_sweep_keeps_completed_runs(tmp_path):
    """One failing value: the other is written, the failure reported, the exit status 9."""
    out = tmp_path / "sweep"
    proc = gelcell("sweep", "shear", "--no-cell", "--param", "ca", "--values", "3e-10", "1e-3",
                   "--mesh-size", "6", "--quiet", "--out", str(out))
    assert proc.returncode == 9, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[0].startswith("gelcell sweep: ca=0.001 failed: gel: Newton's method failed")
    assert lines[-1].startswith("gelcell sweep: error: 1 of 2 values failed (ca=0.001")
    assert "Traceback" not in proc.stderr
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [(r["ca"], r["status"]) for r in rows] == [("3e-10", "ok"), ("0.001", "failed")]
    assert "Newton" in rows[1]["error"] and rows[0]["converged"] == "True"
    assert json.loads((out / "runs" / "ca=3e-10" / "summary.json").read_text())["coupling"]["converged"]
    assert not (out / "runs" / "ca=0.001").exists()
    # the paths printed are the final ones, never the temporary directory's
    assert f"wrote {out}/runs/ca=3e-10:" in proc.stdout and f"wrote {out}:" in proc.stdout
    assert ".tmp-" not in proc.stdout + proc.stderr


# ------------------------------------------------------------------ the mapping
def _diverged(growth: float, cause: BaseException | None) -> CouplingDivergedError:
    records = [types.SimpleNamespace(residual_norms={"Gamma1/traction": 1.0}),
               types.SimpleNamespace(residual_norms={"Gamma1/traction": growth})]
    result = types.SimpleNamespace(windows=[types.SimpleNamespace(records=records)], iterations=2)
    exc = CouplingDivergedError("coupling diverged in the steady solve: participant 'gel' failed in iteration 2 "
                                "(...); residual norms of 'Gamma1/traction': [1, 2]", result)
    exc.__cause__ = cause
    return exc


def test_every_expected_failure_has_its_own_exit_code():
    codes = [code for _, code in EXIT_CODES]
    assert len(set(codes)) == len(codes) and 0 not in codes and 1 not in codes
    newton = NewtonError("cell", "the iterate contains NaN or Inf at iteration 3", [1.0, 2.0])
    cases = [(ParameterError("bad\nworse"), 2), (OutputError("refused"), 3), (ModelLimitError("big"), 4),
             (_diverged(1e5, newton), 5), (CouplingNotConvergedError("slow", None), 6),
             (SingularSystemError("gel", 2), 7), (newton, 8), (SweepError("1 of 2", []), 9),
             (Interrupted(15), 143), (Interrupted(2), 130), (KeyboardInterrupt(), 130),
             (RuntimeError("a bug"), 1)]
    for exc, code in cases:
        assert exit_code(exc) == code, exc
        text = message(exc)
        assert "\n" not in text and text, exc
    assert message(ParameterError("bad\nworse")) == "bad; worse"
    assert "internal error: RuntimeError: a bug" in message(RuntimeError("a bug"))


def test_a_participant_failure_is_reported_by_its_cause():
    """Singular: always the cause.  Newton: the cause unless the coupling residual grew first."""
    singular = SingularSystemError("gel", 1).add_hint("the network is not anchored")
    assert root_cause(_diverged(1e5, singular)) is singular
    assert exit_code(_diverged(1e5, singular)) == 7 and "not anchored" in message(_diverged(1e5, singular))
    newton = NewtonError("gel", "the Jacobian became singular (8 null pivots) at the current iterate", [])
    assert exit_code(_diverged(1.01, newton)) == 8
    assert message(_diverged(1.01, newton)).startswith("gel: Newton's method failed")
    grown = message(_diverged(1e5, newton))
    assert exit_code(_diverged(1e5, newton)) == 5
    assert "grew x1e+05" in grown and "gel solver failed" in grown and "--acceleration" in grown
    assert "residual norms" not in message(_diverged(1e5, None))


# ------------------------------------------------------------------ quiet output (item 7)
@serial_cli
@pytest.mark.parametrize("debug", [False, True])
def test_compiler_lines_only_with_debug(tmp_path, debug):
    """A form compiled on a cold cache: the C compiler's log lines appear only at debug level."""
    script = (f"from gelcell.cli import configure_logging; configure_logging({debug})\n"
              "from mpi4py import MPI; import ufl; from dolfinx import fem, mesh\n"
              "m = mesh.create_unit_square(MPI.COMM_SELF, 1, 1); V = fem.FunctionSpace(m, ('Lagrange', 1))\n"
              "fem.form(ufl.TrialFunction(V) * ufl.TestFunction(V) * ufl.dx)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, XDG_CACHE_HOME=str(tmp_path)))     # nothing cached
    assert proc.returncode == 0, proc.stderr
    assert ("gcc" in proc.stderr) == debug, proc.stderr
    assert ("INFO" in proc.stderr) == debug


# ------------------------------------------------------------------ issue 28: expected failures, bounded reads
MARKERLESS = "# a document\nno coupling-study markers here\n"


def _inputs(tmp_path) -> dict:
    """Hostile and unlucky input files of the issue-28 tests, by name."""
    files = {"binary.toml": b"\x00\x01\xff\xfe binary", "utf16.toml": "[mesh]\nsize_factor = 3\n".encode("utf-16"),
             "binary.csv": b"\x00\x01\xff\xfe binary", "utf16.csv": "t,f\n0,1\n1,1\n".encode("utf-16"),
             "order.toml": b'[case]\nname = "shear"\n[coupling]\norder = ["gel", "fluid"]\n',
             "markerless.md": MARKERLESS.encode()}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    return {name.replace(".", "_"): tmp_path / name for name in files}


@serial_cli
@pytest.mark.parametrize("args, code, words", [
    (["run", "shear", "--config", "{binary_toml}"], 2, ["case file", "not UTF-8"]),
    (["run", "shear", "--config", "{utf16_toml}"], 2, ["case file", "not UTF-8"]),
    (["run", "shear", "--transient", "--inflow", "table:{binary_csv}"], 2, ["inflow", "not UTF-8"]),
    (["run", "shear", "--transient", "--inflow", "table:{utf16_csv}"], 2, ["inflow", "not UTF-8"]),
    (["run", "--config", "{order_toml}"], 2, ["[coupling]", "order", "misses participants ['cell']"]),
    (["study", "--quick", "--update-table", "{markerless_md}"], 2, ["--update-table", "coupling-study markers"]),
    (["study", "--quick", "--update-readme", "{markerless_md}"], 2, ["--update-table", "coupling-study markers"]),
    (["run", "shear", "--config", "/dev/zero"], 2, ["/dev/zero", "not a regular file"]),
    (["run", "shear", "--transient", "--inflow", "table:/dev/zero"], 2, ["inflow", "/dev/zero",
                                                                         "not a regular file"]),
    (["run", "shear", "--gel-moduli", "1e-12"], 4, ["1e+12 times as stiff as the gel", "[1e-06, 1e+06]"]),
    (["run", "shear", "--cell-moduli", "1e9"], 4, ["1e+09 times as stiff as the gel", "[1e-06, 1e+06]"]),
], ids=["binary-case-file", "utf16-case-file", "binary-table", "utf16-table", "coupling-order",
        "update-table-markers", "update-readme-markers", "config-dev-zero", "table-dev-zero", "gel-moduli-tiny",
        "cell-moduli-huge"])
def test_issue28_refused_before_meshing(tmp_path, args, code, words):
    """Items 10, 14, 15: one line and the exit code of the input's fault, before anything is meshed."""
    files = _inputs(tmp_path)
    proc = gelcell(*[a.format(**files) for a in args], "--out", "o", cwd=tmp_path)
    assert proc.returncode == code, proc.stderr
    line = error_line(proc, args[0])
    for word in words:
        assert word in line, line
    assert proc.stdout == "" and not (tmp_path / "o").exists()
    assert (tmp_path / "markerless.md").read_text() == MARKERLESS


def test_the_inflow_table_is_bounded(tmp_path, monkeypatch):
    from gelcell.case import inflow
    big = tmp_path / "big.csv"
    big.write_text("t,f\n0,1\n1,1\n")
    monkeypatch.setattr(inflow, "MAX_TABLE_BYTES", 8)
    with pytest.raises(ParameterError, match="more than the 8 allowed"):
        inflow.parse_inflow(f"table:{big}")


def _interrupted_run(out, checkpoint: bytes | None = None, ranks: int | None = None) -> None:
    """``out.partial/`` as an interrupted time-dependent run leaves it, with the given checkpoint."""
    from coupling.serialization import save_npz
    partial = out.parent / f"{out.name}.partial"
    partial.mkdir()
    (partial / "case.toml").write_text('[case]\nname = "shear"\n[mesh]\nsize_factor = 3.0\n[time]\n'
                                       'transient = true\n')
    if checkpoint is not None:
        (partial / "checkpoint.npz").write_bytes(checkpoint)
    else:
        save_npz(partial / "checkpoint.npz", {"format": "coupling-checkpoint", "ranks": ranks})


@serial_cli
@pytest.mark.parametrize("kind, words", [
    ("truncated", ["cannot be read", "damaged or truncated"]),
    ("two-ranks", ["written on 2 MPI rank(s)", "mpirun -n 2", "this run has 1"]),
])
def test_issue28_resume_refuses_a_checkpoint_it_cannot_use(tmp_path, kind, words):
    """Item 10: a truncated checkpoint, or one of another rank count, is bad input (2), before meshing."""
    out = tmp_path / "run"
    _interrupted_run(out, checkpoint=b"PK\x03\x04 truncated" if kind == "truncated" else None, ranks=2)
    proc = gelcell("run", "--resume", str(out), "--no-figures", "--quiet", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    line = error_line(proc, "run")
    for word in words:
        assert word in line, line
    assert proc.stdout == "" and not out.exists()


@serial_cli
def test_issue28_max_windows_reached(tmp_path):
    """Item 10: the run's window budget is a limit of the run (4), not an internal error."""
    (tmp_path / "case.toml").write_text('[case]\nname = "shear"\n[time]\ntransient = true\nmax_windows = 1\n')
    proc = gelcell("run", "--config", "case.toml", "--mesh-size", "3", "--no-figures", "--quiet", "--out", "o",
                   cwd=tmp_path)
    assert proc.returncode == 4, proc.stderr
    line = error_line(proc, "run")
    assert "1 windows (time.max_windows) reached" in line and "raise max_windows" in line
    assert not (tmp_path / "o").exists()


@serial_cli
def test_issue28_an_unusable_cache_directory_is_skipped_with_a_warning(tmp_path):
    """Item 10: XDG_CACHE_HOME naming a file: the caches are skipped with a warning, the run succeeds."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    env = dict(os.environ, MPLBACKEND="Agg", XDG_CACHE_HOME=str(blocker))
    for key in ("GELCELL_CACHE_DIR", "GELCELL_PRIOR_CACHE_DIR"):
        env.pop(key, None)
    proc = subprocess.run([sys.executable, "-m", "gelcell.cli", "run", "shear", "--no-cell", "--mesh-size", "3",
                           "--no-figures", "--quiet", "--out", "o"], capture_output=True, text=True, env=env,
                          cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and "error" not in proc.stderr
    assert "form compiler's cache" in proc.stderr and "cannot be written" in proc.stderr
    assert (tmp_path / "o" / "summary.json").exists()


def test_writable_directory(tmp_path):
    from femtools import jitcache
    (tmp_path / "a-file").write_text("")
    assert not jitcache.writable_directory(str(tmp_path / "a-file" / "fenics"))
    assert jitcache.writable_directory(str(tmp_path / "fine"))


# ------------------------------------------------------------------ issue 28 item 9: one rank fails
@serial_cli
@pytest.mark.parametrize("failing", ["rank0-ca-nan", "rank1-relative-case-file"])
def test_issue28_a_failure_on_one_rank_ends_every_rank(tmp_path, failing):
    """Under ``mpirun -n 2`` (one program per rank) only one rank fails: the job ends within seconds
    with that rank's one error line and a nonzero exit, where it used to hang."""
    from mpi_run import mpirun_available
    if not mpirun_available():
        pytest.skip("mpirun not available")
    for rank in (0, 1):
        (tmp_path / f"w{rank}").mkdir()
    (tmp_path / "w0" / "case.toml").write_text('[case]\nname = "shear"\n[mesh]\nsize_factor = 3\n')
    common = ["--config", "case.toml", "--no-figures", "--quiet", "--out", str(tmp_path / "o")]
    ranks = ([["--ca", "nan"], []] if failing == "rank0-ca-nan" else [[], []])
    cmd = ["mpirun"]
    for rank, extra in enumerate(ranks):
        wdir = tmp_path / ("w0" if failing == "rank0-ca-nan" else f"w{rank}")   # w1 has no case.toml
        cmd += ([":"] if rank else []) + ["-n", "1", "-wdir", str(wdir), sys.executable, "-m", "gelcell.cli",
                                          "run", *common, *extra]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMPI_MCA_mpi_yield_when_idle="1", MPLBACKEND="Agg")
    started = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    elapsed = time.monotonic() - started
    lines = [line for line in proc.stderr.splitlines() if line.startswith("gelcell run: error: ")]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    rank = 0 if failing == "rank0-ca-nan" else 1
    words = ["parameter 'ca' = nan"] if rank == 0 else ["cannot read case file 'case.toml'"]
    for word in words + [f"on rank {rank} of 2 only: aborting the job"]:
        assert word in lines[0], lines[0]
    assert elapsed < 60, elapsed
    assert not (tmp_path / "o").exists()
