"""The device's defaults of the partitioned coupling: interface coefficients, priors and the [coupling] table.

What a case file's ``[coupling]`` table leaves out is decided here, in one
place (:func:`coupling_config`, :func:`partitioned_config`): the Robin
coefficients of the fluid-gel and gel-cell conditions, the Gamma2
relaxation prior, the acceleration's settings, the convergence measure.
docs/coupling.md and docs/coupling-study.md give the measurements behind them.
"""

from __future__ import annotations

import json
import typing

import numpy as np

import coupling as cp
from gelcell.case import DEFAULT_GAMMA2, CaseParameters
from gelcell.errors import ParameterError
from gelcell.geometry import described, device_layout

__all__ = ["coupling_config", "partitioned_config", "default_robin_coefficient", "default_gamma2_coefficient",
           "gamma2_stiffness_ratio", "default_relaxation_prior", "reuse_key", "AUTO_PRIOR_MAX_UNKNOWNS",
           "TRANSIENT_PRIOR",
           "STEADY_SOLVER_OPTIONS"]


#: the device default uses the linearized prior up to this many interface unknowns (the default
#: mesh has 2440 (shear); at mesh-size 0.5, 4900, it would cost 7 s and 2.5 GB to save ~3 s)
AUTO_PRIOR_MAX_UNKNOWNS = 4000
#: whether time-dependent runs default to the linearized prior of their step (Device.window_scheme)
TRANSIENT_PRIOR = True


#: MUMPS options of a steady run's field solvers: the AMF ordering (ICNTL(7) = 2).  Its analyses
#: are faster than the automatic choice's (PORD for some matrices), its back-substitutions a few
#: per cent slower: a steady run factorises each operator once and back-substitutes ~5-20 times,
#: a time-dependent one ~1000 times, and keeps the automatic choice (docs/performance.md)
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
        contents = g.contents
        if contents is None:
            raise ValueError(f"geometry file {g.file!r} has not been read (gelcell.geometry.described)")
        depth, factor = contents.gel_depth, 1.0 if contents.enclosed_fluid else 10.0
    else:
        depth, factor = g.gel_length, 1.0
    viscosity = ph.ca / params.stress_scale
    return float(factor * viscosity * ph.xi * ph.phi_s0 * depth / (1.0 - ph.phi_s0))


def default_gamma2_coefficient(params: CaseParameters, diameter: float | None = None) -> float:
    """kappa = c (d/s) phi_s0 / r_c: the drained network's stiffness seen from the cell's surface.

    For a circular hole of radius r_c in an elastic plane of shear modulus
    mu_m, a radial surface displacement u_r needs the traction 2 mu_m u_r / r_c
    (c = 2); for a spherical cavity in an elastic space (a 3D device's cell)
    4 mu_m u_r / r_c (c = 4, u_r ~ 1/r^2).  The drained network has
    mu_m = phi_s0 mu_s.  A Robin coefficient equal to the Neumann side's
    stiffness makes the Robin-Neumann iteration contract whatever the cell's
    stiffness (docs/partitioning.md).
    """
    radius = 0.5 * (params.geometry.min_cell_diameter if diameter is None else diameter)
    c = 2.0 if getattr(params.geometry, "chip_height", None) is None else 4.0
    return float(c * params.displacement_scale / params.stress_scale * params.physics.phi_s0 / radius)


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
    d = params.to_input_dict()
    d["physics"].pop("ca", None)
    return json.dumps(d, sort_keys=True, default=str)


