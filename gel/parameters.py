"""Parameters of the poroelastic gel solver (dimensionless groups and unit choice)."""

from __future__ import annotations

import dataclasses
import math

__all__ = ["GelParameters"]


@dataclasses.dataclass(frozen=True)
class GelParameters:
    """Dimensionless gel parameters (model.md section 2) and the solver's units.

    Defaults are the baseline of model.md section 5 (Table 1 of the source
    paper) in the paper's unscaled units (s = d = 1).

    Attributes:
        phi_s0: reference solid volume fraction, in (0, 1).
        xi: drag coefficient xi L0^2 / mu, > 0.
        lambda_s: network Lame modulus over the network shear modulus mu_s,
            > -2/3 (Poisson ratio > -1).
        beta: slip coefficient of I16/I17, beta mu / L0, > 0.
        eta: interfacial permeability coefficient of I15, mu eta / L0, > 0.
        Ca: capillary-like number mu V0 / (L0 mu_s), > 0.
        stress_scale: the stress unit ``s`` of the solver in units of mu_s
            (1: the paper's units; Ca: the viscous unit mu V0 / L0), > 0.
        displacement_scale: the displacement unit ``d`` in units of L0
            (1: the paper's units; Ca: the unit Ca L0), > 0.

    Raises:
        ValueError: a parameter outside its range, naming it, its value and
            the allowed range.
    """

    phi_s0: float = 0.01
    xi: float = 4.5e4
    lambda_s: float = 1.0
    beta: float = 0.02
    eta: float = 0.02
    Ca: float = 3e-10
    stress_scale: float = 1.0
    displacement_scale: float = 1.0

    def __post_init__(self):
        checks = {
            "phi_s0": (lambda v: 0.0 < v < 1.0, "(0, 1)"),
            "xi": (lambda v: v > 0.0, "(0, inf)"),
            "lambda_s": (lambda v: v > -2.0 / 3.0, "(-2/3, inf)"),
            "beta": (lambda v: v > 0.0, "(0, inf)"),
            "eta": (lambda v: v > 0.0, "(0, inf)"),
            "Ca": (lambda v: v > 0.0, "(0, inf)"),
            "stress_scale": (lambda v: v > 0.0, "(0, inf)"),
            "displacement_scale": (lambda v: v > 0.0, "(0, inf)"),
        }
        for name, (ok, allowed) in checks.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"GelParameters.{name} must be a real number, got {value!r}")
            if not math.isfinite(value) or not ok(value):
                raise ValueError(f"GelParameters.{name} = {value!r} is outside the allowed range {allowed}")

    @classmethod
    def viscous_units(cls, **kwargs) -> "GelParameters":
        """The same parameters with s = d = Ca (stress unit mu V0/L0, displacement unit Ca L0).

        This is the well-scaled choice for the device runs: all unknowns are O(1).
        """
        params = cls(**kwargs)
        return dataclasses.replace(params, stress_scale=params.Ca, displacement_scale=params.Ca)

    def replace(self, **changes) -> "GelParameters":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    @property
    def viscosity(self) -> float:
        """Ca / s: the fluid viscosity in the stress unit s."""
        return self.Ca / self.stress_scale

    @property
    def stiffness(self) -> float:
        """d / s: the network shear modulus times d, in the stress unit s."""
        return self.displacement_scale / self.stress_scale

    @property
    def brinkman_length(self) -> float:
        """delta = 1 / sqrt(xi phi_s0) in units of L0 (uniform phi, v_s = 0).

        From the fluid-phase equation divided by phi_f:
        Ca lap v_f - grad p - xi Ca phi_s v_f = 0, i.e. mu_e = Ca, zeta = xi Ca phi_s.
        """
        return 1.0 / math.sqrt(self.xi * self.phi_s0)

    @property
    def darcy_mobility(self) -> float:
        """kappa = phi_f / (xi Ca phi_s) in L0^2 / (mu_s units) at phi = phi_s0.

        The superficial flux is phi_f v_f = -kappa grad p (p in units of mu_s).
        """
        return (1.0 - self.phi_s0) / (self.xi * self.Ca * self.phi_s0)
