"""gelcell never deletes what it did not write, replaces its results atomically, and leaves nothing
behind on failure or interruption (femtools.io, issue 12 item 1).

The unit tests use MPI.COMM_SELF (each rank its own temporary directory); the
command-line tests run gelcell as a subprocess and are serial only.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap

import pytest

from mpi4py import MPI

import femtools.io as fio
from femtools.io import MARKER, OutputError, atomic_directory, check_output_target, deferred_signals
from gelcell.errors import Interrupted, install_signal_handlers
from paused_cli import paused_gelcell, signal_when_paused

SELF = MPI.COMM_SELF


def leftovers(parent) -> list[str]:
    return sorted(n for n in os.listdir(parent) if n.startswith((".tmp-", ".old-", ".gelcell-probe-")))


def make_output(path, text: str) -> None:
    """A directory gelcell wrote, holding result.txt = text."""
    with atomic_directory(str(path), SELF) as tmp:
        with open(os.path.join(tmp, "result.txt"), "w") as f:
            f.write(text)


def read(path) -> str:
    with open(os.path.join(path, "result.txt")) as f:
        return f.read()


# ------------------------------------------------------------------ refusals
@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A working directory with a user's directory and a user's file in it."""
    (tmp_path / "thesis").mkdir()
    (tmp_path / "thesis" / "chapter1.tex").write_text("years of work")
    (tmp_path / "notes.txt").write_text("notes")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("out, why", [
    ("", "empty string"),
    (".", "current directory"),
    ("..", "current directory or contains it"),
    ("thesis", "did not write"),
    ("notes.txt", "existing file"),
    ("notes.txt/run", "is a file"),
])
def test_refuses_what_gelcell_did_not_write(workdir, out, why):
    with pytest.raises(OutputError, match=why):
        check_output_target(out, SELF)
    with pytest.raises(OutputError, match=why):
        with atomic_directory(out, SELF):
            pytest.fail("the block must not run")
    assert (workdir / "thesis" / "chapter1.tex").read_text() == "years of work"
    assert (workdir / "notes.txt").read_text() == "notes"
    assert leftovers(workdir) == []


def test_refuses_a_symbolic_link(workdir):
    make_output(workdir / "real", "old")
    os.symlink(workdir / "real", workdir / "link")
    with pytest.raises(OutputError, match="symbolic link"):
        check_output_target("link", SELF)


def unwritable_directory(tmp_path) -> str:
    """A directory this process cannot create entries in (root ignores permissions: /sys, /proc)."""
    if os.geteuid() != 0:
        os.mkdir(tmp_path / "ro", 0o555)
        return str(tmp_path / "ro")
    for candidate in ("/sys", "/proc"):
        try:
            os.rmdir(tempfile.mkdtemp(dir=candidate))
        except OSError:
            return candidate
    pytest.skip("no unwritable directory on this machine")


def test_refuses_an_unwritable_parent(tmp_path):
    with pytest.raises(OutputError, match="not writable"):
        check_output_target(os.path.join(unwritable_directory(tmp_path), "gelcell-out", "run"), SELF)


def test_accepts_new_empty_and_own_directories(workdir):
    for out in ("new/nested/run", "thesis/run"):
        assert check_output_target(out, SELF) == os.path.abspath(out)
    (workdir / "empty").mkdir()
    check_output_target("empty", SELF)
    make_output(workdir / "mine", "v1")
    check_output_target("mine", SELF)
    info = json.loads((workdir / "mine" / MARKER).read_text())
    assert info["tool"] == "gelcell" and {"version", "command", "created"} <= set(info)


# ------------------------------------------------------------------ atomic replacement
def test_replaces_its_own_results(tmp_path):
    out = tmp_path / "run"
    make_output(out, "old")
    make_output(out, "new")
    assert read(out) == "new" and (out / MARKER).is_file()
    assert oct(out.stat().st_mode & 0o777) == oct(0o755)
    assert leftovers(tmp_path) == []


def test_failure_in_the_block_keeps_the_old_results(tmp_path):
    out = tmp_path / "run"
    make_output(out, "old")
    with pytest.raises(RuntimeError, match="solver failed"):
        with atomic_directory(str(out), SELF) as tmp:
            open(os.path.join(tmp, "result.txt"), "w").write("half")
            raise RuntimeError("solver failed")
    assert read(out) == "old"
    assert leftovers(tmp_path) == []