def coupling_config(scheme: str = "serial", acceleration: str = "iqn-ils", *, limit: float = 1e-10,
                    max_iterations: int = 200, with_cell: bool = True,
                    overrides: typing.Mapping | None = None, transient: bool = False,
                    params: CaseParameters | None = None, gamma2: str = DEFAULT_GAMMA2,
                    jacobian_prior: str | None = None) -> dict:
    """A ``[coupling]`` table for a device run (TOML ``overrides`` are merged on top).

    Convergence: every accelerated data to a relative residual ``limit``.  The
    acceleration's defaults are :func:`_acceleration_table`'s.
    ``jacobian_prior="linearized"`` (IQN): the prior of the quasi-Newton step
    is the Newton step on the coupled map linearised at rest from the three
    solvers' interface Jacobians (``coupling.linearization``); ``"none"``: the
    secant model alone; None: the device's choice (``Device.solve``:
    linearized where it pays).  Time-dependent runs (``transient``): each
    window starts from the quadratic extrapolation of the last three
    (docs/transient.md).
    """
    scheme = f"{scheme}-implicit" if scheme in ("serial", "parallel") else scheme
    order = _participant_names(with_cell)
    relaxation_prior = (default_relaxation_prior(params) if params is not None and not transient
                        and acceleration in ("iqn-ils", "iqn-imvj") and scheme == "serial-implicit"
                        and gamma2 == "dirichlet" else {})
    acc = _acceleration_table(acceleration, transient, relaxation_prior, jacobian_prior)
    config = {"scheme": scheme, "order": order, "max_iterations": max_iterations, "acceleration": acc,
              # the accelerated data: "*" measures forward data too, one more iteration (docs/coupling-study.md)
              "convergence": [{"type": "relative", "limit": limit, "data": "accelerated"}]}
    if transient:
        config["extrapolation_order"] = 2
    return _with_overrides(config, overrides or {}, transient)


def _acceleration_table(acceleration: str, transient: bool, relaxation_prior: dict,
                        jacobian_prior: str | None) -> dict:
    """The device's ``[coupling.acceleration]`` table for one acceleration type.

    Aitken: per-data scaling by the residual sums keeps one omega fair to
    every data.  IQN: fixed per-data value weights keep the kept secant
    columns consistent; steady IQN-ILS keeps the columns of the last 4
    solves (``time_windows_reused``, reused by a Ca sweep without the
    linearized prior); time-dependent IQN-ILS those of the last 40 windows
    (at most 500 columns: for a fixed dt the windows share one interface
    operator, docs/transient.md).  ``relaxation_prior`` (the Gamma2 prior of
    the plain Dirichlet-Neumann split, :func:`default_relaxation_prior`) is
    used unless the linearized prior replaces it.
    """
    acc: dict[str, typing.Any] = {"type": acceleration}
    if acceleration == "constant":
        acc["relaxation"] = 0.5
    elif acceleration == "aitken":
        acc.update(initial_relaxation=0.5, preconditioner={"type": "residual-sum"})
        if transient:
            # a window's map has real eigenvalues below 0 down to ~-12 at small dt (docs/transient.md):
            # omega must stay positive, which the secant estimate of this non-normal map does not ensure
            acc["positive_relaxation"] = True
    elif acceleration in ("iqn-ils", "iqn-imvj"):
        # residual-sum weights drift each iteration; on stiff cells IQN-ILS then stalls at ~1e-9
        acc.update(initial_relaxation=0.5, max_used_iterations=500 if transient else 100,
                   filter={"type": "qr2", "limit": 1e-3}, preconditioner={"type": "value"})
        if acceleration == "iqn-ils":
            acc["time_windows_reused"] = 40 if transient else 4
        if not transient and jacobian_prior is not None:
            acc["jacobian_prior"] = jacobian_prior
        if relaxation_prior and jacobian_prior != "linearized":
            acc["relaxation_prior"] = relaxation_prior
    return acc


def _with_overrides(config: dict, overrides: typing.Mapping, transient: bool = False) -> dict:
    """``config`` with a ``[coupling]`` table's keys on top.

    An ``acceleration`` table of another type replaces the device's; of the
    same type it is merged key by key, and a Jacobian prior it names drops
    the device's relaxation prior; a time-dependent run's linearized prior
    reuses no past windows' columns unless the table says how many.
    """
    acc = config["acceleration"]
    for key, value in overrides.items():
        if key == "acceleration" and isinstance(value, typing.Mapping):
            if value.get("type", acc["type"]) != acc["type"]:
                config["acceleration"] = dict(value)
            else:
                config["acceleration"] = {**acc, **value}
                if value.get("jacobian_prior", "none") != "none" and "relaxation_prior" not in value:
                    config["acceleration"].pop("relaxation_prior", None)     # ours, replaced by theirs
                if (transient and value.get("jacobian_prior") == "linearized" and "time_windows_reused" in acc
                        and "time_windows_reused" not in value):
                    # time-dependent: past windows' columns mislead the exact prior (docs/transient.md)
                    config["acceleration"]["time_windows_reused"] = 0
        else:
            config[key] = value
    return config


