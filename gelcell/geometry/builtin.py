"""The two built-in devices without meshing them: their cells, boundary conditions and closed-form measures.

model.md sections 3 and 4.  Shear flow: parabolic inflow with maximum 1 at
the inlet, zero traction at the outlet, no slip on the channel walls;
v_f = 0 and u_s = 0 on the bowl.  Normal flow: uniform inflow (1, 0), zero
traction at the outlet; v_f = 0 and u_s = 0 on the posts; symmetry (zero
normal velocity and displacement, zero tangential traction) on y = 0 and
y = H.  The cell's flat edge on y = H is a symmetry line too.  Several
cells: each has its own Gamma2 (``Gamma2_k``, facet tag ``gamma2_tag(k)``).
"""

from __future__ import annotations

import math

from gelcell.case import CaseParameters
from gelcell.geometry.layout import CellSpec, ChipInflow, DeviceBoundaries, DeviceLayout, ParabolicInflow
from gelcell.geometry.tags import REGIONS, Tag, cell_region_tag, gamma2_name, gamma2_tag

__all__ = ["builtin_cells", "builtin_layout", "device_boundaries", "device_boundaries_3d", "closed_form_measures",
           "closed_form_measures_3d"]


# --------------------------------------------------------------------------- closed forms
def closed_form_measures(params: CaseParameters) -> dict:
    """Exact areas and boundary lengths of the geometry of ``params``.

    Returns ``{"whole": {"area": {Tag: a}, "length": {Tag: l}}, "fluid": {"area": a,
    "length": {Tag: l}}, "gel": ..., "cell": ...}``; a region's lengths are those
    of the tagged facets of that region's own mesh.  Several cells: their
    areas and Gamma2 lengths are summed under Tag.CELL and Tag.GAMMA2.
    """
    if getattr(params.geometry, "dimension", 2) == 3:
        return closed_form_measures_3d(params)
    cells = params.geometry.cell_list() if params.with_cell else []
    out = _shear_measures(params.geometry, cells) if params.case == "shear" else \
        _normal_measures(params.geometry, cells)
    if not params.with_cell:
        del out["cell"]
    out["whole"] = _whole_measures(out)
    return out


def _shear_measures(g, cells) -> dict:
    """The shear device's regions: a channel over a circular-segment gel."""
    R, th, W, c, L = g.radius, g.half_angle, g.channel_height, g.chamber_width, g.channel_length
    a_cell = sum(math.pi * (0.5 * d) ** 2 for _, _, d in cells)
    gamma2 = sum(math.pi * d for _, _, d in cells)
    fluid = {"area": L * W, "length": {Tag.INLET: W, Tag.OUTLET: W, Tag.WALL: 2 * L - c, Tag.GAMMA1: c}}
    gel = {"area": R * R * (th - math.sin(th) * math.cos(th)) - a_cell,
           "length": {Tag.GAMMA1: c, Tag.BOWL: 2 * R * th}}
    if cells:
        gel["length"][Tag.GAMMA2] = gamma2
    return {"fluid": fluid, "gel": gel, "cell": {"area": a_cell, "length": {Tag.GAMMA2: gamma2}}}


def _normal_measures(g, cells) -> dict:
    """The normal-flow device's half: channels either side of a gel with a post; cells on the line halved."""
    H, Lg, D = g.height, g.gel_length, g.post_diameter
    Lf = g.upstream_length + g.downstream_length
    share = [0.5 if g.on_symmetry_line(y) else 1.0 for _, y, _ in cells]
    a_cell = sum(s * math.pi * (0.5 * d) ** 2 for s, (_, _, d) in zip(share, cells))
    gamma2 = sum(s * math.pi * d for s, (_, _, d) in zip(share, cells))
    cut = sum(d for s, (_, _, d) in zip(share, cells) if s < 1.0)
    fluid = {"area": Lf * H, "length": {Tag.INLET: H, Tag.OUTLET: H, Tag.GAMMA1: H, Tag.GAMMA3: H,
                                        Tag.SYMMETRY_BOTTOM: Lf, Tag.SYMMETRY_TOP: Lf}}
    gel = {"area": Lg * H - math.pi * (0.5 * D) ** 2 - a_cell,
           "length": {Tag.GAMMA1: H, Tag.GAMMA3: H, Tag.POST: math.pi * D,
                      Tag.SYMMETRY_BOTTOM: Lg - 2 * D, Tag.SYMMETRY_TOP: Lg - cut}}
    cell = {"area": a_cell, "length": {Tag.GAMMA2: gamma2}}
    if cells:
        gel["length"][Tag.GAMMA2] = gamma2
    if cut:
        cell["length"][Tag.SYMMETRY_TOP] = cut
    return {"fluid": fluid, "gel": gel, "cell": cell}


