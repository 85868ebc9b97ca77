"""Steady Stokes field solver (Taylor–Hood P2/P1) with interface data in and out.

Equations (dimensionless, any stress unit; ``viscosity`` is mu in that unit)::

    -div(Sigma - P I) = f,   div V = 0   in the fluid,   Sigma = mu (grad V + grad V^T)

Boundary conditions, per tagged boundary:

* ``velocity_bcs``: V = g (full vector);
* ``component_bcs``: V_c = g_c (one Cartesian component, e.g. V_y = 0 on a
  symmetry line or plane; the other components are traction-free);
* interfaces (``FluidInterface``), each split into its normal and tangential
  part, ``"robin"`` or ``"dirichlet"``::

      robin:      t.n + alpha_n V.n = g_N.n        t_tau + alpha_t V_tau = g_T,tau
      dirichlet:  V.n = g_V.n                      V_tau = g_V,tau

  with ``t = (Sigma - P I) n`` the traction exerted ON the fluid, ``n`` the
  fluid's OUTWARD unit normal and ``w_tau = w - (w.n) n``.  alpha = 0 is a
  prescribed traction.  A single Dirichlet part needs a flat, axis-aligned
  interface (a line x_k = const in 2D, a plane in 3D): it becomes a condition
  on the normal component, or on the tangential ones;
* every other boundary is traction-free ("do nothing": t = 0).

The same code runs on 2D triangles and 3D tetrahedra: vectors (data, points,
forces) have gdim = 2 or 3 components.

Consistent interface traction.  The traction returned on an interface is the
P2 field lambda on the interface defined by

    int_Gamma lambda . v ds = R(v) := bulk residual (V, P; v, q = 0)   for all P2 v on Gamma,

i.e. the reaction of the weak form without the interface terms (at an exact
solution R(v) = int t . v ds), recovered with the interface mass matrix:
R is assembled over the cells that hold an interface node only, and the mass
system has the size of the interface (``femtools.interface.InterfaceMass``).
Where a velocity component of an interface node is fixed by ANOTHER
boundary's Dirichlet condition (the ends of Gamma1 on a wall, the inflow or a
symmetry line), that component of lambda is set to zero and left out of the
mass-matrix solve: the reaction there also carries the other boundary's
force.  This is a local O(h) effect at the interface ends; the monolithic
reference pins its multiplier in the same way.
"""

from __future__ import annotations

import dataclasses
import time
import typing

import numpy as np
import scipy.sparse

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import cpp as _cpp, fem, mesh as dmesh
from dolfinx.fem import petsc as fem_petsc

from femtools.functions import quadrature_measure, set_function
from femtools.interface import InterfaceMass, InterfaceNodes, global_dofs
from femtools.mesh import as_tags, connected_components, tagged_facets
from femtools.krylov import linear_solver_choice, stokes_solver
from femtools.linalg import LinearSolver, SolverStats, condensed_matrix, gather_submatrix
from femtools.solver import FieldSolver
from fluid import forms

__all__ = ["FluidInterface", "StokesSolver"]

_KINDS = ("robin", "dirichlet")
_POINT = {2: "(x, y)", 3: "(x, y, z)"}


@dataclasses.dataclass
class FluidInterface:
    """Which interface condition the fluid enforces on a tagged interface.

    Attributes:
        tags: facet tag(s) of the interface in the fluid mesh.
        normal: ``"robin"`` (t.n + alpha_n V.n = g_N.n) or ``"dirichlet"``
            (V.n = g_V.n) for the normal part.
        tangential: ``"robin"`` (t_tau + alpha_t V_tau = g_T,tau) or
            ``"dirichlet"`` (V_tau = g_V,tau) for the tangential part.
        alpha_n: normal Robin coefficient (>= 0, stress per velocity); only
            with ``normal="robin"``.
        alpha_t: tangential Robin coefficient (>= 0); only with
            ``tangential="robin"``.
    """

    tags: typing.Union[int, typing.Sequence[int]]
    normal: str = "robin"
    tangential: str = "robin"
    alpha_n: float = 0.0
    alpha_t: float = 0.0

    def __post_init__(self):
        self.tags = as_tags(self.tags, "FluidInterface.tags")
        for part in ("normal", "tangential"):
            kind = getattr(self, part)
            if kind not in _KINDS:
                raise ValueError(f"FluidInterface: {part} must be one of {_KINDS}, got {kind!r}")
        for part, alpha in (("normal", "alpha_n"), ("tangential", "alpha_t")):
            value = float(getattr(self, alpha))
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f"FluidInterface: {alpha} must be finite and >= 0 "
                                 f"(a negative Robin coefficient makes the operator indefinite), got {value}")
            if getattr(self, part) == "dirichlet" and value != 0.0:
                raise ValueError(f"FluidInterface: {alpha}={value} is only used with {part}='robin', "
                                 f"not with {part}='dirichlet'")
            setattr(self, alpha, value)

    def inputs(self, dim: int) -> dict[str, int]:
        """Input arrays this interface takes in ``dim`` dimensions (name -> number of components)."""
        out = {}
        if "dirichlet" in (self.normal, self.tangential):
            out["velocity"] = dim
        if self.normal == "robin":
            out["robin_normal"] = dim
        if self.tangential == "robin":
            out["robin_tangential"] = dim
        return out


class _Interface:
    """Internal state of one interface: data functions, bcs, traction recovery."""

    def __init__(self, name: str, spec: FluidInterface, marker: int):
        self.name, self.spec, self.marker = name, spec, marker
        self.nodes: InterfaceNodes | None = None
        self.g_velocity: fem.Function | None = None       # full Dirichlet data (P2 vector)
        self.components: tuple[int, ...] = ()             # Cartesian components of a single Dirichlet part
        self.g_component: list[fem.Function] = []        # their data (P2 scalars)
        self.component_nodes: list[InterfaceNodes] = []
        self.g_normal: fem.Function | None = None
        self.g_tangential: fem.Function | None = None
        self.alpha_n: fem.Constant | None = None
        self.alpha_t: fem.Constant | None = None
        self.traction: fem.Function | None = None
        self.traction_mass: InterfaceMass | None = None
        self.force_form = None
        self.traction_current = False
        self.own_constrained: list[np.ndarray] = []      # per component: V dofs fixed by its own Dirichlet part