def test_failure_while_moving_the_new_results_in_restores_the_old(tmp_path, monkeypatch):
    """The new directory cannot be renamed in: the old results go back, nothing is left over."""
    out = tmp_path / "run"
    make_output(out, "old")
    real_replace = os.replace

    def replace(src, dst):
        if os.path.basename(str(src)).startswith(".tmp-"):
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(fio.os, "replace", replace)
    with pytest.raises(OutputError, match="previous contents .* are unchanged"):
        make_output(out, "new")
    assert read(out) == "old"
    assert leftovers(tmp_path) == []


def test_failure_while_deleting_the_old_results_keeps_the_new(tmp_path, monkeypatch, caplog):
    """Deleting the old directory fails half-way: the new results are already in place."""
    out = tmp_path / "run"
    make_output(out, "old")
    real_rmtree = shutil.rmtree

    def rmtree(path, *args, **kwargs):
        if os.path.basename(str(path)).startswith(".old-"):
            os.remove(os.path.join(path, "result.txt"))        # part of it is gone
            raise OSError(13, "Permission denied", str(path))
        return real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(fio.shutil, "rmtree", rmtree)
    make_output(out, "new")
    assert read(out) == "new"
    assert "could not be deleted" in caplog.text
    assert [n for n in leftovers(tmp_path) if not n.startswith(".old-")] == []