def _whole_measures(regions: dict) -> dict:
    """The whole device's areas per region tag and lengths per facet tag (interfaces counted once)."""
    area = {REGIONS[k]: v["area"] for k, v in regions.items()}
    length: dict = {}
    for v in regions.values():
        for tag, value in v["length"].items():
            shared = tag in (Tag.GAMMA1, Tag.GAMMA2, Tag.GAMMA3)
            length[tag] = value if shared else length.get(tag, 0.0) + value
    return {"area": area, "length": length}


def closed_form_measures_3d(params: CaseParameters) -> dict:
    """Exact volumes and surface areas of the 3D device of ``params`` (model.md section 10).

    Returns ``{"whole": {"volume": {Tag: v}, "area": {Tag: a}}, "fluid": {"volume": v,
    "area": {Tag: a}}, "gel": ..., "cell": ...}``.  The half height h = H/2
    extrudes the planar device: a planar area A gives the volume A h and the
    floor and mid-plane areas A, a planar length l the wall area l h.  A
    cell of radius r is a half sphere (volume 2/3 π r^3, Γ2 2 π r^2, flat
    face π r^2 on z = h), a quarter sphere on the normal device's symmetry
    plane y = height (half of each, plus a half disk π r^2 / 2 on that plane).
    """
    g, h = params.geometry, 0.5 * params.geometry.chip_height
    cells = params.geometry.cell_list() if params.with_cell else []
    share = [0.5 if params.case == "normal" and g.on_symmetry_line(y) else 1.0 for _, y, _ in cells]
    r = [0.5 * d for _, _, d in cells]
    cell = {"volume": sum(s * 2 / 3 * math.pi * q ** 3 for s, q in zip(share, r)),
            "area": {Tag.GAMMA2: sum(s * 2 * math.pi * q ** 2 for s, q in zip(share, r)),
                     Tag.SYMMETRY_MID: sum(s * math.pi * q ** 2 for s, q in zip(share, r))}}
    cut = sum(0.5 * math.pi * q ** 2 for s, q in zip(share, r) if s < 1.0)
    if cut:
        cell["area"][Tag.SYMMETRY_TOP] = cut
    flat = _shear_measures(g, []) if params.case == "shear" else _normal_measures(g, [])
    out = {"cell": cell}
    for name in ("fluid", "gel"):
        a2 = flat[name]["area"]
        area = {t: l * h for t, l in flat[name]["length"].items()}
        area.update({Tag.FLOOR: a2, Tag.SYMMETRY_MID: a2})
        out[name] = {"volume": a2 * h, "area": area}
    gel = out["gel"]
    gel["volume"] -= cell["volume"]
    gel["area"][Tag.SYMMETRY_MID] -= cell["area"][Tag.SYMMETRY_MID]
    if cut:
        gel["area"][Tag.SYMMETRY_TOP] -= cut
    if cells:
        gel["area"][Tag.GAMMA2] = cell["area"][Tag.GAMMA2]
    else:
        del out["cell"]
    out["whole"] = _whole_measures_3d(out)
    return out


def _whole_measures_3d(regions: dict) -> dict:
    """The whole 3D device's volumes per region tag and areas per facet tag (interfaces counted once)."""
    volume = {REGIONS[k]: v["volume"] for k, v in regions.items()}
    area: dict = {}
    for v in regions.values():
        for tag, value in v["area"].items():
            shared = tag in (Tag.GAMMA1, Tag.GAMMA2, Tag.GAMMA3)
            area[tag] = value if shared else area.get(tag, 0.0) + value
    return {"volume": volume, "area": area}


def builtin_cells(params) -> list[CellSpec]:
    """The cells of a built-in device (none without the cell)."""
    if not params.with_cell:
        return []
    cells = params.geometry.cell_list()
    n = len(cells)
    height = getattr(params.geometry, "chip_height", None)
    out = []
    for k, (x, y, d) in enumerate(cells, start=1):
        half = params.case == "normal" and params.geometry.on_symmetry_line(y)
        centre = (x, y) if height is None else (x, y, 0.5 * height)     # 3D: on the mid-height plane
        symmetry = ((1,) if half else ()) + (() if height is None else (2,))
        out.append(CellSpec(index=k, name="cell" if n == 1 else f"cell_{k}", region_tag=cell_region_tag(k),
                            facet_tag=gamma2_tag(k), interface=gamma2_name(k, n), centre=centre, diameter=d,
                            symmetry=symmetry))
    return out


