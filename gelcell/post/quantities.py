"""What users ask of a solved device: every quantity of model.md section 7, dimensionless and SI.

Units.  Fields are stored in the solvers' units (velocity V0, stress
s mu_s, displacement d L0, with s = d = Ca by default); ``summarize`` reports
every quantity in the paper's dimensionless units (L0, V0, mu_s) and, in an
``si`` block, in µm, µm/s and mPa.

Conventions of the reported quantities (model.md section 7):
  * maxima of |v_f|, |u_s|, |u_c| are taken over the P2 nodes;
  * stresses and strains are evaluated per cell at the vertices (a DG1
    interpolation of the exact expression, which is linear per cell for the
    small-strain part) and their extrema taken over those points, so that
    the result is independent of the partition;
  * von Mises:  sqrt(sxx^2 + syy^2 - sxx syy + 3 sxy^2), for strains applied
    to the Green-Lagrange strain E = (F^T F - I)/2;
  * the traction parts around the cell are the von Mises measures of -p I,
    phi_f sigma_f, phi_s sigma_s and their sum, maximised over the gel within
    one cell diameter of Gamma2 (distance from the cell's surface <= d);
  * the cell's centroid displacement is the area-weighted mean of u_c; in
    the normal-flow device it is that of the whole (mirrored) cell, whose y
    component vanishes by symmetry;
  * the volume change below Gamma1 is the change of area of the region bounded
    by Gamma1 (Gamma3) and the gel's fixed walls, cell included:
    int_gel (J - 1) + int_cell (J_c - 1); the cell's share is its term over the sum.
    Compression and dilatation largely cancel in it (by ~1e3 at baseline), so
    ``local_volume_change_magnitude`` = int |J - 1| is reported as its scale.

Kinematics.  With ``params.kinematics == "finite"`` stresses are the Cauchy
stresses of the current configuration (the fluid phase's with spatial
gradients, gel.lagrangian), the fluid fields live on the fluid's reference
mesh with ``fluid_mesh_displacement`` mapping it to the current domain, and
locations and profiles are given at the undeformed coordinates X (as on the
small-strain path).  ``model.max_displacement_gradient`` is reported on both
paths: it is the relative size of what the small-strain path neglects.
"""

from __future__ import annotations

import math

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem

import cell.forms as cell_forms
import gel.forms as gel_forms
from femtools.functions import global_max, interpolate, owned_values, von_mises
from femtools.interface import InterfaceNodes
from gelcell.case import CaseParameters
from gelcell.post.fields import DeviceFields

__all__ = ["DeviceQuantities", "combine_cells", "summarize", "gamma_profiles", "flat_quantities"]


# -- evaluation helpers ----------------------------------------------------------
def _max_norm(u: fem.Function) -> float:
    return global_max(np.linalg.norm(owned_values(u), axis=1), u.function_space.mesh.comm)


class _PointValues:
    """Values of scalar UFL expressions at the vertices of every cell (DG1 dofs), owned only."""

    def __init__(self, msh):
        self.space = fem.FunctionSpace(msh, ("DG", 1))
        n = self.space.dofmap.index_map.size_local
        self.points = self.space.tabulate_dof_coordinates()[:n, :msh.geometry.dim]
        self.comm = msh.comm

    def __call__(self, expr) -> np.ndarray:
        f = interpolate(expr, self.space)
        return f.x.array[: self.points.shape[0]].copy()

    def compile(self, expr):
        """A callable returning the values of ``expr`` (compiled once) for the current coefficients."""
        expression = fem.Expression(expr, self.space.element.interpolation_points())
        f = fem.Function(self.space)
        n = self.points.shape[0]

        def values() -> np.ndarray:
            f.interpolate(expression)
            return f.x.array[:n].copy()
        return values

    def extrema(self, values: np.ndarray, mask: np.ndarray | None = None):
        """Global (min, max) and the location of the max."""
        v = values if mask is None else values[mask]
        x = self.points if mask is None else self.points[mask]
        nowhere = [np.nan] * self.points.shape[1]
        local_max = (float(v.max()), x[int(np.argmax(v))].tolist()) if v.size else (-np.inf, nowhere)
        local_min = float(v.min()) if v.size else np.inf
        gathered = self.comm.allgather(local_max)
        vmax, where = max(gathered, key=lambda t: t[0])
        vmin = self.comm.allreduce(local_min, op=MPI.MIN)
        return vmin, vmax, where


