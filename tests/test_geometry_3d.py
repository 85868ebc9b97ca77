"""The built-in 3D devices (model.md section 10) against closed-form volumes and areas, and their case keys.

Meshes at two coarse sizes (``size_factor`` 6 and 4).  Tolerances:

* a measure bounded by planes only (every fluid measure, the gel's Γ1, Γ3
  and y = 0 faces) is exact on a mesh of flat faces: relative error below
  ``EXACT`` = 1e-12 (the measured errors are below 1.3e-14);
* a measure that involves a sphere, the bowl or a post is that of a P2
  (curved) surface whose nodes lie on the exact surface: its geometric error
  is at most O(h^3), so from size 6 to size 4 the error must fall by at least
  (4/6)^3 (measured: by (4/6)^4.1 to (4/6)^4.5, the P2 area superconvergence).
  A mis-tagged facet or a wrong closed form leaves an error that does not
  fall: detected when it exceeds about half the error at size 6 (2.5e-3 of
  the shear cell's Γ2, whose one facet of 22 is 4.5e-2 of it).

Runs under ``pytest`` and under ``scripts/pytest-2-ranks`` (measures reduced over all ranks).
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from gelcell.case import CaseParameters
from gelcell.case.devices import NormalGeometry, ShearGeometry
from gelcell.case.meshsizes import MeshSizes
from gelcell.errors import ParameterError
from gelcell.geometry.builtin import closed_form_measures, closed_form_measures_3d
from gelcell.geometry.tags import Tag, tag_name

from geometry3d_measures import errors, measure

EXACT = 1e-12
SIZES = (6.0, 4.0)
#: the measures that involve a curved surface or curve (sphere, bowl, posts); all others are exact
CURVED = {("gel", "volume"), ("gel", "BOWL"), ("gel", "POST"), ("gel", "GAMMA2"), ("gel", "FLOOR"),
          ("gel", "SYMMETRY_MID"), ("gel", "SYMMETRY_TOP"), ("cell", "volume"), ("cell", "GAMMA2"),
          ("cell", "SYMMETRY_MID"), ("cell", "SYMMETRY_TOP")}


def _case(case: str, size: float, **geometry) -> CaseParameters:
    g = (ShearGeometry if case == "shear" else NormalGeometry)(chip_height=0.4, **geometry)
    return CaseParameters(case=case, geometry=g, mesh=MeshSizes(size_factor=size))


CASES = {
    "shear_cell": lambda f: _case("shear", f),
    # a quarter sphere on the symmetry plane y = 0.5 and a half sphere off it
    "normal_two_cells": lambda f: _case("normal", f, cells=((1.2, 0.5, 0.06), (0.9, 0.3, 0.2, 0.08))),
    "normal_slab_nocell": lambda f: _case("normal", f, walls="symmetric").replace(with_cell=False),
}


@pytest.fixture(scope="module")
def measured():
    return {(label, f): measure(make(f)) for label, make in CASES.items() for f in SIZES}


@pytest.mark.mpi
@pytest.mark.parametrize("label", list(CASES))
def test_flat_measures_exact(measured, label):
    for f in SIZES:
        for key, err in errors(CASES[label](f), measured[label, f]).items():
            if key not in CURVED:
                assert err < EXACT, (label, f, key, err)


@pytest.mark.mpi
@pytest.mark.parametrize("label", list(CASES))
def test_curved_measures_converge(measured, label):
    coarse, fine = (errors(CASES[label](f), measured[label, f]) for f in SIZES)
    for key in coarse:
        if key in CURVED and coarse[key] > EXACT:
            assert fine[key] <= coarse[key] * (SIZES[1] / SIZES[0]) ** 3, (label, key, coarse[key], fine[key])


@pytest.mark.mpi
@pytest.mark.parametrize("label", list(CASES))
def test_tags_of_every_boundary(measured, label):
    """Each region's tags are those of the closed form (per cell Γ2 numbered), every boundary facet tagged."""
    exact = closed_form_measures_3d(CASES[label](SIZES[0]))
    for name, r in measured[label, SIZES[0]]["regions"].items():
        present = {"GAMMA2" if t.startswith("GAMMA2_") else t for t in r["area"]}
        assert present == {tag_name(t) for t in exact[name]["area"]}, (label, name, sorted(present))
        assert r["untagged_boundary_facets"] == 0 and r["tagged_interior_facets"] == 0, (label, name)


@pytest.mark.mpi
@pytest.mark.parametrize("label", list(CASES))
def test_interfaces_match(measured, label):
    """Γ1 (Γ3) of the fluid and gel meshes, Γ2 of the gel and cell meshes: the same nodes, bit for bit."""
    m = measured[label, SIZES[0]]
    assert m["nodes_equal"] and all(m["nodes_equal"].values()), m["nodes_equal"]
    for name, n in m["interface_nodes"].items():
        assert n > 0, name


def test_closed_forms_extrude_the_planar_device():
    """Volumes = planar areas x H/2, wall areas = planar lengths x H/2, floor = planar area (no cell)."""
    p3 = _case("shear", 1.0).replace(with_cell=False)
    p2 = p3.replace(geometry=dataclasses.replace(p3.geometry, chip_height=None))
    m2, m3, h = closed_form_measures(p2), closed_form_measures_3d(p3), 0.2
    for name in ("fluid", "gel"):
        assert m3[name]["volume"] == pytest.approx(m2[name]["area"] * h, rel=1e-15)
        assert m3[name]["area"][Tag.FLOOR] == pytest.approx(m2[name]["area"], rel=1e-15)
        assert m3[name]["area"][Tag.SYMMETRY_MID] == pytest.approx(m2[name]["area"], rel=1e-15)
        for tag, length in m2[name]["length"].items():
            assert m3[name]["area"][tag] == pytest.approx(length * h, rel=1e-15)


