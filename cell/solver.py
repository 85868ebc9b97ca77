"""The neo-Hookean cell as a field solver (model.md sections 2, 3 and 6).

The cell Omega_C is a compressible neo-Hookean solid, in plane strain on a
triangle mesh and in three dimensions on a tetrahedral one (the same code),

    div_X P = 0 in Omega_C,   P = J sigma_c F^-T,
    sigma_c = mu_c J^-1 (F F^T - I) + lambda_c (J - 1) I,   F = I + grad_X u_c,

posed in the total Lagrangian form on the reference (undeformed) mesh, with
P2 (isoparametric) displacement and Newton's method with the exact Jacobian
(``femtools.linalg.NewtonSolver``, which keeps a factorised Jacobian for as
long as it contracts).  The weak form is ``cell.forms.residual``, shared with
the monolithic reference.

Units.  Lengths in the mesh's unit (L0), moduli ``mu``, ``lmbda`` in units of
mu_s, displacement unknown u_hat in the unit ``d = displacement_scale`` (in
L0: u_c = d u_hat) and stresses in the unit ``s = stress_scale`` (in mu_s).
s = d = 1 is the paper's unscaled form; s = d = Ca is the device scaling.

Boundary conditions:
  * interfaces (Gamma2): Dirichlet displacement u_hat = g, every component;
  * symmetry: u_hat[c] = 0 (zero normal displacement, zero tangential traction);
  * dirichlet (tests): prescribed u_hat, all or one component;
  * tractions (tests): dead load  P N = s t0  with N the reference outward normal;
  * every other boundary is traction free.
"""

from __future__ import annotations

import functools
import logging
import time
import typing

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

import basix
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from cell import forms
from femtools.canonical import CanonicalOrder
from femtools.functions import quadrature_measure, set_function, von_mises
from femtools.interface import InterfaceNodes
from femtools.krylov import elasticity_solver, linear_solver_choice
from femtools.linalg import NewtonSolver, assemble_residual_vector, condensed_matrix, jacobian_at_rest
from femtools.mesh import as_tags, tagged_facets
from femtools.solver import FieldSolver

__all__ = ["NeoHookeanCellSolver"]

logger = logging.getLogger(__name__)

Tags = typing.Union[int, typing.Iterable[int]]


