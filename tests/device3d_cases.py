"""The coarse 3D device solves the 3D device tests share: each solved once per test process.

tests/test_device_3d.py, tests/test_outputs_3d.py and tests/test_residuals_3d.py check different
things of the same solutions (model.md section 10: the chip height 0.4, small kinematics unless
asked, every element size x6).  A 3D solve costs 10-40 s here, so each is kept.
"""

from __future__ import annotations

import dataclasses
import functools

from gelcell.case import CaseParameters
from gelcell.run.solve import CaseRun, solve_monolithic, solve_partitioned

#: the chip height of model.md section 10 (100 µm)
HEIGHT = 0.4
#: every element size x6: coarse 3D devices that couple in a few seconds
MESH = 6.0


def params_3d(case: str, walls: str = "noslip", mesh: float = MESH, height: float | None = HEIGHT,
              with_cell: bool = True, kinematics: str = "small") -> CaseParameters:
    """The 3D device of chip height ``height``; ``height=None``: the planar device of the same sizes."""
    p = CaseParameters.default(case, with_cell).with_mesh_size(mesh).with_kinematics(kinematics)
    if height is None:
        return p
    return p.replace(geometry=dataclasses.replace(p.geometry, chip_height=height, walls=walls))


@functools.lru_cache(maxsize=None)
def partitioned(case: str, walls: str = "noslip", mesh: float = MESH, height: float | None = HEIGHT,
                with_cell: bool = True, kinematics: str = "small") -> CaseRun:
    """The partitioned steady solve (coupled to the device default's 1e-10) and its summary."""
    p = params_3d(case, walls, mesh, height, with_cell, kinematics)
    return solve_partitioned(p, verbose=False, checks=False)


@functools.lru_cache(maxsize=None)
def monolithic(case: str, walls: str = "noslip", mesh: float = MESH, height: float | None = HEIGHT,
               with_cell: bool = True, kinematics: str = "small") -> CaseRun:
    """The monolithic reference of the same case."""
    return solve_monolithic(params_3d(case, walls, mesh, height, with_cell, kinematics), checks=False)
