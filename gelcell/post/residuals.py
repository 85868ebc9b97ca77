"""Residual of every interface condition on a solution (partitioned or monolithic).

Works on :class:`gelcell.post.fields.DeviceFields`, so the same check applies to
both results.  Tractions are never differentiated from the fields at the
boundary; they enter as the consistent nodal forces of each field's bulk
weak form ("reactions"):

    t_j     the Stokes residual at interface node j: the force ON the fluid
    F_j     the gel's fluid-phase residual: the fluid-phase partial traction
            phi_f (sigma_f - p I) n, tested
    G_j     the gel's mixture residual: the total traction, tested
    N_j     = G_j - F_j, the network partial traction phi_s (sigma_s - p I) n, tested

and T, the fluid's traction on the gel as a P2 field, is recovered from -t
exactly as the fluid solver recovers it (interface mass matrix, interface
end nodes pinned).  Each condition of model.md section 3 on Gamma1/Gamma3
(n out of the gel, tau its tangent, v_s = 0), tested with the P2 basis
function phi_j of every interface node that is not also on a wall or a
symmetry line (in 3D: a wall, the floor or a symmetry plane), and multiplied
through by phi_s where it would divide by it:

    I13   int (V - phi_f v_f).n phi_j
    I14   G_j + t_j                                               (d components)
    I15   int phi_s Ca (V - v_f).n phi_j - eta (int phi_s T.n phi_j - N_j.n)
    I16   int Ca (V - v_f).tau phi_j + beta t_j.tau
    I17   -int Ca phi_s^2 v_f.tau phi_j + beta N_j.tau

In 3D (d = 3) the tangential conditions I16, I17 hold for both tangents
tau_1, tau_2 of the (plane) interface, and each is the residual of the pair.

Each residual vector's norm is divided by the norm of its largest term.
These are the equations the discrete problem satisfies, so both the
monolithic and the converged partitioned solution give solver-tolerance
residuals.  On Gamma2: |u_s - u_c| and |v_f| at the nodes, and the nodal
force balance of the gel's mixture residual and the cell's residual.

Finite kinematics (docs/finite-strain.md).  The reactions are those of the
pulled-back forms (fluid.ale, gel.lagrangian): nominal forces; the conditions
hold on the CURRENT interface, with its normal n and length ratio j = da/dA
(Nanson, from the gel's side), which vary along it, so each condition is
tested with the vector basis functions phi_j e_k:

    I13+I16   alpha_n int j (V - (phi_f v_f + phi_s v_s)).n n_k phi_j
              - int [T - (Ca/beta) j (V - v_f)]_t,k phi_j
    I14       G_j + t_j
    I15+I17   F_j - int [phi_f (T.n) n + T_t + j (Ca phi_s/eta) ((V - v_f).n) n
                         - j (Ca phi_s^2/beta) (v_f - v_s)_t]_k phi_j     (the gel's fluid phase)

with T the fluid's nominal traction recovered as the fluid recovers it.  On
a curved (current) interface the normal and the tangential parts of a
vector test function phi_j e_k are not polynomials, so I13 and I16 (and I15
and I17) cannot be tested one by one: the discrete problem enforces the
combinations above, the first with the fluid's Robin coefficient alpha_n as
weight (its Robin condition does; the monolithic reference weighs its rows
alike), and each condition alone only to the discretisation error.
"""

from __future__ import annotations

import numpy as np
import scipy.spatial

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

import cell.forms as cell_forms
import fluid.forms as fluid_forms
import gel.forms as gel_forms
import gel.lagrangian as gel_lagrangian
from femtools.continuum import surface_stretch
from femtools.interface import InterfaceNodes
from fluid.ale import ale_bulk_residual
from femtools.linalg import direct_solver
from gelcell.coupled.defaults import default_robin_coefficient
from gelcell.geometry import Tag
from gelcell.post.fields import DeviceFields

__all__ = ["interface_residuals", "format_residuals"]


def _reaction(form, V) -> PETSc.Vec:
    vec = fem_petsc.assemble_vector(fem.form(form))
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return vec


