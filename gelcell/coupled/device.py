"""One device case as three coupled field solvers: meshes, solvers, participants, data and the solve.

:class:`Device` is the only class that knows both the field solvers and the
coupling library.  It builds the meshes, the three solvers with the case's
boundary conditions, wraps each as a coupling participant
(:mod:`gelcell.coupled.participants`), declares the data they exchange
(:mod:`gelcell.coupled.data`) and runs the partitioned coupling with the
device's defaults (:mod:`gelcell.coupled.defaults`); a steady run's
linearized prior is kept on disk (:mod:`gelcell.coupled.priorcache`).
"""

from __future__ import annotations

import time
import typing

import numpy as np

from mpi4py import MPI

import coupling as cp
from cell import NeoHookeanCellSolver
from fluid import FluidInterface, StokesSolver
from fluid.ale import MovingStokesSolver
from gel import GelParameters, PoroelasticGelSolver
from gelcell.case import DEFAULT_GAMMA2, GAMMA2, CaseParameters
from gelcell.coupled import priorcache
from gelcell.coupled.data import coupling_data, extensive_data
from gelcell.coupled import solverchoice
from gelcell.coupled.defaults import (AUTO_PRIOR_MAX_UNKNOWNS, TRANSIENT_PRIOR, coupling_config,
                                      default_gamma2_coefficient, default_robin_coefficient,
                                      device_distribution)
from gelcell.coupled.participants import CellParticipant, FluidParticipant, GelParticipant, MovingFluidParticipant
from gelcell.geometry import described
from gelcell.geometry.meshes import build_meshes

__all__ = ["Device"]

#: the gel's and the cell's Newton tolerance in a device (tighter than the solvers' own default)
NEWTON_RTOL = 1e-12