# --------------------------------------------------------------------------- case keys
def test_case_file_keys_round_trip():
    data = {"case": {"name": "normal"},
            "geometry": {"chip_height": 0.4, "walls": "symmetric", "cells": [[1.2, 0.5, 0.2, 0.06], [0.9, 0.3, 0.08]]}}
    p = CaseParameters.from_dict(data)
    assert p.geometry.dimension == 3 and p.geometry.walls == "symmetric"
    assert p.geometry.cell_list_3d() == [(1.2, 0.5, 0.2, 0.06), (0.9, 0.3, 0.2, 0.08)]
    assert CaseParameters.from_dict(p.to_input_dict()) == p
    assert CaseParameters.default("shear").geometry.dimension == 2          # planar by default


@pytest.mark.parametrize("geometry, name", [
    ({"chip_height": 0.0}, "chip_height"), ({"chip_height": -0.4}, "chip_height"),
    ({"chip_height": "tall"}, "chip_height"), ({"chip_height": 0.4, "walls": "slip"}, "walls"),
    ({"walls": "symmetric"}, "walls"),                                       # a planar device has no floor
    ({"cells": [[2.0, -0.2, 0.2, 0.06]]}, "cells[0]"),                       # (x, y, z, d) needs chip_height
    ({"chip_height": 0.4, "cells": [[2.0, -0.2, 0.1, 0.06]]}, "cells[0].z"),  # not at mid-height
    ({"chip_height": 0.4, "cells": [[2.0, -0.2, 0.2, 0.39]]}, "cells[0].d"),  # through the floor and lid
    ({"chip_height": 0.05}, "cell_diameter"),                                # the default cell through the floor
    ({"chip_height": 0.4, "cells": [[2.0, -0.01, 0.2, 0.06]]}, "cells[0]"),   # leaves the gel through Γ1
])
def test_bad_3d_input_refused_before_meshing(geometry, name):
    with pytest.raises(ParameterError, match=rf"parameter '{re.escape(name)}'"):
        CaseParameters.from_dict({"case": {"name": "shear"}, "geometry": geometry})


# --------------------------------------------------------------------------- conditions of the 3D devices
def _conditioned(b) -> dict[str, set[str]]:
    """Per region, the tag names that carry a condition or an interface (the outlet: zero traction)."""
    names = lambda tags: {tag_name(t) for t in tags}                                  # noqa: E731
    fluid = {t for tags, _ in b.fluid_velocity for t in tags} | {t for tags, _, _ in b.fluid_component for t in tags}
    return {"fluid": names(fluid | {int(Tag.OUTLET)} | set(b.fluid_interfaces.values())),
            "gel": names(set(b.gel_no_slip) | {t for tags, _ in b.gel_symmetry for t in tags}
                         | set(b.fluid_interfaces.values()) | set(b.cell_interfaces.values())),
            "cell": names({t for tags, _ in b.cell_symmetry for t in tags} | set(b.cell_interfaces.values()))}


@pytest.mark.parametrize("label", list(CASES))
def test_every_tag_of_the_mesh_has_its_condition(measured, label):
    """The conditions of device_boundaries_3d name exactly the tags each region's mesh carries."""
    from gelcell.geometry import device_layout
    params = CASES[label](SIZES[0])
    b = device_layout(params).boundaries
    assert b.dim == 3 and all(comps == (0, 1, 2) for _, comps in b.fluid_dirichlet_tags()[:len(b.fluid_velocity)])
    for name, tags in _conditioned(b).items():
        if name in measured[label, SIZES[0]]["regions"]:
            assert set(measured[label, SIZES[0]]["regions"][name]["area"]) == tags, (label, name)
    floor_fixed = int(Tag.FLOOR) in b.gel_no_slip
    assert floor_fixed == (params.geometry.walls == "noslip"), label
    assert any(int(Tag.SYMMETRY_MID) in tags and c == 2 for tags, c in b.gel_symmetry), label


def test_inflow_profiles_of_the_chip():
    """Shear: the duct series, 1 on the centre line, 0 on floor and walls; normal: mean 1 over the height."""
    from gelcell.geometry.layout import ChipInflow
    W, H = 0.2, 0.4
    duct = ChipInflow("duct", W, H)
    v = duct(np.array([[0.0, 0.0, 0.0], [W / 2, 0.0, W / 2], [H / 2, H / 2, 0.0]]))
    assert v[0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12) and not v[1:].any()
    z, w = np.polynomial.legendre.leggauss(3)                      # exact for the quadratic profile
    z = 0.5 * H * (z + 1)
    plane = ChipInflow("plane", 0.5, H)(np.vstack((np.zeros(3), np.full(3, 0.3), z)))[0]
    assert 0.5 * float(w @ plane) == pytest.approx(1.0, rel=1e-14)      # flux per unit height = 2D inflow
    slab = ChipInflow("parabolic", W, H)(np.array([[0.0, 0.0], [W / 2, W / 2], [0.0, H / 2]]))[0]
    assert slab == pytest.approx([1.0, 1.0], rel=1e-15)                 # independent of z