class _TraceProjection:
    """L2 projection onto the P2 trace of one interface, end nodes excluded."""

    def __init__(self, Q: fem.FunctionSpace, facet_tags, tag: int, exclude_points: np.ndarray):
        msh = Q.mesh
        self.Q, self.comm = Q, msh.comm
        self.nodes = InterfaceNodes(Q, facet_tags, tag)
        self.free = ~_among(self.nodes.points, exclude_points)
        self.ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags, metadata={"quadrature_degree": 6})(tag)
        u, v = ufl.TrialFunction(Q), ufl.TestFunction(Q)
        M = fem_petsc.assemble_matrix(fem.form(u * v * self.ds + fem.Constant(msh, 0.0) * u * v * ufl.dx))
        M.assemble()
        imap = Q.dofmap.index_map
        local = self.nodes.local_blocks[self.nodes.owned & self.free[self.nodes.index]]
        self.is_free = PETSc.IS().createGeneral((local + imap.local_range[0]).astype(PETSc.IntType), comm=self.comm)
        self.M = M.createSubMatrix(self.is_free, self.is_free)
        self.ksp = direct_solver(self.comm, self.M, "trace_projection")
        self.v = v

    def _solve(self, vec: PETSc.Vec) -> np.ndarray:
        b = vec.getSubVector(self.is_free)
        x = b.duplicate()
        self.ksp.solve(b, x)
        vec.restoreSubVector(self.is_free, b)
        out = vec.duplicate()
        out.zeroEntries()
        sub = out.getSubVector(self.is_free)
        x.copy(sub)
        out.restoreSubVector(self.is_free, sub)
        return self.nodes.from_array(out.array)[:, 0]

    def of_nodal_load(self, load: np.ndarray) -> np.ndarray:
        """Field whose trace moments are the given nodal loads (N,)."""
        f = fem.Function(self.Q)
        self.nodes.to_function(np.asarray(load).reshape(-1, 1), f)
        vec = f.vector.copy()
        return self._solve(vec)

    def tested(self, expr) -> np.ndarray:
        """``int_Gamma expr phi_j ds`` for every interface node j, ``(N,)``."""
        vec = fem_petsc.assemble_vector(fem.form(expr * self.v * self.ds))
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self.nodes.from_array(vec.array)[:, 0]


def _points_on(V, facet_tags, tags) -> np.ndarray:
    """Coordinates of the nodes of ``V`` on any facet with one of ``tags`` (all ranks)."""
    out = [np.empty((0, V.mesh.geometry.dim))]
    for t in tags:
        present = V.mesh.comm.allreduce(bool(np.any(facet_tags.values == t)), op=MPI.LOR)
        if present:
            out.append(InterfaceNodes(V, facet_tags, t).points)
    return np.vstack(out)


def _among(points: np.ndarray, others: np.ndarray, tol: float = 1e-10) -> np.ndarray:
    """Mask of ``points`` that coincide with one of ``others`` (nodes of two meshes differ by round-off)."""
    if others.shape[0] == 0:
        return np.zeros(points.shape[0], dtype=bool)
    dist, _ = scipy.spatial.cKDTree(others).query(points)
    return dist < tol


def _relative(terms: dict, free: np.ndarray) -> dict[str, float]:
    """``{name: |residual| / max |term|}`` over the free interface nodes."""
    out = {}
    for key, (res, *scales) in terms.items():
        scale = max(np.linalg.norm(np.asarray(sc)[free]) for sc in scales)
        out[key] = float(np.linalg.norm(np.asarray(res)[free]) / scale) if scale > 0 else 0.0
    return out


