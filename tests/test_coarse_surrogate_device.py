"""A 3D device coupled under another device's prior (Device.coarse_surrogate, coupling.CoarseSurrogate).

References: on equal meshes the carried prior is the device's own linearized prior (the same
iterations and answer).  On non-matching meshes it changes the path, not the fixed point; its
iteration counts are measured in benchmarks/coarse_surrogate_3d.py (docs/three-dimensional.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device
from device3d_cases import params_3d


def solved(mesh: float, prior: str, surrogate_of: Device | None = None) -> Device:
    d = Device(params_3d("shear", mesh=mesh))
    surrogate = None if surrogate_of is None else d.coarse_surrogate(surrogate_of)
    result = d.solve(coupling_config(with_cell=True, params=d.params, jacobian_prior=prior), verbose=False,
                     surrogate=surrogate)
    assert result.converged
    return d


def interface_values(d: Device) -> np.ndarray:
    return d.scheme.layout.concat(d.scheme.values)


@pytest.fixture(scope="module")
def coarse() -> Device:
    return solved(6.0, "linearized")


def test_on_equal_meshes_the_carried_prior_is_the_devices_own(coarse):
    carried = solved(6.0, "none", surrogate_of=coarse)
    assert carried.prior_source == "surrogate"
    assert carried.result.iterations == coarse.result.iterations
    x, y = interface_values(carried), interface_values(coarse)
    assert np.linalg.norm(x - y) <= 1e-9 * np.linalg.norm(y)


def test_a_coarse_device_without_its_prior_is_refused():
    d = Device(params_3d("shear", mesh=6.0))            # not solved: no prior yet
    with pytest.raises(ValueError, match="the coarse device has no linearized prior"):
        Device(params_3d("shear", mesh=6.0)).coarse_surrogate(d)
