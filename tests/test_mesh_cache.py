"""The mesh cache of the built-in devices (``gelcell.geometry.meshcache``): a hit gives the same meshes without gmsh.

Every test points ``GELCELL_CACHE_DIR`` at a temporary directory, so none depends on
the user's cache.  Runs under ``pytest`` and under ``mpirun -n 2 python -m pytest``:
each rank compares its own part of the meshes (the partition is deterministic), and
the results are reduced over the ranks before asserting.  Only rank 0 meshes and
touches the cache; the other ranks get the meshes' metadata by broadcast.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from mpi4py import MPI

from gelcell.geometry import meshcache, meshes
from gelcell.geometry.meshes import build_meshes
from gelcell.case import CaseParameters, FileGeometry
from gelcell.errors import ParameterError

COMM = MPI.COMM_WORLD
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def coarse(case: str = "shear") -> CaseParameters:
    return CaseParameters.default(case).with_mesh_size(3)


@pytest.fixture
def cache(empty_cache):
    """An empty cache directory, the same on every rank, with the cache enabled."""
    return empty_cache("GELCELL_CACHE_DIR", "GELCELL_MESH_CACHE")


@pytest.fixture
def meshings(monkeypatch):
    """Counts the devices meshed with gmsh (rank 0; always 0 on the other ranks)."""
    calls = []
    original = meshes._mesh_with_gmsh

    def counted(params):
        calls.append(params)
        return original(params)
    monkeypatch.setattr(meshes, "_mesh_with_gmsh", counted)
    return calls


def no_meshing(monkeypatch):
    """From now on, meshing with gmsh fails the test (a hit must not mesh)."""
    def fail(params):
        raise AssertionError("meshed with gmsh on a cache hit")
    monkeypatch.setattr(meshes, "_mesh_with_gmsh", fail)


def entries(path) -> list[str]:
    """Cache entries (rank 0's directory listing, on every rank)."""
    names = sorted(os.listdir(path)) if COMM.rank == 0 and os.path.isdir(path) else []
    return COMM.bcast(names, root=0)


def snapshot(dev) -> list[np.ndarray]:
    """This rank's part of every mesh: node coordinates, cells, cell and facet tags."""
    out = []
    for name in dev.regions:
        msh, ft = dev.region(name)
        out += [msh.geometry.x, msh.geometry.dofmap.array, ft.indices, ft.values]
    msh, ct, ft = dev.whole
    out += [msh.geometry.x, msh.geometry.dofmap.array, ct.indices, ct.values, ft.indices, ft.values]
    return [np.array(a, copy=True) for a in out]


def same_everywhere(a: list, b: list) -> bool:
    """The two snapshots are identical on every rank."""
    local = len(a) == len(b) and all(u.dtype == v.dtype and np.array_equal(u, v) for u, v in zip(a, b))
    return COMM.allreduce(local, op=MPI.LAND)


def meshed(calls) -> int:
    """Devices meshed with gmsh (on rank 0, where gmsh runs)."""
    return COMM.bcast(len(calls), root=0)


# --------------------------------------------------------------------------- hit and miss
@pytest.mark.parametrize("case", ["shear", "normal"])
def test_a_hit_gives_the_same_meshes_without_gmsh(cache, monkeypatch, case):
    params = coarse(case)
    first = build_meshes(params)
    names = entries(cache)
    assert len(names) == 1 and names[0].startswith(f"{case}-") and names[0].endswith(".npz"), names
    path = cache / names[0]
    if COMM.rank == 0:
        os.utime(path, (0, 0))
    no_meshing(monkeypatch)
    second = build_meshes(params)
    assert same_everywhere(snapshot(first), snapshot(second))
    assert second.counts() == first.counts()
    assert second.build_time > 0
    assert entries(cache) == names            # nothing rewritten, no temporary file left
    assert COMM.bcast(os.path.getmtime(path) > 0 if COMM.rank == 0 else None, root=0)   # the hit touched it


def test_physics_that_does_not_change_the_mesh_reuses_the_entry(cache, monkeypatch, meshings):
    params = coarse()
    first = build_meshes(params)
    other_ca = params.replace(physics=dataclasses.replace(params.physics, ca=1e-9))
    assert meshcache.cache_key(other_ca) == meshcache.cache_key(params)
    no_meshing(monkeypatch)
    assert same_everywhere(snapshot(first), snapshot(build_meshes(other_ca)))
    assert len(entries(cache)) == 1


def test_a_moved_cell_is_another_entry(cache, meshings):
    params = coarse()
    first = build_meshes(params)
    moved = build_meshes(params.with_e(0.3))
    assert meshed(meshings) == 2 and len(entries(cache)) == 2
    assert not same_everywhere(snapshot(first), snapshot(moved))


def test_the_key_follows_what_the_mesh_depends_on():
    params = coarse()
    key = meshcache.cache_key(params)
    changed = {"e": params.with_e(0.3), "mesh size": params.with_mesh_size(2.5),
               "no cell": params.replace(with_cell=False), "case": coarse("normal"),
               # the drag sets the Brinkman layer, hence the element size next to Γ1
               "xi": params.replace(physics=dataclasses.replace(params.physics, xi=1e4)),
               "cell edges": params.replace(mesh=dataclasses.replace(params.mesh, n_cell_edges=40))}
    for what, other in changed.items():
        assert meshcache.cache_key(other) != key, what
    moduli = params.with_cell_moduli(10).with_gel_moduli(2)
    assert meshcache.cache_key(moduli) == key


def test_the_key_follows_the_mesh_format_not_the_source_text(monkeypatch):
    """Meshing changes are declared by bumping MESH_FORMAT; a docstring edit keeps the entries."""
    params = coarse()
    key = meshcache.cache_key(params)
    monkeypatch.setattr(meshcache, "MESH_FORMAT", meshcache.MESH_FORMAT + 1)
    meshcache._environment.cache_clear()
    try:
        assert meshcache.cache_key(params) != key
    finally:
        monkeypatch.undo()
        meshcache._environment.cache_clear()
    assert meshcache.cache_key(params) == key
    assert not any("hash" in name or "source" in name for name in meshcache._environment())


def test_only_the_most_recently_used_entries_are_kept(tmp_path, monkeypatch):
    monkeypatch.setattr(meshcache, "MAX_ENTRIES", 2)
    names = [f"{case}-{k:064x}.npz" for k, case in enumerate(["shear", "normal", "shear", "normal"])]
    foreign = ["notes.npz", ".tmp-abc.npz", "shear-1234.npz"]      # not entries: never removed
    for age, name in enumerate(names + foreign):
        (tmp_path / name).write_bytes(b"")
        os.utime(tmp_path / name, (1000 - age, 1000 - age))
    meshcache._prune(str(tmp_path))
    assert sorted(os.listdir(tmp_path)) == sorted(names[:2] + foreign)


# --------------------------------------------------------------------------- when it is not used
def test_disabled_cache_meshes_every_time(cache, monkeypatch, meshings):
    monkeypatch.setenv("GELCELL_MESH_CACHE", "0")
    first = build_meshes(coarse())
    second = build_meshes(coarse())
    assert meshed(meshings) == 2 and entries(cache) == []
    assert same_everywhere(snapshot(first), snapshot(second))


@pytest.mark.parametrize("damage", ["garbage", "truncated", "foreign"])
def test_a_corrupt_entry_is_ignored_and_replaced(cache, meshings, damage):
    params = coarse()
    first = build_meshes(params)
    path = meshcache.cache_path(params)
    if COMM.rank == 0:
        if damage == "garbage":
            open(path, "wb").write(b"not a mesh")
        elif damage == "truncated":
            data = open(path, "rb").read()
            open(path, "wb").write(data[:len(data) // 2])
        else:
            np.savez(open(path, "wb"), x=np.zeros((3, 3)))
    COMM.Barrier()
    second = build_meshes(params)
    assert meshed(meshings) == 2
    assert same_everywhere(snapshot(first), snapshot(second))
    loaded = meshcache.load(params) is not None if COMM.rank == 0 else True
    assert COMM.bcast(loaded, root=0) and len(entries(cache)) == 1


def test_an_unwritable_cache_directory_does_not_fail_the_run(shared_tmp_path, monkeypatch, meshings):
    blocker = shared_tmp_path / "a-file"        # a directory below a file cannot be created (even by root)
    if COMM.rank == 0:
        blocker.write_text("")
    COMM.Barrier()
    monkeypatch.setenv("GELCELL_CACHE_DIR", str(blocker / "meshes"))
    first = build_meshes(coarse())
    second = build_meshes(coarse())
    assert meshed(meshings) == 2
    assert same_everywhere(snapshot(first), snapshot(second))


@pytest.mark.parametrize("error, raised, words", [
    (ParameterError("cell too close to the bowl"), ParameterError, "cell too close to the bowl"),
    (RuntimeError("boom"), RuntimeError, "meshing the shear device failed: RuntimeError: boom")])
def test_a_failed_build_is_not_cached(cache, monkeypatch, error, raised, words):
    def fail(params):
        raise error
    import gelcell.geometry.builtin_model
    monkeypatch.setattr(gelcell.geometry.builtin_model, "build_model", fail)
    with pytest.raises(raised, match=words):
        build_meshes(coarse())
    assert entries(cache) == []


def test_geometry_files_are_not_cached(cache, meshings):
    """A file's content and options are not in any key: it is meshed every time."""
    params = CaseParameters(case="file", geometry=FileGeometry(os.path.join(HERE, "geometry_files", "small.geo")))
    build_meshes(params)
    build_meshes(params)
    assert meshed(meshings) == 2 and entries(cache) == []


# --------------------------------------------------------------------------- a warm process
@pytest.mark.skip_in_parallel
def test_a_warm_run_does_not_import_gmsh(tmp_path):
    script = textwrap.dedent(f"""
        import sys
        from gelcell.cli import main
        code = main(["run", "shear", "--mesh-size", "3", "--no-figures", "--quiet", "--out", {str(tmp_path / "out")!r}])
        names = ("gmsh", "gelcell.geometry.builtin_model", "dolfinx.io.gmshio")
        print("IMPORTED", sorted(m for m in names if m in sys.modules))
        sys.exit(code)
    """)
    env = dict(os.environ, MPLBACKEND="Agg", GELCELL_CACHE_DIR=str(tmp_path / "meshes"))
    env.pop("GELCELL_MESH_CACHE", None)
    imported = []
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=ROOT,
                              timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        imported.append(next(ln for ln in proc.stdout.splitlines() if ln.startswith("IMPORTED")))
    assert imported[0] == "IMPORTED ['dolfinx.io.gmshio', 'gelcell.geometry.builtin_model', 'gmsh']"    # cold: meshed
    assert imported[1] == "IMPORTED []"                                                     # warm: cached
    assert len(os.listdir(tmp_path / "meshes")) == 1


@pytest.mark.skip_in_parallel
def test_importing_gmsh_keeps_the_sigint_handler():
    """gmsh 4.8 resets SIGINT on import and restores its import-time handler on finalize."""
    script = textwrap.dedent("""
        import signal
        from femtools.gmshimport import import_gmsh
        def first(signum, frame): pass
        def second(signum, frame): pass
        signal.signal(signal.SIGINT, first)
        gmsh = import_gmsh()
        assert signal.getsignal(signal.SIGINT) is first, "import"
        signal.signal(signal.SIGINT, second)        # e.g. the CLI installs its handlers later
        gmsh = import_gmsh()
        gmsh.initialize(readConfigFiles=False)
        gmsh.finalize()
        assert signal.getsignal(signal.SIGINT) is second, "finalize"
        print("OK")
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "OK", proc.stderr


def test_ctrl_c_while_gmsh_is_imported_reaches_the_handler():
    """Issue 28 item 12: gmsh's import loads libgmsh (0.2-0.6 s) after setting SIGINT to the default
    action; a Ctrl-C then killed the process (no error line, no exit 130).  SIGINTs sent all through
    the import reach the installed handler."""
    script = textwrap.dedent("""
        import os, signal, threading, time
        from femtools.gmshimport import import_gmsh
        caught = []
        signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
        importing = threading.Event()
        def ctrl_c():
            importing.wait()
            while importing.is_set():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.01)
        thread = threading.Thread(target=ctrl_c)
        thread.start()
        importing.set()
        import_gmsh()
        importing.clear()
        thread.join()
        time.sleep(0.05)
        print("OK", len(caught) > 0)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0 and proc.stdout.split() == ["OK", "True"], (proc.returncode, proc.stderr)
