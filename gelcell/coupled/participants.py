"""The three field solvers seen by the coupling library: what each reads, solves and writes.

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

Time-dependent runs (model.md section 8; ``Device(..., transient=True)``).
Stokes and the cell are quasi-static: solved as equilibria at t + dt in each
window.  The gel carries the time derivative v_s = du_s/dt (backward Euler
or BDF2, ``gel.solver``).  On Gamma2 the gel enforces v_f = v_s (w = 0) and
receives the cell's force; the cell receives u_s, so v_c = v_s there because
both are the same time difference of the same nodal displacements: Gamma2
carries the displacement, and the time derivative follows from it.  The
participants implement the coupling library's window protocol:
``save_state`` / ``load_state`` (the gel's unknowns and displacement history,
the cell's displacement as Newton's initial guess) and ``begin_window(t, dt)``
(once per window: the inflow V0 f(t + dt) for the fluid; the history shift
and the BDF coefficients for the gel).
"""

from __future__ import annotations

import typing

import numpy as np

import coupling as cp
from cell import NeoHookeanCellSolver
from femtools.timestepping import WindowClock
from fluid import StokesSolver
from gel import PoroelasticGelSolver
from gelcell.coupled.data import GEL_TO_FLUID, GEL_TO_MOVING_FLUID

__all__ = ["FluidParticipant", "MovingFluidParticipant", "GelParticipant", "CellParticipant"]


class _FieldParticipant(cp.Participant):
    """A participant wrapping one field solver (``self.solver``): its interface points and triangles."""

    solver: typing.Any

    def interface_points(self, mesh_name: str) -> np.ndarray:
        return self.solver.interface_points(mesh_name)

    def interface_triangles(self, mesh_name: str) -> np.ndarray:
        return self.solver.interface_triangles(mesh_name)


class FluidParticipant(_FieldParticipant):
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


    def save_state(self):
        return {}

    def load_state(self, state) -> None:
        pass

    def begin_window(self, t: float, dt: float) -> None:
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


class GelParticipant(_FieldParticipant):
    """The gel solver seen by the coupling: I14, I15, I17 on Gamma1/Gamma3, Neumann on Gamma2.

    Time windows: ``begin_window(t, dt)`` makes the state at t the newest
    past state and sets the time step: backward Euler in the first window and
    for ``time_scheme = "be"``, variable-step BDF2 afterwards for ``"bdf2"``.
    The history carries the times it belongs to (``WindowClock``), so that a
    window retaken after a restore pushes the state at t once.
    """

    name = "gel"

    def __init__(self, solver: PoroelasticGelSolver, fluid_interfaces: typing.Iterable[str],
                 cell_interfaces: typing.Iterable[str], gamma2: str = "dirichlet",
                 time_scheme: str = "be"):
        self.solver = solver
        self.fluid_interfaces, self.cell_interfaces = list(fluid_interfaces), list(cell_interfaces)
        self.gamma2 = gamma2
        self.clock = WindowClock(time_scheme)


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

    def begin_window(self, t: float, dt: float) -> None:
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

    def jacobian_key(self) -> float | None:
        """What :meth:`jacobian` depends on besides the case: c0 = a0/dt of the step, the only
        time-stepping coefficient left at rest with a zero history, rounded to 13 significant digits
        (steps that differ by the round-off of accumulated times share a prior); None for a steady solve."""
        if not self.solver.transient:
            return None
        return float(f"{self.solver.history.coefficients[0]:.12e}")

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


class CellParticipant(_FieldParticipant):
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


    def save_state(self):
        return {"u": self.solver.displacement.x.array.copy()}

    def load_state(self, state) -> None:
        self.solver.displacement.x.array[:] = state["u"]

    def checkpoint_state(self):
        return self.solver.checkpoint_state()

    def load_checkpoint_state(self, state) -> None:
        self.solver.load_checkpoint_state(state)

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
