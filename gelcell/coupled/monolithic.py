"""Monolithic reference: every field and every interface condition in ONE system.

One mesh of the whole device carries all unknowns

    V, P    fluid velocity and pressure            (P2^d, P1)   active on the fluid
    w, p    relative velocity v_f - v_s of the
            interstitial fluid, pore pressure      (P2^d, P1)   active on the gel
    u       network displacement in the gel and
            cell displacement in the cell          (P2^d)       active on gel + cell
    lam     the fluid's traction on the gel on
            Gamma1/Gamma3 (a Lagrange multiplier)  (P2^d)       active on Gamma1/Gamma3

(d = 2 or 3, the mesh's dimension), each integrated only over its own subdomain; the dofs of a field outside
its subdomain have no equation and are left out of the linear solves
(they stay zero).  The residual is

    fluid:   bulk Stokes residual on the fluid + int lam . v dS
             (the force on the fluid is -lam)
    gel:     bulk gel residual on the gel + the gel's interface terms of
             gel.forms.fluid_interface_residual with T = lam (I14, I15, I17)
    cell:    total Lagrangian neo-Hookean residual on the cell, tested with
             the same displacement test function as the gel's mixture balance,
             so that u_s = u_c and the traction balance on Gamma2 hold exactly
    lam:     int (V.n - (phi_f v_f + phi_s v_s).n) (mu.n) + (lam - (Ca/beta)(V - v_f))_tau . mu_tau dS
             i.e. I13 and I16, tested with the multiplier's test function mu

with v_f = w + v_s.  Steady: v_s = 0.  Time-dependent (``transient=True``):
v_s is the backward Euler / BDF2 difference of u (femtools.timestepping), the
same discretisation as the partitioned gel, so both solve one discrete
problem per time step; the API mirrors the gel solver's (``set_time_step``,
``push_history``, ``get_state``, ``set_state``).

Gel-side quantities on the interior facets of Gamma1/Gamma3 (phi_s from
grad u, the gel's outward normal) are selected with a gel indicator, never
with the '+'/'-' side, which changes with the partition.  Multiplier
components at nodes where the fluid velocity is fixed by an outer boundary
(the ends of Gamma1 on a wall or a symmetry line) are pinned to zero, as the
partitioned fluid solver does when it recovers its consistent traction.

The system is solved by Newton's method with the exact Jacobian.  It reuses
only the constitutive laws and bulk forms of fluid/gel/cell, not the
coupling loop.

Finite kinematics (``coefficients.kinematics == "finite"``, docs/finite-strain.md).
The gel takes the total Lagrangian forms of ``gel.lagrangian``; the fluid is
Stokes on its current domain pulled back to the (fixed) mesh with the ALE
forms of ``fluid.ale``.  One dolfinx mesh cannot move its fluid part without
moving the gel, whose reference configuration it also is, so the mesh stays
where it is and the fluid's motion is a seventh field:

    u_m     the fluid mesh displacement beyond Gamma1/Gamma3   (P2^d)   active on the fluid

The fluid's mesh displacement is u + u_m on the fluid cells: u (the network
displacement) is one continuous P2 field, equal to u_s on the interface
nodes and left at zero on the fluid's own nodes (they have no equation of u);
u_m is zero on Gamma1/Gamma3 and on the fluid's outer boundaries (its
component normal to a symmetry line only) and satisfies the harmonic
extension (femtools.meshmotion) tested with its own test function.  So u + u_m
is the discrete harmonic extension of u_s with Dirichlet data on the
interface, the same as the partitioned fluid's, and the gel's equations on the
interface nodes see no mesh-motion terms.  The multiplier lam is then the
NOMINAL traction (per unit reference length), and its equations are I13 and
I16 on the current interface (its normal n and length ratio j from the gel's
side): int j (V - q).n (mu.n) dA and int (lam - (Ca/beta) j (V - v_f))_t . mu_t dA,
weighted as the partitioned fluid's Robin condition weighs them (``interface_weight``).
"""

from __future__ import annotations

import dataclasses
import time
import typing

import numpy as np
import scipy.spatial

import ufl
from dolfinx import fem, mesh as dmesh

