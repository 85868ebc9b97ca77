"""Range checks of parameters: the one-line message that names a parameter, its value and its range.

:func:`check_range` appends a message to a list of problems; :func:`raise_problems` raises them as
one :class:`~gelcell.errors.ParameterError`, so that every bad value of a table is reported at once.
"""

from __future__ import annotations

import math
import numbers

from gelcell.errors import ParameterError

__all__ = ["format_value", "range_text", "out_of_range", "check_range", "raise_problems", "poisson_ratio_of",
           "POISSON_WHY"]


# --------------------------------------------------------------------------- helpers
def format_value(x: float) -> str:
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        return repr(x)
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.6g}"


def range_text(lo: float, hi: float, lo_closed: bool = False, hi_closed: bool = False) -> str:
    return f"{'[' if lo_closed else '('}{format_value(lo)}, {format_value(hi)}{']' if hi_closed else ')'}"


def out_of_range(name: str, value, allowed: str, unit: str = "", why: str = "") -> str:
    u = f" {unit}" if unit else ""
    msg = f"parameter '{name}' = {format_value(value)}{u} is outside its allowed range {allowed}{u}"
    return msg + (f": {why}" if why else "")


def check_range(problems: list, name: str, value, lo: float = -math.inf, hi: float = math.inf,
           lo_closed: bool = False, hi_closed: bool = False, unit: str = "", why: str = "",
           integer: bool = False) -> None:
    """Append a message to ``problems`` unless ``value`` is a real number in the range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or (
            integer and not float(value).is_integer()):
        kind = "an integer" if integer else "a number"
        problems.append(f"parameter '{name}' = {value!r} must be {kind} in "
                        f"{range_text(lo, hi, lo_closed, hi_closed)}")
        return
    v = float(value)
    ok_lo = v >= lo if lo_closed else v > lo
    ok_hi = v <= hi if hi_closed else v < hi
    if not (ok_lo and ok_hi) or math.isnan(v):
        problems.append(out_of_range(name, value, range_text(lo, hi, lo_closed, hi_closed),
                                      unit, why))


def raise_problems(problems: list) -> None:
    if problems:
        raise ParameterError("\n".join(problems))


def poisson_ratio_of(lmbda: float, mu: float) -> float:
    """Poisson ratio of a Lamé pair, ν = λ / (2 (λ + μ)) (also for plane strain)."""
    return lmbda / (2.0 * (lmbda + mu))


POISSON_WHY = ("the Poisson ratio ν = λ/(2(λ+μ)) must lie in (-1, 0.5), i.e. μ > 0 and "
           "λ > -2μ/3 (positive bulk modulus)")