def _cell_geometry(cell) -> tuple[np.ndarray, float]:
    """Centre and radius of a :class:`gelcell.geometry.CellSpec`."""
    return np.asarray(cell.centre, dtype=float), 0.5 * float(cell.diameter)


def _entity_mask(space, cells: np.ndarray, n: int) -> np.ndarray:
    """Boolean mask of the first ``n`` dofs (blocks) of ``space`` that belong to ``cells``."""
    mask = np.zeros(n, dtype=bool)
    dofs = np.unique(np.hstack([space.dofmap.cell_dofs(c) for c in cells])) if len(cells) else np.empty(0, int)
    dofs = dofs[dofs < n]
    mask[dofs] = True
    return mask


def combine_cells(states: list[dict]) -> dict:
    """The extremes over cells: the centroid displacement of the cell that moves most, the largest
    maxima and the widest von Mises ranges (one cell: its own values)."""
    if len(states) == 1:
        return dict(states[0])
    out = {"centroid_displacement": list(max(states, key=lambda c: math.hypot(*c["centroid_displacement"]))
                                         ["centroid_displacement"]),
           "max_displacement": max(c["max_displacement"] for c in states)}
    for key in ("von_mises_strain", "von_mises_stress"):
        out[key] = [min(c[key][0] for c in states), max(c[key][1] for c in states)]
    if all("max_traction_von_mises" in c for c in states):
        out["max_traction_von_mises"] = {k: max(c["max_traction_von_mises"][k] for c in states)
                                         for k in states[0]["max_traction_von_mises"]}
    return out


def _assemble(form, comm) -> float:
    return comm.allreduce(fem.assemble_scalar(form), op=MPI.SUM)