class NeoHookeanCellSolver(FieldSolver):
    """Neo-Hookean cell (plane strain or 3D): Dirichlet displacement in, nodal reaction forces out.

    Vectors have gdim components (the mesh's geometric dimension, 2 or 3):
    interface arrays are (N, gdim), constants (gdim,) arrays.

    Args:
        mesh: the cell's mesh (reference configuration; P1 or P2 geometry).
        facet_tags: its facet tags.
        mu: shear modulus mu_c (units of mu_s), > 0.
        lmbda: Lame modulus lambda_c (units of mu_s); the Poisson ratio
            nu = lambda/(2 (lambda + mu)) must lie in (-1, 0.5).
        stress_scale: stress unit ``s`` in units of mu_s, > 0.
        displacement_scale: displacement unit ``d`` in units of L0, > 0.
        interfaces: ``{name: tags}``; Dirichlet-displacement interfaces (Gamma2).
            Input ``"displacement"`` (N, gdim) in units of d; output ``"force"``.
        robin_interfaces: ``{name: (tags, kappa)}``; Robin interfaces: the
            surroundings act as the given nodal forces f* plus springs of
            stiffness kappa (units s / L0) towards a displacement u*:
            int P/s : grad v dX + int kappa (u - u*) . v dS = f*(v).  Inputs
            ``"displacement"`` u* and ``"force"`` f* (nodal forces ON the
            cell, units s L0); outputs ``"force"`` (as for ``interfaces``) and
            ``"displacement"``.  kappa > 0 also holds the rigid modes.
        symmetry: ``[(tags, component)]``: u[component] = 0 on those facets
            (a flat edge or face of the cell on a symmetry line or plane; component
            0 (x), 1 (y) or, in 3D, 2 (z)).
        dirichlet: ``[(tags, value)]`` or ``[(tags, value, component)]``:
            prescribed displacement in units of d; ``value`` a constant
            ((gdim,) array, or a scalar with ``component``) or a callable
            ``x -> (gdim, n)`` (or ``(n,)``) array as for ``Function.interpolate``.
        tractions: ``[(tags, value)]``: dead reference traction P N = s t0 on
            those facets, ``t0`` in units of s; ``value`` a (gdim,) constant, a
            callable ``x -> (gdim, n)`` (interpolated in P2) or a UFL expression
            on this mesh (e.g. ``-p * ufl.FacetNormal(mesh)`` with ``p`` a
            ``fem.Constant``, which keeps a pressure exactly self-equilibrated).
        remove_rigid_modes: for pure traction problems (no interfaces,
            symmetry or dirichlet): remove the rigid-body modes (3 in 2D, 6 in
            3D) by point constraints, see below.
        name: name used in messages and PETSc prefixes.
        quadrature_degree: degree of every dx/ds of the forms (the monolithic
            reference must use the same).
        petsc_options: options of the direct solver (default MUMPS; LDL^T for a symmetric Jacobian, else LU),
            or with ``solver="iterative"`` of the Krylov solver (``femtools.krylov.elasticity_solver``).
        solver: "direct" (MUMPS) or "iterative" (CG with GAMG and the rigid-body near-null space;
            GMRES if the Jacobian is not symmetric).
        newton_rtol: relative incremental tolerance |du| <= rtol |u|.
        reuse: Jacobian reuse of the Newton solver, "adaptive" or "never".
        rigid_mode_rtol: with ``remove_rigid_modes``, the largest resultant
            (force and moment) the point constraints may carry, relative to
            the total applied load, before ``solve`` raises.
        linear_path: each ``solve()`` takes one step with the kept
            linearisation at rest and goes on to the exact Newton solution
            only if the nonlinear remainder matters (see
            ``femtools.linalg.NewtonSolver.solve``): exact for a linear
            problem, and in a coupling loop whose solves continue from the
            previous state the remainder converges with the coupling.

    Rigid-body modes.  A cell loaded by tractions only floats: its tangent
    stiffness has the rigid modes (2D: two translations, one rotation; 3D:
    three and three) as null space.  They are removed by point constraints:
    u = 0 at the node A that is lexicographically smallest in (x, y, z) and
    u_y = 0 at the node B with the largest x; in 3D also u_z = 0 at B and at
    the node C farthest from the line AB in the (x, y) projection (3-2-1
    supports).  These supports are statically determinate (exactly one
    constraint per rigid mode: a rigid motion u = w x (X - A) that they
    allow has w = 0 when x_B - x_A > 0 and (B - A) x (C - A) has a z
    component), so for a self-equilibrated load (zero resultant force
    and moment, which a pressure ``-p N`` is exactly, also on curved P2
    facets) they carry no reaction and the strains and stresses are those of
    the free body; the displacement is the free body's up to the rigid motion
    that fixes A and the direction AB.  Unlike Lagrange multipliers they keep
    the Jacobian an ordinary sparse matrix, so the shared factorise-once
    Newton solver serves unchanged.  After each solve the reactions at the
    pins are measured (``rigid_mode_reaction``); if they exceed
    ``rigid_mode_rtol`` of the applied load, the load was not self-equilibrated
    (or the strains are so large that the dead load's moment about the
    deformed body is no longer balanced) and ``solve`` raises.

    Interface data (arrays over ``interface_points(name)``, (N, gdim), replicated, sorted):
        input ``"displacement"`` (N, gdim): u_hat on the interface, units of d.
        output ``"force"`` (N, gdim): nodal forces ON the cell at the interface
            nodes, R_j = int P/s : grad phi_j dX (``forms.residual`` assembled
            with no boundary conditions and no boundary loads), units of
            s * L0 (per unit depth in 2D), s * L0^2 in 3D, reference configuration.  At a solution
            R_j = int (P N / s) phi_j dS: the consistent nodal form of the
            traction that the surroundings (the gel) exert on the cell, N
            pointing out of the cell.  The gel receives -R_j.  Sum_j R_j is
            the net force on the cell through the interface.  A node shared
            with another boundary carries that boundary's share as well (its
            traction or its reaction).
    """

    name = "cell"
    singular_hint = ("the cell is not held: a rigid-body motion is free; give it a Dirichlet (interface) "
                     "condition, Robin springs, enough symmetry lines, or remove_rigid_modes=True")

    def __init__(self, mesh, facet_tags, *, mu: float, lmbda: float, stress_scale: float = 1.0,
                 displacement_scale: float = 1.0, interfaces: dict[str, Tags] | None = None,
                 robin_interfaces: dict[str, tuple[Tags, float]] | None = None,
                 symmetry: typing.Sequence = (), dirichlet: typing.Sequence = (),
                 tractions: typing.Sequence = (), remove_rigid_modes: bool = False,
                 name: str = "cell", quadrature_degree: int = 4, petsc_options: dict | None = None,
                 newton_rtol: float = 1e-11, reuse: str = "adaptive", rigid_mode_rtol: float = 1e-6,
                 linear_path: bool = False, solver: str = "direct"):
        super().__init__(mesh)
        t0 = time.perf_counter()
        self.name = str(name)
        _validate_parameters(mu, lmbda, stress_scale, displacement_scale, quadrature_degree,
                             newton_rtol, reuse, rigid_mode_rtol)
        interfaces = dict(interfaces or {})
        robin_interfaces = dict(robin_interfaces or {})
        self._check_conditions(interfaces, robin_interfaces, symmetry, dirichlet, remove_rigid_modes)
        self.mesh, self.facet_tags = mesh, facet_tags
        self.comm: MPI.Comm = mesh.comm
        self.gdim = int(mesh.geometry.dim)
        self.quadrature_degree = int(quadrature_degree)
        self.rigid_mode_rtol = float(rigid_mode_rtol)
        self._fdim = mesh.topology.dim - 1
        mesh.topology.create_connectivity(self._fdim, mesh.topology.dim)
        v = self._build_space(mu, lmbda, displacement_scale, stress_scale)

        internal = forms.residual(self.u, v, self._mu, self._lmbda, self._d, self._s, self.dx)
        F_data = self._data_terms(tractions, robin_interfaces, v)
        bcs = self._dirichlet_interface_bcs(interfaces)
        bcs += self._symmetry_bcs(symmetry)
        bcs += self._dirichlet_bcs(dirichlet)
        self._pins = None
        self.rigid_mode_reaction = None
        if remove_rigid_modes:
            pin_bcs, self._pins = self._point_constraints()
            bcs += pin_bcs
        self.bcs = bcs
        # kept Jacobian: the linearisation at rest (the same matrix whenever assembled; exact at large strain)
        # the state part is the internal force: its assembly at the solution is also the "force" output
        iterative = linear_solver_choice(solver, self.name)
        self._newton = NewtonSolver(internal, self.u, bcs, name=self.name, rtol=newton_rtol, reuse=reuse,
                                    petsc_options=petsc_options,
                                    J_reference=jacobian_at_rest(internal + F_data, self.u), F_data=F_data,
                                    linear_solver=elasticity_solver(self.V, self.name, petsc_options)
                                    if iterative else None)
        self._internal_form = self._newton.F
        self.linear_path = bool(linear_path)
        self._compiled: dict[str, object] = {}
        self.timing["setup"] = time.perf_counter() - t0

    # -- construction helpers ----------------------------------------------
    def _check_conditions(self, interfaces, robin_interfaces, symmetry, dirichlet, remove_rigid_modes) -> None:
        """Raise ValueError if interface names clash, or the displacement is held nowhere or twice over."""
        clash = set(interfaces) & set(robin_interfaces)
        if clash:
            raise ValueError(f"{self.name}: interface names used both as Dirichlet and Robin interfaces: "
                             f"{sorted(clash)}")
        if remove_rigid_modes and (interfaces or robin_interfaces or symmetry or dirichlet):
            raise ValueError(f"{self.name}: remove_rigid_modes=True is for pure traction problems; "
                             f"it cannot be combined with interfaces, symmetry or dirichlet")
        if not (remove_rigid_modes or interfaces or robin_interfaces or symmetry or dirichlet):
            raise ValueError(f"{self.name}: no displacement is prescribed anywhere; give interfaces, "
                             f"symmetry or dirichlet, or remove_rigid_modes=True for a pure traction load")

    def _constant(self, value) -> fem.Constant:
        return fem.Constant(self.mesh, PETSc.ScalarType(value))

    def _build_space(self, mu, lmbda, displacement_scale, stress_scale):
        """The P2 displacement space and unknown, the moduli and units as Constants, the measures;
        returns the test function."""
        self.V = fem.VectorFunctionSpace(self.mesh, ("Lagrange", 2))
        self.u = fem.Function(self.V, name="u_hat")
        v = ufl.TestFunction(self.V)
        self._mu, self._lmbda = self._constant(mu), self._constant(lmbda)
        self._d, self._s = self._constant(displacement_scale), self._constant(stress_scale)
        self.dx = quadrature_measure("dx", self.mesh, degree=self.quadrature_degree)
        self.ds = quadrature_measure("ds", self.mesh, self.facet_tags, degree=self.quadrature_degree)
        return v

    def _data_terms(self, tractions, robin_interfaces, v):
        """The boundary terms carrying data: Robin springs minus dead loads (0 if there are none)."""
        external = self._traction_terms(tractions, v)
        internal_robin = self._robin_terms(robin_interfaces, v)
        F_data = 0
        if internal_robin is not None:
            F_data = F_data + internal_robin
        if external is not None:
            F_data = F_data - external
            self._external_form = fem.form(external)
        else:
            self._external_form = None
        return F_data

    def _traction_terms(self, tractions, v):
        """Dead loads: int t . v dS over each entry's facets (None without tractions)."""
        self._tractions: list[tuple[list[int], object]] = []
        external = None
        for k, entry in enumerate(tractions):
            tags, value = _unpack(entry, 2, f"tractions[{k}]")
            self._facets(tags, f"tractions[{k}]")
            t = self._traction_coefficient(value, f"tractions[{k}]")
            self._tractions.append((tags, t))
            term = ufl.inner(t, v) * self.ds(tuple(tags))
            external = term if external is None else external + term
        return external

    def _robin_terms(self, robin_interfaces, v):
        """Robin interfaces: int kappa (u - u*) . v dS on each (None without any); nodal forces f* are
        loads.  Declares the interfaces."""
        self._robin: dict[str, dict] = {}
        internal_robin = None
        for iname, entry in robin_interfaces.items():
            tags, kappa = _unpack(entry, 2, f"robin_interfaces[{iname!r}]")
            tags = as_tags(tags)
            self._facets(tags, f"robin_interfaces[{iname!r}]")
            if not (np.isfinite(kappa) and kappa > 0):
                raise ValueError(f"{self.name}: robin_interfaces[{iname!r}]: kappa = {kappa!r} must be > 0")
            target = fem.Function(self.V, name=f"u_{iname}")
            term = self._constant(kappa) * ufl.inner(self.u - target, v) * self.ds(tuple(tags))
            internal_robin = term if internal_robin is None else internal_robin + term
            nodes = InterfaceNodes(self.V, self.facet_tags, tags)
            owned_rows = nodes.owned
            self._robin[iname] = {"target": target, "nodes": nodes, "loads": np.zeros((nodes.size, self.gdim)),
                                  "dofs": nodes.dofs()[owned_rows], "rows": nodes.index[owned_rows]}
            self._add_interface(iname, nodes, {"displacement": self.gdim, "force": self.gdim})
        return internal_robin

    def _dirichlet_interface_bcs(self, interfaces) -> list:
        """Dirichlet interfaces: u_hat = g (every component) on each; declares the interfaces."""
        bcs = []
        self._interface_bc_values: dict[str, fem.Function] = {}
        self._interface_bcs: dict[str, fem.DirichletBCMetaClass] = {}
        self._interface_stiffness: dict[str, np.ndarray] = {}      # interface_stiffness(), per interface
        for iname, tags in interfaces.items():
            tags = as_tags(tags)
            facets = self._facets(tags, f"interfaces[{iname!r}]")
            g = fem.Function(self.V, name=f"u_{iname}")
            bcs.append(fem.dirichletbc(g, fem.locate_dofs_topological(self.V, self._fdim, facets)))
            self._interface_bc_values[iname] = g
            self._interface_bcs[iname] = bcs[-1]
            self._add_interface(iname, InterfaceNodes(self.V, self.facet_tags, tags), {"displacement": self.gdim})
        return bcs

    def _symmetry_bcs(self, symmetry) -> list:
        """u_hat[c] = 0 on each symmetry entry's facets."""
        bcs = []
        for k, entry in enumerate(symmetry):
            tags, comp = _unpack(entry, 2, f"symmetry[{k}]")
            comp = _component(comp, f"symmetry[{k}]", self.gdim)
            facets = self._facets(tags, f"symmetry[{k}]")
            dofs = fem.locate_dofs_topological(self.V.sub(comp), self._fdim, facets)
            bcs.append(fem.dirichletbc(PETSc.ScalarType(0), dofs, self.V.sub(comp)))
        return bcs

    def _dirichlet_bcs(self, dirichlet) -> list:
        """Prescribed displacements, all components or one, with their values set."""
        bcs = []
        self._dirichlet: list[tuple[int | None, fem.Function]] = []
        for k, entry in enumerate(dirichlet):
            if len(entry) not in (2, 3):
                raise ValueError(f"dirichlet[{k}] must be (tags, value) or (tags, value, component), "
                                 f"got {entry!r}")
            tags, value = as_tags(entry[0]), entry[1]
            comp = _component(entry[2], f"dirichlet[{k}]", self.gdim) if len(entry) == 3 else None
            facets = self._facets(tags, f"dirichlet[{k}]")
            if comp is None:
                g = fem.Function(self.V)
                bcs.append(fem.dirichletbc(g, fem.locate_dofs_topological(self.V, self._fdim, facets)))
            else:
                Vc, _ = self.V.sub(comp).collapse()
                g = fem.Function(Vc)
                dofs = fem.locate_dofs_topological((self.V.sub(comp), Vc), self._fdim, facets)
                bcs.append(fem.dirichletbc(g, dofs, self.V.sub(comp)))
            self._dirichlet.append((comp, g))
            self.set_dirichlet(k, value)
        return bcs
    def _facets(self, tags: list[int], what: str) -> np.ndarray:
        """Local facets with any of ``tags``; raise if none exists on any rank."""
        facets = tagged_facets(self.facet_tags, tags)
        if self.comm.allreduce(facets.size, op=MPI.SUM) == 0:
            present = sorted(set(self.comm.allreduce(set(np.unique(self.facet_tags.values).tolist()),
                                                     op=MPI.BOR)))
            raise ValueError(f"{self.name}: {what}: no facets tagged {tags}; the mesh has tags {present}")
        return facets

    def _traction_coefficient(self, value, what: str):
        """A UFL expression stays as it is; constants and callables go into a P2 Function."""
        if isinstance(value, ufl.core.expr.Expr):
            if ufl.domain.extract_unique_domain(value) not in (None, self.mesh.ufl_domain()):
                raise ValueError(f"{self.name}: {what}: the UFL traction lives on another mesh")
            if value.ufl_shape != (self.gdim,):
                raise ValueError(f"{self.name}: {what}: traction must be a {self.gdim}-vector, "
                                 f"got shape {value.ufl_shape}")
            return value
        return set_function(fem.Function(self.V), value, f"{self.name}: {what}")

    def _point_constraints(self):
        """Pins: u = 0 at the smallest node A (in x, then y, then z), u_y (3D: and u_z) = 0 at the
        node B of largest x; in 3D u_z = 0 at the node C farthest from AB in the (x, y) projection."""
        X = self.V.tabulate_dof_coordinates()[:self.V.dofmap.index_map.size_local, :self.gdim]
        cand = [X[np.lexsort(X.T[::-1])[0]], X[np.lexsort(-X.T[::-1])[0]]] if X.shape[0] else []
        cand = [p for c in self.comm.allgather(cand) for p in c]
        XA = min(cand, key=lambda p: tuple(p))
        XB = min(cand, key=lambda p: tuple(-p))
        size = max(np.ptp([p[i] for p in cand]) for i in range(self.gdim))
        if XB[0] - XA[0] <= 1e-8 * size:
            raise ValueError(f"{self.name}: the mesh has no extent in x; cannot pin the rotation")
        held = [(XB, c) for c in range(1, self.gdim)]
        if self.gdim == 3:
            held.append((self._third_pin(X, XA, XB, size), 2))
        tol = 1e-10 * (1 + size)

        def at(P):
            return lambda x: np.all(np.abs(x[:self.gdim] - P[:, None]) < tol, axis=0)
        dofs_a = fem.locate_dofs_geometrical(self.V, at(XA))
        bcs = [fem.dirichletbc(np.zeros(self.gdim, dtype=PETSc.ScalarType), dofs_a, self.V)]
        bs = self.V.dofmap.index_map_bs
        owned = self.V.dofmap.index_map.size_local * bs
        # unrolled dofs, owned copies only (for the reaction sums): A's components, then each held one
        pins = {"A": np.asarray(XA), "held": [(np.asarray(P), c) for P, c in held],
                "a": [[d * bs + c for d in dofs_a if d * bs + c < owned] for c in range(self.gdim)], "h": []}
        for P, c in held:
            Vc, _ = self.V.sub(c).collapse()
            dofs = fem.locate_dofs_geometrical((self.V.sub(c), Vc), at(P))[0]
            bcs.append(fem.dirichletbc(PETSc.ScalarType(0), dofs, self.V.sub(c)))
            pins["h"].append([int(d) for d in dofs if d < owned])
        return bcs, pins

    def _third_pin(self, X, XA, XB, size):
        """The node C with the largest |(B - A) x (C - A)|_z (ties: the smallest in x, y, z)."""
        b = XB - XA
        score = np.abs(b[0] * (X[:, 1] - XA[1]) - b[1] * (X[:, 0] - XA[0]))
        # rounded: coordinate noise of a node shared by two ranks must not decide the choice
        key = np.round(score / (1e-9 * size**2))
        best = [(float(key[k]), tuple(-np.round(X[k] / (1e-9 * size))), X[k])
                for k in np.flatnonzero(key == key.max())] if X.shape[0] else []
        best = [e for c in self.comm.allgather(best) for e in c]
        k, _, XC = max(best, key=lambda e: e[:2])
        if k * 1e-9 <= 1e-6:
            raise ValueError(f"{self.name}: the mesh is flat in the (x, y) projection; cannot pin the "
                             f"rotation about the x axis")
        return XC

    # -- FieldSolver interface ------------------------------------------------
    def _set_input(self, interface: str, key: str, values: np.ndarray) -> None:
        if interface in self._robin:
            r = self._robin[interface]
            if key == "displacement":
                r["nodes"].to_function(values, r["target"])
                r["target"].x.scatter_forward()
            else:
                r["loads"] = values
                dofs = np.hstack([x["dofs"].ravel() for x in self._robin.values()])
                loads = np.hstack([x["loads"][x["rows"]].ravel() for x in self._robin.values()])
                self._newton.set_nodal_loads(dofs, loads)
            return
        g = self._interface_bc_values[interface]
        self.interface_nodes(interface).to_function(values, g)
        g.x.scatter_forward()

    def _solve(self) -> None:
        iterations = self._newton.solve(linear_path=self.linear_path)
        logger.debug("%s: Newton converged in %d iterations, corrections %s", self.name, iterations,
                     self._newton.history)
        if self._pins is not None:
            self._check_rigid_modes()

    def _canonical_order(self) -> CanonicalOrder:
        if not hasattr(self, "_canonical"):
            self._canonical = CanonicalOrder(self.u.function_space)
        return self._canonical

    def checkpoint_state(self) -> dict:
        """The displacement in the partition-independent order (``femtools.canonical``), and whether it is
        still the last solve's solution (the next solve's linear path starts there)."""
        return {"u": self._canonical_order().gather(self.u.x.array), "newton": self._newton.checkpoint_state()}

    def load_checkpoint_state(self, state: typing.Mapping) -> None:
        """Restore a state written by :meth:`checkpoint_state` (any partition)."""
        self.u.x.array[:] = self._canonical_order().scatter(state["u"])
        self._newton.load_checkpoint_state(state.get("newton", {}))

    def interface_data(self, name: str) -> dict[str, np.ndarray]:
        """``{"force": (N, gdim), "displacement": (N, gdim)}``: nodal forces on the cell (units s * L0, see the
        class docstring) and the nodal displacement there (units of d)."""
        nodes = self.interface_nodes(name)
        return {"force": nodes.from_array(self._newton.state_residual().array),
                "displacement": nodes.from_function(self.u)}

    def interface_stiffness(self, name: str) -> np.ndarray:
        """The cell's Steklov-Poincare operator on Dirichlet interface ``name``, linearised at rest.

        K (gdim N, gdim N), rows and columns ``gdim i + c`` (node i of ``interface_points(name)``,
        component c): the nodal forces on the cell (``interface_data(name)["force"]``)
        that hold a nodal displacement u of the interface, the rest of the cell free
        (its other conditions kept), F = K u, units of s L0 (3D: s L0^2) per unit of d.  The Schur
        complement K_GG - K_GI K_II^-1 K_IG of the Jacobian at rest onto the
        interface dofs; symmetric, positive semi-definite.  Rows and columns of dofs
        another condition fixes (a symmetry line through the interface) are zero.
        Computed once per interface (the operator at rest does not change) and
        returned as a copy.
        """
        if name not in self._interface_bcs:
            raise KeyError(f"{self.name}: {name!r} is not a Dirichlet interface; they are "
                           f"{sorted(self._interface_bcs)}")
        if name not in self._interface_stiffness:
            self._interface_stiffness[name] = self._condensed_stiffness(name)
        return self._interface_stiffness[name].copy()

    def _condensed_stiffness(self, name: str) -> np.ndarray:
        others = [bc for bc in self.bcs if bc is not self._interface_bcs[name]]
        A = fem_petsc.assemble_matrix(self._newton.J_reference, bcs=others)
        A.assemble()
        dofs = self.interface_nodes(name).global_dofs(self.V, bcs=others).ravel()
        on = dofs >= 0
        out = np.zeros((dofs.size, dofs.size))
        # distributed: the cell's matrix stays on the ranks that own its rows
        out[np.ix_(on, on)] = condensed_matrix(A, dofs[on], f"{self.name} interface stiffness")
        A.destroy()
        return 0.5 * (out + out.T)

    def interface_jacobian(self) -> dict[tuple[tuple[str, str], tuple[str, str]], np.ndarray]:
        """d(outputs)/d(inputs) on the Dirichlet interfaces, linearised at rest.

        ``{((name, "force"), (name, "displacement")): K, ((name, "displacement"),
        (name, "displacement")): D}`` per interface, rows and columns ``gdim i + c``
        as in :meth:`interface_stiffness` (K); D is the identity but on the
        components another condition fixes (there the displacement stays 0).
        K's rows of those components are zero: the force there is that
        condition's reaction, which does not depend on the interface data
        through the cell alone (a neighbour that holds the same condition,
        as the gel on a symmetry line, ignores it).
        Interfaces do not affect each other (each belongs to its own body, or the
        blocks between them are left out).
        """
        out = {}
        for name in self._interface_bcs:
            others = [bc for bc in self.bcs if bc is not self._interface_bcs[name]]
            free = (self.interface_nodes(name).global_dofs(self.V, bcs=others).ravel() >= 0).astype(float)
            out[((name, "force"), (name, "displacement"))] = self.interface_stiffness(name)
            out[((name, "displacement"), (name, "displacement"))] = np.diag(free)
        return out

    # -- load updates (tests, load stepping) ------------------------------------
    def set_dirichlet(self, index: int, value) -> None:
        """Change the value of ``dirichlet[index]`` (constant or callable, units of d)."""
        _, g = self._dirichlet[index]
        set_function(g, value, f"{self.name}: dirichlet[{index}]")

    def set_traction(self, index: int, value) -> None:
        """Change ``tractions[index]`` (constant or callable, units of s; not for UFL tractions)."""
        _, t = self._tractions[index]
        if not isinstance(t, fem.Function):
            raise TypeError(f"{self.name}: tractions[{index}] is a UFL expression; change its "
                            f"Constants instead")
        set_function(t, value, f"{self.name}: tractions[{index}]")

    # -- rigid modes -------------------------------------------------------------
    def _check_rigid_modes(self) -> None:
        """Measure what the pins carry; raise if the load was not self-equilibrated."""
        f = assemble_residual_vector(self._external_form) if self._external_form else None
        r = self._newton.state_residual().array.copy()      # F_int - F_ext, no bcs: pin reactions
        if f is not None:
            r -= f.array
        p = self._pins
        loc = np.array([r[d].sum() for d in p["a"]] + [r[d].sum() for d in p["h"]]
                       + [np.abs(f.array).sum() if f is not None else 0.0])
        if f is not None:
            f.destroy()
        total = self.comm.allreduce(loc, op=MPI.SUM)
        force, held, load = total[:self.gdim].copy(), total[self.gdim:-1], total[-1]
        moment = 0.0 if self.gdim == 2 else np.zeros(3)
        for (P, c), value in zip(p["held"], held):
            force[c] += value
            moment = moment + np.cross(P - p["A"], value * np.eye(self.gdim)[c])
        # the pins that hold rotations carry nothing iff the moment vanishes (statically determinate)
        relative = np.hypot(functools.reduce(np.hypot, force), functools.reduce(np.hypot, held))
        self.rigid_mode_reaction = {"force": force, "moment": moment,
                                    "relative": float(relative / load) if load > 0 else 0.0}
        if self.rigid_mode_reaction["relative"] > self.rigid_mode_rtol:
            raise RuntimeError(
                f"{self.name}: the point constraints that remove the rigid modes carry "
                f"{self.rigid_mode_reaction['relative']:.2e} of the applied load (tolerance "
                f"{self.rigid_mode_rtol:.1e}): the traction load is not self-equilibrated "
                f"(resultant force {-force}, moment about A {-np.asarray(moment)}, units of s L0"
                f"{'^2' if self.gdim == 3 else ''})")

    # -- accessors ---------------------------------------------------------------
    @property
    def displacement(self) -> fem.Function:
        """The P2 displacement unknown u_hat (units of d: u_c = d u_hat).

        It is also the initial guess of the next ``solve()`` (set it to start
        Newton elsewhere); its Dirichlet values are overwritten by the solve.
        """
        return self.u

    @property
    def stress_scale(self) -> float:
        return float(self._s.value)

    @property
    def displacement_scale(self) -> float:
        return float(self._d.value)

    @property
    def stats(self) -> dict:
        """Newton/linear-solver counters (factorisations, solves, times)."""
        return self._newton.stats

    @property
    def newton_history(self) -> list[float]:
        """Relative corrections |du|/|u| of the last solve."""
        return list(self._newton.history)

    def cauchy_stress_expression(self):
        """UFL Cauchy stress sigma_c in units of mu_s (= s sigma_hat); 2D: the in-plane 2x2 block."""
        return self._s * forms.cauchy_stress(self.u, self._mu, self._lmbda, self._d, self._s)

    def green_lagrange_expression(self):
        """UFL Green-Lagrange strain E = (F^T F - I)/2 (dimensionless); 2D: the in-plane 2x2 block."""
        return forms.green_lagrange(self.u, self._d)

    def von_mises_expressions(self):
        """UFL ``(stress, strain)`` von Mises measures of sigma_c (units of mu_s) and of the
        Green-Lagrange strain E (``femtools.functions.von_mises``).

        2D, the paper's formula (model.md section 2); the out-of-plane components
        (sigma_zz, E_zz = 0) are not included:

            sigma_v = sqrt(sxx^2 + syy^2 - sxx syy + 3 sxy^2)

        3D, the full formula (model.md section 10):

            sigma_v = sqrt(((sxx - syy)^2 + (syy - szz)^2 + (szz - sxx)^2)/2 + 3 (sxy^2 + syz^2 + szx^2))

        and the same of E for the strain.
        """
        return von_mises(self.cauchy_stress_expression()), von_mises(self.green_lagrange_expression())

    def _dg(self, expr, degree: int, name: str) -> fem.Function:
        shape = expr.ufl_shape
        if shape == ():
            W = fem.FunctionSpace(self.mesh, ("DG", degree))
        else:
            W = fem.TensorFunctionSpace(self.mesh, ("DG", degree), shape=shape)
        f = fem.Function(W, name=name)
        f.interpolate(fem.Expression(expr, W.element.interpolation_points()))
        f.x.scatter_forward()
        return f

    def cauchy_stress(self, degree: int = 1) -> fem.Function:
        """Cauchy stress (units of mu_s) interpolated cell-wise into DG ``degree`` (for output)."""
        return self._dg(self.cauchy_stress_expression(), degree, "sigma_c")

    def green_lagrange_strain(self, degree: int = 1) -> fem.Function:
        """Green-Lagrange strain interpolated cell-wise into DG ``degree`` (for output)."""
        return self._dg(self.green_lagrange_expression(), degree, "E_c")

    def von_mises_stress(self, degree: int = 1) -> fem.Function:
        return self._dg(self.von_mises_expressions()[0], degree, "von_mises_stress")

    def von_mises_strain(self, degree: int = 1) -> fem.Function:
        return self._dg(self.von_mises_expressions()[1], degree, "von_mises_strain")

    def von_mises_range(self) -> dict[str, tuple[float, float]]:
        """``{"stress": (min, max), "strain": (min, max)}`` over the cell.

        Evaluated cell by cell (each cell's own one-sided values) at the
        P2 nodes (vertices and edge midpoints) and at the quadrature points
        of degree ``quadrature_degree``, on owned cells only, then reduced
        over the ranks: the set of points does not depend on the partition.
        Stress in units of mu_s, strain dimensionless.
        """
        if "vm" not in self._compiled:
            cell = basix.CellType.triangle if self.mesh.topology.dim == 2 else basix.CellType.tetrahedron
            lattice = basix.create_lattice(cell, 2, basix.LatticeType.equispaced, True)
            quad, _ = basix.make_quadrature(cell, self.quadrature_degree)
            self._compiled["vm"] = fem.Expression(ufl.as_vector(self.von_mises_expressions()),
                                                  np.vstack([lattice, quad]))
        expr = self._compiled["vm"]
        cells = np.arange(self.mesh.topology.index_map(self.mesh.topology.dim).size_local,
                          dtype=np.int32)
        values = expr.eval(cells).reshape(cells.size, -1, 2)
        if values.size and not np.all(np.isfinite(values)):
            raise FloatingPointError(f"{self.name}: von Mises measure contains NaN or Inf")
        lo = values.min(axis=(0, 1)) if values.size else np.full(2, np.inf)
        hi = values.max(axis=(0, 1)) if values.size else np.full(2, -np.inf)
        self.comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)     # numpy buffers: upper-case
        self.comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
        return {"stress": (float(lo[0]), float(hi[0])), "strain": (float(lo[1]), float(hi[1]))}

    def centroid_displacement(self) -> np.ndarray:
        """Area- (3D: volume-) weighted mean of u_c over the reference cell, (gdim,), units of L0
        (= d * mean u_hat)."""
        if "centroid" not in self._compiled:
            one = fem.Constant(self.mesh, PETSc.ScalarType(1.0))
            self._compiled["centroid"] = [fem.form(self.u[i] * self.dx) for i in range(self.gdim)] + \
                [fem.form(one * self.dx)]
        vals = np.array([fem.assemble_scalar(f) for f in self._compiled["centroid"]])
        vals = self.comm.allreduce(vals, op=MPI.SUM) if self.comm.size > 1 else vals
        return self.displacement_scale * vals[:-1] / vals[-1]

    def max_displacement(self) -> float:
        """max |u_c| over the P2 nodes, units of L0."""
        n = self.V.dofmap.index_map.size_local
        local = np.linalg.norm(self.u.x.array.reshape(-1, self.gdim)[:n], axis=1)
        m = self.comm.allreduce(float(local.max(initial=0.0)), op=MPI.MAX)
        return self.displacement_scale * m

    def boundary_force(self, tags: Tags) -> np.ndarray:
        """Net force on the cell through the facets ``tags``: sum of the nodal forces, (gdim,), units s L0
        (3D: s L0^2).

        The nodal forces are those of the ``"force"`` output (internal
        forces, no loads, no boundary conditions) at every node of those
        facets; nodes shared with other boundaries count fully.
        """
        tags = as_tags(tags)
        facets = self._facets(tags, "boundary_force")
        blocks = fem.locate_dofs_topological(self.V, self._fdim, facets)
        blocks = blocks[blocks < self.V.dofmap.index_map.size_local]
        local = self._newton.state_residual().array.reshape(-1, self.gdim)[blocks].sum(axis=0)
        return self.comm.allreduce(local, op=MPI.SUM) if self.comm.size > 1 else local


