"""Everything ``gelcell run`` writes: summary, fields, profiles, coupling records, figures.

All files of a run go to a temporary directory first, which replaces the
output directory only when every file has been written (femtools.io): a run
that fails leaves no partial results behind.

Fields are written in the paper's dimensionless units (lengths L0,
velocities V0, stresses mu_s); ``summary.json`` has both those and SI units.
"""

from __future__ import annotations

import csv
import json
import os

import h5py
import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem, io

import cell.forms as cell_forms
import gel.forms as gel_forms
from femtools.functions import interpolate, von_mises
from femtools.io import _jsonable
from gelcell.results import DeviceFields, gamma_profiles

__all__ = ["write_fields", "write_profiles", "write_json_file", "gather_p1"]


def write_json_file(path: str, data, comm: MPI.Comm) -> None:
    if comm.rank == 0:
        with open(path, "w") as f:
            json.dump(_jsonable(data), f, indent=2, ensure_ascii=False)
            f.write("\n")


def _scaled(f: fem.Function, factor: float, name: str) -> fem.Function:
    g = fem.Function(f.function_space, name=name)
    g.x.array[:] = factor * f.x.array
    return g


def derived_gel_fields(fields: DeviceFields) -> dict[str, fem.Function]:
    """Gel fields in paper units, on continuous P2 (von Mises interpolated at the nodes)."""
    p = fields.params
    s, d = p.stress_scale, p.displacement_scale
    c = fields.gel_coefficients()
    u, v_f, pp = fields.displacement, fields.interstitial_velocity, fields.pore_pressure
    Q2 = fem.FunctionSpace(fields.gel_mesh, ("Lagrange", 2))
    out = {"v_f": _scaled(v_f, 1.0, "v_f"), "u_s": _scaled(u, d, "u_s"), "p": _scaled(pp, s, "p")}
    out["von_mises_network"] = interpolate(s * von_mises(gel_forms.network_stress(u, c)), Q2,
                                           name="von_mises_network")
    phi_s = gel_forms.solid_fraction(u, c)
    parts = {"pressure": -pp * ufl.Identity(2), "brinkman": (1 - phi_s) * gel_forms.fluid_stress(v_f, c),
             "network": phi_s * gel_forms.network_stress(u, c), "total": gel_forms.total_stress(v_f, u, pp, c)}
    for key, expr in parts.items():
        out[f"von_mises_{key}_part"] = interpolate(s * von_mises(expr), Q2, name=f"von_mises_{key}_part")
    return out


def derived_cell_fields(fields: DeviceFields) -> dict[str, fem.Function]:
    """Cell fields in paper units: displacement, von Mises strain and stress (P2 nodal)."""
    p = fields.params
    s, d = p.stress_scale, p.displacement_scale
    uc = fields.cell_displacement
    cm = fields.cell_mesh
    k = lambda v: fem.Constant(cm, float(v))  # noqa: E731
    Q2 = fem.FunctionSpace(cm, ("Lagrange", 2))
    sigma = cell_forms.cauchy_stress(uc, k(p.mu_c), k(p.lambda_c), k(d), k(s))
    return {"u_c": _scaled(uc, d, "u_c"),
            "von_mises_strain": interpolate(von_mises(cell_forms.green_lagrange(uc, k(d))), Q2,
                                            name="von_mises_strain"),
            "von_mises_stress": interpolate(s * von_mises(sigma), Q2, name="von_mises_stress")}


def _write_xdmf(path: str, msh, functions, comm) -> None:
    with io.XDMFFile(comm, path, "w") as xf:
        xf.write_mesh(msh)
        for f in functions:
            xf.write_function(f, 0.0)


def write_fields(directory: str, fields: DeviceFields) -> list[str]:
    """fluid.xdmf (V, P), gel.xdmf (v_f, p, u_s, von Mises ...), cell.xdmf (u_c, strain, stress)."""
    comm = fields.comm
    p = fields.params
    written = []
    fluid = [_scaled(fields.fluid_velocity, 1.0, "V"), _scaled(fields.fluid_pressure, p.stress_scale, "P")]
    _write_xdmf(os.path.join(directory, "fluid.xdmf"), fields.fluid_velocity.function_space.mesh, fluid, comm)
    written.append("fluid.xdmf")
    _write_xdmf(os.path.join(directory, "gel.xdmf"), fields.gel_mesh, list(derived_gel_fields(fields).values()),
                comm)
    written.append("gel.xdmf")
    if fields.cell_displacement is not None:
        _write_xdmf(os.path.join(directory, "cell.xdmf"), fields.cell_mesh,
                    list(derived_cell_fields(fields).values()), comm)
        written.append("cell.xdmf")
    return written


def write_profiles(directory: str, fields: DeviceFields, comm: MPI.Comm) -> dict[str, dict]:
    """gamma1_profiles.h5/.csv (and gamma3_* for the normal-flow device), paper units."""
    names = ["Gamma1"] + (["Gamma3"] if fields.params.case == "normal" else [])
    out = {}
    for name in names:
        prof = gamma_profiles(fields, name)
        out[name] = prof
        if comm.rank == 0:
            stem = os.path.join(directory, f"{name.lower()}_profiles")
            with h5py.File(stem + ".h5", "w") as h5:
                h5.attrs["units"] = "X, Y in L0; v_f in V0; u_s in L0 (paper's dimensionless units)"
                h5.attrs["case"] = fields.params.case
                for key, values in prof.items():
                    h5.create_dataset(key, data=values)
            with open(stem + ".csv", "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(list(prof))
                for row in zip(*prof.values()):
                    w.writerow([f"{v:.12e}" for v in row])
    return out


def gather_p1(f: fem.Function | None, expr=None, msh=None):
    """Vertex coordinates, triangles and vertex values of a field, gathered on rank 0.

    ``f`` (or a UFL ``expr`` on ``msh``) is interpolated into P1; vector
    fields keep their components.  Returns ``(x, triangles, values)`` on
    rank 0 and ``None`` elsewhere.
    """
    msh = msh or f.function_space.mesh
    comm = msh.comm
    shape = (f.ufl_shape if f is not None else expr.ufl_shape)
    Q = fem.VectorFunctionSpace(msh, ("Lagrange", 1)) if shape else fem.FunctionSpace(msh, ("Lagrange", 1))
    g = interpolate(f if expr is None else expr, Q)
    imap, bs = Q.dofmap.index_map, Q.dofmap.index_map_bs
    n_owned = imap.size_local
    x = Q.tabulate_dof_coordinates()[:n_owned, :2]
    vals = g.x.array.reshape(-1, bs)[:n_owned]
    gidx = imap.local_to_global(np.arange(n_owned + imap.num_ghosts, dtype=np.int32))
    n_cells = msh.topology.index_map(2).size_local
    tri = gidx[Q.dofmap.list.array.reshape(-1, 3)[:n_cells]]
    parts = comm.gather((imap.local_range[0], x, vals, tri), root=0)
    if comm.rank != 0:
        return None
    n = imap.size_global
    X, V = np.zeros((n, 2)), np.zeros((n, bs))
    for start, xs, vs, _ in parts:
        X[start:start + len(xs)] = xs
        V[start:start + len(vs)] = vs
    T = np.vstack([t for *_, t in parts])
    return X, T, (V[:, 0] if bs == 1 else V)