def _interface_reactions(fields: DeviceFields, name: str, tag: int) -> dict:
    """The reactions at the interface nodes and what each check needs besides (forms of the case's kinematics).

    ``t_fluid`` the Stokes residual (force ON the fluid), ``F_load``/``G_load`` the gel's fluid-phase and
    mixture residuals, ``V_on_gel`` the fluid velocity on the gel's nodes, ``proj`` the trace projection
    with the end nodes excluded.
    """
    p = fields.params
    visc = p.physics.ca / p.stress_scale
    c = fields.gel_coefficients()
    V_f, P_f = fields.fluid_velocity, fields.fluid_pressure
    v_f, u, pp = fields.interstitial_velocity, fields.displacement, fields.pore_pressure
    gm = fields.gel_mesh
    # reactions: fluid (force on the fluid), gel fluid phase and gel mixture
    Vfl = V_f.function_space
    dxf = ufl.Measure("dx", domain=Vfl.mesh, metadata={"quadrature_degree": 4})
    vt = ufl.TestFunction(Vfl)
    # numbers enter the forms as Constants: no parameter value (nor the normal's round-off) compiles anything
    visc_c = fem.Constant(Vfl.mesh, visc)
    if p.kinematics == "finite":
        d = fem.Constant(Vfl.mesh, p.displacement_scale)
        fluid_form = ale_bulk_residual(V_f, P_f, vt, 0, visc_c, fields.fluid_mesh_displacement, d, dxf)
    else:
        fluid_form = fluid_forms.bulk_residual(V_f, P_f, vt, 0, visc_c, dxf)
    fluid_nodes = InterfaceNodes(Vfl, fields.fluid_tags, tag)
    t_fluid = fluid_nodes.from_array(_reaction(fluid_form, Vfl).array)
    Vg = v_f.function_space
    dxg = ufl.Measure("dx", domain=gm, metadata={"quadrature_degree": 4})
    w = ufl.TestFunction(Vg)
    forms = fields.gel_forms
    R_w = _reaction(forms.fluid_phase_residual(v_f, u, pp, w, c, dxg), Vg)
    R_m = _reaction(forms.mixture_residual(v_f, u, pp, w, c, dxg), Vg)
    gel_nodes = InterfaceNodes(Vg, fields.gel_tags, tag)
    if not np.allclose(gel_nodes.points, fluid_nodes.points, rtol=0, atol=1e-10):
        raise RuntimeError(f"{name}: fluid and gel interface nodes differ")
    # the fluid velocity on the gel's interface nodes
    V_on_gel = fem.Function(Vg)
    gel_nodes.to_function(fluid_nodes.from_function(V_f), V_on_gel)
    Q = fem.FunctionSpace(gm, ("Lagrange", 2))
    present = set(np.unique(fields.fluid_tags.values).tolist()) | set(np.unique(fields.gel_tags.values).tolist())
    present = gm.comm.allreduce(present, op=MPI.BOR)
    others = sorted({int(t) for t in Tag} | {int(t) for t in present})
    others = [t for t in others if t != tag and t >= 10]
    ends = np.vstack([_points_on(Vfl, fields.fluid_tags, others), _points_on(Vg, fields.gel_tags, others)])
    return dict(c=c, t_fluid=t_fluid, F_load=gel_nodes.from_array(R_w.array), G_load=gel_nodes.from_array(R_m.array),
                V_on_gel=V_on_gel, gel_nodes=gel_nodes, Q=Q, Vg=Vg, Vfl=Vfl,
                proj=_TraceProjection(Q, fields.gel_tags, tag, ends))


def _fluid_interface_residuals(fields: DeviceFields, name: str, tag: int) -> dict[str, float]:
    if fields.params.kinematics == "finite":
        return _finite_fluid_interface_residuals(fields, name, tag)
    p = fields.params
    s = p.stress_scale
    ph = p.physics
    visc, eta, beta = ph.ca / s, ph.eta, ph.beta
    v_f, u, gm = fields.interstitial_velocity, fields.displacement, fields.gel_mesh
    r = _interface_reactions(fields, name, tag)
    c, t_fluid, F_f_load, T_gel_load = r["c"], r["t_fluid"], r["F_load"], r["G_load"]
    V_on_gel, gel_nodes, proj, Vg = r["V_on_gel"], r["gel_nodes"], r["proj"], r["Vg"]
    free = proj.free
    gdim = gm.geometry.dim
    # the fluid's traction on the gel as the field the gel was given: 2D with the ends pinned to 0 (every
    # component); 3D as the fluid recovers it, a component pinned where another boundary fixes it
    if gdim == 2:
        T = fem.Function(Vg)
        gel_nodes.to_function(np.column_stack([proj.of_nodal_load(-t_fluid[:, i]) for i in range(gdim)]), T)
    else:
        T = _recovered_traction(fields, tag, r)
    N_load = T_gel_load - F_f_load        # network partial traction, tested
    n, taus = _interface_frame(proj)
    nn = fem.Constant(gm, n)
    tt = [fem.Constant(gm, tau) for tau in taus]
    visc = fem.Constant(gm, visc)
    phi_s = gel_forms.solid_fraction(u, c)
    tested = proj.tested

    def tangential(term):
        """``(N, d - 1)``: ``term(tau_k as a Constant, tau_k)`` for each tangent tau_k."""
        return np.column_stack([term(t, tau) for t, tau in zip(tt, taus)])
    terms = {
        "I13": [tested(ufl.dot(V_on_gel - (1 - phi_s) * v_f, nn)), tested(ufl.dot(V_on_gel, nn))],
        "I14": [T_gel_load + t_fluid, t_fluid],
        "I15": [tested(phi_s * visc * ufl.dot(V_on_gel - v_f, nn))
                - eta * (tested(phi_s * ufl.dot(T, nn)) - N_load @ n),
                tested(phi_s * visc * ufl.dot(V_on_gel - v_f, nn)), eta * tested(phi_s * ufl.dot(T, nn))],
        "I16": [tangential(lambda t, tau: tested(visc * ufl.dot(V_on_gel - v_f, t)) + beta * (t_fluid @ tau)),
                tangential(lambda t, tau: tested(visc * ufl.dot(V_on_gel - v_f, t))),
                tangential(lambda t, tau: beta * (t_fluid @ tau))],
        "I17": [tangential(lambda t, tau: -tested(visc * phi_s**2 * ufl.dot(v_f, t)) + beta * (N_load @ tau)),
                tangential(lambda t, tau: tested(visc * phi_s**2 * ufl.dot(v_f, t))),
                tangential(lambda t, tau: beta * (N_load @ tau))],
    }
    return _relative(terms, free)