import cell.forms as cell_forms
import fluid.forms as fluid_forms
import gel.forms as gel_forms
import gel.lagrangian as gel_lagrangian
from femtools.continuum import surface_stretch
from femtools.functions import quadrature_measure
from femtools.mesh import settle_coordinate_element, tagged_facets
from femtools.meshmotion import harmonic_residual
from fluid.ale import ale_bulk_residual
from femtools.linalg import NewtonSolver, jacobian_at_rest
from femtools.timestepping import RateHistory
from gelcell.case import CaseParameters
from gelcell.coupled.defaults import default_robin_coefficient
from gelcell.coupled.monolithic_krylov import MonolithicKrylov
from gelcell.geometry import DeviceBoundaries, Tag

__all__ = ["MonolithicCoefficients", "MonolithicSolver", "monolithic_coefficients"]

FIELDS = ("V", "P", "w", "u", "p", "lam")
#: the fields with finite kinematics: the fluid's mesh displacement beyond the interfaces
FIELDS_FINITE = FIELDS + ("u_m",)


@dataclasses.dataclass
class MonolithicCoefficients:
    """Numbers of the coupled problem in the solver's units (see gel.forms)."""

    phi_s0: float
    xi: float
    lambda_s: float
    beta: float
    eta: float
    Ca: float
    mu_c: float
    lambda_c: float
    stress_scale: float
    displacement_scale: float
    kinematics: str = "small"
    #: finite kinematics: the weight of I13 against I16 in the multiplier's rows (the partitioned
    #: fluid's Robin coefficient alpha_n, stress unit per velocity); None: 1
    interface_weight: float | None = None