# -- the summary ------------------------------------------------------------------
class DeviceQuantities:
    """The quantities of model.md section 7 of one :class:`DeviceFields`, compiled once.

    Every form and expression is built on the (persistent) functions of
    ``fields`` with the coefficients as Constants, so evaluating again after
    the functions changed (the windows of a time-dependent run) compiles
    nothing.  ``summary()`` gives every quantity; ``timeseries_row()`` the
    cheap subset recorded per time window.
    """

    #: the columns of ``timeseries_row`` (after t, inflow)
    TIMESERIES = ("centroid_x", "centroid_y", "max_cell_displacement", "cell_strain_min", "cell_strain_max",
                  "cell_stress_min", "cell_stress_max", "max_interstitial_speed", "max_network_displacement",
                  "volume_change_below_gamma1")

    def __init__(self, fields: DeviceFields):
        self.fields = fields
        p = fields.params
        self.comm = comm = fields.comm
        gm = fields.gel_mesh
        c = self.coefficients = fields.gel_coefficients()
        u = fields.displacement
        self.axes = "xyz"[:gm.geometry.dim]      # the components of points and vectors
        self.gel_points = _PointValues(gm)
        dx_gel = ufl.Measure("dx", domain=gm)
        _, theta_gel, _ = gel_forms.kinematics(u, c.d)
        self._forms = {"dA_gel": fem.form(theta_gel * dx_gel), "dA_abs_gel": fem.form(abs(theta_gel) * dx_gel),
                       "area_gel": fem.form(fem.Constant(gm, 1.0) * dx_gel)}
        self._area = {"gel": _assemble(self._forms["area_gel"], comm), "cell": 0.0}
        self._phi_s = gel_forms.solid_fraction(u, c)
        self._sigma_s = gel_forms.network_stress(u, c)
        self._sigma_f = fields.fluid_stress(c)
        self._expressions = {}
        self.cell_points = None
        if fields.cell_displacement is not None:
            uc, cm = fields.cell_displacement, fields.cell_mesh
            k = lambda v: fem.Constant(cm, float(v))  # noqa: E731
            dc, sc = k(p.displacement_scale), k(p.stress_scale)
            dx_cell = ufl.Measure("dx", domain=cm)
            _, theta_cell, _ = cell_forms.kinematics(uc, dc)
            self._forms.update({f"centroid_{x}": fem.form(uc[k] * dx_cell) for k, x in enumerate(self.axes)})
            self._forms.update(dA_cell=fem.form(theta_cell * dx_cell),
                               dA_abs_cell=fem.form(abs(theta_cell) * dx_cell))
            self._area["cell"] = _assemble(fem.form(fem.Constant(cm, 1.0) * dx_cell), comm)
            self.cell_points = _PointValues(cm)
            sigma_c = cell_forms.cauchy_stress(uc, k(p.mu_c), k(p.lambda_c), dc, sc)
            self._expressions["strain"] = self.cell_points.compile(von_mises(cell_forms.green_lagrange(uc, dc)))
            self._expressions["stress"] = self.cell_points.compile(von_mises(sigma_c))
            # several cells: integrals over each cell's elements, extrema over each cell's points and nodes
            self._cell_parts = []
            cells = fields.cells
            if len(cells) > 1:
                ct = fields.cell_regions
                dx_k = ufl.Measure("dx", domain=cm, subdomain_data=ct)
                n_dg = self.cell_points.points.shape[0]
                Vc = uc.function_space
                n_p2 = Vc.dofmap.index_map.size_local
                for spec in cells:
                    elements = ct.find(spec.region_tag)
                    self._cell_parts.append({
                        "spec": spec,
                        **{f"centroid_{x}": fem.form(uc[k] * dx_k(spec.region_tag)) for k, x in enumerate(self.axes)},
                        "area": _assemble(fem.form(fem.Constant(cm, 1.0) * dx_k(spec.region_tag)), comm),
                        "points": _entity_mask(self.cell_points.space, elements, n_dg),
                        "nodes": _entity_mask(Vc, elements, n_p2)})

    def _integral(self, name: str) -> float:
        return _assemble(self._forms[name], self.comm)

    def _expression(self, name: str, expr):
        """The compiled gel point-value expression ``name`` (built on first use)."""
        if name not in self._expressions:
            self._expressions[name] = self.gel_points.compile(expr)
        return self._expressions[name]()

    def cell_states(self) -> list[dict]:
        """Per cell: centroid, max displacement and the von Mises ranges (paper units)."""
        f = self.fields
        if f.cell_displacement is None:
            return []
        p = f.params
        d, s = p.displacement_scale, p.stress_scale
        strain, stress = self._expressions["strain"](), self._expressions["stress"]()
        cells = f.cells
        if len(cells) <= 1:
            parts = [{"spec": cells[0] if cells else None, "centroid_x": None, "points": None, "nodes": None}]
        else:
            parts = self._cell_parts
        out = []
        for part in parts:
            spec = part["spec"]
            if part["centroid_x"] is None:
                centroid = [d * self._integral(f"centroid_{x}") / self._area["cell"] for x in self.axes]
                max_u = d * _max_norm(f.cell_displacement)
            else:
                centroid = [d * _assemble(part[f"centroid_{x}"], self.comm) / part["area"] for x in self.axes]
                norms = np.linalg.norm(owned_values(f.cell_displacement), axis=1)
                max_u = d * global_max(norms[part["nodes"]], self.comm)
            # a cell cut by a symmetry line: the whole (mirrored) cell's centroid moves along the line
            for comp in (spec.symmetry if spec is not None else ()):
                centroid[comp] = 0.0
            e_min, e_max, _ = self.cell_points.extrema(strain, part["points"])
            s_min, s_max, _ = self.cell_points.extrema(stress, part["points"])
            out.append({"centroid_displacement": centroid, "max_displacement": max_u,
                        "von_mises_strain": [e_min, e_max], "von_mises_stress": [s * s_min, s * s_max]})
        return out

    def volume_change(self) -> dict:
        d = self.fields.params.displacement_scale
        dA_gel = d * self._integral("dA_gel")
        dA_abs = d * self._integral("dA_abs_gel")
        dA_cell = 0.0
        if self.fields.cell_displacement is not None:
            dA_cell = d * self._integral("dA_cell")
            dA_abs += d * self._integral("dA_abs_cell")
        total = dA_gel + dA_cell
        return {"volume_change_below_gamma1": total,
                # int |J - 1|: the scale of the local dilatations whose sum the volume change is
                # (compression and dilatation largely cancel, so the sum is much smaller)
                "local_volume_change_magnitude": dA_abs,
                "relative_volume_change_below_gamma1": total / (self._area["gel"] + self._area["cell"]),
                "volume_change_share_of_cell": dA_cell / total if total != 0 else 0.0}

    def timeseries_row(self) -> dict[str, float]:
        """The per-window quantities (``TIMESERIES``, the cell ones the extremes over the cells; in 3D
        also ``centroid_z``; with several cells also ``cell_K_centroid_x/y(/z)`` and ``cell_K_strain_max``),
        paper units; NaN for cell ones without a cell."""
        f = self.fields
        d = f.params.displacement_scale
        row = dict.fromkeys(self.TIMESERIES + tuple(f"centroid_{x}" for x in self.axes[2:]), math.nan)
        states = self.cell_states()
        cell = combine_cells(states) if states else None
        if len(states) > 1:
            # several cells: each cell's centroid and peak strain too (columns cell_K_...)
            for k, st in enumerate(states, start=1):
                row.update({f"cell_{k}_centroid_{x}": v for x, v in zip(self.axes, st["centroid_displacement"])})
                row[f"cell_{k}_strain_max"] = st["von_mises_strain"][1]
        if cell is not None:
            row.update({f"centroid_{x}": v for x, v in zip(self.axes, cell["centroid_displacement"])})
            row.update(max_cell_displacement=cell["max_displacement"],
                       cell_strain_min=cell["von_mises_strain"][0], cell_strain_max=cell["von_mises_strain"][1],
                       cell_stress_min=cell["von_mises_stress"][0], cell_stress_max=cell["von_mises_stress"][1])
        row.update(max_interstitial_speed=_max_norm(f.interstitial_velocity),
                   max_network_displacement=d * _max_norm(f.displacement),
                   volume_change_below_gamma1=self.volume_change()["volume_change_below_gamma1"])
        return row

    def summary(self) -> dict:
        """Every quantity of model.md section 7, dimensionless (paper units) and SI."""
        f = self.fields
        p = f.params
        s, d = p.stress_scale, p.displacement_scale
        c, u, v_f, pp = self.coefficients, f.displacement, f.interstitial_velocity, f.pore_pressure
        gel_points = self.gel_points
        vm_network = self._expression("network", von_mises(self._sigma_s))
        _, vm_net_max, vm_net_where = gel_points.extrema(vm_network)
        grad_norm = self._expression("grad", ufl.sqrt(ufl.inner(ufl.grad(u), ufl.grad(u))))
        finite = p.kinematics == "finite"
        out = {
            "geometry": _geometry_block(p, len(self.axes)),
            "model": {
                "kinematics": p.kinematics,
                "approximation": ("finite strain: total Lagrangian gel and cell, the fluid domain following "
                                  "the gel's surface" if finite else
                                  "gel on the reference configuration (no mesh motion)"),
                # the relative size of the geometric terms the small-strain path drops
                "max_displacement_gradient": d * gel_points.extrema(grad_norm)[1],
            },
            "gel": {
                "max_interstitial_speed": _max_norm(v_f),
                "max_network_displacement": d * _max_norm(u),
                "max_network_von_mises": s * vm_net_max,
                "max_network_von_mises_location": vm_net_where,
            },
            "cell": None,
        }
        states = self.cell_states()
        if states:
            # traction parts: von Mises of each stress part in the gel within one diameter of each cell
            I = ufl.Identity(len(self.axes))
            parts = {"pressure": -pp * I, "brinkman": (1 - self._phi_s) * self._sigma_f,
                     "network": self._phi_s * self._sigma_s, "total": f.gel_forms.total_stress(v_f, u, pp, c)}
            values = {k: self._expression(f"part_{k}", von_mises(e)) for k, e in parts.items()}
            cells = f.cells
            for spec, state in zip(cells, states):
                centre, radius = _cell_geometry(spec)
                near = np.linalg.norm(gel_points.points - centre, axis=1) <= radius + 2 * radius * (1 + 1e-9)
                state["max_traction_von_mises"] = {k: s * gel_points.extrema(v, near)[1] for k, v in values.items()}
            out["cell"] = combine_cells(states)
            out["cells"] = [{"name": spec.name, "interface": spec.interface, "centre": list(spec.centre),
                             "diameter": spec.diameter, **state} for spec, state in zip(cells, states)]
        out["gel"].update(self.volume_change())
        out["si"] = _to_si(out, p)
        return out