class StokesSolver(FieldSolver):
    """Steady Stokes flow on its own mesh; interface data in and out as arrays.

    Taylor–Hood P2/P1.  The operator is linear and does not depend on the
    interface data, so it is assembled and factorised once (MUMPS LDL^T: it is symmetric);
    ``solve()`` re-assembles only the right-hand side.  The same holds for
    the interface mass matrices used to recover the consistent traction.

    Args:
        mesh: the fluid mesh: triangles in 2D or tetrahedra in 3D (gdim = tdim;
            P1 or P2 geometry).  Below, vectors have gdim components.
        facet_tags: facet tags of ``mesh``.
        viscosity: mu in the chosen stress unit (``Ca`` in units of mu_s, 1 in
            units of mu V0 / L0).
        velocity_bcs: ``[(tags, value)]``, full-vector Dirichlet conditions.
            ``value`` is a constant ``(vx, vy[, vz])`` or a callable
            ``x -> (gdim, npts)`` array (as ``Function.interpolate``).
        component_bcs: ``[(tags, component, value)]``, one Cartesian
            component fixed (``value`` a float or ``x -> (npts,)``); the other
            components are traction-free.
        interfaces: ``{name: FluidInterface}``.
        body_force: optional f: a UFL expression, a constant ``(fx, fy[, fz])``
            or a callable ``x -> (gdim, npts)`` (interpolated into P2).
        name: solver name (PETSc prefixes, messages).
        quadrature_degree: quadrature degree of every cell and facet integral
            (the monolithic reference must use the same).
        petsc_options: extra PETSc options of the Stokes solve (of the Krylov solver with
            ``solver="iterative"``, e.g. ``fieldsplit_u_pc_type``).
        solver: "direct" (MUMPS LDL^T) or "iterative" (MINRES with a block preconditioner,
            ``femtools.krylov.stokes_solver``).
        pressure_pin: optional point ``(x, y[, z])``: P = 0 at the pressure node
            nearest to it.  Required when the normal velocity is prescribed
            on the whole boundary (P is then defined only up to a constant;
            the constructor raises without it).

    Where boundaries share a node, the Dirichlet conditions are applied in
    the order interfaces, ``component_bcs``, ``velocity_bcs``: the outer
    boundary conditions win at the ends of an interface.

    Interface inputs (each ``(N, gdim)`` on ``interface_points(name)``; unset
    inputs are zero): ``"velocity"`` g_V (if a part is Dirichlet),
    ``"robin_normal"`` g_N (only g_N.n is used), ``"robin_tangential"`` g_T
    (only its tangential part is used).

    Interface outputs: ``"velocity"`` (N, gdim) nodal V and ``"traction"`` (N, gdim)
    nodal consistent traction lambda ON the fluid (see the module docstring).

    Example::

        solver = StokesSolver(msh, ft, viscosity=1.0,
                              velocity_bcs=[(INLET, inflow), (WALL, (0, 0))],
                              interfaces={"Gamma1": FluidInterface(GAMMA1, alpha_n=1.0)})
        solver.set_interface_data("Gamma1", robin_normal=g)
        solver.solve()
        out = solver.interface_data("Gamma1")    # {"velocity": ..., "traction": ...}
    """

    singular_hint = ("the velocity is fixed nowhere, or the pressure only up to a constant: prescribe the "
                     "velocity somewhere and leave the normal velocity free on part of every fluid region")

    def __init__(self, mesh: dmesh.Mesh, facet_tags: dmesh.MeshTagsMetaClass, *,
                 viscosity: float,
                 velocity_bcs: typing.Sequence = (),
                 component_bcs: typing.Sequence = (),
                 interfaces: typing.Mapping[str, FluidInterface] | None = None,
                 body_force=None,
                 name: str = "fluid",
                 quadrature_degree: int = 4,
                 petsc_options: dict | None = None,
                 pressure_pin: typing.Sequence[float] | None = None, solver: str = "direct"):
        super().__init__(mesh)
        t0 = time.perf_counter()
        self.name = name
        self._iterative = linear_solver_choice(solver, name)
        viscosity = float(viscosity)
        interfaces = self._check_arguments(mesh, viscosity, quadrature_degree, interfaces)
        self.mesh, self.facet_tags = mesh, facet_tags
        self.quadrature_degree = int(quadrature_degree)
        self.comm: MPI.Comm = mesh.comm
        self.gdim = mesh.geometry.dim
        self._fdim = mesh.topology.dim - 1
        mesh.topology.create_connectivity(self._fdim, mesh.topology.dim)
        self._build_spaces(viscosity)
        velocity_bcs, component_bcs = self._boundary_tags(velocity_bcs, component_bcs, interfaces)
        self._declare_interfaces(interfaces)
        self.body_force = self._body_force(body_force)

        # -- Stokes forms ---------------------------------------------------------
        trial = ufl.TrialFunction(self.W)
        u, p = ufl.split(trial)
        v, q = ufl.TestFunctions(self.W)
        n = ufl.FacetNormal(mesh)
        F = self._bulk_residual(u, p, v, q)
        for it in self._ifaces.values():
            F += self._robin_terms(it, u, v, n)

        self.bcs = self._dirichlet_bcs(velocity_bcs, component_bcs, pressure_pin)
        self._solver = self._build_solver(F, trial, v, self.bcs, petsc_options)

        # -- consistent traction: interface mass matrices -------------------------
        self._setup_traction_recovery()
        self._solved = False
        self._jacobian: dict | None = None          # interface_jacobian(), dropped with the operator
        self._jacobian_data: dict | None = None     # its operator-independent parts (data matrices)
        self.interface_jacobian_time = 0.0
        self.timing["setup"] += time.perf_counter() - t0

    # =========================================================================
    # setup helpers (the first three are overridden by fluid.ale.MovingStokesSolver)
    # =========================================================================
    def _bulk_residual(self, u, p, v, q, dx=None):
        """The bulk Stokes residual (operator and traction recovery) over ``dx`` (default: all cells)."""
        return forms.bulk_residual(u, p, v, q, self.mu, dx or self.dx, self.body_force)

    def _robin_residual(self, u, v, n, alpha_n, alpha_t, g_normal, g_tangential, ds):
        return forms.robin_residual(u, v, n, alpha_n, alpha_t, g_normal, g_tangential, ds)

    def _build_solver(self, F, trial, v, bcs, petsc_options):
        """The linear solver of ``F`` (linear in ``trial``): assembled and factorised once."""
        a, L = ufl.lhs(F), ufl.rhs(F)
        # keep L a non-empty form when there is neither a body force nor Robin data
        zero = fem.Constant(self.mesh, PETSc.ScalarType((0.0,) * self.gdim))
        L = L + ufl.inner(zero, v) * self.dx
        return LinearSolver(a, L, self.w, bcs, name=self.name, petsc_options=petsc_options,
                            linear_solver=self._krylov_solver(a, bcs, petsc_options))

    def _krylov_solver(self, a, bcs, petsc_options):
        """With ``solver="iterative"``: MINRES preconditioned by diag(AMG(a_uu), M_p / mu); else None."""
        if not self._iterative:
            return None
        p, q = ufl.TrialFunctions(self.W)[1], ufl.TestFunctions(self.W)[1]
        # additive fieldsplit reads only the diagonal blocks: a's velocity block, the pressure mass
        return stokes_solver(self.W, self.name, fem.form(a + p * q / self.mu * self.dx), bcs, petsc_options,
                             pinned=self._pinned_enclosed())

    def _pinned_enclosed(self) -> bool:
        """Whether the normal velocity is prescribed on the whole boundary (then the pressure is pinned:
        without a pin the constructor raised)."""
        try:
            self._check_pressure_determined()
        except ValueError:
            return True
        return False

    def _check_arguments(self, mesh, viscosity: float, quadrature_degree, interfaces) -> dict:
        """Raise if the viscosity, the mesh's dimension, the quadrature degree or an interface spec is
        wrong; returns the interfaces as a dict."""
        name = self.name
        if not np.isfinite(viscosity) or viscosity <= 0:
            raise ValueError(f"{name}: viscosity must be finite and > 0, got {viscosity}")
        if mesh.geometry.dim not in (2, 3) or mesh.topology.dim != mesh.geometry.dim:
            raise ValueError(f"{name}: mesh must be 2D or 3D with gdim = tdim (triangles or tetrahedra), "
                             f"got gdim={mesh.geometry.dim}, tdim={mesh.topology.dim}")
        if int(quadrature_degree) < 1:
            raise ValueError(f"{name}: quadrature_degree must be >= 1, got {quadrature_degree}")
        interfaces = dict(interfaces or {})
        for key, spec in interfaces.items():
            if not isinstance(spec, FluidInterface):
                raise TypeError(f"{name}: interfaces[{key!r}] must be a FluidInterface, got {type(spec).__name__}")
        return interfaces

    def _build_spaces(self, viscosity: float) -> None:
        """Taylor-Hood W = [P2 vector, P1], its collapsed subspaces and maps, the unknowns, mu and dx."""
        mesh = self.mesh
        P2 = ufl.VectorElement("Lagrange", mesh.ufl_cell(), 2)
        P1 = ufl.FiniteElement("Lagrange", mesh.ufl_cell(), 1)
        self.W = fem.FunctionSpace(mesh, ufl.MixedElement([P2, P1]))
        self.V, V_to_W = self.W.sub(0).collapse()
        self.Q, Q_to_W = self.W.sub(1).collapse()
        self._V_to_W = np.asarray(V_to_W, dtype=np.int32)
        self._Q_to_W = np.asarray(Q_to_W, dtype=np.int32)
        self._Vc = [self.W.sub(0).sub(c).collapse() for c in range(mesh.geometry.dim)]    # (space, map to W)
        self.w = fem.Function(self.W, name="w")
        self._u = fem.Function(self.V, name="V")
        self._p = fem.Function(self.Q, name="P")
        self.mu = fem.Constant(mesh, PETSc.ScalarType(viscosity))
        self.dx = quadrature_measure("dx", mesh, degree=self.quadrature_degree)

    def _boundary_tags(self, velocity_bcs, component_bcs, interfaces) -> tuple[list, list]:
        """``velocity_bcs`` and ``component_bcs`` with their tags as tuples, checked (``_check_tags``)."""
        velocity_bcs = [(as_tags(tags, "velocity_bcs"), value) for tags, value in velocity_bcs]
        component_bcs = [(as_tags(tags, "component_bcs"), int(c), value) for tags, c, value in component_bcs]
        allowed = "0 (x) or 1 (y)" if self.gdim == 2 else "0 (x), 1 (y) or 2 (z)"
        for tags, c, _ in component_bcs:
            if not 0 <= c < self.gdim:
                raise ValueError(f"{self.name}: component_bcs component must be {allowed} in {self.gdim}D, "
                                 f"got {c} for tags {tags}")
        self._check_tags(velocity_bcs, component_bcs, interfaces)
        return velocity_bcs, component_bcs

    def _declare_interfaces(self, interfaces: dict) -> None:
        """One ``_Interface`` per entry (marker k + 1), the interface facet markers and their ``ds``."""
        self._ifaces: dict[str, _Interface] = {}
        marker_facets, marker_values = [], []
        for k, (iname, spec) in enumerate(interfaces.items()):
            it = _Interface(iname, spec, marker=k + 1)
            it.nodes = InterfaceNodes(self.V, self.facet_tags, spec.tags, parent_dofs=self._V_to_W)
            facets = self._facets(spec.tags)
            marker_facets.append(facets)
            marker_values.append(np.full(facets.size, it.marker, dtype=np.int32))
            self._ifaces[iname] = it
            self._add_interface(iname, it.nodes, spec.inputs(self.gdim))
        if marker_facets:
            f = np.hstack(marker_facets)
            order = np.argsort(f)
            self._iface_tags = dmesh.meshtags(self.mesh, self._fdim, f[order], np.hstack(marker_values)[order])
        else:
            self._iface_tags = dmesh.meshtags(self.mesh, self._fdim, np.empty(0, np.int32), np.empty(0, np.int32))
        self.ds = quadrature_measure("ds", self.mesh, self._iface_tags, degree=self.quadrature_degree)

    def _dirichlet_bcs(self, velocity_bcs, component_bcs, pressure_pin) -> list:
        """Dirichlet conditions, interfaces first (outer boundaries win), then the pressure pin or the
        check that the pressure is determined without one."""
        self._constrained = [np.empty(0, np.int32) for _ in range(self.gdim)]   # V dofs per component
        self._boundary_values: list[tuple[fem.Function, np.ndarray]] = []     # (data, its unscaled values)
        self.boundary_velocity_scale = 1.0
        bcs = []
        for it in self._ifaces.values():
            bcs += self._interface_bcs(it)
        for tags, c, value in component_bcs:
            bcs.append(self._component_bc(tags, c, value))
        for tags, value in velocity_bcs:
            bcs.append(self._velocity_bc(tags, value))
        self._velocity_bcs, self._component_bcs = velocity_bcs, component_bcs
        if pressure_pin is not None:
            bcs.append(self._pressure_pin(pressure_pin))
        else:
            self._check_pressure_determined()
        return bcs

    def _facets(self, tags: typing.Sequence[int]) -> np.ndarray:
        return tagged_facets(self.facet_tags, tags)

    def _check_tags(self, velocity_bcs, component_bcs, interfaces) -> None:
        """Every tag exists somewhere; interface tags are used by nothing else."""
        used: dict[int, str] = {}
        for key, spec in interfaces.items():
            for t in spec.tags:
                if t in used:
                    raise ValueError(f"{self.name}: facet tag {t} is used by interface {key!r} and by {used[t]}")
                used[t] = f"interface {key!r}"
        every = [(t, "velocity_bcs") for tags, _ in velocity_bcs for t in tags]
        every += [(t, "component_bcs") for tags, _, _ in component_bcs for t in tags]
        for t, what in every:
            if t in used:
                raise ValueError(f"{self.name}: facet tag {t} is used by {what} and by {used[t]}")
        for t, what in every + [(t, "interfaces") for s in interfaces.values() for t in s.tags]:
            count = self.comm.allreduce(int(self.facet_tags.find(t).size), op=MPI.SUM)
            if count == 0:
                present = self.comm.allreduce([int(v) for v in np.unique(self.facet_tags.values)])
                raise ValueError(f"{self.name}: {what} names facet tag {t}, but no facet of the mesh has it; "
                                 f"tags present: {sorted(set(present))}")

    def _body_force(self, body_force):
        if body_force is None:
            return None
        if callable(body_force) and not isinstance(body_force, ufl.core.expr.Expr):
            f = fem.Function(self.V, name="f")
            f.interpolate(body_force)
            f.x.scatter_forward()
            return f
        d = self.gdim
        if isinstance(body_force, ufl.core.expr.Expr):
            if body_force.ufl_shape != (d,):
                raise ValueError(f"{self.name}: body_force must be a {d}-vector, got shape {body_force.ufl_shape}")
            return body_force
        value = np.asarray(body_force, dtype=float)
        if value.shape != (d,):
            raise ValueError(f"{self.name}: body_force must be a UFL {d}-vector, a callable or {d} numbers, "
                             f"got {body_force!r}")
        return fem.Constant(self.mesh, PETSc.ScalarType(tuple(value)))

    def _robin_terms(self, it: _Interface, u, v, n):
        """Robin (and traction) terms of one interface; Dirichlet parts contribute none."""
        spec = it.spec
        if spec.normal == "dirichlet" and spec.tangential == "dirichlet":
            return 0
        zero = ufl.as_vector((0.0,) * self.gdim)
        if spec.normal == "robin":
            it.alpha_n = fem.Constant(self.mesh, PETSc.ScalarType(spec.alpha_n))
            it.g_normal = fem.Function(self.V, name=f"{it.name}_robin_normal")
        if spec.tangential == "robin":
            it.alpha_t = fem.Constant(self.mesh, PETSc.ScalarType(spec.alpha_t))
            it.g_tangential = fem.Function(self.V, name=f"{it.name}_robin_tangential")
        return self._robin_residual(
            u, v, n,
            it.alpha_n if it.alpha_n is not None else 0,
            it.alpha_t if it.alpha_t is not None else 0,
            it.g_normal if it.g_normal is not None else zero,
            it.g_tangential if it.g_tangential is not None else zero,
            self.ds(it.marker))

    def _mark_constrained(self, V_dofs: np.ndarray, component: int) -> None:
        self._constrained[component] = np.union1d(self._constrained[component],
                                                  np.asarray(V_dofs, dtype=np.int32))

    def _locate(self, tags) -> np.ndarray:
        return fem.locate_dofs_topological(self.V, self._fdim, self._facets(tags))   # V blocks

    def _velocity_bc(self, tags, value) -> fem.DirichletBCMetaClass:
        g = set_function(fem.Function(self.V), value, f"{self.name}: velocity_bcs value for tags {tags}")
        self._boundary_values.append((g, g.x.array.copy()))
        dofs = fem.locate_dofs_topological((self.W.sub(0), self.V), self._fdim, self._facets(tags))
        blocks = self._locate(tags)
        for c in range(self.gdim):
            self._mark_constrained(self.gdim * blocks + c, c)
        return fem.dirichletbc(g, dofs, self.W.sub(0))

    def _component_bc(self, tags, c, value) -> fem.DirichletBCMetaClass:
        Vc = self._Vc[c][0]
        if callable(value):     # a scalar space: (n,) values
            given = value

            def value(x):
                return np.asarray(given(x), dtype=float).reshape(-1)
        g = set_function(fem.Function(Vc), value, f"{self.name}: component_bcs value for tags {tags}")
        self._boundary_values.append((g, g.x.array.copy()))
        dofs = fem.locate_dofs_topological((self.W.sub(0).sub(c), Vc), self._fdim, self._facets(tags))
        self._mark_constrained(self.gdim * self._locate(tags) + c, c)
        return fem.dirichletbc(g, dofs, self.W.sub(0).sub(c))

    def _interface_bcs(self, it: _Interface) -> list:
        spec, d = it.spec, self.gdim
        it.own_constrained = [np.empty(0, np.int32) for _ in range(d)]
        parts = [spec.normal == "dirichlet", spec.tangential == "dirichlet"]
        if not any(parts):
            return []
        blocks = self._locate(spec.tags)
        if all(parts):
            it.g_velocity = fem.Function(self.V, name=f"{it.name}_velocity")
            dofs = fem.locate_dofs_topological((self.W.sub(0), self.V), self._fdim, self._facets(spec.tags))
            it.own_constrained = [d * blocks + c for c in range(d)]
            return [fem.dirichletbc(it.g_velocity, dofs, self.W.sub(0))]
        normal_axis = self._normal_axis(it)
        it.components = (normal_axis,) if parts[0] else tuple(c for c in range(d) if c != normal_axis)
        bcs = []
        for c in it.components:
            Vc = self._Vc[c][0]
            g = fem.Function(Vc, name=f"{it.name}_velocity_{c}")
            nodes = InterfaceNodes(Vc, self.facet_tags, spec.tags)
            if not np.array_equal(nodes.points, it.nodes.points):
                raise RuntimeError(f"{self.name}: interface {it.name!r}: scalar and vector P2 nodes differ")
            it.g_component.append(g)
            it.component_nodes.append(nodes)
            dofs = fem.locate_dofs_topological((self.W.sub(0).sub(c), Vc), self._fdim, self._facets(spec.tags))
            it.own_constrained[c] = d * blocks + c
            bcs.append(fem.dirichletbc(g, dofs, self.W.sub(0).sub(c)))
        return bcs

    def _normal_axis(self, it: _Interface) -> int:
        """k if the interface lies in the line or plane x_k = const; otherwise raise."""
        pts = it.nodes.points
        scale = 1.0 + np.abs(pts).max()
        spread = pts.max(axis=0) - pts.min(axis=0)
        flat = np.flatnonzero(spread <= 1e-10 * scale)
        if flat.size != 1:
            spans = ", ".join(f"d{'xyz'[k]}={spread[k]:.3g}" for k in range(pts.shape[1]))
            raise ValueError(
                f"{self.name}: interface {it.name!r} has normal={it.spec.normal!r} and "
                f"tangential={it.spec.tangential!r}; a single Dirichlet part is only allowed on a flat, "
                f"axis-aligned interface (x = const, y = const{', z = const' if pts.shape[1] == 3 else ''}), "
                f"but its nodes span {spans}. Use 'dirichlet' for both parts or 'robin'.")
        return int(flat[0])

    def _pressure_pin(self, point) -> fem.DirichletBCMetaClass:
        gdim = self.gdim
        point = np.asarray(point, dtype=float).reshape(-1)
        if point.shape != (gdim,) or not np.all(np.isfinite(point)):
            raise ValueError(f"{self.name}: pressure_pin must be a point {_POINT[gdim]}, got {point!r}")
        X = self.Q.tabulate_dof_coordinates()[:, :gdim]
        n_owned = self.Q.dofmap.index_map.size_local
        d = np.linalg.norm(X[:n_owned] - point, axis=1)
        local = (float(d.min()), self.comm.rank) if d.size else (np.inf, self.comm.rank)
        _, owner = self.comm.allreduce(local, op=MPI.MINLOC)
        node = self.comm.bcast(X[int(np.argmin(d))] if self.comm.rank == owner else None, root=owner)
        tol = 1e-12 * (1 + np.abs(node).max())
        dofs = fem.locate_dofs_geometrical((self.W.sub(1), self.Q),
                                           lambda x: np.linalg.norm(x[:gdim].T - node, axis=1) < tol)
        return fem.dirichletbc(fem.Function(self.Q), dofs, self.W.sub(1))

    def _check_pressure_determined(self) -> None:
        """Raise if V.n is prescribed on the whole boundary of a connected fluid part.

        In such a part (cells connected through facets) P is determined only up
        to a constant.  The normal-flow device has two fluid parts, upstream and
        downstream of the gel, so each one needs a free boundary of its own.
        """
        msh, fdim, gdim = self.mesh, self._fdim, self.gdim
        ext = dmesh.exterior_facet_indices(msh.topology)
        free = np.ones(ext.size, dtype=bool)
        full = [t for tags, _ in self._velocity_bcs for t in tags]
        full += [t for it in self._ifaces.values() if it.spec.normal == "dirichlet" for t in it.spec.tags]
        free &= ~np.isin(ext, self._facets(full))
        geo = _cpp.mesh.entities_to_geometry(msh._mesh, fdim, ext, False)
        x = msh.geometry.x
        corners = x[geo[:, :fdim + 1], :gdim] if ext.size else np.zeros((0, fdim + 1, gdim))
        d = corners.max(axis=1) - corners.min(axis=1)      # the facet's extent along each axis
        for tags, c, _ in self._component_bcs:
            # component c is the normal one on a facet in the plane (line) x_c = const
            along = d[:, c] <= 1e-12 * (d.sum(axis=1) + 1e-300)
            free &= ~(np.isin(ext, self._facets(tags)) & along)
        labels, count = connected_components(msh)
        f2c = msh.topology.connectivity(fdim, msh.topology.dim)
        ext_labels = labels[f2c.array[f2c.offsets[ext]]] if ext.size else np.zeros(0, dtype=labels.dtype)
        # facets of ghost cells appear on two ranks; a free facet anywhere frees its part
        has_free = np.zeros(count, dtype=np.int32)
        has_free[ext_labels[free]] = 1
        self.comm.Allreduce(MPI.IN_PLACE, has_free, op=MPI.MAX)
        enclosed = np.flatnonzero(has_free == 0)
        if enclosed.size == 0:
            return
        # a point of the first enclosed part: the mean of its owned cells' first vertices
        n_owned = msh.topology.index_map(msh.topology.dim).size_local
        mine = np.flatnonzero(labels[:n_owned] == enclosed[0])
        first_nodes = msh.geometry.dofmap.array[msh.geometry.dofmap.offsets[mine]]
        sums = np.append(x[first_nodes, :gdim].sum(axis=0), mine.size)
        self.comm.Allreduce(MPI.IN_PLACE, sums, op=MPI.SUM)
        where = ", ".join(f"{w:.3g}" for w in sums[:gdim] / sums[gdim])
        raise ValueError(f"{self.name}: the normal velocity is prescribed on the whole boundary of "
                         f"{enclosed.size} of its {count} connected part(s) (the first one near "
                         f"({where})), so the pressure there is determined only up "
                         f"to a constant; leave part of that boundary free or pass pressure_pin={_POINT[gdim]}")

    def _setup_traction_recovery(self) -> None:
        """Interface mass matrices on the interface nodes, and the reaction near the interfaces.

        The reaction R(s) (bulk residual with q = 0) at an interface node
        receives contributions only from the cells holding that node, so it is
        assembled over those cells; the mass system has the interface's size.
        """
        V = self.V
        u_h, p_h = ufl.split(self.w)
        s = ufl.TestFunction(V)
        tdim = self.mesh.topology.dim
        n_cells = self.mesh.topology.index_map(tdim).size_local
        blocks = np.hstack([it.nodes.local_blocks for it in self._ifaces.values()] + [np.empty(0, np.int32)])
        cell_dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[:n_cells]
        cells = np.flatnonzero(np.isin(cell_dofs, blocks).any(axis=1)).astype(np.int32)
        near = dmesh.meshtags(self.mesh, tdim, cells, np.ones(cells.size, dtype=np.int32))
        dx_near = quadrature_measure("dx", self.mesh, near, degree=self.quadrature_degree)(1)
        # R(s): bulk residual with q = 0, i.e. the reaction without interface terms
        self._reaction_form = fem.form(self._bulk_residual(u_h, p_h, s, 0, dx_near))
        self._reaction = fem_petsc.create_vector(self._reaction_form)
        self._reaction_current = False
        self._traction_stats = SolverStats()
        self._direction = fem.Constant(self.mesh, PETSc.ScalarType(np.eye(self.gdim)[0]))
        t0 = time.perf_counter()
        for it in self._ifaces.values():
            ft = self._single_marker(it)
            ds = quadrature_measure("ds", self.mesh, ft, degree=self.quadrature_degree)
            it.traction = fem.Function(V, name=f"{it.name}_traction")
            on = it.nodes.dofs()              # local (n, gdim) unrolled V dofs on the interface
            keep = np.zeros(on.shape)
            for c in range(self.gdim):
                # fixed by another boundary: outer Dirichlet conditions and the other interfaces'
                other = [self._constrained[c]] + [o.own_constrained[c] for o in self._ifaces.values() if o is not it]
                keep[:, c] = ~np.isin(on[:, c], np.hstack(other))
            it.traction_mass = InterfaceMass(it.nodes, V, ds(1), it.nodes.gather(keep) > 0.5)
            it.force_form = fem.form(ufl.inner(it.traction, self._direction) * ds(1))
        self._traction_stats["factor_time"] += time.perf_counter() - t0
        self._traction_stats["factorizations"] += len(self._ifaces)

    def _assemble_reaction(self) -> PETSc.Vec:
        """The reaction vector, exact at the interface nodes (assembled near the interfaces only)."""
        with self._reaction.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self._reaction, self._reaction_form)
        self._reaction.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self._reaction

    def _single_marker(self, it: _Interface):
        """Facet tags with value 1 on this interface only (one compiled form for all interfaces)."""
        f = self._facets(it.spec.tags)
        return dmesh.meshtags(self.mesh, self._fdim, f, np.ones(f.size, dtype=np.int32))

    # =========================================================================
    # FieldSolver interface
    # =========================================================================
    def _set_input(self, interface: str, key: str, values: np.ndarray) -> None:
        it = self._ifaces[interface]
        if key == "velocity":
            if it.g_velocity is not None:
                it.nodes.to_function(values, it.g_velocity)
            else:
                for c, nodes, g in zip(it.components, it.component_nodes, it.g_component):
                    nodes.to_function(values[:, c], g)
        elif key == "robin_normal":
            it.nodes.to_function(values, it.g_normal)
        elif key == "robin_tangential":
            it.nodes.to_function(values, it.g_tangential)
        else:      # FieldSolver.set_interface_data has checked the key
            raise KeyError(key)

    def _solve(self) -> None:
        self._solver.solve()
        self._u.x.array[:] = self.w.x.array[self._V_to_W]
        self._p.x.array[:] = self.w.x.array[self._Q_to_W]
        for it in self._ifaces.values():
            it.traction_current = False
        self._reaction_current = False
        self._solved = True

    def _require_solution(self) -> None:
        if not self._solved:
            raise RuntimeError(f"{self.name}: call solve() before asking for results")

    def _traction(self, it: _Interface) -> fem.Function:
        self._require_solution()
        if not it.traction_current:
            stats = self._traction_stats
            t0 = time.perf_counter()
            if not self._reaction_current:
                self._assemble_reaction()
                self._reaction_current = True
            R = it.nodes.from_array(self._reaction.array)
            t1 = time.perf_counter()
            it.nodes.to_function(it.traction_mass.solve(R), it.traction)
            stats["assemble_time"] += t1 - t0
            stats["solve_time"] += time.perf_counter() - t1
            stats["solves"] += 1
            it.traction_current = True
        return it.traction

    def interface_data(self, name: str) -> dict[str, np.ndarray]:
        """``{"velocity": (N, gdim), "traction": (N, gdim)}`` on ``interface_points(name)``.

        ``traction`` is the consistent traction lambda exerted ON the fluid
        (t = (Sigma - P I) n, n the fluid's outward normal); components fixed
        by another boundary's Dirichlet condition are 0.
        """
        nodes = self.interface_nodes(name)
        self._require_solution()
        it = self._ifaces[name]
        return {"velocity": nodes.from_function(self._u),
                "traction": nodes.from_function(self._traction(it))}

    # =========================================================================
    # linearised interface map (the coupling's quasi-Newton prior)
    # =========================================================================
    def interface_jacobian(self) -> dict[tuple[tuple[str, str], tuple[str, str]], np.ndarray]:
        """The exact derivative of the interface outputs with respect to the interface inputs.

        Returns ``{((out_interface, out_key), (in_interface, in_key)): J}`` for every pair
        of interfaces (zero blocks included), ``out_key`` in ``"velocity"``, ``"traction"``
        (the arrays of :meth:`interface_data`, the traction ON the fluid with its zero
        components where another Dirichlet condition fixes the velocity) and ``in_key``
        among the interface's Robin inputs ``"robin_normal"``, ``"robin_tangential"``
        (as :meth:`set_interface_data` takes them).  ``J`` is dense, shape
        ``(d N_out, d N_in)`` (d = gdim): row ``d i + c`` is node ``i`` of ``interface_points(out_interface)``,
        component ``c``; the columns likewise for the input.  The same arrays on every rank.

        The map is affine (the operator does not depend on the data), so
        ``out(data + delta) - out(data) = J delta`` exactly.  Derivation: the data enter
        only the right-hand side, b = B g (B the derivative of the Robin form with respect
        to the data, rows on the interface velocity dofs Gamma).  With k = the free
        interface velocity dofs plus one pressure dof per connected fluid part (without
        it the eliminated block of an enclosed part is singular: the pressure constant),
        (K^-1)_kk = S^-1, S the Schur complement of the operator K (with its Dirichlet
        conditions) onto k (``femtools.linalg.condensed_matrix``), and
        since b vanishes off Gamma: V_Gamma = (S^-1)_GG B g.  At a solution the bulk
        residual (the reaction) at an interface row is b - R_rob V_Gamma, R_rob =
        alpha_n B_N + alpha_t B_T the Robin operator, so the traction is
        M_kk^-1 (B g - R_rob V_Gamma) on the kept components (``InterfaceMass``) and 0 on
        the others.  One new compiled form (the data form, also giving R_rob).

        Built lazily and cached until ``update_operator`` or ``set_robin_coefficients``.
        Interfaces with a Dirichlet part raise ``NotImplementedError``.
        """
        if self._jacobian is None:
            t0 = time.perf_counter()
            self._jacobian = self._build_interface_jacobian()
            self.interface_jacobian_time = time.perf_counter() - t0     # seconds of the last build
        return {key: J.copy() for key, J in self._jacobian.items()}

    # -- hooks (fluid.ale.MovingStokesSolver) -----------------------------------
    def _jacobian_operator_form(self):
        """The operator whose Schur complement the Jacobian uses (a compiled bilinear form on W)."""
        return self._solver.a

    def _jacobian_input_keys(self, it: _Interface) -> list[str]:
        return [key for key in ("robin_normal", "robin_tangential") if key in self._inputs[it.name]]

    def _jacobian_input(self, it: _Interface, key: str, data: dict, rows: np.ndarray) -> np.ndarray:
        """d(right-hand side at the kept velocity dofs) / d(input array ``key`` of ``it``): sparse (n_kept, gdim N)."""
        return data[it.name][key]

    # -- construction -------------------------------------------------------------
    def _jacobian_data_matrices(self, kept_v: np.ndarray) -> dict:
        """Per interface: B_N and B_T (rows ``kept_v`` of W, columns the interface nodes of V).

        B_N[i, (j, c)] = int (phi_jc.n)(v_i.n) ds, B_T[i, (j, c)] = int phi_jc,tau . v_i,tau ds over
        the interface: the derivative of the right-hand side of ``forms.robin_residual`` with
        respect to g_N and g_T (and alpha_n B_N + alpha_t B_T is its operator).  Both come
        from one compiled form, switched by two Constants.
        """
        data = self._jacobian_data
        if data is not None and np.array_equal(data["rows"], kept_v):
            return data
        phi = ufl.TrialFunction(self.V)
        v, _ = ufl.TestFunctions(self.W)
        n = ufl.FacetNormal(self.mesh)
        switch = fem.Constant(self.mesh, PETSc.ScalarType((1.0, 0.0)))
        phin, vn = ufl.dot(phi, n), ufl.dot(v, n)
        integrand = switch[0] * phin * vn + switch[1] * ufl.dot(phi - phin * n, v - vn * n)
        data = {"rows": kept_v.copy()}
        for it in self._ifaces.values():
            ds = quadrature_measure("ds", self.mesh, self._single_marker(it), degree=self.quadrature_degree)
            form = fem.form(integrand * ds(1))
            cols = it.nodes.global_dofs(self.V).ravel()
            data[it.name] = {}
            for key, value in (("robin_normal", (1.0, 0.0)), ("robin_tangential", (0.0, 1.0))):
                switch.value[:] = value
                A = fem_petsc.assemble_matrix(form)
                A.assemble()
                data[it.name][key] = gather_submatrix(A, kept_v, cols)      # interface rows and columns only
                A.destroy()
        self._jacobian_data = data
        return data

    def _schur_pressure_dofs(self) -> np.ndarray:
        """One free pressure dof (global index in W) per connected fluid part, replicated."""
        labels, count = connected_components(self.mesh)
        dofmap = self.W.sub(1).dofmap
        imap, bs = self.W.dofmap.index_map, self.W.dofmap.index_map_bs
        n_cells = self.mesh.topology.index_map(self.mesh.topology.dim).size_local
        local = dofmap.list.array.reshape(-1, dofmap.dof_layout.num_dofs)[:n_cells]
        glob = global_dofs(self.W, local.ravel(), self.bcs)            # -1: fixed by a condition
        use = (local.ravel() < imap.size_local * bs) & (glob >= 0)
        best = np.full(count, np.iinfo(np.int64).max, dtype=np.int64)
        np.minimum.at(best, np.repeat(labels[:n_cells], local.shape[1])[use], glob[use].astype(np.int64))
        if self.comm.size > 1:
            self.comm.Allreduce(MPI.IN_PLACE, best, op=MPI.MIN)
        return np.unique(best[best < np.iinfo(np.int64).max])

    def _build_interface_jacobian(self) -> dict:
        partial = [name for name, it in self._ifaces.items()
                   if "dirichlet" in (it.spec.normal, it.spec.tangential)]
        if partial:
            raise NotImplementedError(
                f"{self.name}: interface_jacobian() covers Robin interfaces only, but interface(s) "
                f"{partial} have a Dirichlet part (their 'velocity' input is not linearised)")
        if not self._ifaces:
            return {}
        ifaces = list(self._ifaces.values())
        kept_v, pos = self._kept_velocity_dofs(ifaces)
        nv = kept_v.size
        E = self._inverse_interface_block(kept_v)
        # data matrices, the Robin operator on the kept velocity dofs, the inputs' columns
        data = self._jacobian_data_matrices(kept_v)
        R_rob = self._robin_operator(ifaces, data, pos, nv)
        columns, B = [], []
        for it in ifaces:
            for key in self._jacobian_input_keys(it):
                columns.append((it.name, key))
                B.append(scipy.sparse.csr_matrix(self._jacobian_input(it, key, data, pos[it.name])))
        widths = np.cumsum([0] + [b.shape[1] for b in B])
        B = scipy.sparse.hstack(B).tocsr()
        X = np.asarray((B.T @ E.T).T)             # kept interface velocities per unit input
        R = B.toarray() - R_rob @ X               # reactions at the kept interface velocity dofs
        out = {}
        for it in ifaces:
            out.update(self._interface_jacobian_rows(it, pos[it.name], X, R, columns, widths))
        return out

    def _kept_velocity_dofs(self, ifaces: list) -> tuple[np.ndarray, dict]:
        """The free interface velocity dofs (global, in W, sorted) and, per interface, the position in
        them of each of its (N, gdim) dofs (-1 where fixed)."""
        vel = {it.name: it.nodes.global_dofs(self.W, parent=True, bcs=self.bcs).ravel() for it in ifaces}
        kept_v = np.unique(np.hstack(list(vel.values())))
        kept_v = kept_v[kept_v >= 0]
        pos = {name: np.where(g >= 0, np.searchsorted(kept_v, np.maximum(g, 0)), -1) for name, g in vel.items()}
        return kept_v, pos

    def _inverse_interface_block(self, kept_v: np.ndarray) -> np.ndarray:
        """(K^-1) on the kept velocity dofs: the inverse of the Schur complement onto them and one
        pressure dof per connected part, restricted to the velocity rows and columns."""
        A = fem_petsc.assemble_matrix(self._jacobian_operator_form(), bcs=self.bcs)
        A.assemble()
        S = condensed_matrix(A, np.concatenate([kept_v, self._schur_pressure_dofs()]),
                                         f"{self.name} interface Jacobian")
        A.destroy()
        nv = kept_v.size
        return np.linalg.inv(S)[:nv, :nv]

    def _robin_operator(self, ifaces: list, data: dict, pos: dict, nv: int):
        """R_rob = alpha_n B_N + alpha_t B_T on the kept velocity dofs (sparse, (nv, nv))."""
        R_rob = scipy.sparse.csr_matrix((nv, nv))
        for it in ifaces:
            on = np.flatnonzero(pos[it.name] >= 0)
            op = (float(it.alpha_n.value) * data[it.name]["robin_normal"]
                  + float(it.alpha_t.value) * data[it.name]["robin_tangential"])
            select = scipy.sparse.csr_matrix((np.ones(on.size), (on, pos[it.name][on])), shape=(op.shape[1], nv))
            R_rob = R_rob + op @ select
        return R_rob

    def _interface_jacobian_rows(self, it: _Interface, p: np.ndarray, X: np.ndarray, R: np.ndarray,
                                 columns: list, widths: np.ndarray) -> dict:
        """The blocks of interface ``it``'s outputs: its velocity rows of X, its traction from R."""
        on = p >= 0
        velocity = np.zeros((p.size, X.shape[1]))
        velocity[on] = X[p[on]]
        if np.any(p[it.traction_mass.keep.ravel()] < 0):
            raise RuntimeError(f"{self.name}: interface {it.name!r}: a traction component is kept "
                               f"where the velocity is fixed")
        reaction = np.zeros_like(velocity)
        reaction[on] = R[p[on]]
        traction = it.traction_mass.solve_columns(reaction)
        out = {}
        for k, col in enumerate(columns):
            block = slice(widths[k], widths[k + 1])
            out[((it.name, "velocity"), col)] = np.ascontiguousarray(velocity[:, block])
            out[((it.name, "traction"), col)] = np.ascontiguousarray(traction[:, block])
        return out

    # =========================================================================
    # accessors
    # =========================================================================
    @property
    def velocity(self) -> fem.Function:
        """The velocity V (collapsed P2 vector function); valid after ``solve()``."""
        return self._u

    @property
    def pressure(self) -> fem.Function:
        """The pressure P (collapsed P1 function); valid after ``solve()``."""
        return self._p

    def interface_force(self, name: str) -> np.ndarray:
        """Total force ON the fluid over interface ``name``: int_Gamma lambda ds, shape (gdim,)."""
        self.interface_nodes(name)
        it = self._ifaces[name]
        self._traction(it)
        force = np.zeros(self.gdim)
        for c in range(self.gdim):
            self._direction.value[:] = np.eye(self.gdim)[c]
            force[c] = self.comm.allreduce(fem.assemble_scalar(it.force_form), op=MPI.SUM)
        return force

    def scale_boundary_velocity(self, factor: float) -> None:
        """Multiply the data of ``velocity_bcs`` and ``component_bcs`` by ``factor`` (e.g. an inflow waveform).

        The factor applies to the values given at construction, not cumulatively;
        the operator is unchanged, so no refactorisation.
        """
        factor = float(factor)
        if not np.isfinite(factor):
            raise ValueError(f"{self.name}: boundary velocity factor must be finite, got {factor}")
        for g, base in self._boundary_values:
            g.x.array[:] = factor * base
        self.boundary_velocity_scale = factor

    def update_operator(self) -> None:
        """Re-assemble and re-factorise the Stokes operator (e.g. after changing ``mu.value``)."""
        self._jacobian = None
        self._solver.update_operator()

    def set_robin_coefficients(self, name: str, alpha_n: float | None = None,
                               alpha_t: float | None = None) -> None:
        """Change the Robin coefficients of interface ``name``; re-factorises the operator.

        Only parts declared ``"robin"`` have a coefficient.  Each value must be
        finite and >= 0.
        """
        self.interface_nodes(name)
        it = self._ifaces[name]
        for part, key, value, const in (("normal", "alpha_n", alpha_n, it.alpha_n),
                                        ("tangential", "alpha_t", alpha_t, it.alpha_t)):
            if value is None:
                continue
            value = float(value)
            if const is None:
                raise ValueError(f"{self.name}: interface {name!r} has {part}={getattr(it.spec, part)!r}; "
                                 f"{key} exists only for {part}='robin'")
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f"{self.name}: {key} must be finite and >= 0, got {value}")
            const.value = value
            setattr(it.spec, key, value)
        self._jacobian = None
        self._solver.update_operator()

    @property
    def stats(self) -> dict:
        """Factorisations, solves and times: totals, and per part (``stokes``, ``traction``)."""
        traction = self._traction_stats
        stokes = dict(self._solver.stats)
        total = {k: stokes[k] + traction[k] for k in stokes}
        total.update(stokes=stokes, traction=dict(traction), timing=dict(self.timing))
        return total