class MonolithicSolver:
    """All fields of a device on one mesh, solved at once by Newton's method.

    Args:
        msh, cell_tags, facet_tags: the whole device (regions tagged
            Tag.FLUID, Tag.GEL and the cells' ``cell_region_tags``, default Tag.CELL).
        boundaries: the case's boundary conditions.
        coefficients: parameter values.
        solver: each Newton step's linear solve, ``"direct"`` (MUMPS) or ``"iterative"``
            (:class:`~gelcell.coupled.monolithic_krylov.MonolithicKrylov`).
    """

    def __init__(self, msh, cell_tags, facet_tags, boundaries: DeviceBoundaries,
                 coefficients: MonolithicCoefficients, quadrature_degree: int = 4,
                 newton_rtol: float = 1e-12, petsc_options: dict | None = None,
                 transient: bool = False, cell_region_tags: typing.Sequence[int] | None = None,
                 solver: str = "direct"):
        t0 = time.perf_counter()
        self.mesh, self.cell_tags, self.facet_tags = settle_coordinate_element(msh), cell_tags, facet_tags
        #: the cell tags of the cells (several cells: one tag each)
        self.cell_region_tags = tuple(int(t) for t in (cell_region_tags or (int(Tag.CELL),)))
        self.boundaries, self.coefficients = boundaries, coefficients
        if boundaries.dim != msh.geometry.dim:
            raise ValueError(f"monolithic: the boundaries have {boundaries.dim} components (DeviceBoundaries.dim), "
                             f"the mesh is {msh.geometry.dim}D")
        tdim = msh.topology.dim
        #: the dimension of the device (2 or 3): the vector fields' number of components
        self.gdim = msh.geometry.dim
        msh.topology.create_connectivity(tdim - 1, tdim)
        P2 = ufl.VectorElement("Lagrange", msh.ufl_cell(), 2)
        P1 = ufl.FiniteElement("Lagrange", msh.ufl_cell(), 1)
        if coefficients.kinematics not in ("small", "finite"):
            raise ValueError(f"kinematics must be 'small' or 'finite', got {coefficients.kinematics!r}")
        self.finite = coefficients.kinematics == "finite"
        self.field_names = FIELDS_FINITE if self.finite else FIELDS
        self.W = fem.FunctionSpace(msh, ufl.MixedElement([P2, P1, P2, P2, P1, P2] + ([P2] if self.finite else [])))
        self.w = fem.Function(self.W, name="monolithic")
        self.has_cell = len(boundaries.cell_interfaces) > 0
        self.transient = bool(transient)
        self.history = None
        if self.transient:
            V_u, u_dofs = self.W.sub(3).collapse()
            self._u_dofs = np.asarray(u_dofs, dtype=np.int32)
            self._w_dofs = np.asarray(self.W.sub(2).collapse()[1], dtype=np.int32)
            self.history = RateHistory(V_u, ufl.split(self.w)[3], coefficients.displacement_scale, "u")
        F = self._residual(quadrature_degree)
        self.bcs = self._boundary_conditions()
        if solver not in ("direct", "iterative"):
            raise ValueError(f"monolithic: solver must be 'direct' or 'iterative', got {solver!r}")
        self.solver_kind = solver
        active = self.active_dofs()
        # transient: the Jacobian changes only with dt, so keep it while Newton contracts
        self.newton = NewtonSolver(F, self.w, self.bcs, name="monolithic", rtol=newton_rtol,
                                   reuse="adaptive" if self.transient else "never", max_it=20,
                                   petsc_options=petsc_options, active_dofs=active,
                                   J_reference=(jacobian_at_rest(F, self.w, self.history.past)
                                                if self.transient else None),
                                   linear_solver=(self._krylov_solver(active, quadrature_degree, petsc_options)
                                                  if solver == "iterative" else None))
        self.setup_time = time.perf_counter() - t0
        self.solve_time = 0.0

    # -- forms ----------------------------------------------------------------
    def _constants(self):
        c, msh = self.coefficients, self.mesh
        const = lambda v: fem.Constant(msh, float(v))  # noqa: E731
        s, d = c.stress_scale, c.displacement_scale
        self.gel_coefficients = gel_forms.GelCoefficients(
            phi_s0=const(c.phi_s0), xi=const(c.xi), lambda_s=const(c.lambda_s), beta=const(c.beta),
            eta=const(c.eta), viscosity=const(c.Ca / s), stiffness=const(d / s), d=const(d))
        self.cell_moduli = (const(c.mu_c), const(c.lambda_c), const(d), const(s))
        return self.gel_coefficients

    def _gel_indicator(self) -> fem.Function:
        Q0 = fem.FunctionSpace(self.mesh, ("DG", 0))
        chi = fem.Function(Q0)
        chi.x.array[self.cell_tags.find(int(Tag.GEL))] = 1.0
        chi.x.scatter_forward()
        return chi

    def _residual(self, degree: int):
        msh = self.mesh
        c = self._constants()
        V, P, rel, u, p, lam = ufl.split(self.w)[:6]
        v, q, w, z, q_g, mu = ufl.TestFunctions(self.W)[:6]
        v_s = None if self.history is None else self.history.rate
        v_f = rel if v_s is None else rel + v_s
        dx = quadrature_measure("dx", msh, self.cell_tags, degree)
        dS = quadrature_measure("dS", msh, self.facet_tags, degree)
        n = ufl.FacetNormal(msh)
        chi = self._gel_indicator()

        def gel_side(expr):
            return chi("+") * expr("+") + chi("-") * expr("-")

        alpha_t = c.viscosity / c.beta
        if self.finite:
            F, interface = self._finite_terms(c, v_f, v_s, u, p, dx, n)
        else:
            F = fluid_forms.bulk_residual(V, P, v, q, c.viscosity, dx(int(Tag.FLUID)))
            F += gel_forms.bulk_residual(v_f, u, p, w, z, q_g, c, dx(int(Tag.GEL)), v_s=v_s)
            flux = gel_forms.mixture_flux(v_f, u, c, v_s)
            tangential = lambda a: a - ufl.dot(a, n) * n  # noqa: E731
            interface = (gel_forms.fluid_interface_residual(v_f, u, w, z, lam, V, n, c, 1, v_s)
                         + (ufl.dot(V, n) - ufl.dot(flux, n)) * ufl.dot(mu, n)
                         + ufl.dot(tangential(lam - alpha_t * (V - v_f)), tangential(mu)))
        if self.has_cell:
            mu_c, lambda_c, d, s = self.cell_moduli
            cells = self.cell_region_tags
            F += cell_forms.residual(u, z, mu_c, lambda_c, d, s, dx(cells[0] if len(cells) == 1 else cells))
        # the fluid's load from the multiplier, and a zero multiplier "mass": diagonal entries for
        # the rows pinned at the interface ends
        interface += ufl.dot(lam, v) + fem.Constant(msh, 0.0) * ufl.dot(lam, mu)
        for tag in self.boundaries.fluid_interfaces.values():
            F += gel_side(interface) * dS(tag)
        return F

    def _finite_terms(self, c, v_f, v_s, u, p, dx, N):
        """Finite kinematics: the bulk residual and the interface integrand (module docstring)."""
        msh, d = self.mesh, c.d
        V, P, rel, _, _, lam, u_m = ufl.split(self.w)
        v, q, w, z, q_g, mu, z_m = ufl.TestFunctions(self.W)
        dJdt = None if self.history is None else gel_lagrangian.volume_rate(
            u, self.history.past, self.history.constants, d)
        fluid_motion = u + u_m
        dx_fluid = dx(int(Tag.FLUID))
        F = ale_bulk_residual(V, P, v, q, c.viscosity, fluid_motion, d, dx_fluid)
        F += harmonic_residual(fluid_motion, z_m, dx_fluid)
        F += gel_lagrangian.bulk_residual(v_f, u, p, w, z, q_g, c, dx(int(Tag.GEL)), v_s=v_s, dJdt=dJdt)
        j, n = surface_stretch(u, d, N)
        flux = gel_lagrangian.mixture_flux(v_f, u, c, v_s)
        alpha_t = c.viscosity / c.beta
        weight = fem.Constant(msh, float(self.coefficients.interface_weight or 1.0))
        tangential = lambda a: a - ufl.dot(a, n) * n  # noqa: E731
        interface = (gel_lagrangian.fluid_interface_residual(v_f, u, w, z, lam, V, N, c, 1, v_s)
                     + weight * j * (ufl.dot(V, n) - ufl.dot(flux, n)) * ufl.dot(mu, n)
                     - ufl.dot(tangential(lam - alpha_t * j * (V - v_f)), tangential(mu)))
        return F, interface

    def _krylov_solver(self, active: np.ndarray, degree: int, options: dict | None) -> MonolithicKrylov:
        """FGMRES with the gel-first block sweep (gelcell.coupled.monolithic_krylov); its gel block's pressure
        Schur complement as the gel solver's: (phi_f^2 / k)(grad p . grad q + p q) + beta p q and the
        viscous mass (phi_f^2 / nu_e + beta) p q, k the drag, nu_e = mu phi_f, beta the fixed stress."""
        c = self.gel_coefficients
        p, q = ufl.TrialFunctions(self.W)[4], ufl.TestFunctions(self.W)[4]
        phi_s = c.phi_s0
        phi_f = 1 - phi_s
        drag, nu_e = c.viscosity * c.xi * phi_f * phi_s, c.viscosity * phi_f
        beta = 0.0 if self.history is None else self.history.constants[0] / (c.stiffness * phi_s * (1 + c.lambda_s))
        dx = quadrature_measure("dx", self.mesh, self.cell_tags, degree)(int(Tag.GEL))
        darcy = (phi_f**2 / drag * (ufl.inner(ufl.grad(p), ufl.grad(q)) + p * q) + beta * p * q) * dx
        mass = (phi_f**2 / nu_e + beta) * p * q * dx
        P, Q = ufl.TrialFunctions(self.W)[1], ufl.TestFunctions(self.W)[1]
        fluid_mass = P * Q / c.viscosity * quadrature_measure("dx", self.mesh, self.cell_tags, degree)(int(Tag.FLUID))
        fields = {name: self.W.sub(i).collapse()[1] for i, name in enumerate(self.field_names)}
        vectors = {name: self.W.sub(self.field_names.index(name)).collapse() for name in ("w", "u")}
        return MonolithicKrylov(self.W, active, fields, vectors, fem.form(darcy), fem.form(mass), fem.form(fluid_mass),
                                options=options)

    # -- boundary conditions -------------------------------------------------
    def _sub(self, i: int, comp: int | None = None):
        sub = self.W.sub(i) if comp is None else self.W.sub(i).sub(comp)
        return sub, sub.collapse()[0]

    def _facets(self, tags) -> np.ndarray:
        return tagged_facets(self.facet_tags, tags)

    def _dirichlet(self, i, tags, value=None, comp=None, restrict=None):
        sub, Vs = self._sub(i, comp)
        g = fem.Function(Vs)
        if callable(value):
            g.interpolate(value)
        elif value is not None:
            g.x.array.reshape(-1, np.size(value))[:] = value
        dofs = fem.locate_dofs_topological((sub, Vs), self.mesh.topology.dim - 1, self._facets(tags))
        if restrict is not None:
            keep = np.isin(dofs[0], restrict)
            dofs = [dofs[0][keep], dofs[1][keep]]
        if i == 0:
            self._fluid_data.append((g, g.x.array.copy()))
        return fem.dirichletbc(g, dofs, sub)

    def _active(self, i, regions=None, facets=None) -> np.ndarray:
        """Dofs (in W) of field ``i`` in the closure of the cells of ``regions`` or on ``facets``."""
        sub, Vs = self._sub(i)
        tdim = self.mesh.topology.dim
        if regions is not None:
            cells = np.unique(np.hstack([self.cell_tags.find(int(r)) for r in regions]).astype(np.int32))
            return fem.locate_dofs_topological((sub, Vs), tdim, cells)[0]
        return fem.locate_dofs_topological((sub, Vs), tdim - 1, self._facets(facets))[0]

    def active_dofs(self) -> np.ndarray:
        """Every dof that has an equation: each field on its own subdomain."""
        solid = [int(Tag.GEL), *self.cell_region_tags] if self.has_cell else [Tag.GEL]
        parts = [self._active(0, [Tag.FLUID]), self._active(1, [Tag.FLUID]),
                 self._active(2, [Tag.GEL]), self._active(3, solid), self._active(4, [Tag.GEL]),
                 self._active(5, facets=list(self.boundaries.fluid_interfaces.values()))]
        if self.finite:
            parts.append(self._active(6, [Tag.FLUID]))
        return np.unique(np.hstack(parts))

    def _boundary_conditions(self):
        b = self.boundaries
        iV, iP, ivf, iu, ip, ilam = range(6)
        bcs = []
        self._fluid_data = []          # (Dirichlet data of V, its unscaled values): scaled by the inflow
        for tags, value in b.fluid_velocity:
            bcs.append(self._dirichlet(iV, tags, value))
        for tags, comp, value in b.fluid_component:
            bcs.append(self._dirichlet(iV, tags, value, comp))
        # multiplier components on the interface where the fluid velocity is fixed by an outer boundary
        on_interface = self._active(ilam, facets=list(b.fluid_interfaces.values()))
        zero = (0.0,) * self.gdim
        for tags, comps in b.fluid_dirichlet_tags():
            for comp in comps:
                bcs.append(self._dirichlet(ilam, tags, 0.0, comp, restrict=on_interface))
        no_slip = list(b.gel_no_slip) + list(b.cell_interfaces.values())
        bcs.append(self._dirichlet(ivf, no_slip, zero))
        bcs.append(self._dirichlet(iu, b.gel_no_slip, zero))
        for tags, comp in b.gel_symmetry:
            bcs.append(self._dirichlet(ivf, tags, 0.0, comp))
            bcs.append(self._dirichlet(iu, tags, 0.0, comp))
        for tags, comp in b.cell_symmetry:
            bcs.append(self._dirichlet(iu, tags, 0.0, comp))
        if self.finite:
            bcs += self._mesh_motion_conditions()
        return bcs

    def _mesh_motion_conditions(self) -> list:
        """u_m = 0 on Gamma1/Gamma3 and the fluid's outer boundaries (one component on symmetry lines)."""
        b, im = self.boundaries, 6
        msh, tdim = self.mesh, self.mesh.topology.dim
        sliding = [(tags, comp) for tags, comp, _ in b.fluid_component]
        sliding_facets = self._facets([t for tags, _ in sliding for t in tags]) if sliding else np.empty(0, np.int32)
        exterior = dmesh.exterior_facet_indices(msh.topology)
        f2c = msh.topology.connectivity(tdim - 1, tdim)
        fluid_cells = np.zeros(msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts,
                               dtype=bool)
        fluid_cells[self.cell_tags.find(int(Tag.FLUID))] = True
        outer = np.array([f for f in exterior if fluid_cells[f2c.links(f)[0]]], dtype=np.int32)
        held = np.setdiff1d(outer, sliding_facets)
        sub, Vs = self._sub(im)
        interface = self._facets(list(b.fluid_interfaces.values()))
        bcs = [fem.dirichletbc(fem.Function(Vs), fem.locate_dofs_topological((sub, Vs), tdim - 1, interface), sub)]
        bcs.append(fem.dirichletbc(fem.Function(Vs), fem.locate_dofs_topological((sub, Vs), tdim - 1, held), sub))
        for tags, comp in sliding:
            bcs.append(self._dirichlet(im, tags, 0.0, comp))
        return bcs

    # -- solve and results ---------------------------------------------------
    def solve(self) -> int:
        """Newton on the full system; returns the number of iterations."""
        t0 = time.perf_counter()
        iterations = self.newton.solve()
        self.solve_time += time.perf_counter() - t0
        return iterations

    def field(self, name: str) -> fem.Function:
        """One field as a function on the whole mesh (collapsed): a name of ``field_names``, ``"v_f"``
        (= w + v_s) or (finite kinematics) ``"fluid_motion"`` (= u + u_m, the fluid's mesh displacement)."""
        if name == "v_f":
            f = self.w.sub(FIELDS.index("w")).collapse()
            if self.history is not None:
                # w and u live in two P2 vector subspaces: add v_s node by node
                if not hasattr(self, "_u_block_of_w"):
                    x_w = f.function_space.tabulate_dof_coordinates()
                    x_u = self.history.past[0].function_space.tabulate_dof_coordinates()
                    dist, self._u_block_of_w = scipy.spatial.cKDTree(x_u).query(x_w)
                    if dist.size and dist.max() > 1e-12 * (1.0 + np.abs(x_u).max()):
                        raise RuntimeError("monolithic: the w and u subspaces do not share their nodes")
                v_s = self.history.nodal_rate(self.w.x.array[self._u_dofs])
                f.x.array.reshape(-1, self.gdim)[:] += v_s.reshape(-1, self.gdim)[self._u_block_of_w]
        elif name == "fluid_motion":
            f = self.w.sub(FIELDS.index("u")).collapse()
            f.x.array[:] += self.w.sub(FIELDS_FINITE.index("u_m")).collapse().x.array
        else:
            f = self.w.sub(self.field_names.index(name)).collapse()
        f.name = name
        return f

    def scale_boundary_velocity(self, factor: float) -> None:
        """Multiply the fluid's Dirichlet velocity data (the inflow) by ``factor`` (not cumulative)."""
        for g, base in self._fluid_data:
            g.x.array[:] = float(factor) * base

    # -- time stepping (transient=True) -------------------------------------------
    def set_time_step(self, dt: float, scheme: str = "be", dt_previous: float | None = None) -> None:
        """The time discretisation of v_s for the next solve (see femtools.timestepping)."""
        if self.history.set_step(dt, scheme, dt_previous):
            self.newton.invalidate_jacobian()

    def push_history(self) -> None:
        """Accept the current state: u^{n-1} <- u^n <- u."""
        self.history.push(self.w.x.array[self._u_dofs])

    def get_state(self) -> dict:
        state = {"state": self.w.x.array.copy()}
        if self.history is not None:
            state.update(self.history.state())
        return state

    def set_state(self, state) -> None:
        self.w.x.array[:] = state["state"]
        if self.history is not None:
            self.history.load(state)

    @property
    def num_dofs(self) -> int:
        return self.W.dofmap.index_map.size_global * self.W.dofmap.index_map_bs


def monolithic_coefficients(params: CaseParameters) -> MonolithicCoefficients:
    """The monolithic reference's coefficients; with finite kinematics its I13 rows are weighted by the
    partitioned fluid's default Robin coefficient (docs/finite-strain.md)."""
    ph = params.physics
    finite = params.kinematics == "finite"
    return MonolithicCoefficients(phi_s0=ph.phi_s0, xi=ph.xi, lambda_s=ph.lambda_s, beta=ph.beta, eta=ph.eta,
                                  Ca=ph.ca, mu_c=params.mu_c, lambda_c=params.lambda_c,
                                  stress_scale=params.stress_scale, displacement_scale=params.displacement_scale,
                                  kinematics=params.kinematics,
                                  interface_weight=default_robin_coefficient(params) if finite else None)