def _finite_fluid_interface_residuals(fields: DeviceFields, name: str, tag: int) -> dict[str, float]:
    """The conditions on the current interface, tested with phi_j e_k (module docstring)."""
    p = fields.params
    s, d = p.stress_scale, p.displacement_scale
    ph = p.physics
    visc, eta, beta = ph.ca / s, ph.eta, ph.beta
    v_f, u = fields.interstitial_velocity, fields.displacement
    gm = fields.gel_mesh
    r = _interface_reactions(fields, name, tag)
    c, t_fluid, F_load, G_load = r["c"], r["t_fluid"], r["F_load"], r["G_load"]
    V_on_gel, gel_nodes, proj, Vg, Vfl, Q = (r[k] for k in ("V_on_gel", "gel_nodes", "proj", "Vg", "Vfl", "Q"))
    free = proj.free
    gdim = gm.geometry.dim
    T = _recovered_traction(fields, tag, r)
    j, n = surface_stretch(u, fem.Constant(gm, d), ufl.FacetNormal(gm))
    phi_s = gel_lagrangian.solid_fraction(u, c)
    tangential = lambda a: a - ufl.dot(a, n) * n  # noqa: E731

    def tested(vector):
        """int vector_k phi_j for every interface node j, (N, d)."""
        return np.column_stack([proj.tested(vector[k]) for k in range(gdim)])
    # numbers enter the forms as Constants: no parameter value compiles anything
    visc, eta, beta = (fem.Constant(gm, float(v)) for v in (visc, eta, beta))
    alpha_n, alpha_t = default_robin_coefficient(p), visc / beta
    flux = gel_lagrangian.mixture_flux(v_f, u, c)
    i13 = tested(j * ufl.dot(V_on_gel - flux, n) * n)
    i16 = tested(tangential(T - alpha_t * j * (V_on_gel - v_f)))
    phase = [tested((1 - phi_s) * ufl.dot(T, n) * n + tangential(T)),
             tested(j * visc * phi_s / eta * ufl.dot(V_on_gel - v_f, n) * n),
             tested(j * visc * phi_s**2 / beta * tangential(v_f))]
    scale_13 = tested(j * ufl.dot(V_on_gel, n) * n)
    scales_16 = [tested(tangential(T)), tested(alpha_t * j * tangential(V_on_gel - v_f))]
    terms = {
        "I13+I16": [alpha_n * i13 - i16, alpha_n * scale_13, *scales_16],
        "I14": [G_load + t_fluid, t_fluid],
        "I15+I17": [F_load - phase[0] - phase[1] + phase[2], F_load, *phase],
    }
    return _relative(terms, free)


def _recovered_traction(fields: DeviceFields, tag: int, r: dict) -> fem.Function:
    """The fluid's traction on the gel as the fluid recovers it (fluid.solver), on the gel's space.

    A component is pinned (zero) only at the nodes where another boundary
    fixes that velocity component; ``r``: :func:`_interface_reactions`.
    """
    b = fields.layout.boundaries
    T = fem.Function(r["Vg"])
    columns = []
    for k in range(r["Vg"].mesh.geometry.dim):
        fixing = [t for tags, comps in b.fluid_dirichlet_tags() if k in comps for t in tags]
        proj_k = _TraceProjection(r["Q"], fields.gel_tags, tag, _points_on(r["Vfl"], fields.fluid_tags, fixing))
        columns.append(proj_k.of_nodal_load(-r["t_fluid"][:, k]))
    r["gel_nodes"].to_function(np.column_stack(columns), T)
    return T


