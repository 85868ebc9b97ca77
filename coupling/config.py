"""Typed configuration of a coupling scheme, read from a TOML ``[coupling]`` table.

Every option is a field of a frozen dataclass with an explicit default;
values are validated when the dataclass is constructed, and
:func:`load_config` additionally rejects unknown keys (with a "did you mean"
hint) and options that do not belong to the chosen acceleration type.  Errors
are :class:`ValueError` naming the key, the offending value and what is
allowed.

Example (TOML)::

    [coupling]
    scheme = "serial-implicit"
    order = ["fluid", "gel", "cell"]
    max_iterations = 60

    [[coupling.convergence]]
    data = "Gamma1/traction"
    type = "relative"
    limit = 1e-8

    [coupling.acceleration]
    type = "iqn-ils"
    initial_relaxation = 0.1
    max_used_iterations = 40
    time_windows_reused = 8

    [coupling.acceleration.filter]
    type = "qr2"
    limit = 1e-2

    [coupling.acceleration.preconditioner]
    type = "residual-sum"
    freeze_after = -1
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
from dataclasses import dataclass, field
from typing import Any, Mapping

from coupling.convergence import MEASURE_FORMULAS, measure_type
from coupling.distributed import DISTRIBUTION_FORMS, parse_distribution

__all__ = [
    "SCHEMES", "STATE_RELOADS", "ACCEPTED_VALUES", "ACCELERATIONS", "FILTERS", "PRECONDITIONERS", "MEASURES",
    "ON_MAX_ITERATIONS", "JACOBIAN_PRIORS", "ACCELERATION_OPTIONS", "ConvergenceMeasureConfig",
    "FilterConfig", "PreconditionerConfig", "AccelerationConfig", "CouplingConfig", "load_config",
]

SCHEMES = ("serial-implicit", "parallel-implicit", "serial-explicit", "parallel-explicit")
#: when an implicit scheme restores the participant states within a time window
STATE_RELOADS = ("iteration", "window")
#: which values an accepted time window keeps for its accelerated data
ACCEPTED_VALUES = ("output", "input")
ACCELERATIONS = ("none", "constant", "aitken", "iqn-ils", "iqn-imvj")
FILTERS = ("none", "qr1", "qr2")
PRECONDITIONERS = ("none", "constant", "value", "residual", "residual-sum")
MEASURES = tuple(MEASURE_FORMULAS)
ON_MAX_ITERATIONS = ("raise", "return", "continue")
JACOBIAN_PRIORS = ("none", "linearized")

#: Keys of ``[coupling.acceleration]`` that each acceleration type accepts.
ACCELERATION_OPTIONS: dict[str, tuple[str, ...]] = {
    "none": ("type",),
    "constant": ("type", "relaxation"),
    "aitken": ("type", "initial_relaxation", "omega_min", "omega_max", "positive_relaxation", "preconditioner"),
    "iqn-ils": ("type", "initial_relaxation", "enforce_initial_relaxation", "max_used_iterations",
                "time_windows_reused", "relaxation_prior", "jacobian_prior", "filter", "preconditioner"),
    "iqn-imvj": ("type", "initial_relaxation", "enforce_initial_relaxation", "max_used_iterations",
                 "relaxation_prior", "jacobian_prior", "filter", "preconditioner"),
}


# --------------------------------------------------------------------------- checks
def _fmt(value: Any) -> str:
    return repr(value)


def _choice(where: str, key: str, value: Any, allowed: tuple[str, ...]) -> str:
    if not isinstance(value, str) or value not in allowed:
        hint = ""
        if isinstance(value, str):
            close = difflib.get_close_matches(value, allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"{where}.{key} = {_fmt(value)} is not allowed{hint}; "
                         f"allowed values: {', '.join(repr(a) for a in allowed)}")
    return value


def _integer(where: str, key: str, value: Any, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}.{key} = {_fmt(value)} must be an integer")
    if minimum is not None and value < minimum:
        raise ValueError(f"{where}.{key} = {value} must be >= {minimum}")
    return value


def _real(where: str, key: str, value: Any, *, positive: bool = False, nonnegative: bool = False,
          allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}.{key} = {_fmt(value)} must be a number")
    value = float(value)
    if math.isnan(value) or (math.isinf(value) and not allow_inf):
        raise ValueError(f"{where}.{key} = {value} must be finite")
    if positive and not value > 0.0:
        raise ValueError(f"{where}.{key} = {value} must be > 0")
    if nonnegative and not value >= 0.0:
        raise ValueError(f"{where}.{key} = {value} must be >= 0")
    return value


def _boolean(where: str, key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{where}.{key} = {_fmt(value)} must be true or false")
    return value


def _string(where: str, key: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise ValueError(f"{where}.{key} = {_fmt(value)} must be a non-empty string")
    return value


def _check_keys(where: str, table: Mapping[str, Any], allowed: tuple[str, ...],
                required: tuple[str, ...] = (), meanings: Mapping[str, str] | None = None) -> None:
    """Refuse unknown keys: with the key of the same meaning (``meanings``), else a look-alike key."""
    if not isinstance(table, Mapping):
        raise ValueError(f"{where} must be a table (dict), got {type(table).__name__}")
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            if meanings and key in meanings:
                hint = f" ({meanings[key]})"
            raise ValueError(f"{where}: unknown key {key!r}{hint}; allowed keys: "
                             f"{', '.join(allowed)}")
    for key in required:
        if key not in table:
            raise ValueError(f"{where}: missing required key {key!r}")


#: keys of another framework's convergence criteria, by what they mean here
_CONVERGENCE_KEY_MEANINGS = {
    "tolerance": "CoCoNuT's tolerance is the limit here: 'limit'",
    "order": "CoCoNuT's order of the norm: the norms here are Euclidean (order 2)",
    "mesh": "preCICE's mesh of the data: here a data is named by 'data' alone",
    "abs-limit": "preCICE's absolute-or-relative limits: give an 'absolute' and a 'relative' measure, "
                 "each with suffices = true",
    "rel-limit": "preCICE's absolute-or-relative limits: give an 'absolute' and a 'relative' measure, "
                 "each with suffices = true",
    "strict": "preCICE's strict: here max_iterations with on_max_iterations = 'raise'",
}


def _field_names(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


# --------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class ConvergenceMeasureConfig:
    """One convergence measure on one coupling data (``[[coupling.convergence]]``).

    With ``r = x̃ - x`` the residual of the data in the current iteration (for
    forward data of a serial scheme: the change since the previous iteration)
    and ``‖·‖`` the Euclidean norm over all points and components:

    * ``"absolute"``: ``‖r‖ < limit`` (beware: not scale invariant);
    * ``"relative"``: ``‖r‖ / ‖x̃‖ < limit`` (``x̃`` the newly written value);
    * ``"residual-relative"``: ``‖r‖ / ‖r_1‖ < limit`` with ``r_1`` the residual
      of the first iteration of the time window.

    preCICE's names of the same measures (``"absolute-convergence-measure"``,
    ``"relative-convergence-measure"``, ``"residual-relative-convergence-measure"``)
    are accepted and stored as the short name; another framework's name is
    refused with the measure of its meaning (CoCoNuT's ``relative_norm`` is
    ``"residual-relative"``).

    Attributes:
        type: One of :data:`MEASURES`.
        limit: Threshold, > 0.
        data: Name of the data, ``"*"`` for every exchanged data, or
            ``"accelerated"`` for the accelerated data (serial scheme: those
            read before they are written, whose residual is the fixed-point
            residual; parallel scheme: every data).
        suffices: If true, meeting this measure alone declares convergence.
    """

    type: str
    limit: float
    # "*" also measures the forward data, whose change lags: up to 2x the iterations (docs/coupling-study.md)
    data: str = "accelerated"
    suffices: bool = False

    def __post_init__(self) -> None:
        where = f"coupling.convergence[data={self.data!r}]"
        object.__setattr__(self, "type", measure_type(self.type, where))
        object.__setattr__(self, "limit", _real(where, "limit", self.limit, positive=True))
        _string(where, "data", self.data)
        _boolean(where, "suffices", self.suffices)


@dataclass(frozen=True)
class FilterConfig:
    """QR filter of the quasi-Newton least-squares system (``[coupling.acceleration.filter]``).

    Columns of ``V`` are ordered newest first.  ``"qr1"`` deletes column ``i``
    while ``|R_ii| < limit * ‖R‖_F``; ``"qr2"`` re-orthogonalises the columns
    newest first and deletes a column whose component orthogonal to the newer
    ones is below ``limit`` times its norm (both as in preCICE).

    Attributes:
        type: One of :data:`FILTERS`.
        limit: Filter threshold in (0, 1).
    """

    # QR2 at 1e-2, 1e-3, 1e-4 within 8 %; no filter up to 1.5x, QR1 4-10x (docs/coupling-study.md)
    type: str = "qr2"
    limit: float = 1e-2

    def __post_init__(self) -> None:
        where = "coupling.acceleration.filter"
        _choice(where, "type", self.type, FILTERS)
        limit = _real(where, "limit", self.limit, positive=True)
        if limit >= 1.0:
            raise ValueError(f"{where}.limit = {limit} must be < 1")
        object.__setattr__(self, "limit", limit)


@dataclass(frozen=True)
class PreconditionerConfig:
    """Per-data scaling of the accelerated vector (``[coupling.acceleration.preconditioner]``).

    The least-squares problems and Aitken's formula use ``w ∘ r`` with one
    weight per data (constant over its entries):

    * ``"none"``: ``w_d = 1``;
    * ``"constant"``: ``w_d = 1 / factors[d]`` (``factors`` must name every
      accelerated data);
    * ``"value"``: ``w_d = 1 / ‖x_d‖`` from the values at the end of the
      previous window (within the first window: of the current iterate);
    * ``"residual"``: ``w_d = 1 / ‖r_d‖`` of the current iteration;
    * ``"residual-sum"``: ``w_d = 1 / Σ_k ‖r_d^k‖ / ‖r^k‖`` summed over the
      iterations of the current window.

    Attributes:
        type: One of :data:`PRECONDITIONERS`.
        factors: Data name -> scaling factor, for ``"constant"`` only.
        freeze_after: Stop updating the weights after this many time windows
            (-1: never).
    """

    type: str = "none"
    factors: Mapping[str, float] = field(default_factory=dict)
    freeze_after: int = -1

    def __post_init__(self) -> None:
        where = "coupling.acceleration.preconditioner"
        _choice(where, "type", self.type, PRECONDITIONERS)
        if not isinstance(self.factors, Mapping):
            raise ValueError(f"{where}.factors = {self.factors!r} must be a table data -> factor")
        factors = {str(k): _real(where, f"factors[{k!r}]", v, positive=True)
                   for k, v in self.factors.items()}
        if self.type == "constant" and not factors:
            raise ValueError(f"{where}.factors must name every accelerated data when type = 'constant'")
        if self.type != "constant" and factors:
            raise ValueError(f"{where}.factors is only allowed with type = 'constant' "
                             f"(type = {self.type!r})")
        object.__setattr__(self, "factors", factors)
        freeze = _integer(where, "freeze_after", self.freeze_after)
        if freeze == 0 or freeze < -1:
            raise ValueError(f"{where}.freeze_after = {freeze} must be -1 (never) or >= 1")


@dataclass(frozen=True)
class AccelerationConfig:
    """Acceleration of the fixed-point iteration (``[coupling.acceleration]``).

    Attributes:
        type: One of :data:`ACCELERATIONS`.
        relaxation: Constant under-relaxation factor ω (``"constant"``).
        initial_relaxation: ω of the first iteration (Aitken, IQN) and the
            fallback relaxation of IQN when no column is usable.
        omega_min: Lower bound of |ω| for Aitken (sign kept).
        omega_max: Upper bound of |ω| for Aitken (``inf``: unbounded).
        positive_relaxation: Aitken: use |ω|.  Right when the fixed-point
            map's eigenvalues are real and below 1 (the overshoot of a
            Dirichlet–Neumann-type split): the secant estimate of a non-normal
            map can flip the sign of ω there, and the iteration then stalls.
        max_used_iterations: IQN: maximum number of kept columns (all windows).
        time_windows_reused: IQN-ILS: number of past windows whose columns are kept.
        enforce_initial_relaxation: IQN: relax (instead of a quasi-Newton step
            with reused information) in the first iteration of every window.
        relaxation_prior: IQN: the initial inverse Jacobian of the
            generalised-Broyden update, ``J0 = diag(1 - ω_d)``: data ``d`` is
            relaxed with ``ω_d`` in the directions the secant columns do not
            span (instead of IQN-ILS's plain ``x̃``, i.e. ``ω = 1``).  A table
            data name -> ω; the key ``"*"`` sets every other data (default 1).
            Empty (default): no prior, the classical IQN-ILS/IMVJ.
        jacobian_prior: IQN: ``"linearized"``: the prior is the Newton step
            on the coupled map linearised from every participant's
            ``jacobian()`` (:class:`coupling.linearization.LinearizedPrior`),
            instead of a relaxation; ``"none"`` (default): no such prior.
            Excludes ``relaxation_prior``.
        filter: QR filter options (IQN).
        preconditioner: Scaling options (Aitken, IQN).
    """

    type: str = "none"
    relaxation: float = 0.5
    initial_relaxation: float = 0.5
    omega_min: float = 0.0
    omega_max: float = math.inf
    positive_relaxation: bool = False
    max_used_iterations: int = 50
    time_windows_reused: int = 0
    enforce_initial_relaxation: bool = False
    relaxation_prior: Mapping[str, float] = field(default_factory=dict)
    jacobian_prior: str = "none"
    filter: FilterConfig = field(default_factory=FilterConfig)
    preconditioner: PreconditionerConfig = field(default_factory=PreconditionerConfig)

    def __post_init__(self) -> None:
        where = "coupling.acceleration"
        _choice(where, "type", self.type, ACCELERATIONS)
        object.__setattr__(self, "relaxation", _real(where, "relaxation", self.relaxation, positive=True))
        object.__setattr__(self, "initial_relaxation",
                           _real(where, "initial_relaxation", self.initial_relaxation, positive=True))
        lo = _real(where, "omega_min", self.omega_min, nonnegative=True)
        hi = _real(where, "omega_max", self.omega_max, positive=True, allow_inf=True)
        if lo > hi:
            raise ValueError(f"{where}.omega_min = {lo} must be <= omega_max = {hi}")
        object.__setattr__(self, "omega_min", lo)
        object.__setattr__(self, "omega_max", hi)
        _boolean(where, "positive_relaxation", self.positive_relaxation)
        _integer(where, "max_used_iterations", self.max_used_iterations, minimum=1)
        _integer(where, "time_windows_reused", self.time_windows_reused, minimum=0)
        _boolean(where, "enforce_initial_relaxation", self.enforce_initial_relaxation)
        if not isinstance(self.relaxation_prior, Mapping):
            raise ValueError(f"{where}.relaxation_prior = {self.relaxation_prior!r} must be a table "
                             f"data -> relaxation factor (key '*': every other data)")
        object.__setattr__(self, "relaxation_prior",
                           {str(k): _real(where, f"relaxation_prior[{k!r}]", v, positive=True)
                            for k, v in self.relaxation_prior.items()})
        _choice(where, "jacobian_prior", self.jacobian_prior, JACOBIAN_PRIORS)
        if self.jacobian_prior != "none" and self.relaxation_prior:
            raise ValueError(f"{where}: jacobian_prior = {self.jacobian_prior!r} and relaxation_prior are "
                             f"two priors of the same step; give one of them")
        if not isinstance(self.filter, FilterConfig):
            raise ValueError(f"{where}.filter must be a FilterConfig, got {self.filter!r}")
        if not isinstance(self.preconditioner, PreconditionerConfig):
            raise ValueError(f"{where}.preconditioner must be a PreconditionerConfig, "
                             f"got {self.preconditioner!r}")


@dataclass(frozen=True)
class CouplingConfig:
    """Configuration of a coupling scheme (the ``[coupling]`` table).

    Attributes:
        scheme: One of :data:`SCHEMES`.
        order: Participant names in execution order (serial schemes: the
            Gauss–Seidel order).  Empty: the order in which participants are
            passed to :func:`coupling.build_scheme`.
        max_iterations: Maximum coupling iterations per time window.
        min_iterations: Minimum coupling iterations per time window.
        on_max_iterations: ``"raise"`` a :class:`CouplingNotConvergedError`,
            ``"return"`` the result with ``converged=False``, or ``"continue"``
            with the next time window (preCICE's behaviour).
        divergence_factor: Raise :class:`CouplingDivergedError` when a
            residual norm exceeds this factor times its reference (the first
            residual of the window, floored at 1e-6 times the first value
            norm); ``inf`` disables the growth test (NaN/Inf always raise).
        convergence: The convergence measures; all must be met (or one with
            ``suffices = true``).  Implicit schemes need at least one.
        acceleration: Acceleration options.
        verbose: Print one progress line per iteration (rank 0 only).
        record_data: Record every participant's inputs and outputs per
            iteration (for :func:`coupling.replay`).
        check_replicated: Under MPI, check that participants' interface points
            and outputs are identical on all ranks (debugging aid; one
            allgather per array).
        extrapolation_order: Initial guess of a time window's data: 0 = the
            previous window's converged values, 1 = their linear extrapolation
            from the last two windows, 2 = quadratic from the last three
            (variable dt allowed; preCICE's ``extrapolation-order``).
        state_reload: When an implicit scheme restores the participants'
            states in a time window: ``"iteration"`` = before every iteration
            after the first (preCICE's checkpoint reading: each iteration
            starts from the state at the window's start); ``"window"`` = only
            when the whole window is retaken (:meth:`CouplingScheme.restore`),
            so that each solve continues from the previous iteration's state.
            ``"window"`` needs participants whose ``advance(t, dt)`` is
            idempotent within a window and whose state only seeds the next
            solve (e.g. a Newton initial guess, the time history kept apart).
            With ``"window"``, ``save_state``/``load_state`` are not called
            within a window at all.
        accepted_value: The value of the accelerated data that an accepted
            window keeps (the next window's start, what :meth:`latest`
            returns and ``end_window`` receives): ``"output"`` = ``x̃``, what
            the participants wrote in the last iteration (preCICE's choice);
            ``"input"`` = ``x``, what they read in it, the values their states
            were computed from.  The two differ by the last residual: less
            than the convergence limit in a converged window, up to the whole
            residual in a window accepted unconverged (``on_max_iterations =
            "continue"``).  Forward data (serial schemes) are the last written
            values either way.
        distribute: The participants' process groups,
            ``"name[+name...][:ranks],..."`` (:mod:`coupling.distributed`);
            ``""`` (default): every participant on every rank.  The
            application builds the :class:`~coupling.distributed.Distribution`
            from it, constructs its group's participants and passes both to
            :func:`~coupling.schemes.build_scheme`.
    """

    scheme: str = "serial-implicit"
    order: tuple[str, ...] = ()
    max_iterations: int = 50
    min_iterations: int = 1
    on_max_iterations: str = "raise"
    divergence_factor: float = 1e8
    convergence: tuple[ConvergenceMeasureConfig, ...] = ()
    acceleration: AccelerationConfig = field(default_factory=AccelerationConfig)
    verbose: bool = True
    record_data: bool = False
    check_replicated: bool = False
    extrapolation_order: int = 0
    # "window" took as many or more iterations, and diverged with reused windows (docs/coupling-study.md)
    state_reload: str = "iteration"
    accepted_value: str = "output"
    distribute: str = ""

    def __post_init__(self) -> None:
        where = "coupling"
        if not isinstance(self.distribute, str):
            raise ValueError(f"{where}.distribute = {self.distribute!r} must be a string: {DISTRIBUTION_FORMS}")
        if self.distribute:
            try:
                parse_distribution(self.distribute)   # the form; the names and ranks: Distribution
            except ValueError as exc:
                raise ValueError(f"{where}.{exc}") from None
        _choice(where, "state_reload", self.state_reload, STATE_RELOADS)
        _choice(where, "accepted_value", self.accepted_value, ACCEPTED_VALUES)
        _integer(where, "extrapolation_order", self.extrapolation_order, minimum=0)
        if self.extrapolation_order > 2:
            raise ValueError(f"{where}.extrapolation_order = {self.extrapolation_order} must be 0, 1 or 2")
        _choice(where, "scheme", self.scheme, SCHEMES)
        if isinstance(self.order, str) or not all(isinstance(o, str) and o for o in self.order):
            raise ValueError(f"{where}.order = {self.order!r} must be a list of participant names")
        if len(set(self.order)) != len(self.order):
            raise ValueError(f"{where}.order = {list(self.order)!r} names a participant twice")
        object.__setattr__(self, "order", tuple(self.order))
        _integer(where, "max_iterations", self.max_iterations, minimum=1)
        _integer(where, "min_iterations", self.min_iterations, minimum=1)
        if self.min_iterations > self.max_iterations:
            raise ValueError(f"{where}.min_iterations = {self.min_iterations} must be <= "
                             f"max_iterations = {self.max_iterations}")
        _choice(where, "on_max_iterations", self.on_max_iterations, ON_MAX_ITERATIONS)
        factor = _real(where, "divergence_factor", self.divergence_factor, positive=True,
                       allow_inf=True)
        if factor <= 1.0:
            raise ValueError(f"{where}.divergence_factor = {factor} must be > 1 (inf disables)")
        object.__setattr__(self, "divergence_factor", factor)
        measures = tuple(self.convergence)
        for m in measures:
            if not isinstance(m, ConvergenceMeasureConfig):
                raise ValueError(f"{where}.convergence entries must be ConvergenceMeasureConfig, "
                                 f"got {m!r}")
        object.__setattr__(self, "convergence", measures)
        if not isinstance(self.acceleration, AccelerationConfig):
            raise ValueError(f"{where}.acceleration must be an AccelerationConfig, "
                             f"got {self.acceleration!r}")
        if self.scheme.endswith("explicit") and self.acceleration.type != "none":
            raise ValueError(f"{where}.acceleration.type = {self.acceleration.type!r} is not "
                             f"allowed with scheme = {self.scheme!r}; allowed values: 'none'")
        for key in ("verbose", "record_data", "check_replicated"):
            _boolean(where, key, getattr(self, key))

    @property
    def implicit(self) -> bool:
        """True for the implicit (iterating) schemes."""
        return self.scheme.endswith("implicit")

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], where: str = "coupling") -> "CouplingConfig":
        """Build and validate a configuration from a ``[coupling]`` table (dict).

        Raises:
            ValueError: On unknown keys, missing required keys, wrong types or
                values outside the allowed set; the message names the key.
        """
        _check_keys(where, table, _field_names(cls))
        kwargs = dict(table)
        if "order" in kwargs:
            order = kwargs["order"]
            if not isinstance(order, (list, tuple)):
                raise ValueError(f"{where}.order = {order!r} must be a list of participant names")
            kwargs["order"] = tuple(order)
        if "convergence" in kwargs:
            entries = kwargs["convergence"]
            if isinstance(entries, Mapping):
                entries = [entries]
            if not isinstance(entries, (list, tuple)):
                raise ValueError(f"{where}.convergence must be a list of tables "
                                 f"([[coupling.convergence]]), got {entries!r}")
            parsed = []
            for i, entry in enumerate(entries):
                sub = f"{where}.convergence[{i}]"
                _check_keys(sub, entry, _field_names(ConvergenceMeasureConfig),
                            required=("type", "limit"), meanings=_CONVERGENCE_KEY_MEANINGS)
                parsed.append(ConvergenceMeasureConfig(**entry))
            kwargs["convergence"] = tuple(parsed)
        if "acceleration" in kwargs:
            kwargs["acceleration"] = _acceleration_from_dict(kwargs["acceleration"],
                                                             f"{where}.acceleration")
        return cls(**kwargs)


def _acceleration_from_dict(table: Mapping[str, Any], where: str) -> AccelerationConfig:
    _check_keys(where, table, _field_names(AccelerationConfig))
    kind = _choice(where, "type", table["type"] if "type" in table else AccelerationConfig.type,
                   ACCELERATIONS)
    allowed = ACCELERATION_OPTIONS[kind]
    for key in table:
        if key not in allowed:
            raise ValueError(f"{where}.{key} is not an option of type = {kind!r}; options of "
                             f"{kind!r}: {', '.join(allowed)}")
    kwargs = dict(table)
    if "filter" in kwargs:
        sub = f"{where}.filter"
        _check_keys(sub, kwargs["filter"], _field_names(FilterConfig))
        kwargs["filter"] = FilterConfig(**kwargs["filter"])
    if "preconditioner" in kwargs:
        sub = f"{where}.preconditioner"
        _check_keys(sub, kwargs["preconditioner"], _field_names(PreconditionerConfig))
        kwargs["preconditioner"] = PreconditionerConfig(**kwargs["preconditioner"])
    return AccelerationConfig(**kwargs)


def load_config(source: "str | os.PathLike | Mapping[str, Any] | CouplingConfig",
                table: str | None = "coupling") -> CouplingConfig:
    """Read and validate a coupling configuration.

    Args:
        source: A :class:`CouplingConfig` (returned unchanged), a dict holding
            the ``[coupling]`` table itself, or the path of a TOML file.
        table: For a TOML file, the (dotted) name of the table holding the
            coupling options; ``None`` uses the whole file.

    Returns:
        The validated :class:`CouplingConfig`.

    Raises:
        ValueError: On invalid configuration (the message names the key, the
            value and what is allowed), or if the TOML file has no such table.
    """
    if isinstance(source, CouplingConfig):
        return source
    if isinstance(source, Mapping):
        return CouplingConfig.from_dict(source)
    path = os.fspath(source)
    with open(path, "rb") as fh:
        document = tomllib.load(fh)
    where = "<file>"
    if table is not None:
        for part in table.split("."):
            if not isinstance(document, Mapping) or part not in document:
                raise ValueError(f"{path}: no [{table}] table")
            document = document[part]
        where = table
    return CouplingConfig.from_dict(document, where=where)
