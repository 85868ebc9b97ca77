"""Poroelastic gel field solver, steady or time-dependent (model.md sections 2, 3, 6 and 8).

Unknowns on the gel's own mesh (triangles in 2D, plane strain, or tetrahedra in 3D: the same
code; ``dim`` = 2 or 3 below is the mesh's dimension), in one mixed space in this order:

    w    relative velocity v_f - v_s of the interstitial fluid (P2 vector), units of V0
    u    network displacement u_s (P2 vector), units of d L0  (u_s = d u)
    p    pore pressure (P1), units of the stress unit s (in units of mu_s)

with v_f = w + v_s.  Steady state: v_s = 0, so w = v_f.  Time-dependent
(``transient=True``, quasi-static: no inertia), v_s = du_s/dt discretised by
backward Euler or (variable-step) BDF2:

    v_s^{n+1} = (d / dt) (a0 u^{n+1} + a1 u^n + a2 u^{n-1})

with (a0, a1, a2) = (1, -1, 0) for backward Euler and, for BDF2 with
omega = dt_n / dt_{n-1}, ((1 + 2 omega)/(1 + omega), -(1 + omega), omega^2/(1 + omega)).

The weak form is ``gel.forms`` (shared with the monolithic reference): the
fluid phase (G3) tested with w, the mixture balance (G3 + G4) tested with z,
and the mass balance div(phi_f v_f + phi_s v_s) = 0 (G2) tested with q, with
phi_s = phi_s0 / J and a neo-Hookean network.  Newton's method with the exact
Jacobian (``femtools.linalg.NewtonSolver``, Jacobian kept across calls while
it contracts, refactorised when dt changes).

Kinematics (``kinematics=``): ``"small"`` poses those equations on the
undeformed domain with gradients in X and the Cauchy stress in place of the
first Piola stress (exact to the size of the strains, ~1e-6 at the device's
loads); ``"finite"`` uses the total Lagrangian forms of ``gel.lagrangian``
(first Piola stress of the total stress, spatial gradients of the fluid
phase, Piola-transformed relative flux, interface terms on the current
interface by Nanson's formula, dJ/dt in the mass balance; docs/finite-strain.md).
Both linearise to the same operator at rest, so the kept Jacobian (and its
factorisation) is the same matrix on both paths.

Boundary conditions (n is the gel's outward normal everywhere):

* ``no_slip`` tags: w = 0 and u = 0, i.e. v_f = v_s = 0 (the chamber bowl, the posts).
* ``symmetry`` [(tags, c)]: w[c] = 0 and u[c] = 0; the tangential
  tractions of both phases are zero (natural).
* ``fluid_interfaces`` {name: tags} (Gamma1, Gamma3): the split of
  model.md section 6 as written in ``gel.forms.fluid_interface_residual``.
  Inputs (N, dim) each: ``traction`` T = (Sigma - P I) n, the fluid's traction
  ON the gel (force per unit length, area in 3D, stress unit s; with ``kinematics="finite"``
  per unit REFERENCE length, the nominal traction), ``velocity`` V, the
  fluid velocity (units of V0).  Outputs: ``mixture_velocity``
  phi_f v_f + phi_s v_s (its normal component is the volume flux from the gel
  into the fluid, I13), ``superficial_velocity`` phi_f v_f,
  ``interstitial_velocity`` v_f, ``traction`` the total traction the gel
  exerts there, (N, dim), and ``pressure`` p, (N, 1); finite kinematics add
  ``normal_flux`` (the consistent nodal volume flux through the current
  interface) and ``displacement`` (for the fluid's mesh motion).
* ``cell_interfaces`` {name: tags} (Gamma2): w = 0, i.e. v_f = v_s (= v_c,
  since u_s = u_c there and both use the same time discretisation).  Input
  ``force`` (N, dim): NODAL forces ON the gel from the cell (entries of a
  consistent load vector, units of s L0, not a traction density); they enter
  the mixture equation.  Output ``displacement`` (N, dim): nodal u in units of d L0.
  With an interface stiffness K (``set_interface_stiffnesses``, a Robin
  condition) the load is ``force + K (u* - u)``, u* the input
  ``displacement`` (N, dim) (units of d L0; unused without K).
* ``tractions`` [(tags, value)]: a dead load t on the mixture equation,
  (phi_f sigma_f + phi_s sigma_s - p I) n = t (stress unit s), e.g. a
  permeable piston on a drained surface (Terzaghi).
* Every other boundary is natural: zero partial tractions of both phases,
  i.e. phi_f (sigma_f - p I) n = 0 and phi_s sigma_s n = 0 (an open,
  load-free boundary at p = 0).

Interface inputs that are never set are zero.  All interface arrays follow
the rank-independent node order of ``femtools.interface.InterfaceNodes``.
``interface_jacobian()`` returns the input -> output map linearised at rest
(dense blocks per pair of interfaces, e.g. for a quasi-Newton coupling prior).

Time stepping (``transient=True``)::

    gel.set_time_step(dt, scheme="be")      # or "bdf2" (needs two past states)
    gel.solve()                             # the state at t + dt
    gel.push_history()                      # accept it: u^{n-1} <- u^n <- u
    state = gel.get_state()                 # a copy, e.g. for coupling iterations
    gel.set_state(state)
"""

from __future__ import annotations

import logging
import time
import typing

import numpy as np
import scipy.linalg
import scipy.spatial

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from ufl.algorithms import expand_derivatives
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from femtools.functions import quadrature_measure, set_function, von_mises
from femtools.interface import InterfaceNodes
from femtools.krylov import gel_solver, linear_solver_choice
from femtools.linalg import NewtonSolver, assemble_residual_vector, condensed_matrix, \
    gather_entries, gather_submatrix, jacobian_at_rest
from femtools.mesh import as_tags, tagged_facets
from femtools.canonical import CanonicalOrder, MixedCanonical
from femtools.solver import FieldSolver
from femtools.timestepping import RateHistory
from gel import forms, lagrangian
from gel.parameters import GelParameters

__all__ = ["PoroelasticGelSolver", "GelParameters", "KINEMATICS"]

#: ``"small"``: gel.forms (gradients in X, Cauchy stress as if it were the first Piola stress);
#: ``"finite"``: gel.lagrangian (total Lagrangian, exact kinematics; docs/finite-strain.md)
KINEMATICS = ("small", "finite")

log = logging.getLogger(__name__)

FIELDS = ("w", "u", "p")

# MUMPS options on top of femtools' defaults.  In the paper's units (s = d = 1)
# the fluid rows are ~Ca = 3e-10 times the network rows; without row/column
# equilibration MUMPS delays so many pivots in parallel that its workspace
# estimate fails (INFOG(1) = -9).  Iterative row/column scaling (ICNTL(8) = 8)
# and more workspace slack (ICNTL(14)) make both unit choices factorise alike.
DEFAULT_PETSC_OPTIONS = {"mat_mumps_icntl_8": 8, "mat_mumps_icntl_14": 200}
_FIELD_INDEX = {name: i for i, name in enumerate(FIELDS)}
_FIELD_INDEX["v_f"] = 0     # Dirichlet data for v_f are data for w (= v_f where v_s = 0)


def _inverse_row_max(M: PETSc.Mat) -> PETSc.Vec:
    """1 / the largest |entry| of each owned row of M (1 where there is none), in M's row layout."""
    indptr, _, values = M.getValuesCSR()
    counts = np.diff(indptr)
    out = np.ones(counts.size)
    nonempty = counts > 0
    if values.size:
        out[nonempty] = np.maximum.reduceat(np.abs(values), indptr[:-1][nonempty])
    vec = M.createVecLeft()
    vec.array[:] = 1.0 / np.where(out > 0, out, 1.0)
    return vec