def _geometry_block(p: CaseParameters, dim: int) -> dict:
    """``geometry`` of the summary: the dimension, and a 3D built-in device's chip height and walls."""
    height = getattr(p.geometry, "chip_height", None)
    return {"dimension": dim, "chip_height": height,
            "walls": None if height is None else p.geometry.walls}


def summarize(fields: DeviceFields) -> dict:
    """Every quantity of model.md section 7, dimensionless (paper units) and SI."""
    return DeviceQuantities(fields).summary()


def _to_si(out: dict, p: CaseParameters) -> dict:
    """The same quantities in µm, µm/s and mPa (strains and shares stay dimensionless)."""
    L = p.to_report(1.0, "length")
    V = p.to_report(1.0, "velocity")
    S = p.to_report(1.0, "stress")
    g = out["gel"]
    dim = out["geometry"]["dimension"]
    measure = {2: ("area", "µm^2"), 3: ("volume", "µm^3")}[dim]     # of the volume change
    si = {"model": dict(out["model"]),
          "units": {"length": "µm", "velocity": "µm/s", "stress": "mPa", measure[0]: measure[1]},
          "gel": {"max_interstitial_speed": g["max_interstitial_speed"] * V,
                  "max_network_displacement": g["max_network_displacement"] * L,
                  "max_network_von_mises": g["max_network_von_mises"] * S,
                  "max_network_von_mises_location": [x * L for x in g["max_network_von_mises_location"]],
                  "volume_change_below_gamma1": g["volume_change_below_gamma1"] * L ** dim,
                  "local_volume_change_magnitude": g["local_volume_change_magnitude"] * L ** dim,
                  "relative_volume_change_below_gamma1": g["relative_volume_change_below_gamma1"],
                  "volume_change_share_of_cell": g["volume_change_share_of_cell"]}}
    si["cell"] = None if out["cell"] is None else _cell_si(out["cell"], L, S)
    if out.get("cells"):
        si["cells"] = [{"name": c["name"], "centre": [x * L for x in c["centre"]], "diameter": c["diameter"] * L,
                        **_cell_si(c, L, S)} for c in out["cells"]]
    return si