def test_the_target_is_checked_again_before_it_is_replaced(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(OutputError, match="did not write"):
        with atomic_directory(str(out), SELF) as tmp:
            out.mkdir()
            (out / "user.txt").write_text("placed there during the run")
            open(os.path.join(tmp, "result.txt"), "w").write("new")
    assert (out / "user.txt").read_text() == "placed there during the run"
    kept = leftovers(tmp_path)
    assert len(kept) == 1 and read(tmp_path / kept[0]) == "new"     # the new results are not lost


# ------------------------------------------------------------------ partial (time-dependent runs)
def test_partial_directory_survives_failure_and_is_promoted_on_success(tmp_path):
    out = tmp_path / "run"
    partial = tmp_path / ("run" + fio.PARTIAL_SUFFIX)
    make_output(out, "old")
    with pytest.raises(RuntimeError):
        with atomic_directory(str(out), SELF, partial=True) as work:
            assert work == str(partial) and (partial / MARKER).is_file()
            open(os.path.join(work, "checkpoint"), "w").write("step 7")
            raise RuntimeError("interrupted")
    assert (partial / "checkpoint").read_text() == "step 7" and read(out) == "old"
    with atomic_directory(str(out), SELF, partial=True) as work:        # --resume
        assert open(os.path.join(work, "checkpoint")).read() == "step 7"
        open(os.path.join(work, "result.txt"), "w").write("new")
    assert read(out) == "new" and (out / "checkpoint").is_file() and (out / MARKER).is_file()
    assert not partial.exists() and leftovers(tmp_path) == []


def test_partial_directory_without_marker_is_refused(tmp_path):
    partial = tmp_path / ("run" + fio.PARTIAL_SUFFIX)
    partial.mkdir()
    (partial / "data").write_text("someone's")
    with pytest.raises(OutputError, match="did not write"):
        check_output_target(str(tmp_path / "run"), SELF, partial=True)
    check_output_target(str(tmp_path / "run"), SELF)        # not looked at without partial


# ------------------------------------------------------------------ signals
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_in_the_block_removes_the_temporary_directory(tmp_path, signum):
    out = tmp_path / "run"
    make_output(out, "old")
    with install_signal_handlers():
        with pytest.raises(Interrupted) as info:
            with atomic_directory(str(out), SELF) as tmp:
                open(os.path.join(tmp, "result.txt"), "w").write("half")
                signal.raise_signal(signum)
    assert info.value.signum == signum
    assert read(out) == "old" and leftovers(tmp_path) == []


def test_signals_are_held_while_the_directories_are_renamed():
    with install_signal_handlers():
        with pytest.raises(Interrupted):
            with deferred_signals():
                signal.raise_signal(signal.SIGTERM)
                held = True                     # reached: the signal waits for the block's end
        assert held


# ------------------------------------------------------------------ the command line
def gelcell(*args, cwd=None, env=None):
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1", **(env or {}))
    return subprocess.run([sys.executable, "-m", "gelcell.cli", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=600)


def one_error_line(proc, command="run") -> str:
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"gelcell {command}: error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


@pytest.mark.skip_in_parallel
@pytest.mark.parametrize("out, why", [("", "empty string"), (".", "current directory"),
                                      ("thesis", "did not write"), ("notes.txt", "existing file")])
def test_cli_refuses_before_meshing(workdir, out, why):
    proc = gelcell("run", "shear", "--mesh-size", "3", "--quiet", "--out", out, cwd=workdir)
    assert proc.returncode == 3, proc.stderr
    assert why in one_error_line(proc)
    assert proc.stdout == ""                                   # nothing was solved
    assert (workdir / "thesis" / "chapter1.tex").read_text() == "years of work"
    assert sorted(os.listdir(workdir)) == ["notes.txt", "thesis"]


@pytest.fixture
def old_results(tmp_path):
    """A gelcell output directory that a failed or interrupted run must leave untouched."""
    out = tmp_path / "out"
    make_output(out, "old")
    return out, sorted(os.listdir(out)), read(out)


@pytest.mark.skip_in_parallel
def test_cli_marks_and_replaces_its_own_output(old_results):
    out = old_results[0]
    proc = gelcell("mesh", "normal", "--no-cell", "--mesh-size", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    info = json.loads((out / MARKER).read_text())
    assert info["tool"] == "gelcell" and "mesh normal" in info["command"]
    assert (out / "fluid.xdmf").is_file() and not (out / "result.txt").exists()
    assert leftovers(out.parent) == []


@pytest.mark.skip_in_parallel
@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_cli_signal_while_solving_leaves_nothing_behind(old_results, signum, code):
    out, files, text = old_results
    # the signal arrives inside the gel's second solve: the coupling iterations have started
    proc = paused_gelcell(["run", "shear", "--mesh-size", "3", "--no-figures", "--out", str(out)])
    _, err = signal_when_paused(proc, signum, timeout=120)
    assert proc.returncode == code, err
    assert f"interrupted by {signal.Signals(signum).name}" in err and "Traceback" not in err
    assert sorted(os.listdir(out)) == files and read(out) == text
    assert leftovers(out.parent) == []


@pytest.mark.skip_in_parallel
def test_cli_sigterm_while_writing_leaves_nothing_behind(old_results):
    """SIGTERM arrives while the results are being written into the temporary directory."""
    out, files, text = old_results
    script = textwrap.dedent(f"""
        import os, signal, sys
        import gelcell.run.steady
        from gelcell.cli import main
        write_profiles = gelcell.run.steady.write_profiles
        def killed_while_writing(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGTERM)
            return write_profiles(*args, **kwargs)
        gelcell.run.steady.write_profiles = killed_while_writing
        sys.exit(main(["run", "shear", "--mesh-size", "3", "--no-figures", "--quiet", "--out", {str(out)!r}]))
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 143, proc.stderr
    assert "interrupted by SIGTERM" in one_error_line(proc)
    assert sorted(os.listdir(out)) == files and read(out) == text
    assert leftovers(out.parent) == []


# ------------------------------------------------------------------ issue 28
GEOMETRY = os.path.join(os.path.dirname(os.path.abspath(__file__)), "geometry_files", "small.geo")


def cli_main(*args) -> int:
    from gelcell import cli
    return cli.main(list(args))


def shared_output(shared_tmp_path, comm, name="D") -> str:
    """A gelcell output directory (its marker, result.txt), the same on every rank."""
    out = shared_tmp_path / name
    if comm.rank == 0:
        make_output(out, "old")
    comm.Barrier()
    return str(out)


INPUTS = {
    "config": (["run", "shear", "--config", "{D}/case.toml"], "case.toml", "[mesh]\nsize_factor = 3\n"),
    "config-below": (["run", "shear", "--config", "{D}/inputs/case.toml"], "inputs/case.toml",
                     "[mesh]\nsize_factor = 3\n"),
    "geometry": (["run", "--geometry", "{D}/device.geo", "--mesh-size", "3"], "device.geo", None),
    "inflow": (["run", "shear", "--transient", "--mesh-size", "3", "--t-end", "1e-7", "--inflow",
                "table:{D}/pump.csv"], "pump.csv", "t,f\n0,0\n1e-6,1\n"),
    "sweep": (["sweep", "shear", "--param", "ca", "--values", "1e-3", "2e-3", "--config", "{D}/case.toml"],
              "case.toml", "[mesh]\nsize_factor = 3\n"),
}


@pytest.mark.parametrize("kind", list(INPUTS))
def test_an_output_directory_holding_an_input_of_the_run_is_refused(shared_tmp_path, comm, cli_stderr, kind):
    """Issue 28 item 5: --out D with --config D/case.toml (or a geometry file, an inflow table, a sweep's
    case file) in D would delete the input when D is replaced: exit 3 before meshing, nothing deleted."""
    out = shared_output(shared_tmp_path, comm)
    args, name, text = INPUTS[kind]
    path = os.path.join(out, name)
    if comm.rank == 0:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        if text is None:
            shutil.copy(GEOMETRY, path)
        else:
            with open(path, "w") as f:
                f.write(text)
    comm.Barrier()
    before = sorted(os.listdir(out))
    extra = [] if args[0] == "sweep" else ["--no-figures"]
    assert cli_main(*[a.format(D=out) for a in args], *extra, "--quiet", "--out", out) == 3
    err = cli_stderr()
    assert "contains an input of this run" in err and name.split("/")[-1] in err, err
    assert sorted(os.listdir(out)) == before and read(out) == "old" and os.path.isfile(path)
    assert not os.path.exists(out + fio.PARTIAL_SUFFIX)


def test_an_input_next_to_the_output_directory_is_accepted(tmp_path):
    (tmp_path / "case.toml").write_text("[mesh]\nsize_factor = 3\n")
    inputs = [("--config", str(tmp_path / "case.toml"))]
    assert check_output_target(str(tmp_path / "run"), SELF, partial=True, inputs=inputs)
    os.symlink(tmp_path / "run", tmp_path / "link-to-run")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "pump.csv").write_text("t,f\n0,0\n1,1\n")
    with pytest.raises(OutputError, match="contains an input"):       # through a link into the directory
        check_output_target(str(tmp_path / "run"), SELF, inputs=[("--inflow table", str(tmp_path / "link-to-run"
                                                                                        / "pump.csv"))])


def test_a_too_long_output_name_is_refused_before_meshing(shared_tmp_path, comm, cli_stderr):
    """Issue 28 item 13: a name that fits but whose temporary sibling (.tmp-<name>-XXXXXXXX) does not is
    refused up front (exit 3), not after the case is solved; a name of the longest allowed length passes."""
    name_max = os.pathconf(str(shared_tmp_path), "PC_NAME_MAX")
    for partial in (False, True):
        with pytest.raises(OutputError, match="too long"):
            check_output_target(str(shared_tmp_path / ("r" * (name_max - 10))), SELF, partial=partial)
        check_output_target(str(shared_tmp_path / ("r" * (name_max - 14))), SELF, partial=partial)
    with pytest.raises(OutputError, match="too long"):          # a directory still to be created
        check_output_target(str(shared_tmp_path / ("d" * (name_max + 1)) / "run"), SELF)
    out = shared_tmp_path / ("a" * 245)
    assert cli_main("run", "shear", "--mesh-size", "3", "--no-figures", "--quiet", "--out", str(out)) == 3
    err = cli_stderr()
    assert "too long (245 bytes)" in err and f"at most {name_max - 14} bytes" in err, err
    assert not out.exists() and leftovers(shared_tmp_path) == []


def test_the_working_directory_of_an_interrupted_run_is_not_an_output(shared_tmp_path, comm, cli_stderr):
    """Issue 28 item 16: --out B.partial (an interrupted run's checkpoint) is refused, naming run B."""
    partial = shared_tmp_path / ("B" + fio.PARTIAL_SUFFIX)
    if comm.rank == 0:
        with pytest.raises(RuntimeError):
            with atomic_directory(str(shared_tmp_path / "B"), SELF, partial=True) as work:
                open(os.path.join(work, "checkpoint.npz"), "w").write("window 7")
                raise RuntimeError("interrupted")
    comm.Barrier()
    for out in (str(partial), str(partial) + os.sep):
        assert cli_main("run", "shear", "--mesh-size", "3", "--no-figures", "--quiet", "--out", out) == 3
        err = cli_stderr()
        assert "working directory (checkpoint) of the interrupted time-dependent run" in err, err
        assert f"--resume {shared_tmp_path / 'B'}" in err, err
    assert (partial / "checkpoint.npz").read_text() == "window 7"
    assert not os.path.exists(str(partial) + fio.PARTIAL_SUFFIX)


def test_a_partial_directory_is_locked_while_a_run_works_in_it(tmp_path):
    """Issue 28 item 8 (femtools.io): the lock of DIR.partial/ is held for the block and released after."""
    out = str(tmp_path / "run")
    with atomic_directory(out, SELF, partial=True) as work:
        info = json.loads(open(os.path.join(work, fio.LOCK_INFO)).read())
        assert info["pid"] == os.getpid()
        fd = os.open(work, os.O_RDONLY)                 # another descriptor: another open file description
        try:
            with pytest.raises(BlockingIOError):
                fio.fcntl.flock(fd, fio.fcntl.LOCK_EX | fio.fcntl.LOCK_NB)
        finally:
            os.close(fd)
        open(os.path.join(work, "result.txt"), "w").write("new")
    assert read(out) == "new" and not os.path.exists(os.path.join(out, fio.LOCK_INFO))
    check_output_target(out, SELF, partial=True)


@pytest.mark.skip_in_parallel
def test_cli_a_second_run_on_the_same_out_is_refused_naming_the_first(tmp_path):
    """Issue 28 item 8: while a time-dependent run works in DIR.partial/, a second run on DIR (new,
    resumed or steady) exits 3 naming the first (pid, command); the first's checkpoint is intact."""
    out = tmp_path / "run"
    common = ["run", "shear", "--transient", "--mesh-size", "3", "--dt", "1.5e-7", "--t-end", "4.5e-7",
              "--no-figures", "--quiet"]
    first = paused_gelcell(common + ["--out", str(out)],
                           target="gelcell.coupled.participants.GelParticipant.begin_window", call=3)
    try:
        for line in first.stdout:
            if line.strip() == "PAUSED":
                break
        for args in (common + ["--out", str(out) + os.sep], ["run", "--resume", str(out)],
                     ["run", "shear", "--mesh-size", "3", "--out", str(out)]):
            proc = gelcell(*args)
            assert proc.returncode == 3, proc.stderr
            line = one_error_line(proc)
            assert "is in use by another gelcell run" in line and f"pid {first.pid} " in line, line
            assert proc.stdout == ""
        assert sorted(os.listdir(tmp_path)) == ["run.partial"]
        assert (tmp_path / "run.partial" / "checkpoint.npz").is_file()
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=120)
    assert first.returncode == 143
    assert not (tmp_path / "run.partial" / fio.LOCK_INFO).exists()


@pytest.mark.skip_in_parallel
def test_cli_full_disk_during_a_time_dependent_run(tmp_path):
    """Issue 28 item 11: the disk fills while the 3rd checkpoint is written (a writer that raises ENOSPC
    after some bytes): one line saying so, exit 3, no traceback, no checkpoint.npz.tmp left behind; the
    last complete checkpoint is kept."""
    out = tmp_path / "run"
    script = textwrap.dedent(f"""
        import builtins, errno, os, sys
        import coupling.serialization as serialization
        from gelcell.cli import main
        calls = [0]
        class FullDisk:
            def __init__(self, fh):
                self.fh = fh
            def write(self, data):
                self.fh.write(bytes(data)[:100])
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            def __enter__(self):
                return self
            def __exit__(self, *exc):
                self.fh.close()
        def full_open(path, mode="r", *args, **kwargs):
            fh = builtins.open(path, mode, *args, **kwargs)
            if str(path).endswith("checkpoint.npz.tmp"):
                calls[0] += 1
                if calls[0] == 3:
                    return FullDisk(fh)
            return fh
        serialization.open = full_open
        sys.exit(main(["run", "shear", "--transient", "--mesh-size", "3", "--dt", "1.5e-7", "--t-end", "4.5e-7",
                       "--no-figures", "--quiet", "--out", {str(out)!r}]))
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 3, proc.stderr
    line = one_error_line(proc)
    assert "the disk is full" in line and "checkpoint.npz.tmp" in line, line
    partial = tmp_path / "run.partial"
    assert sorted(os.listdir(partial)) == [MARKER, "case.toml", "checkpoint.npz", "frames"]
    assert not [n for n in os.listdir(partial / "frames") if n.endswith(".tmp")]
    assert not out.exists()