def _equilibrate(K: PETSc.Mat) -> tuple[PETSc.Vec, PETSc.Vec]:
    """K <- Dr K Dc in place, rows, then columns, scaled by 1 / their largest |entry|; returns
    ``(dr, dc)`` (distributed, each rank its own rows; the columns' scales through K^T's rows)."""
    dr = _inverse_row_max(K)
    K.diagonalScale(L=dr)
    Kt = K.transpose(PETSc.Mat())          # a new matrix (without one, petsc4py transposes in place)
    dc = _inverse_row_max(Kt)
    Kt.destroy()
    K.diagonalScale(R=dc)
    return dr, dc


class _Positions:
    """The position in G of each global dof (-1 off G), without an array of the field's size."""

    def __init__(self, gamma: np.ndarray):
        self._order = np.argsort(gamma)
        self._sorted = gamma[self._order]

    def __getitem__(self, dofs) -> np.ndarray:
        d = np.asarray(dofs, dtype=np.int64)
        if self._sorted.size == 0:
            return np.full(d.shape, -1, dtype=np.int64)
        k = np.minimum(np.searchsorted(self._sorted, d), self._sorted.size - 1)
        return np.where(self._sorted[k] == d, self._order[k], -1)


def _interface_set(sel, pressure) -> tuple[np.ndarray, int]:
    """G = [flow dofs (w on fluid interfaces, one p), network dofs (u on all interfaces)], each part
    sorted, fixed dofs left out; returns ``(G, number of flow dofs)``."""
    w_dofs = [g.ravel() for (_, f), g in sel.items() if f == "w"]
    u_dofs = [g.ravel() for (_, f), g in sel.items() if f == "u"]
    gamma_f = np.unique(np.hstack(w_dofs + [pressure, np.empty(0, np.int64)]))
    gamma_u = np.unique(np.hstack(u_dofs + [np.empty(0, np.int64)]))
    gamma_f, gamma_u = gamma_f[gamma_f >= 0], gamma_u[gamma_u >= 0]
    return np.hstack([gamma_f, gamma_u]), gamma_f.size


def _positions(pos: _Positions, dofs) -> np.ndarray:
    """Positions in G of (N, dim) dofs, -1 where fixed (``pos``: the position of each dof, -1 off G)."""
    d = np.asarray(dofs).ravel()
    return np.where(d >= 0, pos[np.maximum(d, 0)], -1)


def _rows_of(pos: _Positions, dofs, Xin: np.ndarray) -> np.ndarray:
    """(dim N, n_in) rows of the interface state ``Xin`` at ``dofs`` (zero where fixed)."""
    g = _positions(pos, dofs)
    out = Xin[np.maximum(g, 0)]
    out[g < 0] = 0.0
    return out


def _solve_flow_first(S: np.ndarray, Dm: np.ndarray, nf: int, flow_cols: int) -> np.ndarray:
    """S'^-1 Dm (dense LU).  At rest the steady flow does not see the network: S' is then block
    lower-triangular in (flow, network) and is solved by blocks, the first ``flow_cols`` columns
    (the flow inputs) through both blocks."""
    ng = S.shape[0]
    X = np.zeros_like(Dm)
    if nf and np.abs(S[:nf, nf:]).max(initial=0.0) <= 1e-13 * np.abs(S).max(initial=0.0):
        X[:nf, :flow_cols] = scipy.linalg.lu_solve(scipy.linalg.lu_factor(S[:nf, :nf], check_finite=False),
                                                   Dm[:nf, :flow_cols], check_finite=False)
        rhs = Dm[nf:].copy()
        rhs[:, :flow_cols] -= S[nf:, :nf] @ X[:nf, :flow_cols]
        X[nf:] = scipy.linalg.lu_solve(scipy.linalg.lu_factor(S[nf:, nf:], check_finite=False), rhs,
                                       check_finite=False)
    elif ng:
        X = scipy.linalg.lu_solve(scipy.linalg.lu_factor(S, check_finite=False), Dm, check_finite=False)
    return X


def _mesh_dimension(mesh) -> int:
    """The gel's dimension: 2 (triangles in the plane) or 3 (tetrahedra); ValueError otherwise."""
    gdim, tdim = mesh.geometry.dim, mesh.topology.dim
    if tdim not in (2, 3) or gdim != tdim:
        raise ValueError(f"mesh must be 2D cells in the plane or 3D cells in space (geometric dimension = "
                         f"topological dimension, 2 or 3), got geometric {gdim}, topological {tdim}")
    return tdim


def _check_arguments(params, quadrature_degree, newton_rtol, kinematics) -> None:
    """Raise TypeError or ValueError naming the first argument of the gel solver that is wrong."""
    if not isinstance(params, GelParameters):
        raise TypeError(f"params must be a GelParameters, got {type(params).__name__}")
    if int(quadrature_degree) < 1:
        raise ValueError(f"quadrature_degree must be >= 1, got {quadrature_degree!r}")
    if not (0.0 < newton_rtol < 1.0):
        raise ValueError(f"newton_rtol must be in (0, 1), got {newton_rtol!r}")
    if kinematics not in KINEMATICS:
        raise ValueError(f"kinematics must be one of {KINEMATICS}, got {kinematics!r}")


