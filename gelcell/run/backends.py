"""What a time-dependent run steps: the coupled field solvers, or the monolithic reference.

A backend advances one window [t, t + dt] (``window``), keeps its fields on
the region meshes (``fields``, ``update_fields``), takes and restores
snapshots (a rejected adaptive step) and writes and reads checkpoints in an
order that does not depend on the mesh partition.
"""

from __future__ import annotations

import contextlib
import os
import typing

from mpi4py import MPI

from dolfinx import fem

from coupling.serialization import load_npz, save_npz
from femtools.canonical import CanonicalOrder, MixedCanonical
from femtools.timestepping import WindowClock
from femtools.transfer import NodalTransfer
from gelcell.case import CaseParameters
from gelcell.coupled.device import Device
from gelcell.coupled.monolithic import MonolithicSolver, monolithic_coefficients
from gelcell.errors import ParameterError
from gelcell.geometry.meshes import build_meshes
from gelcell.post.fields import DeviceFields, WorldFields, fields_from_device

__all__ = ["WindowOutcome", "PartitionedBackend", "MonolithicBackend"]


class WindowOutcome(typing.NamedTuple):
    iterations: int
    residual: float


# ----------------------------------------------------------------------------- backends
class PartitionedBackend:
    """The three coupled field solvers of a :class:`Device`, one coupling per window."""

    method = "partitioned"

    def __init__(self, device: Device, config: typing.Mapping, comm: MPI.Comm):
        self.device, self.comm = device, comm
        self.config, self.scheme = device.window_scheme(config)
        # distributed: copies on the world's region meshes, renewed by update_fields
        self._world = WorldFields(device) if device.distribution is not None else None
        self.fields = fields_from_device(device) if self._world is None else self._world.fields

    def window(self, t: float, dt: float) -> WindowOutcome:
        if abs(self.scheme.time - t) > 1e-12 * max(abs(t), dt):
            raise RuntimeError(f"coupling time {self.scheme.time} differs from the run's time {t}")
        rec = self.scheme.advance_window(dt)
        # the convergence measures' largest value: the forward data the measures leave out only change
        measured = rec.records[-1].measures if rec.records else []
        residual = max((m.value for m in measured), default=0.0)
        return WindowOutcome(rec.iterations, residual)

    def update_fields(self) -> None:
        if self._world is not None:
            self._world.update()
            return
        gel, f = self.device.gel, self.fields        # the fluid's and the cell's are the solvers' own
        gel.interstitial_velocity(out=f.interstitial_velocity)
        gel.displacement(out=f.displacement)
        gel.pore_pressure(out=f.pore_pressure)

    def snapshot(self):
        return self.scheme.snapshot()

    def restore(self, snapshot) -> None:
        self.scheme.restore(snapshot)

    def save(self, path: str, extra) -> None:
        self.scheme.save_checkpoint(path, extra=extra)

    def load(self, path: str):
        return self.scheme.load_checkpoint(path)

    def write_records(self, directory: str) -> None:
        self.scheme.write_records(directory)

    def describe(self) -> dict:
        acc = self.config["acceleration"]
        return {"scheme": self.config["scheme"], "acceleration": acc["type"],
                "time_windows_reused": acc.get("time_windows_reused"),
                "robin_coefficient": self.device.alpha_n, "gamma2": self.device.gamma2,
                "jacobian_prior": self.prior_description,
                "distribute": self.device.distribute}

    @property
    def prior_description(self) -> str:
        """The quasi-Newton prior in words, with the factorisations computed so far."""
        prior = self.scheme.linearized_prior
        if prior is None:
            return "none"
        return f"linearized per dt ({prior.factorizations} computed, {prior.loaded} from the disk cache)"