def _cell_si(cl: dict, L: float, S: float) -> dict:
    return {"centroid_displacement": [x * L for x in cl["centroid_displacement"]],
            "max_displacement": cl["max_displacement"] * L,
            "von_mises_strain": list(cl["von_mises_strain"]),
            "von_mises_stress": [x * S for x in cl["von_mises_stress"]],
            "max_traction_von_mises": {k: v * S for k, v in cl["max_traction_von_mises"].items()}}


def gamma_profiles(fields: DeviceFields, interface: str = "Gamma1") -> dict[str, np.ndarray]:
    """v_f and u_s along a fluid-gel interface against the undeformed coordinates (paper units).

    Rows are sorted along the interface (by X on Gamma1 of the shear device,
    by Y on the vertical interfaces of the normal-flow device).  In 3D
    (model.md section 10) the profile is the interface's line at mid-height,
    its P2 nodes at z = H/2 (the symmetry plane, the top of the computed half
    height; a geometry file without ``chip_height``: :func:`_mid_height`), with
    the columns Z, v_fz and u_sz besides; v_fz = u_sz = 0 there by symmetry.
    """
    tag = int(fields.layout.fluid_interfaces[interface])
    d = fields.params.displacement_scale
    nodes = InterfaceNodes(fields.interstitial_velocity.function_space, fields.gel_tags, tag)
    on_line = _mid_height(fields, nodes.points) if nodes.points.shape[1] == 3 else slice(None)
    points = nodes.points[on_line]
    vf = nodes.from_function(fields.interstitial_velocity)[on_line]
    us = d * nodes.from_function(fields.displacement)[on_line]
    X, Y = points[:, 0], points[:, 1]
    order = np.argsort(X if np.ptp(X) >= np.ptp(Y) else Y, kind="stable")
    if points.shape[1] == 2:
        return {"X": X[order], "Y": Y[order], "v_fx": vf[order, 0], "v_fy": vf[order, 1],
                "u_sx": us[order, 0], "u_sy": us[order, 1]}
    return {"X": X[order], "Y": Y[order], "Z": points[order, 2],
            "v_fx": vf[order, 0], "v_fy": vf[order, 1], "v_fz": vf[order, 2],
            "u_sx": us[order, 0], "u_sy": us[order, 1], "u_sz": us[order, 2]}


