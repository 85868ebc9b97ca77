"""The composition layer: one device case as three coupled participants.

This is the only module that knows both the field solvers and the coupling
library.  It builds the meshes, the three solvers with the case's boundary
conditions, wraps each solver as a coupling participant, and declares the
data they exchange.

Partitioning (derivation in docs/partitioning.md).  On Gamma1/Gamma3 the gel
enforces I14 (both components), I15 and I17 given the fluid's traction T and
velocity V; the fluid enforces I16 and a Robin form of I13,

    T_F.n - alpha_n V.n = T_G.n - alpha_n q_G            (normal, alpha_n > 0)
    Ca (V - v_f).t = beta (Sigma n).t                    (tangential, I16)

with T_G the gel's total traction and q_G = phi_f v_f.n the gel's normal flux
(n out of the gel).  At convergence T_G = T_F (the gel enforces I14), so the
Robin condition reduces to I13, and neither enclosed domain (the upstream
fluid of the normal-flow device, the gel chamber of the shear device) ever
receives a Dirichlet normal velocity.  On Gamma2 the cell takes the gel's
displacement (Dirichlet) and returns its consistent nodal reaction; the gel
takes the opposite nodal forces (Neumann) and v_f = 0.

With ``gamma2="schur"`` the gel carries the cell's stiffness on Gamma2 (a
Robin condition whose operator is the cell's Steklov-Poincare operator K at
rest, ``NeoHookeanCellSolver.interface_stiffness``): the cell sends its
force f and its interface displacement u_c (``Gamma2/cell_displacement``),
and the gel's load there is f + K (u_c - u_s).  For a linear cell the gel then solves
with the cell condensed into it, so Gamma2 needs no iterations of its own;
at the fixed point u_s = u_c and the load is f again (docs/partitioning.md).

Data (per fluid interface G in Gamma1, Gamma3, all on matching nodes):

    G/traction               fluid -> gel   T_F, the fluid's traction on the gel
    G/velocity               fluid -> gel   V
    G/gel_traction           gel -> fluid   T_G (total traction the gel applies)
    G/mixture_velocity       gel -> fluid   phi_f v_f + phi_s v_s (normal part = flux q_G, I13)
    G/interstitial_velocity  gel -> fluid   v_f (tangential part enters I16)
    Gamma2/displacement      gel -> cell    u_s
    Gamma2/force             cell -> gel    nodal force of the cell on the gel

Units inside the solvers: velocity V0, length L0, stress Ca mu_s (= mu V0/L0),
displacement Ca L0 (CaseParameters.stress_scale / displacement_scale).

Finite kinematics (``params.kinematics == "finite"``, docs/finite-strain.md):
the gel is total Lagrangian (``gel.lagrangian``) and the fluid domain
follows the gel's surface (``fluid.ale.MovingStokesSolver``: a harmonic
extension of the gel's interface displacement, Stokes on the current
configuration).  Tractions are then nominal (per unit reference length of
the interface) and the data on Gamma1/Gamma3 are

    G/traction, G/velocity   fluid -> gel   as above (T_F nominal)
    G/gel_traction           gel -> fluid   T_G (nominal)
    G/normal_flux            gel -> fluid   int j (phi_f v_f + phi_s v_s).n (psi_i n) dA, the gel's
                                            consistent nodal volume flux through the CURRENT interface
    G/interstitial_velocity  gel -> fluid   v_f (I16)
    G/displacement           gel -> fluid   u_s on the interface: the fluid's mesh motion

so that the fluid's Robin condition holds in the same weak form as the
monolithic reference's I13 on the current interface.

Time-dependent runs (model.md section 8; ``Device(..., transient=True)``).
Stokes and the cell are quasi-static: solved as equilibria at t + dt in each
window.  The gel carries the time derivative v_s = du_s/dt (backward Euler
or BDF2, ``gel.solver``).  On Gamma2 the gel enforces v_f = v_s (w = 0) and
receives the cell's force; the cell receives u_s, so v_c = v_s there because
both are the same time difference of the same nodal displacements: Gamma2
carries the displacement, and the time derivative follows from it.  The
participants implement the coupling library's window protocol:
``save_state`` / ``load_state`` (the gel's unknowns and displacement history,
the cell's displacement as Newton's initial guess) and ``advance(t, dt)``
(the inflow V0 f(t + dt) for the fluid; the history shift and the BDF
coefficients for the gel).
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
from femtools.serialize import CanonicalOrder
from femtools.timestepping import WindowClock
from gelcell.boundaries import DeviceBoundaries, device_layout
from gelcell.geometry import build_device
from gelcell import priorcache
from gelcell.parameters import DEFAULT_GAMMA2, GAMMA2, CaseParameters

__all__ = ["Device", "FluidParticipant", "MovingFluidParticipant", "GelParticipant", "CellParticipant",
           "coupling_data", "default_robin_coefficient", "coupling_config", "gamma2_stiffness_ratio",
           "default_relaxation_prior", "reuse_key", "AUTO_PRIOR_MAX_UNKNOWNS"]

FLUID_TO_GEL = ("traction", "velocity")
GEL_TO_FLUID = ("gel_traction", "mixture_velocity", "interstitial_velocity")
#: gel -> fluid with finite kinematics (see the module docstring)
GEL_TO_MOVING_FLUID = ("gel_traction", "normal_flux", "interstitial_velocity", "displacement")
#: the device default uses the linearized prior up to this many interface unknowns (the default
#: mesh has 2440 (shear); at mesh-size 0.5, 4900, it would cost 7 s and 2.5 GB to save ~3 s)
AUTO_PRIOR_MAX_UNKNOWNS = 4000
#: MUMPS options of a steady run's field solvers: the AMF ordering (ICNTL(7) = 2).  Its analyses
#: are faster than the automatic choice's (PORD for some matrices), its back-substitutions a few
#: per cent slower: a steady run factorises each operator once and back-substitutes ~5-20 times,
#: a time-dependent one ~1000 times, and keeps the automatic choice (README "Performance")
STEADY_SOLVER_OPTIONS = {"mat_mumps_icntl_7": 2}


def default_robin_coefficient(params: CaseParameters) -> float:
    """alpha_n = C (Ca/s) xi phi_s0 l / phi_f0: C times the gel's Darcy resistance over a depth l.

    l is the gel's extent normal to Gamma1: the gel layer in the normal-flow
    device, the chamber depth in the shear device.

    * Normal flow (C = 1): the upstream fluid is enclosed, so the Robin
      coefficient must stay finite; matching the gel's impedance of its
      slowest (uniform) mode makes the Robin-Neumann iteration contract for
      every mode (docs/partitioning.md).
    * Shear flow (C = 10): the fluid is not enclosed, but the gel chamber is,
      so its slowest modes carry no net flux and have a far larger impedance
      than the Darcy estimate; a coefficient towards the Dirichlet limit
      suits them (measured: IQN-ILS iterations stop dropping beyond C ~ 10,
      see the coupling study).
    """
    g, ph = params.geometry, params.physics
    if params.case == "shear":
        depth, factor = g.radius * (1.0 - np.cos(g.half_angle)), 10.0
    elif params.case == "file":
        # depth: the gel's area over the interfaces' length; C = 1 if some fluid is enclosed (as the
        # upstream fluid of the normal-flow device), else 10 (the gel is then the enclosed side)
        info = g.layout
        depth, factor = info.gel_depth, 1.0 if info.enclosed_fluid else 10.0
    else:
        depth, factor = g.gel_length, 1.0
    viscosity = ph.ca / params.stress_scale
    return float(factor * viscosity * ph.xi * ph.phi_s0 * depth / (1.0 - ph.phi_s0))


def default_gamma2_coefficient(params: CaseParameters, diameter: float | None = None) -> float:
    """kappa = 2 (d/s) phi_s0 / r_c: the drained network's stiffness seen from the cell's surface.

    For a circular hole of radius r_c in an elastic plane of shear modulus
    mu_m, a radial surface displacement u_r needs the traction 2 mu_m u_r / r_c;
    the drained network has mu_m = phi_s0 mu_s.  A Robin coefficient equal to
    the Neumann side's stiffness makes the Robin-Neumann iteration contract
    whatever the cell's stiffness (docs/partitioning.md).
    """
    radius = 0.5 * (params.geometry.min_cell_diameter if diameter is None else diameter)
    return float(2.0 * params.displacement_scale / params.stress_scale * params.physics.phi_s0 / radius)


def gamma2_stiffness_ratio(params: CaseParameters) -> float:
    """rho = S_C / S_G: the cell's over the drained network's short-wave stiffness on Gamma2.

    An elastic body of shear modulus mu and Lame constant lam resists a
    short-wave surface displacement of wavenumber k with the traction
    2 m(mu, lam) |k| u, m = mu (lam + mu) / (lam + 2 mu) (plane strain
    half-space).  The gel around the cell is the drained network (mu, lam) =
    phi_s0 (mu_s, lam_s); so the Dirichlet-Neumann iteration on Gamma2 (the cell
    takes the displacement, the gel the force) multiplies a short-wave error
    by -rho.  Measured spectra of the coupled map (docs/coupling.md): the
    Gamma2 eigenvalues lie between about -rho/2 and -2 rho (the long waves
    of the small inclusion are the stiffest).  rho = 1 for the default cell
    and 10 for a cell x10 or a gel x0.1.
    """
    def m(mu: float, lam: float) -> float:
        return mu * (lam + mu) / (lam + 2.0 * mu)
    ph = params.physics
    return float(m(params.mu_c, params.lambda_c) / m(ph.phi_s0, ph.phi_s0 * ph.lambda_s))


def default_relaxation_prior(params: CaseParameters) -> dict[str, float]:
    """The quasi-Newton prior of a steady device run: Gamma2 force data relaxed with 1/(1 + rho).

    IQN-ILS does a plain fixed-point step in the directions its secant
    columns do not span yet; on Gamma2 that step multiplies the error by
    about -rho (:func:`gamma2_stiffness_ratio`).  The prior J0 = (1 - omega) I
    with omega = 1/(1 + rho) (the relaxation that removes an eigenvalue
    -rho) makes those directions contract from the first iteration.  No
    prior on Gamma1: its eigenvalues lie in [-1, 0], where a relaxation
    gains nothing measurable (docs/coupling.md).
    """
    if not params.with_cell:
        return {}
    b = device_layout(params).boundaries       # every cell's Gamma2 (built-in or geometry file)
    omega = 1.0 / (1.0 + gamma2_stiffness_ratio(params))
    return {f"{g}/force": omega for g in b.cell_interfaces}


def reuse_key(params: CaseParameters) -> str:
    """Identifies the scaled coupled problem: equal keys = the same interface operator in solver units.

    Every parameter except Ca: the solver's units of stress and displacement
    are both proportional to Ca (CaseParameters.stress_scale,
    displacement_scale), so at fixed everything else the scaled problem, its
    interface operator and its solution do not depend on Ca (up to the
    strain-sized nonlinearity of the finite-strain path).
    """
    import dataclasses
    import json
    d = dataclasses.asdict(params)
    d["physics"].pop("ca", None)
    d.pop("coupling", None)
    d.pop("time", None)
    return json.dumps(d, sort_keys=True, default=str)


def coupling_data(boundaries: DeviceBoundaries, gamma2: str = "dirichlet", kinematics: str = "small") -> list[cp.Data]:
    """The coupling data of a device (see the module docstring)."""
    data = []
    to_fluid = GEL_TO_MOVING_FLUID if kinematics == "finite" else GEL_TO_FLUID
    for g in boundaries.fluid_interfaces:
        data += [cp.Data(f"{g}/{k}", mesh=g, dim=2, writer="fluid", readers=("gel",)) for k in FLUID_TO_GEL]
        data += [cp.Data(f"{g}/{k}", mesh=g, dim=2, writer="gel", readers=("fluid",)) for k in to_fluid]
    for g in boundaries.cell_interfaces:
        data += [cp.Data(f"{g}/displacement", mesh=g, dim=2, writer="gel", readers=("cell",)),
                 cp.Data(f"{g}/force", mesh=g, dim=2, writer="cell", readers=("gel",))]
        if gamma2 == "robin":
            data.append(cp.Data(f"{g}/gel_force", mesh=g, dim=2, writer="gel", readers=("cell",)))
        elif gamma2 == "schur":
            data.append(cp.Data(f"{g}/cell_displacement", mesh=g, dim=2, writer="cell", readers=("gel",)))
    return data


def coupling_config(scheme: str = "serial", acceleration: str = "iqn-ils", *, limit: float = 1e-10,
                    max_iterations: int = 200, with_cell: bool = True,
                    overrides: typing.Mapping | None = None, transient: bool = False,
                    params: CaseParameters | None = None, gamma2: str = DEFAULT_GAMMA2,
                    jacobian_prior: str | None = None) -> dict:
    """A ``[coupling]`` table for a device run (TOML overrides are merged on top).

    Convergence: every exchanged data to a relative residual ``limit``.
    Steady serial runs with IQN: with the case's ``params`` and the plain
    Dirichlet-Neumann ``gamma2="dirichlet"`` the Gamma2 relaxation prior
    (:func:`default_relaxation_prior`; it is derived for that split; the default
    ``"schur"`` has no Gamma2 amplification to relax), and the secant columns of the
    last 4 solves are kept (``time_windows_reused``; no effect on one solve,
    reused by a Ca sweep without the linearized prior, see ``Device.solve(reuse=...)``).
    ``jacobian_prior="linearized"`` (IQN): the prior of the quasi-Newton step
    is the Newton step on the coupled map linearised at rest from the three
    solvers' interface Jacobians (``coupling.linearization``; each
    participant's ``jacobian()``), instead of the relaxation prior; ``"none"``:
    the secant model alone (with the relaxation prior); None: the device's
    choice (``Device.solve``: linearized where it pays).
    Time-dependent runs (``transient``): each window starts from the quadratic
    extrapolation of the last three (docs/transient.md), every iteration solves from the window's
    checkpoint (the library's ``state_reload = "iteration"``, so that each
    solve is one function of its interface data; docs/transient.md measures
    the alternative), and IQN-ILS keeps the secant columns of
    the last 40 windows (at most 500): for a fixed dt the windows share one
    interface operator, so after ~15 windows the kept columns span it and a
    window takes ~4 iterations instead of ~10 (measured, docs/transient.md).
    """
    order = ["fluid", "gel", "cell"] if with_cell else ["fluid", "gel"]
    acc: dict[str, typing.Any] = {"type": acceleration}
    if acceleration == "constant":
        acc["relaxation"] = 0.5
    elif acceleration == "aitken":
        # per-data scaling by the residual sums keeps one omega fair to every data
        acc.update(initial_relaxation=0.5, preconditioner={"type": "residual-sum"})
        if transient:
            # a window's map has real eigenvalues below 0 down to ~-12 at small dt (docs/transient.md):
            # omega must stay positive, which the secant estimate of this non-normal map does not ensure
            acc["positive_relaxation"] = True
    elif acceleration in ("iqn-ils", "iqn-imvj"):
        # value scaling: fixed per-data weights, so the kept secant columns stay consistent
        # (residual-sum weights drift each iteration; on stiff cells IQN-ILS then stalls at ~1e-9)
        acc.update(initial_relaxation=0.5, max_used_iterations=100,
                   filter={"type": "qr2", "limit": 1e-3},
                   preconditioner={"type": "value"})
        if transient:
            acc["max_used_iterations"] = 500
            if acceleration == "iqn-ils":
                acc["time_windows_reused"] = 40
        else:
            if acceleration == "iqn-ils":
                acc["time_windows_reused"] = 4
            prior = (default_relaxation_prior(params)
                     if params is not None and scheme == "serial" and gamma2 == "dirichlet" else {})
            if jacobian_prior is not None:
                acc["jacobian_prior"] = jacobian_prior
            if prior and jacobian_prior != "linearized":      # the linearized prior replaces it
                acc["relaxation_prior"] = prior
    config = {"scheme": f"{scheme}-implicit" if scheme in ("serial", "parallel") else scheme,
              "order": order, "max_iterations": max_iterations, "acceleration": acc,
              "convergence": [{"type": "relative", "limit": limit, "data": "*"}]}
    if transient:
        config["extrapolation_order"] = 2
    for key, value in (overrides or {}).items():
        if key == "acceleration" and isinstance(value, typing.Mapping):
            if value.get("type", acc["type"]) != acc["type"]:
                config["acceleration"] = dict(value)
            else:
                config["acceleration"] = {**acc, **value}
                if value.get("jacobian_prior", "none") != "none" and "relaxation_prior" not in value:
                    config["acceleration"].pop("relaxation_prior", None)     # ours, replaced by theirs
        else:
            config[key] = value
    return config


class FluidParticipant(cp.Participant):
    """The Stokes solver seen by the coupling: Robin I13 + I16 on Gamma1/Gamma3.

    Fluid convention: t = (Sigma - P I) n_F is the traction ON the fluid, n_F
    its outward normal (= -n).  The model's conditions become

        t.n_F + alpha_n V.n_F = g_N.n_F,   g_N = -T_G + alpha_n q_G
        t_tau + alpha_t V_tau = g_T,tau,   g_T = alpha_t v_f,  alpha_t = (Ca/s)/beta

    with q_G = phi_f v_f + phi_s v_s the gel's mixture velocity, and the
    fluid's traction on the gel is T_F = -t.  Quasi-static in time: the
    window [t, t + dt] solves Stokes at t + dt with the inflow scaled by
    ``inflow(t + dt)`` (no state of its own).
    """

    name = "fluid"

    def __init__(self, solver: StokesSolver, interfaces: typing.Iterable[str], alpha_n: float,
                 alpha_t: float, inflow: typing.Callable[[float], float] | None = None):
        self.solver, self.interfaces = solver, list(interfaces)
        self.alpha_n, self.alpha_t = float(alpha_n), float(alpha_t)
        self.inflow = inflow

    def interface_points(self, mesh_name: str) -> np.ndarray:
        return self.solver.interface_points(mesh_name)

    def save_state(self):
        return {}

    def load_state(self, state) -> None:
        pass

    def advance(self, t: float, dt: float) -> None:
        if self.inflow is not None:
            self.solver.scale_boundary_velocity(self.inflow(t + dt))

    def _set_inputs(self, g: str, inputs) -> None:
        T_G = inputs[f"{g}/gel_traction"]
        q = inputs[f"{g}/mixture_velocity"]
        v_f = inputs[f"{g}/interstitial_velocity"]
        self.solver.set_interface_data(g, robin_normal=-T_G + self.alpha_n * q, robin_tangential=self.alpha_t * v_f)

    def _input_factors(self, g: str, key: str) -> list[tuple[str, float]]:
        """d(solver input ``key`` on ``g``)/d(data), per data it is made of (see ``_set_inputs``)."""
        if key == "robin_normal":
            return [(f"{g}/gel_traction", -1.0), (f"{g}/mixture_velocity", self.alpha_n)]
        if key == "robin_tangential":
            return [(f"{g}/interstitial_velocity", self.alpha_t)]
        return []

    def jacobian(self):
        """d(traction, velocity)/d(the gel's data), from the Stokes solver's exact linear map."""
        out: dict[tuple[str, str], np.ndarray] = {}
        for ((g, key), (h, solver_input)), J in self.solver.interface_jacobian().items():
            sign = -1.0 if key == "traction" else 1.0          # the gel gets T_F = -t
            for data, factor in self._input_factors(h, solver_input):
                pair = (f"{g}/{key}", data)
                out[pair] = out.get(pair, 0.0) + (sign * factor) * J
        return out

    def solve(self, inputs):
        for g in self.interfaces:
            self._set_inputs(g, inputs)
        self.solver.solve()
        out = {}
        for g in self.interfaces:
            d = self.solver.interface_data(g)
            out[f"{g}/traction"] = -d["traction"]
            out[f"{g}/velocity"] = d["velocity"]
        return out


class MovingFluidParticipant(FluidParticipant):
    """The moving-domain Stokes solver (finite kinematics): the same conditions on the current interface.

    It takes the gel's interface displacement (its mesh motion), the gel's
    nominal traction and its consistent nodal normal flux (``normal_flux``):

        t_0.n + alpha_n j V.n = -T_G.n + alpha_n q_n     (weakly, q_n as nodal loads)
        t_0,tau + alpha_t j V_tau = alpha_t j v_f,tau

    with t_0 the nominal traction on the fluid (fluid.ale).  Its state (the
    unknowns, Newton's initial guess, and the mesh position) is saved and
    restored with the time windows and checkpoints.
    """

    def save_state(self):
        return self.solver.get_state()

    def load_state(self, state) -> None:
        self.solver.set_state(state)

    def checkpoint_state(self):
        return self.solver.checkpoint_state()

    def load_checkpoint_state(self, state) -> None:
        self.solver.load_checkpoint_state(state)

    def _input_factors(self, g: str, key: str) -> list[tuple[str, float]]:
        # the mesh motion (displacement) is left out: a strain-sized geometric effect
        return {"robin_normal": [(f"{g}/gel_traction", -1.0)],
                "robin_tangential": [(f"{g}/interstitial_velocity", self.alpha_t)],
                "normal_flux": [(f"{g}/normal_flux", 1.0)]}.get(key, [])

    def _set_inputs(self, g: str, inputs) -> None:
        self.solver.set_interface_data(g, robin_normal=-inputs[f"{g}/gel_traction"],
                                       robin_tangential=self.alpha_t * inputs[f"{g}/interstitial_velocity"],
                                       normal_flux=inputs[f"{g}/normal_flux"],
                                       displacement=inputs[f"{g}/displacement"])


class GelParticipant(cp.Participant):
    """The gel solver seen by the coupling: I14, I15, I17 on Gamma1/Gamma3, Neumann on Gamma2.

    Time windows: ``advance(t, dt)`` makes the state at t the newest past
    state (once per window: the history carries the time it belongs to, so
    calling it again after ``load_state`` is idempotent) and sets the time
    step: backward Euler in the first window and for ``time_scheme = "be"``,
    variable-step BDF2 afterwards for ``"bdf2"``.
    """

    name = "gel"

    def __init__(self, solver: PoroelasticGelSolver, fluid_interfaces: typing.Iterable[str],
                 cell_interfaces: typing.Iterable[str], gamma2: str = "dirichlet",
                 time_scheme: str = "be"):
        self.solver = solver
        self.fluid_interfaces, self.cell_interfaces = list(fluid_interfaces), list(cell_interfaces)
        self.gamma2 = gamma2
        self.clock = WindowClock(time_scheme)

    def interface_points(self, mesh_name: str) -> np.ndarray:
        return self.solver.interface_points(mesh_name)

    def save_state(self):
        return {**self.solver.get_state(), "history_times": self.clock.state()}

    def load_state(self, state) -> None:
        self.solver.set_state(state)
        self.clock.load(state["history_times"])

    def checkpoint_state(self):
        return {**self.solver.checkpoint_state(), "history_times": self.clock.state()}

    def load_checkpoint_state(self, state) -> None:
        self.solver.load_checkpoint_state(state)
        self.clock.load(state["history_times"])

    def advance(self, t: float, dt: float) -> None:
        scheme, dt_previous = self.clock.enter(t, dt, self.solver.push_history)
        self.solver.set_time_step(dt, scheme, dt_previous)

    def jacobian(self):
        """d(outputs)/d(inputs) of the gel linearised at rest (``PoroelasticGelSolver.interface_jacobian``).

        The solver's keys are the data's, except its fluid-interface ``traction`` (sent as
        ``gel_traction``) and its cell-interface ``displacement`` input (``cell_displacement``,
        read with ``gamma2="schur"`` only); outputs it does not send are left out.
        """
        sent = {f"{g}/{k}" for g in self.fluid_interfaces for k in ("gel_traction",) + self._sent()}
        sent |= {f"{g}/displacement" for g in self.cell_interfaces}
        out: dict[tuple[str, str], np.ndarray] = {}
        for ((g, key), (h, solver_input)), J in self.solver.interface_jacobian().items():
            data_out = f"{g}/gel_traction" if g in self.fluid_interfaces and key == "traction" else f"{g}/{key}"
            data_in = f"{h}/{solver_input}"
            if h in self.cell_interfaces and solver_input == "displacement":
                if self.gamma2 != "schur":
                    continue                    # u* is read by the condensed split only
                data_in = f"{h}/cell_displacement"
            if data_out in sent:
                out[(data_out, data_in)] = J
        return out

    def _sent(self) -> tuple[str, ...]:
        return GEL_TO_MOVING_FLUID[1:] if self.solver.kinematics == "finite" else GEL_TO_FLUID[1:]

    def solve(self, inputs):
        for g in self.fluid_interfaces:
            self.solver.set_interface_data(g, traction=inputs[f"{g}/traction"],
                                           velocity=inputs[f"{g}/velocity"])
        for g in self.cell_interfaces:
            # "schur": the cell's own displacement completes the gel's Robin condition
            held = {"displacement": inputs[f"{g}/cell_displacement"]} if self.gamma2 == "schur" else {}
            self.solver.set_interface_data(g, force=inputs[f"{g}/force"], **held)
        self.solver.solve()
        out = {}
        for g in self.cell_interfaces:
            out[f"{g}/displacement"] = self.solver.interface_data(g)["displacement"]
            if self.gamma2 == "robin":
                # the force the gel exerts on the cell: the opposite of the load it carries
                out[f"{g}/gel_force"] = -inputs[f"{g}/force"]
        sent = self._sent()
        for g in self.fluid_interfaces:
            d = self.solver.interface_data(g)
            out[f"{g}/gel_traction"] = d["traction"]
            for key in sent:
                out[f"{g}/{key}"] = d[key]
        return out


class CellParticipant(cp.Participant):
    """The cell solver seen by the coupling; returns the force on the gel.

    Dirichlet-Neumann: the cell takes the gel's displacement; with
    ``gamma2="schur"`` (the default) it also sends its own interface
    displacement, which with its force makes the gel's Robin condition.
    Robin-Neumann: the cell takes the gel's force on it plus springs kappa
    towards the gel's displacement, f = f_gel + kappa M (u_s - u_c); at
    convergence u_c = u_s and the forces balance.  Quasi-static in time; its
    state is its displacement (Newton's initial guess in the next window).
    """

    name = "cell"

    def __init__(self, solver: NeoHookeanCellSolver, interfaces: typing.Iterable[str],
                 gamma2: str = "dirichlet"):
        self.solver, self.interfaces, self.gamma2 = solver, list(interfaces), gamma2

    def interface_points(self, mesh_name: str) -> np.ndarray:
        return self.solver.interface_points(mesh_name)

    def save_state(self):
        return {"u": self.solver.displacement.x.array.copy()}

    def load_state(self, state) -> None:
        self.solver.displacement.x.array[:] = state["u"]

    def checkpoint_state(self):
        if not hasattr(self, "_canonical"):
            self._canonical = CanonicalOrder(self.solver.displacement.function_space)
        return {"u": self._canonical.gather(self.solver.displacement.x.array)}

    def load_checkpoint_state(self, state) -> None:
        self.checkpoint_state()
        self.solver.displacement.x.array[:] = self._canonical.scatter(state["u"])

    def advance(self, t: float, dt: float) -> None:
        pass

    def jacobian(self):
        """d(force, cell_displacement)/d(displacement): the cell's Steklov-Poincare operator at rest."""
        if self.gamma2 == "robin":
            raise NotImplementedError("the cell's jacobian() is built for the Dirichlet-Neumann and condensed "
                                      "splits (gamma2 'dirichlet' or 'schur'), not 'robin'")
        out = {}
        for ((g, key), _), J in self.solver.interface_jacobian().items():
            if key == "force":
                out[(f"{g}/force", f"{g}/displacement")] = -J          # the gel feels the opposite
            elif self.gamma2 == "schur":
                out[(f"{g}/cell_displacement", f"{g}/displacement")] = J
        return out

    def solve(self, inputs):
        for g in self.interfaces:
            if self.gamma2 == "robin":
                self.solver.set_interface_data(g, displacement=inputs[f"{g}/displacement"],
                                               force=inputs[f"{g}/gel_force"])
            else:
                self.solver.set_interface_data(g, displacement=inputs[f"{g}/displacement"])
        self.solver.solve()
        # the cell's reaction is the force ON the cell; the gel feels the opposite
        out = {}
        for g in self.interfaces:
            data = self.solver.interface_data(g)
            out[f"{g}/force"] = -data["force"]
            if self.gamma2 == "schur":
                out[f"{g}/cell_displacement"] = data["displacement"]
        return out


class Device:
    """A device case: meshes, the three field solvers and their coupling.

    Args:
        params: the case (geometry, parameters, mesh sizes).
        comm: MPI communicator.
        robin_coefficient: alpha_n in the solvers' stress unit per unit
            velocity; default :func:`default_robin_coefficient`.
        whole_mesh: also build the whole-device mesh (for the monolithic
            reference and field comparisons).
        transient: build the time-dependent gel (see the module docstring);
            ``time_scheme`` ``"be"`` or ``"bdf2"``, ``inflow`` the waveform
            f(t) that multiplies the inflow (None: 1).
    """

    def __init__(self, params: CaseParameters, comm: MPI.Comm = MPI.COMM_WORLD,
                 robin_coefficient: float | None = None, whole_mesh: bool = False,
                 newton_rtol: float = 1e-12, gamma2: str = DEFAULT_GAMMA2,
                 gamma2_coefficient: float | None = None, transient: bool = False,
                 time_scheme: str = "be", inflow: typing.Callable[[float], float] | None = None):
        t0 = time.perf_counter()
        params.validate()
        self.params, self.comm = params, comm
        self.mesh = build_device(params, comm, whole=whole_mesh)
        self.layout = self.mesh.layout
        self.boundaries = self.layout.boundaries
        b, ph = self.boundaries, params.physics
        s, d = params.stress_scale, params.displacement_scale
        viscosity = ph.ca / s
        self.alpha_n = default_robin_coefficient(params) if robin_coefficient is None else robin_coefficient
        self.alpha_t = viscosity / ph.beta
        if not self.alpha_n > 0:
            raise ValueError(f"robin_coefficient = {self.alpha_n} must be > 0")
        if gamma2 not in GAMMA2:
            raise ValueError(f"gamma2 = {gamma2!r}: the split on Gamma2 must be one of {', '.join(GAMMA2)}")
        self.gamma2 = gamma2
        self.kappa = default_gamma2_coefficient(params) if gamma2_coefficient is None else gamma2_coefficient
        # per cell: the stiffness seen from its own surface
        kappas = {c.interface: (default_gamma2_coefficient(params, c.diameter) if gamma2_coefficient is None
                                else gamma2_coefficient) for c in self.layout.cells}
        if gamma2 == "robin" and not self.kappa > 0:
            raise ValueError(f"gamma2_coefficient = {self.kappa} must be > 0")
        self.mesh_time = time.perf_counter() - t0
        t0 = time.perf_counter()
        fluid_mesh, fluid_tags = self.mesh.region("fluid")
        self.kinematics = params.kinematics
        finite = self.kinematics == "finite"
        # the moving fluid's linear path in steady runs only: a time-dependent iteration restarts
        # from the window's checkpoint, and a resumed run must repeat the uninterrupted one
        fluid_class, fluid_kw = ((MovingStokesSolver, {"displacement_scale": d, "linear_path": not transient})
                                 if finite else (StokesSolver, {}))
        options = None if transient else dict(STEADY_SOLVER_OPTIONS)
        self.fluid = fluid_class(
            fluid_mesh, fluid_tags, viscosity=viscosity, velocity_bcs=b.fluid_velocity,
            component_bcs=b.fluid_component,
            interfaces={name: FluidInterface(tag, "robin", "robin", self.alpha_n, self.alpha_t)
                        for name, tag in b.fluid_interfaces.items()}, petsc_options=options, **fluid_kw)
        gel_mesh, gel_tags = self.mesh.region("gel")
        self.gel_parameters = GelParameters(phi_s0=ph.phi_s0, xi=ph.xi, lambda_s=ph.lambda_s,
                                            beta=ph.beta, eta=ph.eta, Ca=ph.ca, stress_scale=s,
                                            displacement_scale=d)
        self.gel = PoroelasticGelSolver(
            gel_mesh, gel_tags, self.gel_parameters, no_slip=b.gel_no_slip, symmetry=b.gel_symmetry,
            fluid_interfaces=b.fluid_interfaces, cell_interfaces=b.cell_interfaces,
            newton_rtol=newton_rtol, transient=transient, kinematics=self.kinematics,
            linear_path=True, petsc_options=options)
        self.cell = None
        if params.with_cell:
            cell_mesh, cell_tags = self.mesh.region("cell")
            robin = gamma2 == "robin"
            self.cell = NeoHookeanCellSolver(
                cell_mesh, cell_tags, mu=params.mu_c, lmbda=params.lambda_c, stress_scale=s,
                displacement_scale=d, interfaces=None if robin else b.cell_interfaces,
                robin_interfaces={k: (t, kappas[k]) for k, t in b.cell_interfaces.items()} if robin else None,
                symmetry=b.cell_symmetry, newton_rtol=newton_rtol, linear_path=True, petsc_options=options)
        self.setup_time = time.perf_counter() - t0
        self.transient = bool(transient)
        fluid_participant = MovingFluidParticipant if finite else FluidParticipant
        self.participants = [fluid_participant(self.fluid, b.fluid_interfaces, self.alpha_n, self.alpha_t,
                                               inflow),
                             GelParticipant(self.gel, b.fluid_interfaces, b.cell_interfaces, gamma2,
                                            time_scheme)]
        if self.cell is not None:
            if gamma2 == "schur":
                self._condense_cell()
            self.participants.append(CellParticipant(self.cell, b.cell_interfaces, gamma2))
        self.data = coupling_data(b, gamma2, self.kinematics)
        self.scheme: cp.CouplingScheme | None = None
        self.result: cp.CouplingResult | None = None
        #: where the last solve's linearized prior came from: "computed", "disk cache", "reused" or None
        self.prior_source: str | None = None

    def _condense_cell(self) -> None:
        """Give the gel the cell's Steklov-Poincare operator on each Gamma2 (``gamma2="schur"``)."""
        t0 = time.perf_counter()
        stiffnesses = {}
        for g in self.boundaries.cell_interfaces:
            K = self.cell.interface_stiffness(g)
            # the gel's node order (the data's "matching" mapping): P K P^T, P per component
            P = cp.build_mapping("matching", self.cell.interface_points(g), self.gel.interface_points(g)).matrix
            P2 = np.kron(P.toarray(), np.eye(2))
            stiffnesses[g] = P2 @ K @ P2.T
        self.gel.set_interface_stiffnesses(stiffnesses)
        self.setup_time += time.perf_counter() - t0

    def _choose_solve_paths(self, config: typing.Mapping) -> None:
        """The exact solve path under the linearized prior, the linear path otherwise.

        The linear path leaves each solve's strain-sized nonlinear remainder
        (relative to the step) to the next coupling iteration.  After the
        prior's Newton step, a step the size of the solution, that remainder
        (~1e-5) is most of the next residual, and the prior would take it for
        the map's: measured, 8 iterations instead of 4 (shear baseline).
        """
        acceleration = config.get("acceleration") or {}
        exact = isinstance(acceleration, typing.Mapping) and acceleration.get("jacobian_prior") == "linearized"
        if exact and self.gamma2 == "robin":
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
              initial: typing.Mapping | None = None) -> cp.CouplingResult:
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
        prediction extrapolated from earlier solves.
        """
        config = dict(config or coupling_config(with_cell=self.cell is not None, params=self.params))
        config.setdefault("verbose", verbose)
        config.setdefault("record_data", record_data)
        chosen = self._default_prior(config)
        self.scheme = cp.build_scheme(chosen, self.participants, self.data, comm=self.comm)
        if chosen is not config and not self._prior_pays(self.scheme.layout.size):
            chosen = config                             # the plain secant model
            self.scheme = cp.build_scheme(chosen, self.participants, self.data, comm=self.comm)
        self._choose_solve_paths(chosen)
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
        if self.prior_source == "computed":
            prior.load_state(priorcache.load(self, self.scheme, self.comm))
            self.prior_source = "computed" if prior.state() is None else "disk cache"
        self.result = self.scheme.solve()
        if self.prior_source == "computed" and self.result.converged:
            priorcache.store(self, self.scheme, prior.state(), self.comm)
        return self.result

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

        The default where it pays: a steady run with IQN
        whose acceleration table sets neither ``jacobian_prior`` nor
        ``relaxation_prior``, with ``gamma2`` "schur" or "dirichlet" (the
        cell's Jacobian has no Robin-Neumann form), and at most
        :data:`AUTO_PRIOR_MAX_UNKNOWNS` interface unknowns whose dense system
        fits in memory (:meth:`_prior_pays`, checked by the caller).  Its factorisation is then kept on disk
        (:mod:`gelcell.priorcache`): computing it costs more than the
        iterations it saves in one run, loading it does not.
        """
        acc = config.get("acceleration")
        if (not isinstance(acc, typing.Mapping) or acc.get("type") not in ("iqn-ils", "iqn-imvj")
                or "jacobian_prior" in acc or acc.get("relaxation_prior") or self.transient
                or self.gamma2 == "robin"):
            return config
        return {**config, "acceleration": {**acc, "jacobian_prior": "linearized"}}