class MonolithicBackend:
    """The monolithic reference with the same time discretisation, one Newton solve per window."""

    method = "monolithic"

    def __init__(self, params: CaseParameters, comm: MPI.Comm, time_scheme: str, inflow, solver: str = "direct"):
        self.params, self.comm, self.inflow = params, comm, inflow
        self.meshes = build_meshes(params, comm, whole=True)
        msh, ct, ft = self.meshes.whole
        layout = self.meshes.layout
        self.solver = MonolithicSolver(msh, ct, ft, layout.boundaries, monolithic_coefficients(params), transient=True,
                                       cell_region_tags=layout.cell_region_tags or None, solver=solver)
        self.clock = WindowClock(time_scheme)
        self._transfers: dict = {}
        self.fields = self._region_fields()
        self.update_fields()

    def _region_fields(self) -> DeviceFields:
        out = {}
        fluid = ("V", "P", "fluid_motion") if self.params.kinematics == "finite" else ("V", "P")
        regions = [("fluid", fluid), ("gel", ("v_f", "u", "p"))]
        if self.params.with_cell:
            regions.append(("cell", ("u",)))
        tags = {}
        for region, names in regions:
            msh, tags[region] = self.meshes.region(region)
            for name in names:
                src = self.solver.field(name)
                degree_space = (fem.FunctionSpace(msh, ("Lagrange", 1)) if name in ("P", "p")
                                else fem.VectorFunctionSpace(msh, ("Lagrange", 2)))
                key = f"{region}/{name}"
                out[key] = fem.Function(degree_space, name=name)
                self._transfers[key] = NodalTransfer(src.function_space, degree_space)
        return DeviceFields(params=self.params, fluid_velocity=out["fluid/V"], fluid_pressure=out["fluid/P"],
                            interstitial_velocity=out["gel/v_f"], displacement=out["gel/u"],
                            pore_pressure=out["gel/p"], cell_displacement=out.get("cell/u"),
                            fluid_tags=tags["fluid"], gel_tags=tags["gel"], cell_tags=tags.get("cell"),
                            fluid_mesh_displacement=out.get("fluid/fluid_motion"), layout=self.meshes.layout,
                            cell_regions=self.meshes.cell_tags)

    def update_fields(self) -> None:
        f = self.fields
        targets = {"fluid/V": f.fluid_velocity, "fluid/P": f.fluid_pressure, "gel/v_f": f.interstitial_velocity,
                   "gel/u": f.displacement, "gel/p": f.pore_pressure}
        if f.cell_displacement is not None:
            targets["cell/u"] = f.cell_displacement
        if f.fluid_mesh_displacement is not None:
            targets["fluid/fluid_motion"] = f.fluid_mesh_displacement
        cache = {}
        for key, dst in targets.items():
            name = key.split("/")[1]
            if name not in cache:
                cache[name] = self.solver.field(name)
            self._transfers[key].apply(cache[name], dst)

    def window(self, t: float, dt: float) -> WindowOutcome:
        scheme, dt_previous = self.clock.enter(t, dt, self.solver.push_history)
        self.solver.set_time_step(dt, scheme, dt_previous)
        self.solver.scale_boundary_velocity(self.inflow(t + dt))
        iterations = self.solver.solve()
        return WindowOutcome(iterations, self.solver.newton.history[-1] if self.solver.newton.history else 0.0)

    def snapshot(self):
        return {"state": self.solver.get_state(), "times": self.clock.state()}

    def restore(self, snapshot) -> None:
        self.solver.set_state(snapshot["state"])
        self.clock.load(snapshot["times"])

    def _canonical(self):
        if not hasattr(self, "_orders"):
            self._orders = (MixedCanonical(self.solver.W, self.solver.field_names),
                            CanonicalOrder(self.solver.history.past[0].function_space))
        return self._orders

    def save(self, path: str, extra) -> None:
        """Partition-independent arrays (``femtools.canonical``) and the run's own state (rank 0's)."""
        mixed, order_u = self._canonical()
        history = self.solver.history
        state = {"format": "gelcell-monolithic-checkpoint", "fields": mixed.gather(self.solver.w.x.array),
                 "past": [order_u.gather(f.x.array) for f in history.past], "length": history.length,
                 "step": history.step_state(), "times": self.clock.state(), "extra": extra}
        failed = None                   # an OSError of rank 0 (a full disk), raised on every rank
        if self.comm.rank == 0:
            try:
                save_npz(f"{path}.tmp", state)
                os.replace(f"{path}.tmp", path)
            except OSError as exc:
                failed = (exc.errno, exc.strerror or str(exc), exc.filename or f"{path}.tmp")
                with contextlib.suppress(OSError):
                    os.remove(f"{path}.tmp")
        failed = self.comm.bcast(failed, root=0)
        if failed is not None:
            raise OSError(*failed)

    def load(self, path: str):
        state = load_npz(path)
        if state.get("format") != "gelcell-monolithic-checkpoint":
            raise ParameterError(f"{path}: not a checkpoint of a monolithic time-dependent run")
        mixed, order_u = self._canonical()
        mixed.scatter(state["fields"], self.solver.w.x.array)
        self.solver.history.load({"past_0": order_u.scatter(state["past"][0]),
                                  "past_1": order_u.scatter(state["past"][1]), "length": state["length"]})
        if "step" in state:              # the rate of the saved state (v_f of a run resumed after its last window)
            self.solver.history.load_step(state["step"])
            self.solver.newton.invalidate_jacobian()
        self.clock.load(state["times"])
        return state["extra"]

    def write_records(self, directory: str) -> None:
        pass

    def describe(self) -> dict:
        return {"newton": "exact Jacobian, kept while it contracts (refactorised when dt changes)"}
