"""The 3D devices' mesh estimate and the refusal of a mesh that does not fit (issue 29, item 7).

:func:`gelcell.post.validity.estimate_mesh_3d` predicts gmsh's tetrahedra from
the closed-form volumes and areas and the size fields of
:mod:`gelcell.geometry.builtin_model3d`.  Measured against gmsh's meshes of
both devices (chip height 0.4, the default cell) its error is at most 10.6 %
with no-slip walls (size factors 5 to 1) and 16.4 % with symmetric ones (3
and 2; docs/performance.md, "3D devices"): the tests take 15 % and 20 % at
the coarse sizes 4 and 3 (meshing only, no solves).  A mesh that does not fit is
refused before gmsh runs, with the finest ``--mesh-size`` that fits.
"""

from __future__ import annotations

import dataclasses

import pytest

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.cli import main
from gelcell.errors import ModelLimitError
from gelcell.geometry import meshes
from gelcell.post import validity
from gelcell.post.validity import check_case, check_mesh_size, estimate_mesh
from gelcell.run.solve import solve_partitioned

#: the largest relative errors measured: 10.6 % (no-slip, sizes 5 to 1) and 16.4 % (symmetric, 3 and 2)
TOLERANCE = {"noslip": 0.15, "symmetric": 0.2}


def _params_3d(case: str, size: float, walls: str = "noslip") -> CaseParameters:
    p = CaseParameters.default(case)
    return p.replace(geometry=dataclasses.replace(p.geometry, chip_height=0.4, walls=walls)).with_mesh_size(size)


@pytest.mark.parametrize("walls, size", [("noslip", 4.0), ("noslip", 3.0), ("symmetric", 3.0)])
@pytest.mark.parametrize("case", ["shear", "normal"])
def test_tetrahedra_estimate_matches_gmsh(case, walls, size):
    params = _params_3d(case, size, walls)
    counts = meshes.build_meshes(params, MPI.COMM_WORLD, whole=False).counts()
    actual = sum(counts[r]["cells"] for r in ("fluid", "gel", "cell"))
    assert abs(estimate_mesh(params)["elements"] / actual - 1.0) < TOLERANCE[walls]


def test_3d_mesh_that_does_not_fit_is_refused_with_a_size_that_fits():
    params = _params_3d("shear", 2.0)
    memory = 2**31                      # 2 GiB: size 2 needs about 4.9 GiB (measured: 4.9 GiB)
    with pytest.raises(ModelLimitError, match=r"--mesh-size 2 would make about .* elements") as info:
        check_mesh_size(params, memory=memory)
    suggested = float(str(info.value).split("choose --mesh-size ")[1].split()[0])
    assert suggested > 2.0
    check_mesh_size(params.with_mesh_size(suggested), memory=memory)


def test_a_3d_run_is_refused_before_meshing(monkeypatch):
    def no_meshing(*args, **kwargs):
        raise AssertionError("the mesh was built before the refusal")

    monkeypatch.setattr(meshes, "_mesh_with_gmsh", no_meshing)
    monkeypatch.setattr(validity, "machine_memory", lambda: 2**30)      # a 1 GiB machine
    for case in ("shear", "normal"):
        params = _params_3d(case, 1.0)
        with pytest.raises(ModelLimitError, match="--mesh-size 1 would make .* choose --mesh-size"):
            check_case(params)
        with pytest.raises(ModelLimitError, match="choose --mesh-size"):
            solve_partitioned(params, checks=False, verbose=False)


def test_the_cli_refuses_a_3d_mesh_that_does_not_fit(shared_tmp_path, cli_stderr, monkeypatch):
    monkeypatch.setattr(meshes, "_mesh_with_gmsh", lambda *a, **k: pytest.fail("meshed before the refusal"))
    out = shared_tmp_path / "out"
    code = main(["run", "normal", "--height", "0.4", "--mesh-size", "0.25", "--quiet", "--out", str(out)])
    err = cli_stderr()
    assert code == 4, err                   # exit 4: the model's limits (about 6 TB)
    assert "--mesh-size 0.25 would make about" in err and "choose --mesh-size" in err, err
    assert not out.exists()


def test_the_iterative_path_is_estimated_by_its_own_law():
    params = _params_3d("shear", 1.0)
    direct, iterative = (estimate_mesh(params, s)["memory_bytes"] for s in ("direct", "iterative"))
    assert iterative < direct             # no factorisation: no N^(4/3) fill
    memory = int(0.5 * (iterative + direct) / validity.MEMORY_SHARE)   # fits the iterative path only
    check_mesh_size(params, memory=memory, solver="iterative")
    with pytest.raises(ModelLimitError, match=r"choose --mesh-size [0-9.]+ or larger, or --solver iterative "
                                              r"\(about [0-9.]+ GiB\)"):
        check_mesh_size(params, memory=memory)
    with pytest.raises(ModelLimitError, match=r"GiB with the iterative solvers; this machine"):
        check_mesh_size(params, memory=int(0.5 * iterative / validity.MEMORY_SHARE), solver="iterative")


def test_an_iterative_3d_run_that_fits_is_not_refused(monkeypatch):
    class Meshing(Exception):
        pass

    def meshing(*args, **kwargs):
        raise Meshing

    params = _params_3d("shear", 1.0)
    direct, iterative = (estimate_mesh(params, s)["memory_bytes"] for s in ("direct", "iterative"))
    monkeypatch.setattr(meshes, "_mesh_with_gmsh", meshing)
    monkeypatch.setattr(validity, "machine_memory", lambda: int(0.5 * (iterative + direct) / validity.MEMORY_SHARE))
    with pytest.raises(ModelLimitError, match="or --solver iterative"):
        solve_partitioned(params, checks=False, verbose=False)
    with pytest.raises(RuntimeError, match="Meshing"):    # past the check, into meshing
        solve_partitioned(params, checks=False, verbose=False, solver="iterative")
