"""Stokes flow on a moving domain, solved on the current configuration (ALE pull-back).

The fluid's current domain is the image of its reference mesh under
x = X + u_m(X), u_m = d u_hat_m the mesh displacement (``femtools.meshmotion``:
the harmonic extension of the gel's interface displacement).  Stokes is
posed on the current domain and pulled back to the reference mesh with
F_m = I + grad_X u_m, J_m = det F_m (``femtools.continuum``):

    int_t 2 mu D_x(V):D_x(v) - P div_x v - q div_x V dv
      = int_0 2 mu sym(grad V adj F_m) : sym(grad v adj F_m) / J_m
              - P grad v : cof F_m - q grad V : cof F_m dX

since grad_x a = grad_X a adj F_m / J_m and dv = J_m dX.  For a P2 mesh
displacement on the isoparametric P2 mesh this is not an approximation: the
moved mesh's element maps are X(xi) + u_m(X(xi)), its basis functions are the
reference ones composed with the inverse map, and with the same quadrature
rule the form assembled on the moved mesh equals this pull-back to round-off
(tests/test_moving_fluid.py checks it).  The mesh never moves in memory, the
reference mesh keeps its factorised operator at rest (the Jacobian of the
pull-back at u_m = 0 is the Stokes operator), and the monolithic reference,
whose single mesh cannot move the fluid without moving the gel, assembles the
same form.

Interfaces (Robin parts, on the current interface with its normal n and
length (2D) or area (3D) ratio j = da/dA, Nanson's formula):

    int j [alpha_n (V.n)(v.n) + alpha_t V_t.v_t] dA - int (g_N.n)(v.n) dA - int j g_T,t . v_t dA
        - alpha_n <f, v>

* ``robin_normal`` g_N is a NOMINAL traction (force per unit reference length
  or area), like the traction this solver returns;
* ``robin_tangential`` g_T is a velocity-type datum (e.g. alpha_t v_f),
  weighted by the current length or area;
* ``normal_flux`` f (nodal, units V0 L0): the consistent nodal vector
  int j q_n (psi_i n) dA of a normal flux q_n (the gel's
  ``gel.lagrangian.normal_flux_load``); it makes the normal condition
  alpha_n (V.n - q_n) = (g_N - t).n hold in the same weak form as the
  monolithic reference's I13;
* ``displacement`` (N, gdim): the interface's displacement (units of d L0), the
  data of the mesh motion.

Every array has gdim = 2 or 3 components: the same code runs on triangles and
tetrahedra (``femtools.continuum`` gives J, cof F and Nanson's formula in both).

``traction`` (output) is the consistent reaction of the pulled-back bulk
form recovered with the reference interface mass matrix: the NOMINAL
traction on the fluid (its force per unit reference length or area of the interface).

The field problem is linear in (V, P) for a given mesh; it is solved by
``femtools.linalg.NewtonSolver`` with the operator at rest as the kept
Jacobian: at small displacements every solve costs back-substitutions only;
at large ones the exact operator of the current mesh takes over.
"""

from __future__ import annotations

import typing

import numpy as np
import scipy.sparse

import ufl
from dolfinx import fem

from femtools.continuum import adjugate, cofactor, kinematics, surface_stretch
from femtools.linalg import NewtonSolver, jacobian_at_rest
from femtools.meshmotion import MeshMotion
from femtools.canonical import CanonicalOrder, MixedCanonical
from fluid.solver import StokesSolver

__all__ = ["ale_bulk_residual", "ale_robin_residual", "MovingStokesSolver"]


def ale_bulk_residual(V, P, v, q, viscosity, u_m, d, dx, body_force=None):
    """The Stokes residual of the current domain pulled back to the reference one (module docstring).

    ``body_force`` is a load per unit CURRENT volume as a function of X (it is multiplied by J_m).
    """
    _, _, J = kinematics(u_m, d)
    adj, cof = adjugate(u_m, d), cofactor(u_m, d)
    DV, Dv = ufl.sym(ufl.grad(V) * adj), ufl.sym(ufl.grad(v) * adj)
    r = (2 * viscosity * ufl.inner(DV, Dv) / J - P * ufl.inner(ufl.grad(v), cof)
         - q * ufl.inner(ufl.grad(V), cof)) * dx
    if body_force is not None:
        r -= J * ufl.inner(body_force, v) * dx
    return r


def ale_robin_residual(V, v, u_m, d, N, alpha_n, alpha_t, g_normal, g_tangential, ds):
    """Robin terms on the current interface (module docstring); ``N`` the reference outward normal."""
    j, n = surface_stretch(u_m, d, N)
    Vn, vn = ufl.dot(V, n), ufl.dot(v, n)
    Vt, vt = V - Vn * n, v - vn * n
    return (j * (alpha_n * Vn * vn + alpha_t * ufl.dot(Vt, vt) - ufl.dot(g_tangential, vt))
            - ufl.dot(g_normal, n) * vn) * ds