def _interface_frame(proj) -> tuple[np.ndarray, list[np.ndarray]]:
    """Unit normal (out of the gel) and tangents of a straight (2D) or plane (3D) interface.

    2D: the tangent (-n_y, n_x); 3D: two orthonormal tangents, the first the
    projection (I - n n^T) of the axis least aligned with n.  The tangential
    conditions are tested with both, so which pair it is does not matter.
    """
    ds = proj.ds
    n_ufl = ufl.FacetNormal(proj.Q.mesh)
    gdim = proj.Q.mesh.geometry.dim
    length = proj.comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ds)), op=MPI.SUM)
    n = np.array([proj.comm.allreduce(fem.assemble_scalar(fem.form(n_ufl[i] * ds)), op=MPI.SUM)
                  for i in range(gdim)]) / length
    if abs(np.linalg.norm(n) - 1.0) > 1e-8:
        raise NotImplementedError("the interface-condition check assumes a straight (plane) interface")
    if gdim == 2:
        return n, [np.array([-n[1], n[0]])]
    axis = np.eye(3)[int(np.argmin(np.abs(n)))]
    t1 = axis - (axis @ n) * n
    t1 /= np.linalg.norm(t1)
    return n, [t1, np.cross(n, t1)]


def _cell_interface_residuals(fields: DeviceFields, spec) -> dict[str, float]:
    p = fields.params
    s, d = p.stress_scale, p.displacement_scale
    c = fields.gel_coefficients()
    v_f, u, pp, uc = fields.interstitial_velocity, fields.displacement, fields.pore_pressure, fields.cell_displacement
    Vg, Vc = v_f.function_space, uc.function_space
    gel_nodes = InterfaceNodes(Vg, fields.gel_tags, int(spec.facet_tag))
    cell_nodes = InterfaceNodes(Vc, fields.cell_tags, int(spec.facet_tag))
    if not np.allclose(gel_nodes.points, cell_nodes.points, rtol=0, atol=1e-10):
        raise RuntimeError(f"{spec.interface}: gel and cell interface nodes differ")
    dxg = ufl.Measure("dx", domain=Vg.mesh, metadata={"quadrature_degree": 4})
    dxc = ufl.Measure("dx", domain=Vc.mesh, metadata={"quadrature_degree": 4})
    R_m = gel_nodes.from_array(_reaction(fields.gel_forms.mixture_residual(v_f, u, pp, ufl.TestFunction(Vg), c,
                                                                           dxg), Vg).array)
    cm = Vc.mesh
    k = lambda v: fem.Constant(cm, float(v))  # noqa: E731
    R_c = cell_nodes.from_array(_reaction(cell_forms.residual(uc, ufl.TestFunction(Vc), k(p.mu_c), k(p.lambda_c),
                                                              k(d), k(s), dxc), Vc).array)
    # nodes where a symmetry condition also acts carry its reaction: leave out that component
    mask = np.ones_like(R_c, dtype=bool)
    for tags, comp in fields.layout.boundaries.cell_symmetry:
        sym = _points_on(Vc, fields.cell_tags, [int(t) for t in tags])
        mask[_among(cell_nodes.points, sym), comp] = False
    us, ucn = gel_nodes.from_function(u), cell_nodes.from_function(uc)
    vf = gel_nodes.from_function(v_f)
    return {
        "displacement": float(np.linalg.norm(us - ucn) / max(np.linalg.norm(ucn), 1e-300)),
        "no_slip": float(np.abs(vf).max() / max(np.abs(fields.interstitial_velocity.x.array).max(), 1e-300)),
        "traction": float(np.linalg.norm((R_m + R_c)[mask]) / max(np.linalg.norm(R_c[mask]), 1e-300)),
    }


def interface_residuals(fields: DeviceFields) -> dict[str, dict[str, float]]:
    """Relative residual of every interface condition, by interface."""
    out = {}
    for name, tag in fields.layout.fluid_interfaces.items():
        try:
            out[name] = _fluid_interface_residuals(fields, name, int(tag))
        except NotImplementedError:      # small-strain check of a curved interface: not available
            continue
    for spec in fields.cells:
        out[spec.interface] = _cell_interface_residuals(fields, spec)
    return out


def format_residuals(residuals: dict[str, dict[str, float]], title: str = "") -> str:
    lines = [f"interface-condition residuals{(' (' + title + ')') if title else ''}:"]
    for name, r in residuals.items():
        lines.append(f"  {name:7s} " + "  ".join(f"{k} {v:.1e}" for k, v in r.items()))
    return "\n".join(lines)