def _mid_height(fields: DeviceFields, points: np.ndarray) -> np.ndarray:
    """Mask of the (replicated) interface nodes ``points`` on the plane z = H/2 (model.md section 10).

    A geometry file without chip_height: the top of a half-height mesh (with the SYMMETRY_MID plane), else
    the middle of the interface's z extent.
    """
    from gelcell.geometry import Tag
    H = fields.params.geometry.chip_height
    z = points[:, 2]
    half = fields.comm.allreduce(bool(np.any(fields.gel_tags.values == int(Tag.SYMMETRY_MID))), op=MPI.LOR)
    z_mid = 0.5 * H if H is not None else (z.max() if half else 0.5 * (z.min() + z.max()))
    mask = np.abs(z - z_mid) <= 1e-8 * (1.0 + abs(z_mid))
    if not mask.any():
        raise ValueError(f"no interface node at mid-height z = {z_mid:g} (the interface spans z in "
                         f"[{z.min():g}, {z.max():g}])")
    return mask


def flat_quantities(summary: dict) -> dict[str, float]:
    """Every scalar of a summary's ``gel``/``cell`` blocks as ``{"cell.von_mises_strain[1]": ...}``.

    Locations are left out; vectors are split by index and dicts by key.
    """
    out = {}
    for block in ("gel", "cell"):
        for key, value in (summary.get(block) or {}).items():
            if key.endswith("_location"):
                continue
            if isinstance(value, dict):
                out.update({f"{block}.{key}.{k}": v for k, v in value.items()})
            elif isinstance(value, (list, tuple)):
                out.update({f"{block}.{key}[{i}]": v for i, v in enumerate(value)})
            else:
                out[f"{block}.{key}"] = value
    return out
