"""The materials of a case: the dimensionless groups, the SI scales and the cell's moduli (model.md sections 2, 5).
"""

from __future__ import annotations

import dataclasses

from gelcell.case.ranges import POISSON_WHY, check_range, poisson_ratio_of, raise_problems

__all__ = ["Physics", "Dimensional", "CellMaterial"]


# --------------------------------------------------------------------------- blocks
@dataclasses.dataclass(frozen=True)
class Physics:
    """Dimensionless groups of model.md section 2 (Table 1 defaults)."""

    phi_s0: float = 0.01     #: solid volume fraction of the unloaded gel, (0, 1)
    lambda_s: float = 1.0    #: λ_s / μ_s of the network, > -2/3
    xi: float = 4.5e4        #: drag ξ̄ = ξ L0² / μ
    beta: float = 0.02       #: slip β̄ = μ β / L0
    eta: float = 0.02        #: interfacial permeability η̄ = μ η / L0
    ca: float = 3e-10        #: Ca = μ V0 / (L0 μ_s)

    def __post_init__(self):
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        check_range(p, "phi_s0", self.phi_s0, 0.0, 1.0)
        check_range(p, "lambda_s", self.lambda_s, -2.0 / 3.0, why="λ_s/μ_s; " + POISSON_WHY)
        for name in ("xi", "beta", "eta", "ca"):
            check_range(p, name, getattr(self, name), 0.0)
        return p


@dataclasses.dataclass(frozen=True)
class Dimensional:
    """SI scales (model.md section 5).  V0 is derived: V0 = Ca L0 μ_s / μ."""

    L0: float = 250e-6           #: length scale [m]
    mu: float = 1e-3             #: perfusate viscosity [Pa s]
    mu_s: float = 40e3           #: network shear modulus μ_s [Pa] (stress scale)
    pore_radius: float = 2.5e-6  #: pore radius of the gel [m] (informative)

    def __post_init__(self):
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        check_range(p, "L0", self.L0, 0.0, unit="m")
        check_range(p, "mu", self.mu, 0.0, unit="Pa s")
        check_range(p, "mu_s", self.mu_s, 0.0, unit="Pa")
        check_range(p, "pore_radius", self.pore_radius, 0.0, unit="m")
        return p


@dataclasses.dataclass(frozen=True)
class CellMaterial:
    """Lamé moduli of the neo-Hookean cell in Pa (primary values).

    Default: Young's modulus 1 kPa and ν = 0.25, i.e. μ_c = λ_c = 400 Pa
    = φ_s0 μ_s at baseline (model.md section 5).
    """

    mu_c: float = 400.0      #: shear modulus [Pa]
    lambda_c: float = 400.0  #: first Lamé parameter [Pa]

    @classmethod
    def from_young(cls, youngs_modulus: float, poisson_ratio: float) -> "CellMaterial":
        p: list[str] = []
        check_range(p, "youngs_modulus", youngs_modulus, 0.0, unit="Pa")
        check_range(p, "poisson_ratio", poisson_ratio, -1.0, 0.5)
        raise_problems(p)
        E, nu = float(youngs_modulus), float(poisson_ratio)
        return cls(mu_c=E / (2 * (1 + nu)), lambda_c=E * nu / ((1 + nu) * (1 - 2 * nu)))

    @property
    def youngs_modulus(self) -> float:
        """E = μ (3λ + 2μ) / (λ + μ) [Pa]."""
        return self.mu_c * (3 * self.lambda_c + 2 * self.mu_c) / (self.lambda_c + self.mu_c)

    @property
    def poisson_ratio(self) -> float:
        return poisson_ratio_of(self.lambda_c, self.mu_c)

    def __post_init__(self):
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        check_range(p, "mu_c", self.mu_c, 0.0, unit="Pa")
        if not p:
            check_range(p, "lambda_c", self.lambda_c, -2.0 * self.mu_c / 3.0, unit="Pa",
                   why="cell " + POISSON_WHY)
        return p