class Device:
    """A device case: meshes, the three field solvers and their coupling.

    Args:
        params: the case (geometry, parameters, mesh sizes).
        comm: MPI communicator.
        robin_coefficient: alpha_n in the solvers' stress unit per unit
            velocity; default :func:`default_robin_coefficient`.
        gamma2: the split on Gamma2 (``"schur"``, ``"dirichlet"`` or ``"robin"``).
        transient: build the time-dependent gel (see the module docstring);
            ``time_scheme`` ``"be"`` or ``"bdf2"``, ``inflow`` the waveform
            f(t) that multiplies the inflow (None: 1).
        solver: the fields' linear solves, ``"direct"``, ``"iterative"`` or
            ``"auto"`` (:mod:`gelcell.coupled.solverchoice`; what each field
            got: :attr:`solver_kinds`); ``petsc_options``: ``{field: {option:
            value}}``, PETSc options of one field's solver.
        distribute: participants in separate process groups of ``comm``
            (``[coupling] distribute``, e.g. ``"fluid:1,gel+cell:1"``;
            :mod:`coupling.distributed`): each group meshes every region on
            its own communicator (the simpler choice: meshing is cheap next
            to the solves) and builds only its fields' solvers; the others
            are ``None`` on its ranks.  ``None`` or ``""``: every field on
            every rank.
    """

    def __init__(self, params: CaseParameters, comm: MPI.Comm = MPI.COMM_WORLD,
                 robin_coefficient: float | None = None, gamma2: str = DEFAULT_GAMMA2,
                 transient: bool = False, time_scheme: str = "be",
                 inflow: typing.Callable[[float], float] | None = None, solver: str = "direct",
                 petsc_options: typing.Mapping[str, typing.Mapping] | None = None,
                 distribute: str | None = None):
        t0 = time.perf_counter()
        params = described(params)
        params.validate()
        self.params, self.comm = params, comm
        self.transient = bool(transient)
        self.kinematics = params.kinematics
        self._set_coefficients(robin_coefficient, gamma2)
        #: the process groups of the participants (None: every field on every rank)
        self.distribution = device_distribution(distribute, params, comm)
        self.group_comm = comm if self.distribution is None else self.distribution.group_comm
        self.meshes = build_meshes(params, self.group_comm)
        self.layout = self.meshes.layout
        self.boundaries = self.layout.boundaries
        self.mesh_time = time.perf_counter() - t0
        t0 = time.perf_counter()
        self.solver = solver
        self.solver_kinds = self._choose_solvers(solver)
        user = dict(petsc_options or {})
        # time-dependent runs keep PETSc's automatic choices (STEADY_SOLVER_OPTIONS: steady direct solves)
        options = {f: solverchoice.field_options(k, self.transient, user.get(f)) for f, k in self.solver_kinds.items()}
        self.fluid = self._fluid_solver(options["fluid"]) if self.is_local("fluid") else None
        self.gel = self._gel_solver(options["gel"]) if self.is_local("gel") else None
        self.cell = self._cell_solver(options["cell"]) if params.with_cell and self.is_local("cell") else None
        self.setup_time = time.perf_counter() - t0
        self.participants = self._participants(time_scheme, inflow)
        dim = self.meshes.region("fluid")[0].geometry.dim
        self.data = coupling_data(self.boundaries, gamma2, self.kinematics, dim=dim)
        self.scheme: cp.CouplingScheme | None = None
        self.result: cp.CouplingResult | None = None
        #: where the last solve's prior came from: "computed", "disk cache", "reused" (its linearized
        #: prior), "surrogate" (another model's, :meth:`coarse_surrogate`) or None
        self.prior_source: str | None = None
        #: why the default went without its linearized prior (None: it did not)
        self.prior_declined: str | None = None

    @property
    def distribute(self) -> str | None:
        """The spec of the process groups (``distribute``), None if every field runs on every rank."""
        return None if self.distribution is None else self.distribution.spec

    def is_local(self, field: str) -> bool:
        """Whether ``field``'s solver runs on this rank (always, unless the device is distributed)."""
        return self.distribution is None or self.distribution.is_local(field)

    def _from_field(self, field: str, compute: typing.Callable[[], typing.Any]) -> typing.Any:
        """``compute()`` on the ranks of ``field``'s solver, its result on every rank."""
        return compute() if self.distribution is None else self.distribution.from_owner(field, compute)

    def _set_coefficients(self, robin_coefficient: float | None, gamma2: str) -> None:
        """The Robin coefficients on Gamma1/3 (alpha_n, alpha_t) and the split on Gamma2 with its kappa."""
        params = self.params
        self.alpha_n = default_robin_coefficient(params) if robin_coefficient is None else robin_coefficient
        self.alpha_t = params.physics.ca / params.stress_scale / params.physics.beta
        if not self.alpha_n > 0:
            raise ValueError(f"robin_coefficient = {self.alpha_n} must be > 0")
        if gamma2 not in GAMMA2:
            raise ValueError(f"gamma2 = {gamma2!r}: the split on Gamma2 must be one of {', '.join(GAMMA2)}")
        self.gamma2 = gamma2
        self.kappa = default_gamma2_coefficient(params)

    def _choose_solvers(self, solver: str) -> dict[str, str]:
        """``{field: "direct" | "iterative"}`` of the fields this device has, under ``solver``."""
        if solver not in solverchoice.KINDS:
            raise ValueError(f"solver = {solver!r} must be one of {', '.join(solverchoice.KINDS)}")
        fields = [f for f in solverchoice.FIELDS if f != "cell" or self.params.with_cell]
        return {f: solverchoice.choose(solver, self.meshes.region(f)[0], f) for f in fields}

    def krylov_iterations(self) -> dict[str, dict]:
        """Per field solved iteratively: its linear ``solves``, their Krylov ``iterations`` and the ``mean``."""
        def counts(stats) -> dict:
            solves, its = int(stats["solves"]), int(stats["krylov_iterations"])
            return {"solves": solves, "iterations": its, "mean": its / solves if solves else 0.0}

        def of_fluid() -> dict:
            stats = self.fluid.stats
            out = {"fluid": counts(stats["stokes"])}
            if "mesh_motion" in stats:
                out["mesh_motion"] = counts(stats["mesh_motion"])
            return out

        sources = {"fluid": of_fluid, "gel": lambda: {"gel": counts(self.gel.newton.stats)},
                   "cell": lambda: {"cell": counts(self.cell.stats)}}
        out = {}
        for field, kind in self.solver_kinds.items():
            if kind == "iterative" and field in sources:
                out.update(self._from_field(field, sources[field]))
        return out

    def _fluid_solver(self, options: dict | None) -> StokesSolver:
        """Stokes on the fluid mesh, Robin conditions on each fluid-gel interface."""
        b, params = self.boundaries, self.params
        mesh, tags = self.meshes.region("fluid")
        # the moving fluid's linear path in steady runs only: a time-dependent iteration restarts
        # from the window's checkpoint, and a resumed run must repeat the uninterrupted one
        fluid_class, extra = ((MovingStokesSolver, {"displacement_scale": params.displacement_scale,
                                                    "linear_path": not self.transient})
                              if self.kinematics == "finite" else (StokesSolver, {}))
        interfaces = {name: FluidInterface(tag, "robin", "robin", self.alpha_n, self.alpha_t)
                      for name, tag in b.fluid_interfaces.items()}
        return fluid_class(mesh, tags, viscosity=params.physics.ca / params.stress_scale,
                           velocity_bcs=b.fluid_velocity, component_bcs=b.fluid_component,
                           interfaces=interfaces, petsc_options=options, solver=self.solver_kinds["fluid"], **extra)

    def _gel_solver(self, options: dict | None) -> PoroelasticGelSolver:
        """The poroelastic gel on the gel mesh, with its walls, symmetry lines and interfaces."""
        b, params, ph = self.boundaries, self.params, self.params.physics
        mesh, tags = self.meshes.region("gel")
        self.gel_parameters = GelParameters(phi_s0=ph.phi_s0, xi=ph.xi, lambda_s=ph.lambda_s,
                                            beta=ph.beta, eta=ph.eta, Ca=ph.ca, stress_scale=params.stress_scale,
                                            displacement_scale=params.displacement_scale)
        return PoroelasticGelSolver(
            mesh, tags, self.gel_parameters, no_slip=b.gel_no_slip, symmetry=b.gel_symmetry,
            fluid_interfaces=b.fluid_interfaces, cell_interfaces=b.cell_interfaces,
            transient=self.transient, kinematics=self.kinematics, linear_path=True, petsc_options=options,
            newton_rtol=NEWTON_RTOL, solver=self.solver_kinds["gel"])

    def _cell_solver(self, options: dict | None) -> NeoHookeanCellSolver:
        """The neo-Hookean cells; under ``gamma2="robin"`` each with its own surface's stiffness."""
        b, params = self.boundaries, self.params
        mesh, tags = self.meshes.region("cell")
        robin = None
        if self.gamma2 == "robin":
            # per cell: the stiffness seen from its own surface
            kappas = {c.interface: default_gamma2_coefficient(params, c.diameter) for c in self.layout.cells}
            robin = {k: (t, kappas[k]) for k, t in b.cell_interfaces.items()}
        return NeoHookeanCellSolver(
            mesh, tags, mu=params.mu_c, lmbda=params.lambda_c, stress_scale=params.stress_scale,
            displacement_scale=params.displacement_scale,
            interfaces=None if robin else b.cell_interfaces, robin_interfaces=robin,
            symmetry=b.cell_symmetry, linear_path=True, petsc_options=options, newton_rtol=NEWTON_RTOL,
            solver=self.solver_kinds["cell"])

    def _participants(self, time_scheme: str, inflow) -> list:
        """The coupling participants: fluid, gel and (with a cell) the cell."""
        b = self.boundaries
        fluid_participant = MovingFluidParticipant if self.kinematics == "finite" else FluidParticipant
        participants = []
        if self.fluid is not None:
            participants.append(fluid_participant(self.fluid, b.fluid_interfaces, self.alpha_n, self.alpha_t,
                                                  inflow))
        if self.gel is not None:
            participants.append(GelParticipant(self.gel, b.fluid_interfaces, b.cell_interfaces, self.gamma2,
                                               time_scheme))
        if self.params.with_cell and self.gamma2 == "schur":
            self._condense_cell()
        if self.cell is not None:
            participants.append(CellParticipant(self.cell, b.cell_interfaces, self.gamma2))
        return participants

    def _condense_cell(self) -> None:
        """Give the gel the cell's Steklov-Poincare operator on each Gamma2 (``gamma2="schur"``)."""
        t0 = time.perf_counter()
        stiffnesses = {}
        for g in self.boundaries.cell_interfaces:
            # distributed: from the cell's ranks to the gel's (collective on every rank)
            K, cell_points = self._from_field("cell", lambda g=g: (self.cell.interface_stiffness(g),
                                                                   self.cell.interface_points(g)))
            if self.gel is None:
                continue
            # the gel's node order (the data's "matching" mapping): P K P^T, P per component
            P = cp.build_mapping("matching", cell_points, self.gel.interface_points(g)).matrix
            P2 = np.kron(P.toarray(), np.eye(self.gel.mesh.geometry.dim))
            stiffnesses[g] = P2 @ K @ P2.T
        if self.gel is not None:
            self.gel.set_interface_stiffnesses(stiffnesses)
        self.setup_time += time.perf_counter() - t0

    def _choose_solve_paths(self, config: typing.Mapping, exact: bool = False) -> None:
        """The exact solve path under the linearized prior (or ``exact``), the linear path otherwise.

        The linear path leaves each solve's strain-sized nonlinear remainder
        (relative to the step) to the next coupling iteration.  After the
        prior's Newton step, a step the size of the solution, that remainder
        (~1e-5) is most of the next residual, and the prior would take it for
        the map's: measured, 8 iterations instead of 4 (shear baseline).
        """
        acceleration = config.get("acceleration") or {}
        linearized = isinstance(acceleration, typing.Mapping) and acceleration.get("jacobian_prior") == "linearized"
        exact = exact or linearized
        if linearized and self.gamma2 == "robin":
            raise ValueError("coupling.acceleration.jacobian_prior = 'linearized' needs gamma2 'dirichlet' or "
                             "'schur' (the cell's Jacobian is not built for the Robin-Neumann split)")
        # as built: gel and cell on the linear path, the moving fluid in steady runs only (the
        # fixed-mesh StokesSolver is linear and has no such path)
        for solver, default in ((self.gel, True), (self.cell, True), (self.fluid, not self.transient)):
            if solver is not None and hasattr(solver, "linear_path"):
                solver.linear_path = default and not exact

    def _fits(self, states: typing.Mapping | None) -> bool:
        """Whether participant states (``save_state()`` per name) have this device's array shapes."""
        def shapes(obj):
            if isinstance(obj, dict):
                return {k: shapes(v) for k, v in obj.items()}
            return np.shape(obj)
        mine = {p.name: p.save_state() for p in self.participants}
        ok = bool(states) and all(name in mine and shapes(st) == shapes(mine[name])
                                  for name, st in states.items() if st is not None)
        return bool(self.comm.allreduce(ok, op=MPI.LAND))      # the same decision on every rank

    def solve(self, config: typing.Mapping | None = None, verbose: bool = True,
              record_data: bool = False, reuse: typing.Mapping | None = None,
              initial: typing.Mapping | None = None, surrogate: typing.Any = None) -> cp.CouplingResult:
        """Run the partitioned coupling to convergence (steady state).

        ``reuse``: a ``scheme.reuse_state()`` of a solve of the same scaled
        problem (equal :func:`reuse_key`, e.g. the previous value of a Ca
        sweep): its converged interface data are the initial guess, and its
        quasi-Newton columns the initial model, or, under the linearized
        prior, its prior's factorisation without the columns (they model the
        strain-sized remainder, which scales with Ca).  In solver units the data of
        such problems are the same, so no rescaling is needed.  Participant
        states in it (the field solutions: the linear path's starting point)
        are loaded if they have this device's array shapes.  ``initial``:
        interface data (solver units) that replace the initial guess, e.g. a
        prediction extrapolated from earlier solves.  ``surrogate``: the
        quasi-Newton prior of another model of this problem (e.g. a
        ``coupling.CoarseSurrogate`` of a coarser device), in place of the
        device's default prior.
        """
        config = dict(config or coupling_config(with_cell=self.cell is not None, params=self.params))
        config.setdefault("verbose", verbose)
        config.setdefault("record_data", record_data)
        self._build_scheme(config, surrogate)
        if reuse is not None:
            # under the linearized prior the secant columns model what the prior leaves out, the
            # strain-sized part, which scales with Ca: another Ca's columns mislead (normal device,
            # default mesh: 6 and 4 iterations at the 2nd and 3rd value of a sweep with them, 4 and 3 without)
            self.scheme.load_reuse_state(reuse, acceleration=self.scheme.linearized_prior is None,
                                         participants=self._fits(reuse.get("participants")))
        if initial is not None:
            self.scheme.set_values(initial)
        prior = self.linearized_prior
        self.prior_source = None if prior is None else "reused" if prior.state() is not None else "computed"
        if surrogate is not None:
            self.prior_source = "surrogate"
        if self.prior_source == "computed":
            prior.load_state(priorcache.load(self, self.scheme, self.comm))
            self.prior_source = "computed" if prior.state() is None else "disk cache"
        self.result = self.scheme.solve()
        if self.prior_source == "computed" and self.result.converged:
            priorcache.store(self, self.scheme, prior.state(), self.comm)
        return self.result

    def _build_scheme(self, config: dict, surrogate: typing.Any = None) -> dict:
        """Build ``self.scheme`` under the default prior where it pays, else ``config``; return the one used."""
        self.prior_declined = None
        if surrogate is not None:
            self.scheme = self._new_scheme(config, surrogate)
            self._choose_solve_paths(config, exact=True)
            return config
        chosen = self._default_prior(config)
        self.scheme = self._new_scheme(chosen)
        if chosen is not config and not self._prior_pays(self.scheme.layout.size):
            chosen = config                             # the plain secant model
            self.prior_declined = (f"{self.scheme.layout.size} interface unknowns; the default's dense "
                                   f"linearized prior pays up to {AUTO_PRIOR_MAX_UNKNOWNS}")
            self.scheme = self._new_scheme(chosen)
        self._choose_solve_paths(chosen)
        return chosen

    def _new_scheme(self, config: dict, surrogate: typing.Any = None) -> cp.CouplingScheme:
        """The coupling scheme of ``config`` over this device's participants (on every rank)."""
        if self.distribution is None:
            return cp.build_scheme(config, self.participants, self.data, comm=self.comm, surrogate=surrogate)
        return cp.build_scheme(config, self.participants, self.data, distribution=self.distribution,
                               surrogate=surrogate)

    def window_scheme(self, config: typing.Mapping) -> tuple[dict, cp.CouplingScheme]:
        """The coupling of a time-dependent run's windows and its configuration.

        ``config`` with the linearized prior where the device default has it
        (:meth:`_default_prior`, :data:`TRANSIENT_PRIOR`): the participants'
        interface Jacobians of one step from rest, so one factorisation per
        step size and scheme (the gel's ``jacobian_key``), kept for the last
        few (``coupling.LinearizedPrior``) and on disk
        (:class:`gelcell.coupled.priorcache.WindowPriors`); and the solve paths it needs.
        """
        config = dict(config)
        chosen = self._build_scheme(config)
        prior = self.linearized_prior
        self.prior_source = None if prior is None else "per dt (computed or from the disk cache)"
        if prior is not None and priorcache.enabled():
            prior.store = priorcache.WindowPriors(self, self.scheme, self.comm)
        return chosen, self.scheme

    def coarse_surrogate(self, coarse: "Device") -> typing.Callable[[cp.CouplingScheme], cp.CoarseSurrogate]:
        """The prior of ``coarse`` (the same case on coarser meshes, solved under its linearized prior)
        carried to this device's scheme: pass it to :meth:`solve` as ``surrogate`` (3D devices only:
        the transfers project onto the interfaces' triangles)."""
        if coarse.linearized_prior is None:
            raise ValueError("coarse_surrogate: the coarse device has no linearized prior; solve it with "
                             "coupling.acceleration.jacobian_prior = 'linearized' first")
        return lambda scheme: cp.CoarseSurrogate.on_surfaces(scheme, coarse.scheme,
                                                              extensive=extensive_data(scheme.layout.names))

    @property
    def linearized_prior(self) -> cp.LinearizedPrior | None:
        """The last solve's linearized prior, or None if it had none."""
        return self.scheme.linearized_prior if self.scheme is not None else None

    def _prior_pays(self, unknowns: int) -> bool:
        """Whether the default may use the linearized prior on this many interface unknowns: at most
        :data:`AUTO_PRIOR_MAX_UNKNOWNS`, and its dense system fits in memory (the same decision on
        every rank)."""
        try:
            cp.LinearizedPrior.check_memory(unknowns, unknowns)
            fits = unknowns <= AUTO_PRIOR_MAX_UNKNOWNS
        except MemoryError:
            fits = False                               # an explicit jacobian_prior would say so, by name
        return bool(self.comm.allreduce(fits, op=MPI.LAND))

    def _default_prior(self, config: dict) -> dict:
        """``config`` with the linearized prior where the device default has it (a new dict), else ``config``.

        The default where it pays: a steady run (a time-dependent one too, its
        prior per step, without past windows' columns: :meth:`window_scheme`) with IQN
        whose acceleration table sets neither ``jacobian_prior`` nor
        ``relaxation_prior``, with ``gamma2`` "schur" or "dirichlet" (the
        cell's Jacobian has no Robin-Neumann form), and at most
        :data:`AUTO_PRIOR_MAX_UNKNOWNS` interface unknowns whose dense system
        fits in memory (:meth:`_prior_pays`, checked by the caller).  Its factorisation is then kept on disk
        (:mod:`gelcell.coupled.priorcache`): computing it costs more than the
        iterations it saves in one run, loading it does not.
        """
        acc = config.get("acceleration")
        if (not isinstance(acc, typing.Mapping) or acc.get("type") not in ("iqn-ils", "iqn-imvj")
                or "jacobian_prior" in acc or acc.get("relaxation_prior")
                or (self.transient and not TRANSIENT_PRIOR) or self.gamma2 == "robin"):
            return config
        acc = {**acc, "jacobian_prior": "linearized"}
        if self.transient and acc["type"] == "iqn-ils":
            acc["time_windows_reused"] = 0              # past windows' columns mislead the exact prior
        return {**config, "acceleration": acc}
