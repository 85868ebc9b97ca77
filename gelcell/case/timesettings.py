"""Settings of a time-dependent run and the time scales they default from (model.md section 8).

Times are in the paper's unit L0/V0 (the source paper's Δt = 5e-8 is in this
unit); the output reports them in seconds as well.  One
:class:`TimeSettings` comes from the ``[time]`` table of a case file and the
command line (``--transient --dt --t-end --until-steady --time-scheme
--adaptive --time-tol --inflow --until-periodic --periodic-tol
--steps-per-period``), and is validated before anything is meshed: a bad
value raises :class:`~gelcell.errors.ParameterError` naming it.

Time scales (:func:`time_scales`), paper units:

* consolidation  tau_c = H^2 / (M k),  M = phi_s0 (2 + lambda_s) the drained
  oedometric modulus, k = phi_f0 / (xi Ca phi_s0) the Darcy mobility and H
  the drainage length: the chamber depth R (1 - cos theta) of the shear
  device (drained through Gamma1 only), half the gel layer of the normal-flow
  device (drained through Gamma1 and Gamma3).  tau_c is proportional to Ca,
  so the physical time tau_c L0 / V0 does not depend on the flow speed.
* Kelvin-Voigt  tau_KV = phi_f0 Ca / phi_s0: the viscous interstitial fluid
  moving with the network in the first instants (undrained start-up).

Defaults: BDF2 at ``dt = tau_c / 40`` (fixed steps; from rest it starts at dt/4 and dt/2,
:data:`gelcell.run.transient.BDF2_START`), which puts the milestones t50/t90/t99 within 1 % of
their dt -> 0 limits on both devices, where backward Euler is 4-6 % late (docs/transient.md,
"Accuracy of the milestones"); adaptive runs start at
``tau_KV / 10`` and grow.  A run stops at ``t_end``, or when steady: the
gel's displacement changes by less than ``steady_tol`` of itself per
consolidation time tau_c (relative change per unit time, in units of tau_c).

Until periodic (``until_periodic``): a periodic inflow (a sine, a square wave,
a table whose first and last f are equal, then repeated) with period P is
stepped at the fixed dt = P / N, N = ``steps_per_period`` (default 40, the
default steps per tau_c; a given dt must divide P), until the response of
one period differs from the one before by less than ``periodic_tol``
(:mod:`gelcell.post.periodic`), or ``max_cycles`` periods have run.  It
excludes ``t_end``, ``until_steady`` and ``adaptive``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import typing

from gelcell.case.inflow import Waveform, parse_inflow
from gelcell.case.parameters import CaseParameters
from gelcell.errors import ParameterError

__all__ = ["TimeSettings", "time_scales", "TIME_KEYS"]

#: keys of the ``[time]`` table
TIME_KEYS = ("transient", "dt", "t_end", "until_steady", "scheme", "adaptive", "time_tol", "steady_tol",
             "inflow", "output_every", "max_windows", "until_periodic", "periodic_tol", "steps_per_period",
             "max_cycles")
#: steps per period of an until-periodic run without dt: the steps per tau_c of the fixed default
STEPS_PER_PERIOD = 40
#: fewest steps per period: the first harmonic of the response (its phase lag) needs at least 4 samples
MIN_STEPS_PER_PERIOD = 4


def time_scales(params: CaseParameters) -> dict[str, float]:
    """``{"consolidation", "kelvin_voigt", "drainage_length"}`` in paper units (see the module docstring)."""
    ph, g = params.physics, params.geometry
    if params.case == "shear":
        depth = g.radius * (1.0 - math.cos(g.half_angle))
    elif params.case == "file":
        depth = g.contents.gel_depth          # the gel's area over the fluid-gel interfaces' length
    else:
        depth = 0.5 * g.gel_length
    modulus = ph.phi_s0 * (2.0 + ph.lambda_s)
    mobility = (1.0 - ph.phi_s0) / (ph.xi * ph.ca * ph.phi_s0)
    return {"consolidation": depth**2 / (modulus * mobility),
            "kelvin_voigt": (1.0 - ph.phi_s0) * ph.ca / ph.phi_s0,
            "drainage_length": depth}


def _number(problems: list, key: str, value, positive: bool = True, below: float | None = None):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        problems.append(f"parameter 'time.{key}' = {value!r} must be a finite number")
        return None
    if positive and not value > 0:
        problems.append(f"parameter 'time.{key}' = {value!r} must be > 0")
    elif below is not None and not value < below:
        problems.append(f"parameter 'time.{key}' = {value!r} must be < {below:g}")
    return float(value)


@dataclasses.dataclass(frozen=True)
class TimeSettings:
    """How a time-dependent run steps and stops (see the module docstring).

    Attributes:
        transient: run in time (``--transient`` or ``[time] transient = true``).
        dt: fixed step, or the first step of an adaptive run (None: from the time scales).
        t_end: end time (None: until steady).
        until_steady: stop when steady (also the default when t_end is not given).
        scheme: ``"bdf2"`` (the default: within 1 % of the dt -> 0 milestones at tau_c/40, docs/transient.md)
            or ``"be"`` (backward Euler).
        adaptive: choose dt from an error estimate with tolerance ``time_tol``.
        time_tol: relative local error per step allowed by the adaptive control, in (0, 1).
        steady_tol: relative change per consolidation time below which the run is steady, in (0, 1).
        inflow: the waveform specification (:mod:`gelcell.case.inflow`).
        output_every: an XDMF frame every this many windows (and the last one).
        max_windows: the run stops with an error after this many windows.
        until_periodic: step a periodic inflow until the response repeats (see the module docstring).
        periodic_tol: the cycle-to-cycle change below which the response is periodic, in (0, 1).
        steps_per_period: windows per period (None: P / dt if dt is given, else ``STEPS_PER_PERIOD``).
        max_cycles: an until-periodic run ends (not converged) after this many periods, integer >= 2.
        waveform: the parsed ``inflow`` (a table repeated with until_periodic).
    """

    transient: bool = False
    dt: float | None = None
    t_end: float | None = None
    until_steady: bool = False
    scheme: str = "bdf2"
    adaptive: bool = False
    time_tol: float = 1e-3
    steady_tol: float = 1e-4
    inflow: str = "step"
    output_every: int = 5
    max_windows: int = 20000
    until_periodic: bool = False
    periodic_tol: float = 1e-3
    steps_per_period: int | None = None
    max_cycles: int = 50
    base_dir: str | None = dataclasses.field(default=None, compare=False)

    def __post_init__(self):
        problems: list[str] = []
        if not isinstance(self.transient, bool):
            problems.append(f"parameter 'time.transient' = {self.transient!r} must be true or false")
        _number(problems, "dt", self.dt)
        _number(problems, "t_end", self.t_end)
        for key in ("until_steady", "adaptive", "until_periodic"):
            if not isinstance(getattr(self, key), bool):
                problems.append(f"parameter 'time.{key}' = {getattr(self, key)!r} must be true or false")
        if self.scheme not in ("be", "bdf2"):
            problems.append(f"parameter 'time.scheme' = {self.scheme!r} must be 'be' (backward Euler) "
                            f"or 'bdf2'")
        _number(problems, "time_tol", self.time_tol, below=1.0)
        _number(problems, "steady_tol", self.steady_tol, below=1.0)
        _number(problems, "periodic_tol", self.periodic_tol, below=1.0)
        for key, least in (("output_every", 1), ("max_windows", 1), ("max_cycles", 2),
                           ("steps_per_period", MIN_STEPS_PER_PERIOD)):
            value = getattr(self, key)
            if key == "steps_per_period" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                problems.append(f"parameter 'time.{key}' = {value!r} must be an integer >= {least}")
        if problems:
            raise ParameterError("; ".join(problems))
        waveform = parse_inflow(self.inflow, self.base_dir)
        if self.until_periodic:
            waveform = self._periodic_waveform(waveform)
        object.__setattr__(self, "waveform", waveform)
        if waveform.kind == "table":
            # keep the table's absolute path, so that a resumed run finds it from anywhere
            path = self.inflow.partition(":")[2].strip()
            if not os.path.isabs(path):
                path = os.path.abspath(os.path.join(self.base_dir or os.getcwd(), path))
            object.__setattr__(self, "inflow", f"table:{path}")
        if self.dt is not None and self.t_end is not None and self.dt > self.t_end:
            raise ParameterError(f"parameter 'time.dt' = {self.dt:g} must not exceed 'time.t_end' = "
                                 f"{self.t_end:g}")
        if self.until_periodic:
            self._check_periodic_stepping(waveform.period)
        elif (self.until_steady or self.t_end is None) and waveform.constant_after is None:
            raise ParameterError(f"the inflow {self.inflow!r} never becomes constant, so the run cannot "
                                 f"stop when steady: give 'time.t_end' (--t-end)")

    waveform: Waveform = dataclasses.field(init=False, repr=False, compare=False, default=None)

    def _periodic_waveform(self, waveform: Waveform) -> Waveform:
        """The waveform an until-periodic run steps (a table repeated); refuse what conflicts with it."""
        for key, why in (("until_steady", "stops when steady"), ("adaptive", "chooses its own steps"),
                         ("t_end", "stops at a given time")):
            if getattr(self, key) not in (None, False):
                raise ParameterError(f"parameter 'time.{key}' = {getattr(self, key)!r}: a run with "
                                     f"'time.until_periodic' (--until-periodic) stops when the response repeats "
                                     f"with the period (at most 'time.max_cycles' periods), not one that {why}")
        if waveform.kind == "table":
            return waveform.repeated()
        if waveform.period is None:
            raise ParameterError(f"parameter 'inflow' = {self.inflow!r} is not periodic, which "
                                 f"'time.until_periodic' (--until-periodic) needs: give sine:MEAN,AMP,PERIOD, "
                                 f"square:ON,OFF or a table:FILE.csv whose first and last f are equal")
        return waveform

    def _check_periodic_stepping(self, period: float) -> None:
        """dt must divide the period, and agree with steps_per_period if both are given."""
        if self.dt is None:
            return
        steps = round(period / self.dt)
        if steps < MIN_STEPS_PER_PERIOD or abs(steps * self.dt - period) > 1e-9 * period:
            raise ParameterError(f"parameter 'time.dt' = {self.dt:g} must divide the inflow's period {period:g} "
                                 f"into at least {MIN_STEPS_PER_PERIOD} equal steps (e.g. --dt "
                                 f"{period / max(steps, MIN_STEPS_PER_PERIOD):.12g}), or give "
                                 f"'time.steps_per_period' instead")
        if self.steps_per_period is not None and self.steps_per_period != steps:
            raise ParameterError(f"parameter 'time.steps_per_period' = {self.steps_per_period} disagrees with "
                                 f"'time.dt' = {self.dt:g}, which divides the period {period:g} into {steps} "
                                 f"steps: give one of them")

    @property
    def stops_when_steady(self) -> bool:
        return not self.until_periodic and (self.until_steady or self.t_end is None)

    @property
    def period_steps(self) -> int | None:
        """Windows per period of an until-periodic run (None otherwise)."""
        if not self.until_periodic:
            return None
        if self.dt is not None:
            return round(self.waveform.period / self.dt)
        return self.steps_per_period or STEPS_PER_PERIOD

    @classmethod
    def from_dict(cls, table: typing.Mapping | None, overrides: typing.Mapping | None = None,
                  source: str = "input", base_dir: str | None = None) -> "TimeSettings":
        """From a ``[time]`` table and command-line overrides (``None`` values ignored)."""
        data = dict(table or {})
        unknown = [k for k in data if k not in TIME_KEYS]
        if unknown:
            raise ParameterError(f"unknown key 'time.{unknown[0]}' in {source} (known: {list(TIME_KEYS)})")
        data.update({k: v for k, v in (overrides or {}).items() if v is not None})
        return cls(**data, base_dir=base_dir)

    def to_dict(self) -> dict:
        """The settings as a ``[time]`` table (what ``from_dict`` reads back)."""
        return {k: getattr(self, k) for k in TIME_KEYS}

    def resolved(self, params: CaseParameters) -> dict:
        """dt, its bounds and the stop rule for ``params`` (defaults from :func:`time_scales`)."""
        scales = time_scales(params)
        tau = scales["consolidation"]
        if self.until_periodic:
            dt = self.waveform.period / self.period_steps
        elif self.dt is not None:
            dt = self.dt
        else:
            dt = scales["kelvin_voigt"] / 10 if self.adaptive else tau / 40
        return {"dt": dt, "dt_max": max(2.0 * tau, dt), "dt_min": 1e-6 * min(dt, scales["kelvin_voigt"]),
                "t_end": self.t_end, "until_steady": self.stops_when_steady, "scales": scales,
                "until_periodic": self.until_periodic, "steps_per_period": self.period_steps,
                "period": self.waveform.period if self.until_periodic else None}