class PoroelasticGelSolver(FieldSolver):
    """Steady poroelastic two-phase gel on its own mesh (see the module docstring).

    Args:
        mesh: the gel mesh (P1 or P2 geometry).
        facet_tags: facet tags of ``mesh``.
        params: ``GelParameters`` (dimensionless groups and the units s, d).
        no_slip: tags where v_f = 0 and u = 0.
        symmetry: ``[(tags, component)]``: w[component] = 0 and u[component] = 0.
        fluid_interfaces: ``{name: tags}`` fluid-gel interfaces (Gamma1, Gamma3).
        cell_interfaces: ``{name: tags}`` gel-cell interfaces (Gamma2).
        dirichlet: extra Dirichlet data, mainly for tests:
            ``[(tags, field, value)]`` or ``[(tags, field, value, component)]``
            with field in ``"w" | "u" | "p"`` (u in units of d L0, p in
            units of s; ``"v_f"`` is accepted for ``"w"``, which it equals
            where v_s = 0) and value a number, a vector of numbers, or a
            callable ``x -> values`` as for ``Function.interpolate``.
        tractions: ``[(tags, value)]``: dead loads on the mixture equation,
            total traction = value (stress unit s); value a (dim,) vector or a
            callable ``x -> (dim, n)``; change it with ``set_traction``.
        body_forces: optional ``(f_w, f_z, f_q)`` UFL expressions (manufactured
            solutions), see ``gel.forms.bulk_residual``.
        name: name of the solver (logs, PETSc option prefixes).
        quadrature_degree: quadrature degree of every integral (keep it equal
            to the monolithic reference's).
        petsc_options: overrides of the MUMPS LU options (defaults: femtools'
            plus ``DEFAULT_PETSC_OPTIONS``), or with ``solver="iterative"`` options of the
            Krylov solver (``femtools.krylov.gel_solver``, e.g. ``ksp_rtol``).
        solver: "direct" (MUMPS; block forward substitution of the linearisation at rest) or
            "iterative" (GMRES, block lower-triangular preconditioner: AMG on the flow and the
            network blocks, the pressure Schur complement as the sum of its Darcy + fixed-stress
            and its viscous inverses; ``femtools.krylov.PressureSchur``).
        newton_rtol: relative Newton tolerance |du| <= rtol |u|.
        transient: build the time-dependent forms (v_s from the displacement
            history, see the module docstring); the solver is steady until
            ``set_time_step`` is called.
        kinematics: ``"small"`` (``gel.forms``: the equations on the
            undeformed domain, exact to the size of the strains) or
            ``"finite"`` (``gel.lagrangian``: total Lagrangian, every geometric
            term kept; fluid interfaces then take the NOMINAL traction, force
            per unit reference length, and also return ``normal_flux`` and
            ``displacement``).
        newton_reuse: ``"adaptive"`` (keep the factorised Jacobian at rest while
            it contracts) or ``"never"`` (exact Newton, a factorisation per iteration).
        linear_path: each ``solve()`` takes one step with the kept
            linearisation at rest and the current interface data, and goes on
            to the exact Newton solution only if the nonlinear remainder
            matters (``femtools.linalg.NewtonSolver.solve``).  Exact for a
            linear problem; for a coupling loop whose every solve continues
            from the previous state (a steady partitioned run), the remainder
            converges with the coupling.  Default: the exact path.

    Example::

        params = GelParameters.viscous_units()            # s = d = Ca
        gel = PoroelasticGelSolver(msh, ft, params, no_slip=[BOWL],
                                   fluid_interfaces={"Gamma1": GAMMA1})
        gel.set_interface_data("Gamma1", traction=T, velocity=V)
        gel.solve()
        flux = gel.interface_data("Gamma1")["superficial_velocity"]
    """

    singular_hint = ("the network is not anchored (give a no_slip or Dirichlet condition on u), "
                     "or the pore pressure is fixed only up to a constant (leave the flow free somewhere)")

    def __init__(self, mesh, facet_tags, params: GelParameters, *,
                 no_slip: typing.Iterable[int] = (),
                 symmetry: typing.Iterable[tuple] = (),
                 fluid_interfaces: typing.Mapping[str, typing.Any] | None = None,
                 cell_interfaces: typing.Mapping[str, typing.Any] | None = None,
                 dirichlet: typing.Iterable[tuple] = (),
                 tractions: typing.Iterable[tuple] = (),
                 body_forces=None, name: str = "gel", quadrature_degree: int = 4,
                 petsc_options: dict | None = None, newton_rtol: float = 1e-11,
                 transient: bool = False, kinematics: str = "small", newton_reuse: str = "adaptive",
                 linear_path: bool = False, solver: str = "direct"):
        t0 = time.perf_counter()
        super().__init__(mesh)
        self._iterative = linear_solver_choice(solver, name)
        _check_arguments(params, quadrature_degree, newton_rtol, kinematics)
        self.dim = _mesh_dimension(mesh)
        self.kinematics = kinematics
        self._forms = forms if kinematics == "small" else lagrangian
        self.name = name
        self.mesh = mesh
        self.facet_tags = facet_tags
        self.quadrature_degree = int(quadrature_degree)
        self.transient = bool(transient)
        fluid_interfaces, cell_interfaces = self._interface_registry(fluid_interfaces, cell_interfaces)

        self._build_spaces()
        self.params = params
        self._build_coefficients(params)
        self.dx = quadrature_measure("dx", mesh, degree=self.quadrature_degree)
        self.ds = quadrature_measure("ds", mesh, facet_tags, degree=self.quadrature_degree)
        self.n = ufl.FacetNormal(mesh)

        self._build_time_terms()
        rel, u, p = ufl.split(self.state)
        w, z, q = ufl.TestFunctions(self.W)
        # the residual in two parts: the bulk (depends on the state only) and the interface and
        # load terms (boundary integrals, the only part that changes with the coupling data)
        F_state = self._state_residual(rel, u, p, w, z, q, body_forces)
        F_data = 0
        for iname, tags in fluid_interfaces.items():
            F_data += self._add_fluid_interface(iname, tags)
        for iname, tags in cell_interfaces.items():
            self._add_cell_interface(iname, tags)
        F_data += self._add_tractions(tractions, z)
        self.bcs = self._build_bcs(no_slip, symmetry, dirichlet)
        F = F_state + F_data
        self.residual_form = F
        self._newton = self._build_newton(F_state, F_data, F, petsc_options, newton_rtol, newton_reuse)
        self.linear_path = bool(linear_path)
        self._build_postprocessing()
        self.timing["setup"] = time.perf_counter() - t0
        self.timing["newton_iterations"] = 0

    # -- construction helpers ---------------------------------------------
    def _interface_registry(self, fluid_interfaces, cell_interfaces) -> tuple[dict, dict]:
        """The facet tags present on any rank, the empty interface registries and caches; returns the
        interface arguments as dicts (raises if a name is both a fluid and a cell interface)."""
        comm = self.mesh.comm
        self._present_tags = set(int(t) for t in np.unique(
            np.hstack(comm.allgather(np.unique(self.facet_tags.values)))))
        fluid_interfaces = dict(fluid_interfaces or {})
        cell_interfaces = dict(cell_interfaces or {})
        self._fluid, self._cell = {}, {}
        self._stiffness: dict[str, tuple[np.ndarray, np.ndarray]] = {}     # Robin operators of cell interfaces
        self._jacobian_cache: dict | None = None          # interface_jacobian(), at rest
        self._jacobian_form = None                         # its compiled data form
        clash = set(fluid_interfaces) & set(cell_interfaces)
        if clash:
            raise ValueError(f"interface names used both as fluid and cell interfaces: {sorted(clash)}")
        return fluid_interfaces, cell_interfaces

    def _state_residual(self, rel, u, p, w, z, q, body_forces):
        """The bulk residual (``gel.forms`` or ``gel.lagrangian``): the part that depends on the state only."""
        v_f = rel + self.v_s if self.transient else rel
        if self.kinematics == "small":
            return forms.bulk_residual(v_f, u, p, w, z, q, self.coefficients, self.dx, body_forces, self.v_s)
        dJdt = None if not self.transient else lagrangian.volume_rate(
            u, self.history.past, self.history.constants, self.coefficients.d)
        return lagrangian.bulk_residual(v_f, u, p, w, z, q, self.coefficients, self.dx, body_forces,
                                        self.v_s, dJdt)

    def _build_newton(self, F_state, F_data, F, petsc_options, newton_rtol, newton_reuse) -> NewtonSolver:
        """The Newton solver of ``F_state + F_data`` with the linearisation at rest as its kept Jacobian."""
        options = dict(DEFAULT_PETSC_OPTIONS, **(petsc_options or {}))
        # the kept Jacobian is the linearisation at rest (no state, no interface data): the same matrix
        # whenever it is needed, e.g. after a restart; the exact one takes over at large loads
        data = [d[k] for d in self._fluid.values() for k in ("T", "V")]
        data += list(self.history.past) if self.transient else []
        # at rest (steady) the flow's equations do not contain u: the linearisation is block
        # lower-triangular in ((w, p), u) and is factorised block by block (checked when assembled)
        flow = np.hstack([self._sub[0][1], self._sub[2][1]])
        J_reference = jacobian_at_rest(F, self.state, data)
        return NewtonSolver(F_state, self.state, self.bcs, name=self.name, rtol=newton_rtol, reuse=newton_reuse,
                            petsc_options=options, J_reference=J_reference,
                            F_data=F_data, reference_blocks=[flow, self._sub[1][1]],
                            linear_solver=self._krylov_solver(J_reference, petsc_options))

    def _krylov_solver(self, J_reference, petsc_options):
        """With ``solver="iterative"``: GMRES with the block preconditioner of ``femtools.krylov.gel_solver``,
        its pressure block from the coefficients at rest (else None)."""
        if not self._iterative:
            return None
        c = self.coefficients
        p, q = ufl.TrialFunctions(self.W)[2], ufl.TestFunctions(self.W)[2]
        phi_s, phi_f = c.phi_s0, 1 - c.phi_s0
        drag = c.viscosity * c.xi * phi_f * phi_s           # k of the Brinkman block
        nu_e = c.viscosity * phi_f                          # its viscous coefficient
        # fixed stress: c0 (v_s = c0 u + ...) over the drained bulk modulus phi_s (1 + lambda_s) stiffness
        beta = 0.0 if not self.transient else self.history.constants[0] / (c.stiffness * phi_s * (1 + c.lambda_s))
        # phi_f^2 / k p q: a Poincare-scale mass that keeps the Neumann Laplacian regular when beta = 0
        darcy = phi_f**2 / drag * (ufl.inner(ufl.grad(p), ufl.grad(q)) + p * q) + beta * p * q
        mass = (phi_f**2 / nu_e + beta) * p * q
        return gel_solver(self.W, self.name, fem.form(J_reference + darcy * self.dx), fem.form(mass * self.dx),
                          self.bcs, petsc_options)
    def _build_spaces(self) -> None:
        """Mixed space [w (P2 vector), u (P2 vector), p (P1)], its collapsed subspaces, the state."""
        cell = self.mesh.ufl_cell()
        P2 = ufl.VectorElement("Lagrange", cell, 2)
        P1 = ufl.FiniteElement("Lagrange", cell, 1)
        self.W = fem.FunctionSpace(self.mesh, ufl.MixedElement([P2, P2, P1]))
        self._sub = [self.W.sub(i).collapse() for i in range(3)]   # (space, parent dofs)
        self.Q2 = fem.FunctionSpace(self.mesh, ("Lagrange", 2))    # nodal scalars at the P2 nodes
        self.state = fem.Function(self.W, name=f"{self.name}_state")

    def _build_time_terms(self) -> None:
        """v_s = c0 u + c1 u^n + c2 u^{n-1} with Constants: one compiled form for BE, BDF2 and any dt."""
        self.v_s = None
        if not self.transient:
            return
        V_u, self._u_dofs = self._sub[1]
        self._u_dofs = np.asarray(self._u_dofs, dtype=np.int32)
        self.history = RateHistory(V_u, ufl.split(self.state)[1], self.params.displacement_scale, "u")
        self.v_s = self.history.rate
        self._velocity = fem.Function(V_u, name="v_s")       # nodal v_s of the current state
        # the node of the u space at each node of the w space (both P2 vector spaces on this mesh)
        V_w = self._sub[0][0]
        x_w, x_u = V_w.tabulate_dof_coordinates(), V_u.tabulate_dof_coordinates()
        dist, self._u_block_of_w = scipy.spatial.cKDTree(x_u).query(x_w)
        if dist.size and dist.max() > 1e-12 * (1.0 + np.abs(x_u).max()):
            raise RuntimeError(f"{self.name}: the w and u spaces do not share their nodes")

    def _build_coefficients(self, params: GelParameters) -> None:
        """Coefficients as Constants: one compiled form serves every parameter value."""
        self._const = {k: fem.Constant(self.mesh, PETSc.ScalarType(0.0)) for k in
                       ("phi_s0", "xi", "lambda_s", "beta", "eta", "viscosity", "stiffness", "d")}
        self.coefficients = forms.GelCoefficients(**self._const)
        self._stress_unit = fem.Constant(self.mesh, PETSc.ScalarType(0.0))   # s, output in units of mu_s
        self._assign_constants(params)

    def _add_fluid_interface(self, iname: str, tags) -> ufl.Form:
        """Declare a fluid interface; return its residual terms (gel.forms.fluid_interface_residual)."""
        tags = self._check_tags(tags, f"fluid_interfaces[{iname!r}]")
        V_vf, map_vf = self._sub[0]
        nodes = InterfaceNodes(V_vf, self.facet_tags, tags, parent_dofs=map_vf)
        scalar = InterfaceNodes(self.Q2, self.facet_tags, tags)
        if not np.array_equal(nodes.points, scalar.points):
            raise RuntimeError(f"{self.name}: {iname}: P2 vector and scalar interface nodes differ")
        V_u, map_u = self._sub[1]
        displacement_nodes = InterfaceNodes(V_u, self.facet_tags, tags, parent_dofs=map_u)
        if not np.array_equal(nodes.points, displacement_nodes.points):
            raise RuntimeError(f"{self.name}: {iname}: velocity and displacement interface nodes differ")
        T = fem.Function(V_vf, name=f"{iname}_traction")
        V = fem.Function(V_vf, name=f"{iname}_velocity")
        self._fluid[iname] = dict(tags=tags, nodes=nodes, scalar=scalar, displacement_nodes=displacement_nodes,
                                  T=T, V=V, traction=np.zeros((nodes.size, self.dim)))
        self._add_interface(iname, nodes, {"traction": self.dim, "velocity": self.dim})
        rel, u, _ = ufl.split(self.state)
        w, z, _ = ufl.TestFunctions(self.W)
        v_f = rel + self.v_s if self.transient else rel
        if self.kinematics == "finite":
            psi = ufl.TestFunction(V_vf)
            self._fluid[iname]["flux_form"] = fem.form(lagrangian.normal_flux_load(
                v_f, u, psi, self.n, self.coefficients, self.ds(tags), self.v_s))
        residual = self._forms.fluid_interface_residual(v_f, u, w, z, T, V, self.n, self.coefficients,
                                                        self.ds(tags), self.v_s)
        self._fluid[iname]["residual"] = residual          # for interface_jacobian()
        return residual

    def _add_cell_interface(self, iname: str, tags) -> None:
        """Declare a cell interface: the owned mixed-space u dofs that receive its nodal forces."""
        tags = self._check_tags(tags, f"cell_interfaces[{iname!r}]")
        V_u, map_u = self._sub[1]
        nodes = InterfaceNodes(V_u, self.facet_tags, tags, parent_dofs=map_u)
        n_owned = self.W.dofmap.index_map.size_local * self.W.dofmap.index_map_bs
        dofs = nodes.dofs(parent=True)                   # (n_local, dim) mixed-space dofs of u
        keep = np.all(dofs < n_owned, axis=1)            # owned by this rank in the MIXED space
        self._cell[iname] = dict(tags=tags, nodes=nodes, dofs=dofs[keep], rows=nodes.index[keep],
                                 force=np.zeros((nodes.size, self.dim)),
                                 displacement=np.zeros((nodes.size, self.dim)))
        self._add_interface(iname, nodes, {"force": self.dim, "displacement": self.dim})

    def set_interface_stiffnesses(self, stiffnesses: typing.Mapping[str, np.ndarray]) -> None:
        """Robin conditions on cell interfaces: on each ``name``, the load becomes ``force + K (u* - u)``.

        ``stiffness`` K: (dim N, dim N), rows and columns ``dim i + c`` (node i of
        ``interface_points(name)``, component c), units of s L0 per unit of
        d L0: the neighbour's Steklov-Poincare operator (the nodal forces it
        needs to hold a nodal displacement).  u* is the input ``displacement``
        (the neighbour's own displacement there, with which it exerts
        ``force``).  The gel then carries the neighbour's stiffness itself: a
        Dirichlet-Neumann iteration on the interface converges at once for a
        linear neighbour, and at the fixed point u = u* and the load is
        ``force`` again.  K is symmetrised; entries on Dirichlet dofs of the
        gel are left out.
        """
        for name, stiffness in stiffnesses.items():
            if name not in self._cell:
                raise KeyError(f"{self.name}: {name!r} is not a cell interface; cell interfaces: "
                               f"{sorted(self._cell)}")
            nodes = self._cell[name]["nodes"]
            K = np.asarray(stiffness, dtype=float)
            n = self.dim * nodes.size
            if K.shape != (n, n):
                raise ValueError(f"{self.name}: the stiffness of {name!r} must be ({n}, {n}) for its "
                                 f"{nodes.size} nodes in {self.dim}D, got {K.shape}")
            if not np.all(np.isfinite(K)):
                raise ValueError(f"{self.name}: the stiffness of {name!r} contains NaN or Inf")
            self._stiffness[name] = (nodes.global_dofs(self.W, parent=True, bcs=self.bcs).ravel(), 0.5 * (K + K.T))
        # one block per interface (cells do not touch each other), handed over once for all of them
        self._newton.set_interface_stiffness(np.hstack([d for d, _ in self._stiffness.values()]),
                                             scipy.linalg.block_diag(*[k for _, k in self._stiffness.values()]))
        self._jacobian_cache = None

    def _add_tractions(self, tractions, z) -> ufl.Form:
        """Dead loads on the mixture equation: - int t . z ds on each entry's facets."""
        self._tractions = []
        F = 0
        for k, entry in enumerate(tractions):
            if not isinstance(entry, (tuple, list)) or len(entry) != 2:
                raise ValueError(f"{self.name}: tractions[{k}] must be (tags, value), got {entry!r}")
            tags = self._check_tags(entry[0], f"tractions[{k}]")
            t = fem.Function(self._sub[1][0], name=f"traction_{k}")
            self._tractions.append(t)
            self.set_traction(k, entry[1])
            F -= ufl.dot(t, z) * self.ds(tags)
        return F

    def set_traction(self, index: int, value) -> None:
        """Change ``tractions[index]``: a (dim,) vector or a callable ``x -> (dim, n)`` (stress unit s)."""
        set_function(self._tractions[index], value, f"{self.name}: tractions[{index}]")

    def _build_bcs(self, no_slip, symmetry, dirichlet) -> list:
        """Dirichlet conditions: no slip, symmetry, w = 0 on cell interfaces, extra data."""
        self._bc_functions = []
        bcs = []
        if isinstance(no_slip, (int, np.integer)) or len(tuple(no_slip)) > 0:
            tags = self._check_tags(no_slip, "no_slip")
            bcs += [self._dirichlet(tags, "w", 0.0), self._dirichlet(tags, "u", 0.0)]
        for entry in symmetry:
            try:
                tags, comp = entry
            except (TypeError, ValueError):
                raise ValueError(f"symmetry entries are (tags, component), got {entry!r}") from None
            tags = self._check_tags(tags, "symmetry")
            bcs += [self._dirichlet(tags, "w", 0.0, comp), self._dirichlet(tags, "u", 0.0, comp)]
        for data in self._cell.values():
            bcs.append(self._dirichlet(data["tags"], "w", 0.0))
        for entry in dirichlet:
            if not isinstance(entry, (tuple, list)) or len(entry) not in (3, 4):
                raise ValueError(f"dirichlet entries are (tags, field, value[, component]), got {entry!r}")
            bcs.append(self._dirichlet(self._check_tags(entry[0], "dirichlet"), *entry[1:]))
        return bcs

    def _build_postprocessing(self) -> None:
        """Forms for the nodal phi_f average and the P1 -> P2 pressure interpolation."""
        _, u, p = ufl.split(self.state)
        psi = ufl.TestFunction(self.Q2)
        ds_all = quadrature_measure("ds", self.mesh, degree=self.quadrature_degree)
        phi_f = 1 - forms.solid_fraction(u, self.coefficients)
        if self.dim == 2:
            # weights int psi_i ds (h/6 at the vertices, 2h/3 at the midpoint of a P2 edge)
            self._phi_f_num = fem.form(phi_f * psi * ds_all)
            self._phi_f_den = fem.form(psi * ds_all)
        else:
            # int psi_i dA is zero for the vertex functions of a P2 triangle: weights int psi_i^2 dA,
            # the diagonal of the boundary mass matrix
            chi = ufl.TrialFunction(self.Q2)
            self._phi_f_num = fem.form(phi_f * chi * psi * ds_all)
            self._phi_f_den = fem.form(chi * psi * ds_all)
            self._boundary_matrices = {}
        self._p_expr = fem.Expression(p, self.Q2.element.interpolation_points())
        self._p2 = fem.Function(self.Q2)
        # the nodal pressure is read on the fluid interfaces only: interpolate on their cells
        tdim = self.mesh.topology.dim
        self.mesh.topology.create_connectivity(tdim - 1, tdim)
        f2c = self.mesh.topology.connectivity(tdim - 1, tdim)
        facets = tagged_facets(self.facet_tags, [t for d in self._fluid.values() for t in d["tags"]])
        self._interface_cells = np.unique(np.hstack([f2c.links(f) for f in facets] + [np.empty(0, np.int32)])
                                          ).astype(np.int32)

    def _check_tags(self, tags, what: str) -> tuple[int, ...]:
        tags = as_tags(tags, what)
        missing = [t for t in tags if t not in self._present_tags]
        if missing:
            raise ValueError(f"{self.name}: {what}: facet tag(s) {missing} not in the mesh's facet tags "
                             f"{sorted(self._present_tags)}")
        return tags

    def _dirichlet(self, tags, field: str, value, component: int | None = None) -> fem.DirichletBCMetaClass:
        """Dirichlet condition on ``field`` (optionally one component) on facets ``tags``."""
        if field not in _FIELD_INDEX:
            raise ValueError(f"{self.name}: Dirichlet field must be one of {FIELDS}, got {field!r}")
        i = _FIELD_INDEX[field]
        sub = self.W.sub(i)
        if component is not None:
            if field == "p" or component not in range(self.dim):
                raise ValueError(f"{self.name}: component must be in 0..{self.dim - 1} for w and u "
                                 f"(None for p), got {component!r} for {field!r}")
            sub = sub.sub(int(component))
        space, _ = sub.collapse()
        g = set_function(fem.Function(space), value, f"{self.name}: Dirichlet value for {field!r}")
        facets = tagged_facets(self.facet_tags, tags)
        dofs = fem.locate_dofs_topological((sub, space), self.mesh.topology.dim - 1, facets)
        self._bc_functions.append(g)
        return fem.dirichletbc(g, dofs, sub)

    def _assign_constants(self, params: GelParameters) -> None:
        values = dict(phi_s0=params.phi_s0, xi=params.xi, lambda_s=params.lambda_s, beta=params.beta,
                      eta=params.eta, viscosity=params.viscosity, stiffness=params.stiffness,
                      d=params.displacement_scale)
        for k, v in values.items():
            self._const[k].value = v
        self._stress_unit.value = params.stress_scale

    def update_parameters(self, params: GelParameters) -> None:
        """Change the parameters without recompiling; the next solve refactorises.

        Note that changing ``stress_scale`` or ``displacement_scale`` changes
        the units of the state and of all interface data.
        """
        if not isinstance(params, GelParameters):
            raise TypeError(f"params must be a GelParameters, got {type(params).__name__}")
        self.params = params
        self._assign_constants(params)
        if self.transient:
            self.history.set_scale(params.displacement_scale)
            self._update_velocity()
        self._newton.invalidate_jacobian()
        self._jacobian_cache = None

    # -- time stepping -------------------------------------------------------
    def _require_transient(self, what: str) -> None:
        if not self.transient:
            raise RuntimeError(f"{self.name}: {what} needs a solver built with transient=True")

    def set_time_step(self, dt: float, scheme: str = "be", dt_previous: float | None = None) -> None:
        """Use v_s = (d/dt)(a0 u + a1 u^n + a2 u^{n-1}) for the next solves (see the module docstring).

        Args:
            dt: the step t^{n+1} - t^n in the paper's time unit L0/V0, > 0.
            scheme: ``"be"`` (backward Euler) or ``"bdf2"`` (variable-step
                BDF2; needs two past states, i.e. ``push_history`` called twice).
            dt_previous: t^n - t^{n-1} for BDF2 (default: ``dt``).
        """
        self._require_transient("set_time_step")
        if self.history.set_step(dt, scheme, dt_previous):
            # the Jacobian holds (d/dt) a0: a new factorisation for a new step size or scheme
            self._newton.invalidate_jacobian()
            self._jacobian_cache = None
        self._update_velocity()

    def set_steady(self) -> None:
        """v_s = 0 again: the next solves are steady (the history is kept)."""
        self._require_transient("set_steady")
        if self.history.set_steady():
            self._newton.invalidate_jacobian()
            self._jacobian_cache = None
        self._update_velocity()

    def _update_velocity(self) -> None:
        """Nodal v_s of the current state (same P2 space as u, so the combination is exact)."""
        self._velocity.x.array[:] = self.history.nodal_rate(self.state.x.array[self._u_dofs])

    def push_history(self) -> None:
        """Accept the current state as the newest past state: u^{n-1} <- u^n <- u."""
        self._require_transient("push_history")
        self.history.push(self.state.x.array[self._u_dofs])
        self._update_velocity()

    @property
    def history_length(self) -> int:
        """Number of past states held (0, 1 or 2): 2 are needed for BDF2."""
        self._require_transient("history_length")
        return self.history.length

    def get_state(self) -> dict[str, np.ndarray]:
        """A copy of the local state: the unknowns and the displacement history (this rank's arrays)."""
        state = {"state": self.state.x.array.copy()}
        if self.transient:
            state.update(self.history.state())
        return state

    def _canonical_orders(self) -> None:
        if not hasattr(self, "_canonical"):
            self._canonical = MixedCanonical(self.W, FIELDS)
            self._canonical_u = CanonicalOrder(self._sub[1][0])

    def checkpoint_state(self) -> dict:
        """The state in the partition-independent node order (``femtools.canonical``), same on every rank.

        A run restarted on another partition (or rank count) reads it back
        with :meth:`load_checkpoint_state`.
        """
        self._canonical_orders()
        state = {f"state_{k}": v for k, v in self._canonical.gather(self.state.x.array).items()}
        if self.transient:
            state.update(past_0=self._canonical_u.gather(self.history.past[0].x.array),
                         past_1=self._canonical_u.gather(self.history.past[1].x.array),
                         length=np.array(self.history.length), step=self.history.step_state())
        state["newton"] = self._newton.checkpoint_state()      # the linear path's starting point
        return state

    def load_checkpoint_state(self, state: typing.Mapping[str, np.ndarray]) -> None:
        """Restore a state written by :meth:`checkpoint_state` (any partition)."""
        self._canonical_orders()
        self._canonical.scatter({k: state[f"state_{k}"] for k in FIELDS}, self.state.x.array)
        if self.transient:
            local = {f"past_{k}": self._canonical_u.scatter(state[f"past_{k}"]) for k in (0, 1)}
            self.history.load({**local, "length": state["length"]})
            if "step" in state:
                # v_s of the saved state is that of its step: a run resumed after its last window
                # reports the quantities (interstitial speed, tractions) of that window
                self.history.load_step(state["step"])
                self._newton.invalidate_jacobian()
                self._jacobian_cache = None
            self._update_velocity()
        self._newton.load_checkpoint_state(state.get("newton", {}))

    def set_state(self, state: typing.Mapping[str, np.ndarray]) -> None:
        """Restore a state returned by ``get_state`` on this rank (copies from it)."""
        values = np.asarray(state["state"], dtype=float)
        if values.shape != self.state.x.array.shape:
            raise ValueError(f"{self.name}: state has shape {values.shape}, expected {self.state.x.array.shape}")
        self.state.x.array[:] = values
        if self.transient:
            self.history.load(state)
            self._update_velocity()

    # -- FieldSolver interface -------------------------------------------
    def _set_input(self, interface: str, key: str, values: np.ndarray) -> None:
        if interface in self._fluid:
            data = self._fluid[interface]
            if key == "traction":
                data["traction"] = values.copy()
                data["nodes"].to_function(values, data["T"])
            else:
                data["nodes"].to_function(values, data["V"])
        else:
            self._cell[interface][key] = values.copy()

    def _solve(self) -> None:
        dofs = [d["dofs"].ravel() for d in self._cell.values()]
        vals = [self._cell_load(name)[d["rows"]].ravel() for name, d in self._cell.items()]
        self._newton.set_nodal_loads(np.hstack(dofs).astype(np.int32) if dofs else np.empty(0, np.int32),
                                     np.hstack(vals) if vals else np.empty(0))
        its = self._newton.solve(linear_path=self.linear_path)
        if self.transient:
            self._update_velocity()
        self.timing["newton_iterations"] += its
        log.debug("%s: Newton converged in %d iterations, corrections %s", self.name, its,
                  self._newton.history)

    def _cell_load(self, name: str) -> np.ndarray:
        """The nodal load on cell interface ``name`` but for -K u: force + K u* (N, dim)."""
        d = self._cell[name]
        if name not in self._stiffness:
            return d["force"]
        K = self._stiffness[name][1]
        return d["force"] + (K @ d["displacement"].ravel()).reshape(d["force"].shape)

    def interface_data(self, name: str) -> dict[str, np.ndarray]:
        """Outputs on interface ``name`` (see the module docstring).

        Fluid interfaces:
            ``mixture_velocity`` (N, dim): phi_f v_f + phi_s v_s at the nodes (units of
                V0); its normal part is the volume flux into the fluid (I13).
            ``superficial_velocity`` (N, dim): phi_f v_f at the nodes,
                with phi_f the boundary-lumped average of 1 - phi_s0/J around each
                node (weights int psi_i ds in 2D, int psi_i^2 ds in 3D; J is discontinuous
                between cells; the average is rank-independent).
            ``interstitial_velocity`` (N, dim): nodal v_f = w + v_s.
            ``traction`` (N, dim): the total traction (phi_f sigma_f + phi_s sigma_s - p I) n
                the gel applies there, in the stress unit s.  The gel enforces I14,
                T_total = T, weakly in its mixture equation, so this is the input T
                (returned as given: the nodal reaction of the mixture equation would
                only restate the input's consistent load vector).
            ``pressure`` (N, 1): nodal pore pressure p (units of s).
            With ``kinematics="finite"`` also
            ``normal_flux`` (N, dim): the consistent nodal vector
                int j (phi_f v_f + phi_s v_s).n (psi_i n) dA of the volume flux
                through the CURRENT interface (n its normal, j = da/dA; units V0 L0),
                ``gel.lagrangian.normal_flux_load``;
            ``displacement`` (N, dim): nodal u (units of d L0), for the fluid's mesh motion.
        Cell interfaces:
            ``displacement`` (N, dim): nodal u in units of d L0.
        """
        nodes = self.interface_nodes(name)
        x = self.state.x.array
        if name in self._fluid:
            data = self._fluid[name]
            v = nodes.from_array(x, parent=True)
            phi_f = self._phi_f_nodal(data["scalar"])
            mixture = phi_f * v
            if self.transient:
                v_s = data["displacement_nodes"].from_function(self._velocity)
                mixture = phi_f * v + v_s          # phi_f (w + v_s) + phi_s v_s
                v = v + v_s
            out = {"mixture_velocity": mixture,
                   "superficial_velocity": phi_f * v,
                   "interstitial_velocity": v,
                   "traction": data["traction"].copy(),
                   "pressure": self._pressure_nodal(data["scalar"])}
            if self.kinematics == "finite":
                vec = assemble_residual_vector(data["flux_form"])
                out["normal_flux"] = nodes.from_array(vec.array)
                vec.destroy()
                out["displacement"] = data["displacement_nodes"].from_array(x, parent=True)
            return out
        return {"displacement": nodes.from_array(x, parent=True)}

    # -- linearised interface map -----------------------------------------
    def interface_jacobian(self) -> dict[tuple[tuple[str, str], tuple[str, str]], np.ndarray]:
        """The interface input -> output map linearised at rest, as dense blocks (same on every rank).

        Returns ``{((out_interface, out_key), (in_interface, in_key)): J}`` for
        every pair of interfaces, J of shape ``(dim N_out, dim N_in)`` with row
        ``dim i + c`` = node i of ``interface_points(out_interface)``, component
        c, and columns likewise for the input: the derivative of
        ``interface_data(out_interface)[out_key]`` with respect to the input
        array of ``set_interface_data(in_interface, **{in_key: array})``, at
        the zero state with zero interface data, i.e. through the kept
        Jacobian ``J_reference`` (with the Dirichlet conditions and the
        interface stiffnesses of ``set_interface_stiffnesses``).

        Inputs: fluid interfaces ``traction``, ``velocity``; cell interfaces
        ``force`` and ``displacement`` (d/du* = d/dforce K; a zero block
        without a stiffness).  Outputs: fluid interfaces ``traction`` (the
        identity with respect to its own traction input), ``mixture_velocity``,
        ``superficial_velocity`` (both (1 - phi_s0) v_f at rest),
        ``interstitial_velocity`` and with ``kinematics="finite"`` also
        ``normal_flux`` and ``displacement``; cell interfaces ``displacement``.
        (``pressure`` is not included.)  Units those of the arrays.

        Computed once (a MUMPS Schur complement of the kept matrix onto the
        interface dofs, on rank 0, broadcast) and cached until the kept matrix
        changes (``update_parameters``, ``set_interface_stiffnesses``,
        ``set_time_step``, ``set_steady``).  The arrays are read-only.

        Time-dependent solvers (a time step set): at rest the history is zero, so
        v_s = c0 u with c0 = d a0/dt (``RateHistory``); it enters through the kept
        matrix and the outputs (``interstitial_velocity`` v_f = w + c0 u,
        ``mixture_velocity`` phi_f w + c0 u, ``superficial_velocity`` phi_f v_f,
        ``normal_flux`` of (1 - phi_s0) w + c0 u).  The map is then that of one
        step from a state at rest with a zero history.
        """
        if self._jacobian_cache is None:
            t0 = time.perf_counter()
            self._jacobian_cache = self._build_interface_jacobian()
            self.timing["interface_jacobian"] = time.perf_counter() - t0
        return dict(self._jacobian_cache)

    def _data_derivative_form(self) -> tuple[fem.FormMetaClass, list[tuple[str, str]]]:
        """dR/d(data) at rest as ONE bilinear form (W test x P2 vector trial), one term per block.

        Block j = (fluid interface, kind) is selected by ``switch[j] = 1`` (a Constant vector):
        kind ``traction`` (d F_data/dT), ``velocity`` (d F_data/dV) and with finite kinematics
        ``flux``, the linearised normal-flux load ``gel.lagrangian.normal_flux_load`` tested with the
        w part of W (read at its w rows).  One compiled form, assembled once per block.
        """
        if self._jacobian_form is None:
            kinds = ("traction", "velocity") + (("flux",) if self.kinematics == "finite" else ())
            blocks = [(name, kind) for name in self._fluid for kind in kinds]
            V_vf = self._sub[0][0]
            trial = ufl.TrialFunction(V_vf)
            w, _, _ = ufl.TestFunctions(self.W)
            u = ufl.split(self.state)[1]
            switch = fem.Constant(self.mesh, np.zeros(len(blocks), dtype=PETSc.ScalarType))
            rest = {self.state: fem.Function(self.W)}
            for d in self._fluid.values():
                rest[d["T"]] = fem.Function(V_vf)
                rest[d["V"]] = fem.Function(V_vf)
            if self.transient:
                rest.update({f: fem.Function(f.function_space) for f in self.history.past})
            total = 0
            for j, (name, kind) in enumerate(blocks):
                d = self._fluid[name]
                if kind == "flux":
                    # at rest: linear in v_f (its u dependence multiplies phi_f v_f + phi_s v_s = 0);
                    # the v_s part (time-dependent) is added from u in _interface_jacobian_blocks
                    term = lagrangian.normal_flux_load(trial, u, w, self.n, self.coefficients, self.ds(d["tags"]))
                else:
                    term = ufl.derivative(d["residual"], d["T" if kind == "traction" else "V"], trial)
                total += switch[j] * term
            self._jacobian_form = (fem.form(ufl.replace(expand_derivatives(total), rest)), blocks, switch)
        return self._jacobian_form

    def _data_derivatives(self, rows: dict, columns: dict) -> dict:
        """``{(interface, kind): CSR}``: the rows ``rows[kind]`` (global W dofs) and the columns
        ``columns[interface]`` (global dofs of the collapsed w space) of :meth:`_data_derivative_form`'s
        blocks, on every rank (collective; only these interface rows and columns are gathered)."""
        form, blocks, switch = self._data_derivative_form()
        A = fem_petsc.create_matrix(form)
        out = {}
        for j, block in enumerate(blocks):
            value = np.zeros(len(blocks))
            value[j] = 1.0
            switch.value = value
            A.zeroEntries()
            fem_petsc.assemble_matrix(A, form)
            A.assemble()
            name, kind = block
            picked = rows[name, "flux"] if kind == "flux" else rows["gamma"]
            out[block] = gather_submatrix(A, picked, columns[name])
        A.destroy()
        return out

    def _interface_selection(self) -> tuple[dict, np.ndarray]:
        """``(sel, pressure)``: (interface, field) -> (N, dim) global W dofs of w or u (-1 where fixed),
        and the one pressure dof kept with them (replicated)."""
        sel = {}
        for name, d in self._fluid.items():
            sel[name, "w"] = d["nodes"].global_dofs(self.W, parent=True, bcs=self.bcs)
            sel[name, "u"] = d["displacement_nodes"].global_dofs(self.W, parent=True, bcs=self.bcs)
        for name, d in self._cell.items():
            sel[name, "u"] = d["nodes"].global_dofs(self.W, parent=True, bcs=self.bcs)
        # with every interface velocity held, the flow's interior block fixes the pressure only up to a
        # constant (a singular interior block): keep one pressure dof of an interface as well (not read,
        # no data on it)
        interfaces = list(self._fluid.values()) + list(self._cell.values())
        pressure = (InterfaceNodes(self._sub[2][0], self.facet_tags, interfaces[0]["tags"],
                                   parent_dofs=self._sub[2][1]).global_dofs(self.W, parent=True, bcs=self.bcs)
                    if interfaces else np.empty((0, 1), np.int64))
        return sel, pressure[pressure >= 0][:1]

    def _condensed_kept_matrix(self, gamma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(S, dr_G, dc_G)``: the Schur complement onto G (in the order of ``gamma``) of Dr K Dc, K the
        kept matrix (J_reference, Dirichlet rows, interface stiffnesses), rows and columns equilibrated
        (in the paper's units the fluid rows are ~Ca times the network rows); distributed (collective)."""
        K = self._newton.reference_matrix()
        dr, dc = _equilibrate(K)
        order = np.argsort(gamma)
        S = np.empty((gamma.size, gamma.size))
        S[np.ix_(order, order)] = condensed_matrix(K, gamma[order], f"{self.name} interface Jacobian")
        out = S, gather_entries(dr, gamma), gather_entries(dc, gamma)
        for obj in (K, dr, dc):
            obj.destroy()
        return out

    def _build_interface_jacobian(self) -> dict:
        """See :meth:`interface_jacobian`: dX_G = -S^-1 dR_G/d(data), S the Schur complement of the
        kept matrix onto the interface dofs G (the data act on no other row; no other row is read)."""
        comm = self.mesh.comm
        # -- collective part, distributed: the condensed matrix and the data derivatives' interface rows
        sel, pressure = self._interface_selection()
        gamma, nf = _interface_set(sel, pressure)
        condensed = self._condensed_kept_matrix(gamma)
        derivative, flux_rows = None, {}
        if self._fluid:
            V_vf = self._sub[0][0]
            columns = {name: d["nodes"].global_dofs(V_vf).ravel() for name, d in self._fluid.items()}
            if self.kinematics == "finite":
                flux_rows = {name: d["nodes"].global_dofs(self.W, parent=True).ravel()
                             for name, d in self._fluid.items()}
            rows = {"gamma": gamma, **{(name, "flux"): r for name, r in flux_rows.items()}}
            derivative = self._data_derivatives(rows, columns)
        # -- dense algebra of interface size on rank 0, broadcast
        result, error = None, None
        if comm.rank == 0:
            try:
                result = self._interface_jacobian_blocks(condensed, gamma, nf, sel, derivative, flux_rows)
            except Exception as exc:            # every rank raises alike
                error = exc
        if comm.size > 1:
            result, error = comm.bcast((result, error), root=0)
        if error is not None:
            raise error
        for v in result.values():
            v.setflags(write=False)
        return result

    def _interface_jacobian_blocks(self, condensed, gamma, nf, sel, derivative, flux_rows) -> dict:
        """Rank-local dense algebra of :meth:`_build_interface_jacobian` (``condensed``: its
        :meth:`_condensed_kept_matrix`; the Schur complement of Dr K Dc is Dr_G S Dc_G)."""
        S, dr_g, dc_g = condensed
        # G = [flow dofs (w on fluid interfaces, one p), network dofs (u on all interfaces)]
        ng = gamma.size
        pos = _Positions(gamma)
        keys, columns, n_flow_inputs = self._input_columns(sel, gamma, pos, derivative)
        widths = [c.shape[1] for c in columns]
        Dm = dr_g[:, None] * (np.hstack(columns) if columns else np.zeros((ng, 0)))
        X = _solve_flow_first(S, Dm, nf, sum(widths[:n_flow_inputs]))
        X *= -dc_g[:, None]
        response = dict(zip(keys, np.split(X, np.cumsum(widths)[:-1], axis=1) if keys else []))
        for name in self._cell:
            force = response[name, "force"]
            response[name, "displacement"] = (force @ self._stiffness[name][1] if name in self._stiffness
                                              else np.zeros_like(force))
        out = self._fluid_interface_outputs(sel, pos, derivative, flux_rows, response)
        for name in self._cell:
            for key_in in response:
                out[(name, "displacement"), key_in] = _rows_of(pos, sel[name, "u"], response[key_in])
        return out

    def _input_columns(self, sel, gamma, pos, derivative) -> tuple[list, list, int]:
        """dR_G/d(input), (n_G, dim N_in) per input, the fluid interfaces' inputs (on the flow rows)
        first; returns ``(keys, columns, number of fluid inputs)``."""
        keys, columns = [], []
        if derivative is not None:
            B = derivative
            for name in self._fluid:
                for key in ("traction", "velocity"):
                    keys.append((name, key))
                    columns.append(B[name, key].toarray())
        n_flow_inputs = len(keys)
        for name in self._cell:
            g = _positions(pos, sel[name, "u"])
            force = np.zeros((gamma.size, g.size))
            on = g >= 0
            force[g[on], np.flatnonzero(on)] = -1.0            # the load is subtracted from the residual
            keys.append((name, "force"))
            columns.append(force)
        return keys, columns, n_flow_inputs

    def _fluid_interface_outputs(self, sel, pos, derivative, flux_rows, response) -> dict:
        """The output blocks of the fluid interfaces, per input, from the interface states ``response``."""
        phi_f = 1.0 - float(self._const["phi_s0"].value)
        # at rest (zero history) v_s = c0 u at the nodes and in the forms (the same P2 space)
        c0 = self.history.coefficients[0] if self.transient else 0.0
        out = {}
        for name, d in self._fluid.items():
            flux = None
            if flux_rows:
                flux = derivative[name, "flux"].toarray()   # (1 - phi_s0) (. n, psi n)
            n_out = self.dim * d["nodes"].size
            for key_in in response:
                Xin = response[key_in]
                w = _rows_of(pos, sel[name, "w"], Xin)
                u = _rows_of(pos, sel[name, "u"], Xin)
                v_s = c0 * u
                v_f = w + v_s if c0 else w
                out[(name, "interstitial_velocity"), key_in] = v_f
                superficial = phi_f * v_f
                # steady (v_s = 0): the same (read-only) array for both
                out[(name, "mixture_velocity"), key_in] = phi_f * w + v_s if c0 else superficial
                out[(name, "superficial_velocity"), key_in] = superficial
                out[(name, "traction"), key_in] = (np.eye(n_out) if key_in == (name, "traction")
                                                   else np.zeros((n_out, Xin.shape[1])))
                if flux is not None:
                    # j (phi_f v_f + phi_s v_s).n linearised: (1 - phi_s0) w + v_s
                    out[(name, "normal_flux"), key_in] = flux @ (w + v_s / phi_f)
                    out[(name, "displacement"), key_in] = u
        return out

    # -- nodal helpers ---------------------------------------------------
    def _boundary_weights(self, form) -> PETSc.Vec:
        """int (.) psi_i ds (2D), or the diagonal int (.) psi_i^2 ds of the boundary mass matrix (3D)."""
        if self.dim == 2:
            vec = fem_petsc.assemble_vector(form)
            vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            return vec
        if form not in self._boundary_matrices:        # one sparsity pattern per form, kept
            self._boundary_matrices[form] = fem_petsc.create_matrix(form)
        A = self._boundary_matrices[form]
        A.zeroEntries()
        fem_petsc.assemble_matrix(A, form)
        A.assemble()
        return A.getDiagonal()

    def _phi_f_nodal(self, scalar_nodes: InterfaceNodes) -> np.ndarray:
        """phi_f at the interface nodes: its average over the boundary facets around each node,
        weighted as in :meth:`_boundary_weights` (positive weights; rank-independent)."""
        num, den = self._boundary_weights(self._phi_f_num), self._boundary_weights(self._phi_f_den)
        a, b = scalar_nodes.from_array(num.array), scalar_nodes.from_array(den.array)
        num.destroy()
        den.destroy()
        if np.any(b <= 0):
            raise RuntimeError(f"{self.name}: non-positive boundary weight in the phi_f average")
        return a / b

    def _pressure_nodal(self, scalar_nodes: InterfaceNodes) -> np.ndarray:
        self._p2.interpolate(self._p_expr, cells=self._interface_cells)
        return scalar_nodes.from_function(self._p2)

    # -- accessors ---------------------------------------------------------
    def _field(self, i: int, out: fem.Function | None, name: str) -> fem.Function:
        """Field i of the state as a Function on its collapsed space (``out`` is filled if given)."""
        space, parent = self._sub[i]
        f = fem.Function(space, name=name) if out is None else out
        f.x.array[:] = self.state.x.array[parent]
        return f

    def relative_velocity(self, out: fem.Function | None = None) -> fem.Function:
        """w = v_f - v_s (collapsed P2 vector Function), units of V0."""
        return self._field(0, out, "w")

    def interstitial_velocity(self, out: fem.Function | None = None) -> fem.Function:
        """v_f = w + v_s (collapsed P2 vector Function), units of V0."""
        v_f = self._field(0, out, "v_f")
        if self.transient:
            v_f.x.array.reshape(-1, self.dim)[:] += self._velocity.x.array.reshape(-1, self.dim)[self._u_block_of_w]
        return v_f

    def displacement(self, out: fem.Function | None = None) -> fem.Function:
        """u (collapsed P2 vector Function) in units of d L0: u_s = d * u."""
        return self._field(1, out, "u")

    def pore_pressure(self, out: fem.Function | None = None) -> fem.Function:
        """p (collapsed P1 Function) in the stress unit s: p_paper = s * p."""
        return self._field(2, out, "p")

    @property
    def newton(self) -> NewtonSolver:
        """The Newton solver (read its ``stats`` and ``history``)."""
        return self._newton

    # -- post-processing (UFL expressions of the current state) ---------------
    def solid_fraction(self):
        """phi_s = phi_s0 / J (UFL)."""
        return self._forms.solid_fraction(ufl.split(self.state)[1], self.coefficients)

    def network_stress(self):
        """Network Cauchy stress sigma_s in units of mu_s, s * sigma_hat_s (UFL)."""
        return self._stress_unit * self._forms.network_stress(ufl.split(self.state)[1], self.coefficients)

    def network_von_mises(self):
        """Von Mises measure of sigma_s in units of mu_s (UFL; the paper's formula in 2D, the full one in 3D)."""
        return von_mises(self.network_stress())

    def total_stress(self):
        """Total stress phi_f sigma_f + phi_s sigma_s - p I in units of mu_s (UFL)."""
        rel, u, p = ufl.split(self.state)
        v_f = rel + self.v_s if self.transient else rel
        return self._stress_unit * self._forms.total_stress(v_f, u, p, self.coefficients)

    def reset(self) -> None:
        """Zero the state and the history (the next solve starts from rest)."""
        self.state.x.array[:] = 0.0
        self.state.x.scatter_forward()
        if self.transient:
            self.history.reset()
            self._update_velocity()

    def norms(self) -> dict[str, float]:
        """Global Euclidean norms of the owned nodal values of w, u, p (for checks and logs)."""
        out = {}
        comm = self.mesh.comm
        for i, f in enumerate(FIELDS):
            g = self.state.sub(i).collapse()
            imap, bs = g.function_space.dofmap.index_map, g.function_space.dofmap.index_map_bs
            local = float(np.sum(g.x.array[: imap.size_local * bs] ** 2))
            out[f] = float(np.sqrt(comm.allreduce(local, op=MPI.SUM)))
        return out
