"""Inflow waveforms f(t): the device's inflow is V0 f(t) (model.md section 8).

Specifications (``--inflow`` and the ``inflow`` key of the ``[time]`` table);
times are in the paper's time unit L0/V0, like ``dt`` and ``t_end``:

    step                    f = 1 for t >= 0 (switched on at t = 0; the default)
    ramp:T                  f = min(t/T, 1)
    sine:MEAN,AMP,PERIOD    f = MEAN + AMP sin(2 pi t / PERIOD)
    square:ON,OFF           f = 1 for ON, then 0 for OFF, repeated (on first)
    table:FILE.csv          (t, f) rows, linear in between, constant beyond the ends
                            (a regular UTF-8 CSV file of at most MAX_TABLE_BYTES)

Periodic waveforms (:attr:`Waveform.period`, what ``--until-periodic`` needs):
a sine (period PERIOD), a square wave (ON + OFF), and a table whose first and
last f are equal: :meth:`Waveform.repeated` makes it repeat with its span
t_last - t_first as the period, f(t) = f_table(t_first + mod(t - t_first, span)).
A time within 1e-9 of a period of an edge (a square wave's switch, a repeated
table's start) is taken to be on it, so that samples at the same phase of
different periods see the same f despite round-off in t.

Every spec is parsed and checked (:func:`parse_inflow`) before anything is
meshed: a bad spec raises :class:`~gelcell.errors.ParameterError` naming
``inflow`` and what is allowed.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os

import numpy as np

from gelcell.case.casefile import read_bounded
from gelcell.errors import ParameterError

__all__ = ["Waveform", "parse_inflow", "WAVEFORMS", "MAX_TABLE_BYTES"]

WAVEFORMS = ("step", "ramp:T", "sine:MEAN,AMP,PERIOD", "square:ON,OFF", "table:FILE.csv")
#: a table of (t, f) rows is at most a few hundred kB (8 MiB: some 300 000 rows); anything larger is not one
MAX_TABLE_BYTES = 8 << 20


@dataclasses.dataclass(frozen=True)
class Waveform:
    """A parsed inflow waveform; call it with t (or an array of t).

    Attributes:
        kind: ``"step"``, ``"ramp"``, ``"sine"``, ``"square"`` or ``"table"``.
        spec: the specification it was parsed from.
        values: its numbers (ramp time; mean, amplitude, period; on, off).
        table: ``(t, f)`` arrays of a table.
    """

    kind: str
    spec: str
    values: tuple[float, ...] = ()
    table: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    #: a table repeated with its span as the period (:meth:`repeated`); else constant beyond its ends
    repeat: bool = False

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        if self.kind == "step":
            f = np.ones_like(t)
        elif self.kind == "ramp":
            f = np.minimum(t / self.values[0], 1.0)
        elif self.kind == "sine":
            mean, amp, period = self.values
            f = mean + amp * np.sin(2 * np.pi * t / period)
        elif self.kind == "square":
            on, off = self.values
            f = np.where(_phase(t, 0.0, on + off, (on,)) < on, 1.0, 0.0)
        elif self.repeat:
            times, values = self.table
            f = np.interp(times[0] + _phase(t, times[0], times[-1] - times[0]), times, values)
        else:
            f = np.interp(t, *self.table)
        return float(f) if f.ndim == 0 else f

    @property
    def periodic_table(self) -> bool:
        """A table that can repeat: at least two rows and its first and last f equal."""
        return self.kind == "table" and len(self.table[0]) >= 2 and self.table[1][0] == self.table[1][-1]

    def repeated(self) -> "Waveform":
        """This table repeated with its span as the period (raise ParameterError if it cannot repeat)."""
        if not self.periodic_table:
            raise _bad(self.spec, "a table repeats only if it has two rows or more and its first and last f "
                                  "are equal (its period is then its time span)")
        return dataclasses.replace(self, repeat=True)

    @property
    def constant_after(self) -> float | None:
        """The time after which f is constant (None if it never is, e.g. a sine)."""
        if self.kind == "step":
            return 0.0
        if self.kind == "ramp":
            return self.values[0]
        if self.kind == "table":
            return None if self.repeat and len(set(self.table[1])) > 1 else self.table[0][-1]
        if self.kind == "sine" and self.values[1] == 0.0:
            return 0.0
        return None

    @property
    def period(self) -> float | None:
        """The period of a sine, a square wave or a repeated table; None for the others."""
        if self.kind == "sine":
            return self.values[2]
        if self.kind == "square":
            return self.values[0] + self.values[1]
        if self.repeat:
            return self.table[0][-1] - self.table[0][0]
        return None

    def breakpoints(self, t0: float, t1: float) -> list[float]:
        """Times in (t0, t1) where f has a kink or a jump (ramp end, square edges, table rows)."""
        if self.kind == "ramp":
            pts = [self.values[0]]
        elif self.kind == "square":
            on, off = self.values
            period = on + off
            k0 = math.floor(t0 / period)
            pts = [k * period + s for k in range(k0, k0 + int((t1 - t0) / period) + 2) for s in (0.0, on)]
        elif self.repeat:
            times = np.asarray(self.table[0])
            span = times[-1] - times[0]
            k0 = math.floor((t0 - times[0]) / span)
            pts = [p + k * span for k in range(k0, k0 + int((t1 - t0) / span) + 2) for p in times]
        elif self.kind == "table":
            pts = list(self.table[0])
        else:
            pts = []
        return sorted(p for p in pts if t0 < p < t1)


def _phase(t: np.ndarray, origin: float, period: float, edges: tuple[float, ...] = ()) -> np.ndarray:
    """mod(t - origin, period) in [0, period), snapped onto 0 and onto ``edges`` within 1e-9 period."""
    phase = np.mod(t - origin, period)
    snap = 1e-9 * period
    phase = np.where(period - phase < snap, 0.0, phase)
    for edge in edges:
        phase = np.where(np.abs(phase - edge) < snap, edge, phase)
    return phase


def _bad(spec: str, why: str) -> ParameterError:
    return ParameterError(f"parameter 'inflow' = {spec!r}: {why}; allowed: {', '.join(WAVEFORMS)} "
                          f"(times in the paper's unit L0/V0)")


def _numbers(spec: str, text: str, count: int) -> tuple[float, ...]:
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != count:
        raise _bad(spec, f"expected {count} number(s) after ':'")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise _bad(spec, f"{text!r} is not {count} comma-separated number(s)") from None
    if not all(math.isfinite(v) for v in values):
        raise _bad(spec, "the numbers must be finite")
    return values


def _read_table(spec: str, path: str, base_dir: str | None) -> tuple[tuple[float, ...], tuple[float, ...]]:
    full = path if os.path.isabs(path) or base_dir is None else os.path.join(base_dir, path)
    try:
        data = read_bounded(full, "inflow table", MAX_TABLE_BYTES)
    except ParameterError as exc:
        raise _bad(spec, str(exc)) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _bad(spec, f"the table {full!r} is not UTF-8 text (byte {exc.start}): a table is CSV text") from None
    if "\x00" in text:
        raise _bad(spec, f"the table {full!r} holds NUL bytes: a table is CSV text")
    rows = [r for r in csv.reader(text.splitlines()) if r and not r[0].lstrip().startswith("#")]
    if rows:
        try:
            float(rows[0][0])
        except ValueError:
            rows = rows[1:]                      # a header line
    if not rows:
        raise _bad(spec, f"the table {full!r} has no (t, f) rows")
    try:
        data = np.array([[float(r[0]), float(r[1])] for r in rows])
    except (ValueError, IndexError):
        raise _bad(spec, f"every row of {full!r} must hold two numbers t, f") from None
    if not np.all(np.isfinite(data)):
        raise _bad(spec, f"the table {full!r} contains NaN or Inf")
    t, f = data[:, 0], data[:, 1]
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0))
        raise _bad(spec, f"the times of {full!r} must increase strictly (row {k + 2}: t = {t[k + 1]:g} "
                         f"after {t[k]:g})")
    if t[0] > 0:
        raise _bad(spec, f"the table {full!r} must start at t <= 0 (it starts at {t[0]:g})")
    return tuple(t.tolist()), tuple(f.tolist())


def parse_inflow(spec: str, base_dir: str | None = None) -> Waveform:
    """Parse an inflow specification (see the module docstring); raise ParameterError if it is bad.

    ``base_dir``: directory that a relative table path is relative to (the
    config file's directory; the working directory if None).
    """
    if not isinstance(spec, str) or not spec.strip():
        raise _bad(str(spec), "empty or not a string")
    spec = spec.strip()
    kind, _, rest = spec.partition(":")
    kind = kind.strip().lower()
    if kind == "step":
        if rest:
            raise _bad(spec, "'step' takes no numbers")
        return Waveform("step", spec)
    if kind == "ramp":
        (T,) = _numbers(spec, rest, 1)
        if T <= 0:
            raise _bad(spec, "the ramp time T must be > 0")
        return Waveform("ramp", spec, (T,))
    if kind == "sine":
        mean, amp, period = _numbers(spec, rest, 3)
        if period <= 0:
            raise _bad(spec, "the PERIOD must be > 0")
        return Waveform("sine", spec, (mean, amp, period))
    if kind == "square":
        on, off = _numbers(spec, rest, 2)
        if on <= 0 or off < 0:
            raise _bad(spec, "ON must be > 0 and OFF >= 0")
        return Waveform("square", spec, (on, off))
    if kind == "table":
        if not rest.strip():
            raise _bad(spec, "'table' needs a file: table:FILE.csv")
        return Waveform("table", spec, table=_read_table(spec, rest.strip(), base_dir))
    raise _bad(spec, f"unknown waveform {kind!r}")