class _NewtonAsLinear:
    """A NewtonSolver behind the ``solve``/``update_operator``/``stats`` of a LinearSolver."""

    def __init__(self, newton: NewtonSolver, linear_path: bool = False):
        self.newton, self.linear_path = newton, linear_path

    def solve(self):
        return self.newton.solve(linear_path=self.linear_path)

    def update_operator(self) -> None:
        self.newton.invalidate_jacobian()

    @property
    def stats(self):
        return self.newton.stats


class MovingStokesSolver(StokesSolver):
    """Stokes on a domain that follows its interfaces' displacement (see the module docstring).

    Takes every argument of :class:`fluid.StokesSolver`, plus:

    Args:
        displacement_scale: the unit d (in units of L0) of the displacement data.
        mesh_boundaries: ``{name: tags}``: further boundaries whose mesh
            displacement is prescribed (``set_boundary_displacement``), e.g.
            the walls of a test channel; every interface is a moving boundary.
        newton_rtol: relative tolerance of the (V, P) correction.
        linear_path: each ``solve()`` that continues from the previous
            solution takes one step with the kept linearisation at rest, the
            mesh position and interface data being data of the step
            (``femtools.linalg.NewtonSolver``, ``data_coefficients``); for a
            coupling loop whose solves continue from each other (a steady
            partitioned run) the remainder converges with the coupling.
            Default: the exact path.

    Mesh motion (``femtools.meshmotion.MeshMotion``, with the same ``petsc_options``): data on the interfaces
    and ``mesh_boundaries``, sliding on the ``component_bcs`` boundaries
    (symmetry lines or planes: the component they fix is held), held on every other
    boundary.
    """

    def __init__(self, mesh, facet_tags, *, displacement_scale: float = 1.0,
                 mesh_boundaries: typing.Mapping[str, typing.Any] | None = None,
                 newton_rtol: float = 1e-12, linear_path: bool = False, **kwargs):
        d = float(displacement_scale)
        if not (np.isfinite(d) and d > 0):
            raise ValueError(f"displacement_scale must be finite and > 0, got {displacement_scale!r}")
        self._d = fem.Constant(mesh, d)
        self._newton_rtol = float(newton_rtol)
        self._linear_path = bool(linear_path)
        interfaces = dict(kwargs.get("interfaces") or {})
        moving = {name: spec.tags for name, spec in interfaces.items()}
        moving.update(dict(mesh_boundaries or {}))
        sliding = [(tags, int(c)) for tags, c, _ in kwargs.get("component_bcs", ())]
        self.mesh_space = fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
        self.motion = MeshMotion(self.mesh_space, facet_tags, moving, sliding,
                                 name=f"{kwargs.get('name', 'fluid')}_mesh_motion",
                                 quadrature_degree=kwargs.get("quadrature_degree", 4),
                                 petsc_options=kwargs.get("petsc_options"),
                                 solver=kwargs.get("solver", "direct"))
        self.mesh_displacement = self.motion.displacement
        self._mesh_boundaries = set(mesh_boundaries or {})
        self._flux = {}
        super().__init__(mesh, facet_tags, **kwargs)
        n_owned = self.W.dofmap.index_map.size_local * self.W.dofmap.index_map_bs
        for name, it in self._ifaces.items():
            self._inputs[name]["displacement"] = self.gdim
            if it.spec.normal == "robin":
                self._inputs[name]["normal_flux"] = self.gdim
                dofs = it.nodes.dofs(parent=True)
                keep = np.all(dofs < n_owned, axis=1)
                self._flux[name] = {"dofs": dofs[keep], "rows": it.nodes.index[keep],
                                    "values": np.zeros((it.nodes.size, self.gdim))}

    @property
    def linear_path(self) -> bool:
        """Whether a solve that continues from the previous solution takes one kept-Jacobian step."""
        return self._linear_path

    @linear_path.setter
    def linear_path(self, value: bool) -> None:
        self._linear_path = bool(value)
        self._solver.linear_path = self._linear_path

    # -- hooks of StokesSolver --------------------------------------------------
    def _bulk_residual(self, u, p, v, q, dx=None):
        return ale_bulk_residual(u, p, v, q, self.mu, self.mesh_displacement, self._d, dx or self.dx,
                                 self.body_force)

    def _robin_residual(self, u, v, n, alpha_n, alpha_t, g_normal, g_tangential, ds):
        return ale_robin_residual(u, v, self.mesh_displacement, self._d, n, alpha_n, alpha_t, g_normal,
                                  g_tangential, ds)

    def _build_solver(self, F, trial, v, bcs, petsc_options):
        F = ufl.replace(F, {trial: self.w})
        J_reference = jacobian_at_rest(F, self.w, [self.mesh_displacement])
        # every coefficient but the unknowns is data: the mesh position and the interface data
        self.newton = NewtonSolver(F, self.w, bcs, name=self.name, rtol=self._newton_rtol, reuse="adaptive",
                                   petsc_options=petsc_options, J_reference=J_reference,
                                   data_coefficients=[c for c in F.coefficients() if c is not self.w],
                                   linear_solver=self._krylov_solver(J_reference, bcs, petsc_options))
        return _NewtonAsLinear(self.newton, self._linear_path)

    # -- linearised interface map ----------------------------------------------------
    def interface_jacobian(self) -> dict[tuple[tuple[str, str], tuple[str, str]], np.ndarray]:
        """The derivative of the interface outputs with respect to the inputs, linearised at rest.

        As :meth:`fluid.StokesSolver.interface_jacobian` (same keys, shapes and row/column
        order), on the reference (undeformed) configuration with zero mesh displacement:
        the operator is the Jacobian at rest (``newton.J_reference``), whatever the current
        mesh position.  Inputs: ``"robin_normal"``, ``"robin_tangential"`` and
        ``"normal_flux"`` (nodal loads alpha_n f on the interface velocity rows).  The
        ``"displacement"`` input (the mesh motion) is left out: its effect is geometric,
        of the size of the strain times the state, not part of this map.  At zero
        displacement the solver is linear in the other inputs, so
        ``out(data + delta) - out(data) = J delta`` to the Newton tolerance (round-off).
        """
        return super().interface_jacobian()

    def _jacobian_operator_form(self):
        return self.newton.J_reference

    def _jacobian_input_keys(self, it) -> list[str]:
        keys = super()._jacobian_input_keys(it)
        return keys + (["normal_flux"] if "normal_flux" in self._inputs[it.name] else [])

    def _jacobian_input(self, it, key, data, rows):
        if key != "normal_flux":
            return super()._jacobian_input(it, key, data, rows)
        # the nodal loads alpha_n f, subtracted from the residual: + alpha_n f on the right-hand side
        on = np.flatnonzero(rows >= 0)
        return scipy.sparse.csr_matrix((np.full(on.size, float(it.alpha_n.value)), (rows[on], on)),
                                       shape=(data["rows"].size, rows.size))

    # -- data ---------------------------------------------------------------------
    def _set_input(self, interface: str, key: str, values: np.ndarray) -> None:
        if key == "displacement":
            self.motion.set_displacement(interface, values)
        elif key == "normal_flux":
            self._flux[interface]["values"] = np.array(values, dtype=float)
        else:
            super()._set_input(interface, key, values)

    def set_boundary_displacement(self, name: str, value) -> None:
        """Mesh displacement of ``mesh_boundaries[name]``: (N, gdim) nodal values or a callable ``x -> (gdim, n)``."""
        if name not in self._mesh_boundaries:
            raise KeyError(f"{self.name}: no mesh boundary {name!r}; it has {sorted(self._mesh_boundaries)}")
        if callable(value):
            g = fem.Function(self.mesh_space)
            g.interpolate(value)
            value = self.motion.nodes[name].from_function(g)
        self.motion.set_displacement(name, value)

    def _solve(self) -> None:
        self.motion.solve()
        dofs = [f["dofs"].ravel() for f in self._flux.values()]
        vals = [float(self._ifaces[k].alpha_n.value) * f["values"][f["rows"]].ravel() for k, f in self._flux.items()]
        # a corner node shared by two interfaces takes both loads (set_nodal_loads sums repeated dofs)
        self.newton.set_nodal_loads(np.hstack(dofs).astype(np.int32) if dofs else np.empty(0, np.int32),
                                    np.hstack(vals) if vals else np.empty(0))
        super()._solve()

    # -- state (time windows, checkpoints) ------------------------------------------
    def get_state(self) -> dict[str, np.ndarray]:
        """The unknowns (Newton's initial guess) and the mesh position, this rank's arrays."""
        return {"state": self.w.x.array.copy(), "mesh": self.mesh_displacement.x.array.copy()}

    def set_state(self, state) -> None:
        self.w.x.array[:] = state["state"]
        self.mesh_displacement.x.array[:] = state["mesh"]

    def _orders(self):
        if not hasattr(self, "_canonical"):
            self._canonical = (MixedCanonical(self.W, ("V", "P")), CanonicalOrder(self.mesh_space))
        return self._canonical

    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """The state in the partition-independent order (``femtools.canonical``)."""
        mixed, order = self._orders()
        state = {f"state_{k}": v for k, v in mixed.gather(self.w.x.array).items()}
        state["mesh"] = order.gather(self.mesh_displacement.x.array)
        state["newton"] = self.newton.checkpoint_state()        # the linear path's starting point
        return state

    def load_checkpoint_state(self, state) -> None:
        mixed, order = self._orders()
        mixed.scatter({k: state[f"state_{k}"] for k in ("V", "P")}, self.w.x.array)
        self.mesh_displacement.x.array[:] = order.scatter(state["mesh"])
        self.newton.load_checkpoint_state(state.get("newton", {}))

    @property
    def stats(self) -> dict:
        out = super().stats
        out["mesh_motion"] = dict(self.motion.stats)
        return out