def _unpack(entry, n: int, what: str):
    if len(entry) != n:
        raise ValueError(f"{what} must be a tuple of {n} items (tags, value), got {entry!r}")
    return as_tags(entry[0]), entry[1]


def _component(comp, what: str, gdim: int) -> int:
    if comp not in range(gdim):
        names = "0 (x) or 1 (y)" if gdim == 2 else "0 (x), 1 (y) or 2 (z)"
        raise ValueError(f"{what}: component must be {names}, got {comp!r}")
    return int(comp)


def _validate_parameters(mu, lmbda, s, d, qdeg, rtol, reuse, rigid_rtol) -> None:
    """Raise ValueError naming the first parameter outside its range."""
    for key, value in dict(mu=mu, lmbda=lmbda, stress_scale=s, displacement_scale=d).items():
        if not isinstance(value, (int, float, np.floating, np.integer)) or not np.isfinite(value):
            raise ValueError(f"{key} must be a finite number, got {value!r}")
    if not mu > 0:
        raise ValueError(f"mu must be > 0 (shear modulus), got {mu}")
    if not lmbda > -2.0 * mu / 3.0:
        nu = lmbda / (2 * (lmbda + mu)) if lmbda + mu != 0 else float("inf")
        raise ValueError(f"Poisson ratio nu = lmbda/(2 (lmbda + mu)) = {nu:.4g} (lmbda={lmbda}, mu={mu}) "
                         f"must lie in (-1, 0.5), i.e. lmbda > -2 mu / 3")
    for key, value in dict(stress_scale=s, displacement_scale=d).items():
        if not value > 0:
            raise ValueError(f"{key} must be > 0, got {value}")
    if int(qdeg) != qdeg or qdeg < 1:
        raise ValueError(f"quadrature_degree must be a positive integer, got {qdeg!r}")
    if not (np.isfinite(rtol) and 0 < rtol < 1):
        raise ValueError(f"newton_rtol must lie in (0, 1), got {rtol!r}")
    if reuse not in ("adaptive", "never"):
        raise ValueError(f"reuse must be 'adaptive' or 'never', got {reuse!r}")
    if not (np.isfinite(rigid_rtol) and rigid_rtol > 0):
        raise ValueError(f"rigid_mode_rtol must be > 0, got {rigid_rtol!r}")
