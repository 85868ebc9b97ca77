"""The interface-condition residuals of the 3D devices (model.md section 10) on both solutions.

The coupled 3D shear and normal devices with a cell (coarse, small strain):
the converged partitioned solution (coupling tolerance 1e-10) and the
monolithic reference satisfy every discrete interface condition, so both give
solver-tolerance residuals (``gelcell.post.residuals``; in 3D the tangential
conditions with both tangents of the plane interfaces, the nodes on the floor
and on the mid-height symmetry plane left out as the 2D walls' and symmetry
lines' are), and the two solutions agree to the coupling tolerance; the
finite-strain check too, on the partitioned shear device.

The bound is the 2D test's (tests/test_device.py), for the same reason: the
network-slip and permeability conditions (I15, I17) involve the network's
partial traction, ~1e-4 of the total; measured on these meshes up to 2e-9 on
both solutions alike (the 2D normal device at mesh size 3: 1.6e-9).
Every check reduces over MPI (``./scripts/pytest-2-ranks tests/test_residuals_3d.py``).
"""

from __future__ import annotations

import pytest

from mpi4py import MPI

import device3d_cases
from gelcell.post.fields import relative_differences
from gelcell.post.residuals import interface_residuals
from test_outputs_3d import device_3d

COMM = MPI.COMM_WORLD
#: the 2D test's bound (tests/test_device.py)
SOLVER_TOLERANCE = 1e-8


@pytest.fixture(scope="module", params=["shear", "normal"])
def partitioned(request):
    return device_3d(request.param)[1]


@pytest.fixture(scope="module")
def monolithic(partitioned):
    return device3d_cases.monolithic(partitioned.params.case).fields


def _worst(residuals: dict) -> float:
    return max(v for r in residuals.values() for v in r.values())


def test_every_interface_is_checked(partitioned):
    residuals = interface_residuals(partitioned)
    expected = {"shear": {"Gamma1", "Gamma2"}, "normal": {"Gamma1", "Gamma3", "Gamma2"}}[partitioned.params.case]
    assert set(residuals) == expected
    # in 3D the small-strain conditions one by one, as in 2D
    assert set(residuals["Gamma1"]) == {"I13", "I14", "I15", "I16", "I17"}
    assert set(residuals["Gamma2"]) == {"displacement", "no_slip", "traction"}


def test_partitioned_residuals_at_solver_tolerance(partitioned):
    residuals = interface_residuals(partitioned)
    assert _worst(residuals) < SOLVER_TOLERANCE, residuals


def test_monolithic_residuals_at_solver_tolerance(monolithic):
    residuals = interface_residuals(monolithic)
    assert _worst(residuals) < SOLVER_TOLERANCE, residuals


def test_partitioned_equals_monolithic(partitioned, monolithic):
    diff = relative_differences(partitioned, monolithic)
    assert max(diff.values()) < 1e-6, diff


def test_finite_strain_residuals_at_solver_tolerance():
    """The finite-strain check in 3D (the combinations I13+I16, I15+I17 on the current interface) on the
    converged partitioned shear device: measured 6e-11 (I13+I16), 7e-13 (I15+I17)."""
    fields = device_3d("shear", kinematics="finite")[1]
    residuals = interface_residuals(fields)
    assert set(residuals["Gamma1"]) == {"I13+I16", "I14", "I15+I17"}
    assert _worst(residuals) < SOLVER_TOLERANCE, residuals
