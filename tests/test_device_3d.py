"""The built-in 3D devices (model.md section 10, issue 29) run as a whole, on coarse meshes.

References: the planar device (the slab of section 10, floor and lid as
symmetry planes, equals it to discretisation error: the difference must
shrink under refinement), the monolithic reference (the same discrete
problem: partitioned = monolithic to 1e-6, steady and in every window of a
time-dependent run), and 1 vs 2 MPI ranks.  Small kinematics throughout: the
3D finite-strain forms cost ~30 s each to compile and are checked per field
(tests/test_gel_3d.py, tests/test_cell_3d.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

from device3d_cases import HEIGHT, MESH, monolithic, params_3d, partitioned
from femtools.functions import values_at_points
from gelcell.post.fields import relative_differences
from gelcell.post.quantities import flat_quantities
from mpi_run import run_mpi
from test_transient import relative_difference
from transient_cases import run, tau

COMM = MPI.COMM_WORLD


# --------------------------------------------------------------------------- slab = planar device
def _owned_nodes(f) -> tuple[np.ndarray, np.ndarray]:
    """Every rank's owned dof coordinates and values of ``f``, gathered on all ranks (coarse meshes only)."""
    V = f.function_space
    n, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
    x, values = V.tabulate_dof_coordinates()[:n], f.x.array[: n * bs].reshape(n, bs)
    return np.vstack(COMM.allgather(x)), np.vstack(COMM.allgather(values))


def _slab_minus_plane(case: str, mesh_size: float) -> dict[str, tuple[float, float]]:
    """Per field: the RMS over the planar device's nodes of |slab - plane| / RMS |plane|, the slab
    evaluated at mid-depth of its computed half height, and the same for its z component."""
    plane = partitioned(case, mesh=mesh_size, height=None, with_cell=False).fields
    slab = partitioned(case, "symmetric", mesh=mesh_size, with_cell=False).fields
    out = {}
    for name in ("fluid_velocity", "interstitial_velocity", "displacement", "pore_pressure"):
        x, planar = _owned_nodes(getattr(plane, name))
        x[:, 2] = 0.25 * HEIGHT
        values = values_at_points(getattr(slab, name), x)
        inside = ~np.isnan(values[:, 0])     # planar nodes on a curved wall lie outside the slab's straight tets
        assert inside.mean() > 0.8, (name, inside.mean())
        k, scale = planar.shape[1], np.sqrt(np.mean(np.sum(planar[inside] ** 2, axis=1)))
        in_plane = np.sqrt(np.mean(np.sum((values[inside, :k] - planar[inside]) ** 2, axis=1))) / scale
        normal = np.sqrt(np.mean(values[inside, k:] ** 2)) / scale if values.shape[1] > k else 0.0
        out[name] = (float(in_plane), float(normal))
    return out


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_slab_equals_the_planar_device_to_discretisation_error(case):
    """Without a cell the slab's solution does not depend on z and is the plane-strain one (model.md
    section 10), so slab - plane is the difference of two discretisations of one solution: it shrinks
    from size factor 6 to 4 in every field, and the slab's z components are no larger than it.  (The
    fluid pressure is left out: its largest differences sit at the outlet's corners, where the
    do-nothing outlet meets a no-slip wall and both discretisations are locally inexact.)"""
    coarse, fine = _slab_minus_plane(case, 6.0), _slab_minus_plane(case, 4.0)
    for name in coarse:
        print(f"{case} {name}: slab - plane {coarse[name][0]:.2e} -> {fine[name][0]:.2e}, "
              f"z component {coarse[name][1]:.1e} -> {fine[name][1]:.1e}")
        assert fine[name][0] < coarse[name][0], name
        assert fine[name][1] <= 2 * max(fine[name][0], coarse[name][1]), name


# --------------------------------------------------------------------------- partitioned = monolithic
@pytest.mark.parametrize("case", ["shear", "normal"])
def test_partitioned_equals_monolithic_with_a_cell(case):
    """The 3D device with its spherical cell and bonded floor: the partitioned fields (each on its
    own mesh, coupled to 1e-10) equal the monolithic reference's to 1e-6 relative (L2)."""
    part, mono = partitioned(case), monolithic(case)
    differences = relative_differences(part.fields, mono.fields)
    print(f"{case} 3D: {part.summary['coupling']['iterations']} coupling iterations; "
          + ", ".join(f"{k} {v:.1e}" for k, v in differences.items()))
    assert part.summary["coupling"]["converged"]
    assert max(differences.values()) <= 1e-6, differences
    assert len(part.summary["cell"]["centroid_displacement"]) == 3
    assert part.summary["geometry"] == {"dimension": 3, "chip_height": HEIGHT, "walls": "noslip"}


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_partitioned_equals_monolithic_in_every_window(case):
    """Three backward-Euler windows from rest (dt = tau_c/20): every window's quantities agree to 1e-6."""
    p = params_3d(case)
    kw = dict(dt=tau(p) / 20, t_end=2 * tau(p) / 20, scheme="be")
    partitioned, monolithic = run(p, **kw), run(p, monolithic=True, **kw)
    assert len(partitioned["rows"]) == len(monolithic["rows"]) == 3
    columns = [c for c in partitioned["series"] if c not in ("t", "inflow", "iterations", "residual")]
    assert relative_difference(partitioned["series"], monolithic["series"], columns) < 1e-6
    assert "centroid_z" in partitioned["rows"][-1]


# --------------------------------------------------------------------------- 1 and 2 ranks
def test_same_3d_device_on_one_and_two_ranks():
    """The 3D shear device with a cell: the summary's quantities and the coupling iterations of this
    (serial) process and of a run on 2 ranks."""
    parallel = run_mpi("device_summary.py", 2, ["shear", str(MESH), str(HEIGHT), "small"])
    serial = flat_quantities(partitioned("shear").summary)
    serial["iterations"] = partitioned("shear").summary["coupling"]["iterations"]
    assert serial["iterations"] == parallel["iterations"]
    for key, value in serial.items():
        assert parallel[key] == pytest.approx(value, rel=1e-8, abs=1e-14), key