def partitioned_config(params: CaseParameters, coupling: typing.Mapping | None = None, transient: bool = False,
                       gamma2: str = DEFAULT_GAMMA2, ranks: int | None = None) -> dict:
    """The ``[coupling]`` table of a partitioned run: the device's defaults, then ``coupling`` on top, validated.

    ``coupling`` (a case file's table, with the command line's keys already in
    it) chooses the scheme (``scheme``, default ``"serial-implicit"``) and the
    acceleration (``acceleration.type``, default ``"iqn-ils"``, ``"none"`` for
    an explicit scheme), whose defaults the rest of the table then overrides.
    Raises :class:`ParameterError` naming the bad key or value, before
    anything is meshed; ``ranks``: the run's MPI ranks, which ``distribute``
    must fit.
    """
    params = described(params)
    table = dict(coupling or {})
    scheme = table.get("scheme", "serial-implicit")
    acceleration = table.get("acceleration")
    kind = acceleration.get("type") if isinstance(acceleration, typing.Mapping) else None
    if kind is None:
        kind = "none" if isinstance(scheme, str) and scheme.endswith("explicit") else "iqn-ils"
    config = coupling_config(scheme, kind, with_cell=params.with_cell, overrides=table, transient=transient,
                             params=params, gamma2=gamma2)
    try:
        loaded = cp.load_config(config)
    except ValueError as exc:
        raise ParameterError(f"the [coupling] table is invalid: {exc}") from None
    _check_order(loaded.order, params.with_cell)
    _check_distribute(loaded.distribute, params.with_cell, ranks)
    return config


def _participant_names(with_cell: bool) -> list[str]:
    return ["fluid", "gel", "cell"] if with_cell else ["fluid", "gel"]


def _check_distribute(spec: str, with_cell: bool, ranks: int | None = None) -> None:
    """``[coupling] distribute``, if given, puts each participant of the device in one group and (with
    ``ranks``) fits that many ranks (ParameterError naming the key and the allowed forms if not)."""
    if not spec:
        return
    try:
        cp.parse_distribution(spec, _participant_names(with_cell))
        if ranks is not None:
            cp.group_sizes(spec, ranks)
    except ValueError as exc:
        raise ParameterError(f"the [coupling] table is invalid: coupling.{exc}") from None


def device_distribution(spec: str | None, params: CaseParameters, comm: typing.Any) -> cp.Distribution | None:
    """The process groups of ``[coupling] distribute`` on ``comm`` (None for none): ParameterError, before
    anything is meshed, if the spec is malformed, misses or repeats a field, or does not fit the ranks."""
    if not spec:
        return None
    try:                    # Distribution parses the spec, checks the names and fits the ranks
        return cp.Distribution(spec, comm, names=_participant_names(params.with_cell))
    except ValueError as exc:
        raise ParameterError(f"the [coupling] table is invalid: coupling.{exc}") from None


def _check_order(order: typing.Sequence[str], with_cell: bool) -> None:
    """``[coupling] order``, if given, names each participant of the device once (ParameterError if not)."""
    names = _participant_names(with_cell)
    if order and sorted(order) != sorted(names):
        unknown = [o for o in order if o not in names]
        missing = [n for n in names if n not in order]
        why = (f"names unknown participants {unknown}" if unknown else f"misses participants {missing}")
        raise ParameterError(f"the [coupling] table is invalid: coupling.order = {list(order)!r} {why}; "
                             f"give every participant of this device once: {names}")