def device_boundaries(case: str, with_cell: bool, channel_height: float = 0.2,
                      cells: list[CellSpec] | None = None) -> DeviceBoundaries:
    """The boundary conditions of the ``"shear"`` or ``"normal"`` device (``cells``: its cells, default one)."""
    if cells is None:
        cell_ifaces = {"Gamma2": int(Tag.GAMMA2)} if with_cell else {}
    else:
        cell_ifaces = {c.interface: c.facet_tag for c in cells} if with_cell else {}
    if case == "shear":
        return DeviceBoundaries(
            fluid_velocity=[([int(Tag.INLET)], ParabolicInflow(channel_height)),
                            ([int(Tag.WALL)], (0.0, 0.0))],
            fluid_component=[],
            gel_no_slip=[int(Tag.BOWL)],
            gel_symmetry=[],
            cell_symmetry=[],
            fluid_interfaces={"Gamma1": int(Tag.GAMMA1)},
            cell_interfaces=cell_ifaces)
    if case == "normal":
        sym = [int(Tag.SYMMETRY_BOTTOM), int(Tag.SYMMETRY_TOP)]
        return DeviceBoundaries(
            fluid_velocity=[([int(Tag.INLET)], (1.0, 0.0))],
            fluid_component=[(sym, 1, 0.0)],
            gel_no_slip=[int(Tag.POST)],
            gel_symmetry=[(sym, 1)],
            cell_symmetry=([([int(Tag.SYMMETRY_TOP)], 1)] if cells is None or any(c.symmetry for c in cells)
                           else []),
            fluid_interfaces={"Gamma1": int(Tag.GAMMA1), "Gamma3": int(Tag.GAMMA3)},
            cell_interfaces=cell_ifaces)
    raise ValueError(f"case must be 'shear' or 'normal', got {case!r}")


def device_boundaries_3d(params: CaseParameters, cells: list[CellSpec]) -> DeviceBoundaries:
    """The conditions of a 3D device (model.md section 10): the planar ones with three components, plus

    * the floor z = 0: ``walls = "noslip"``: V = 0 (fluid), v_f = 0 and u_s = 0 (gel bonded);
      ``"symmetric"``: zero z component (the slab);
    * the mid-height plane z = H/2: zero z component of every field (the cells' flat faces too);
    * the inflow: the duct series with maximum 1 (shear) or plane Poiseuille with mean 1 (normal)
      between floor and lid; in the slab the planar profile, uniform in z (:class:`ChipInflow`).
    """
    g = params.geometry
    planar = device_boundaries(params.case, params.with_cell, getattr(g, "channel_height", 0.2), cells)
    floor, mid, walls = [int(Tag.FLOOR)], [int(Tag.SYMMETRY_MID)], g.walls == "noslip"
    shear = params.case == "shear"
    profile = ("duct" if shear else "plane") if walls else ("parabolic" if shear else "uniform")
    inflow = ChipInflow(profile, g.channel_height if shear else g.height, g.chip_height)
    velocity = [(tags, inflow if tags == [int(Tag.INLET)] else (0.0, 0.0, 0.0)) for tags, _ in planar.fluid_velocity]
    component = planar.fluid_component + [(mid, 2, 0.0)]
    gel_no_slip, gel_symmetry = list(planar.gel_no_slip), planar.gel_symmetry + [(mid, 2)]
    if walls:
        velocity.append((floor, (0.0, 0.0, 0.0)))
        gel_no_slip += floor
    else:
        component.append((floor, 2, 0.0))
        gel_symmetry.append((floor, 2))
    cell_symmetry = planar.cell_symmetry + ([(mid, 2)] if cells else [])
    return DeviceBoundaries(fluid_velocity=velocity, fluid_component=component, gel_no_slip=gel_no_slip,
                            gel_symmetry=gel_symmetry, cell_symmetry=cell_symmetry,
                            fluid_interfaces=planar.fluid_interfaces, cell_interfaces=planar.cell_interfaces, dim=3)


def builtin_layout(params: CaseParameters) -> DeviceLayout:
    """The layout of the ``shear`` or ``normal`` device of ``params`` (2D or 3D)."""
    cells = builtin_cells(params)
    if getattr(params.geometry, "chip_height", None) is not None:
        b = device_boundaries_3d(params, cells)
    else:
        b = device_boundaries(params.case, params.with_cell, getattr(params.geometry, "channel_height", 0.2), cells)
    return DeviceLayout(boundaries=b, cells=cells, fluid_interfaces=dict(b.fluid_interfaces),
                        wide=params.case == "normal")
