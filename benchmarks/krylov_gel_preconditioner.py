"""Why the gel's pressure block is a sum: GMRES iterations of each variant across the parameter regimes.

    .venv/bin/python benchmarks/krylov_gel_preconditioner.py

The gel's iterative solve (femtools.krylov.gel_solver) preconditions the
pressure by S^-1 ~ (Darcy + fixed stress)^-1 + (viscous mass)^-1
(femtools.krylov.PressureSchur).  This prints the Krylov iterations of the
first solve on the chamber of tests/test_krylov.py at 8, 16, 32 cells a side
for: both terms (the default), the Darcy term alone, the viscous term alone,
and both without the fixed-stress mass; in the device's regime (xi = 4.5e4:
Darcy-dominated, Brinkman length 0.047), at xi / 1000 (Brinkman-dominated),
at phi_s0 = 0.1, and one backward-Euler step from rest of dt = 1e-8
(undrained), 1e-4 and 1.  "fail" is a Krylov solve that did not converge in
1000 iterations.  Prints only.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import ufl  # noqa: E402
from dolfinx import fem  # noqa: E402

import gel.solver  # noqa: E402
from femtools.errors import LinearSolveError  # noqa: E402
from femtools.krylov import PressureSchur, gel_solver  # noqa: E402
from gel import GelParameters  # noqa: E402
from test_krylov import gel_chamber  # noqa: E402

LEVELS = (8, 16, 32)
REGIMES = {"device": {}, "xi / 1000": dict(xi=45.0), "phi_s0 = 0.1": dict(phi_s0=0.1),
           "dt = 1e-8": dict(dt=1e-8), "dt = 1e-4": dict(dt=1e-4), "dt = 1": dict(dt=1.0)}
_DEFAULT = gel.solver.PoroelasticGelSolver._krylov_solver


def _without_fixed_stress(self, J_reference, petsc_options):
    """The default pressure block with beta = 0 (the Darcy and the viscous terms only)."""
    c = self.coefficients
    p, q = ufl.TrialFunctions(self.W)[2], ufl.TestFunctions(self.W)[2]
    phi_s, phi_f = c.phi_s0, 1 - c.phi_s0
    drag, nu_e = c.viscosity * c.xi * phi_f * phi_s, c.viscosity * phi_f
    darcy = phi_f**2 / drag * (ufl.inner(ufl.grad(p), ufl.grad(q)) + p * q)
    return gel_solver(self.W, self.name, fem.form(J_reference + darcy * self.dx),
                      fem.form(phi_f**2 / nu_e * p * q * self.dx), self.bcs, petsc_options)


VARIANTS = {"sum (default)": (("darcy", "viscous"), _DEFAULT), "Darcy alone": (("darcy",), _DEFAULT),
            "viscous alone": (("viscous",), _DEFAULT),
            "sum, no fixed stress": (("darcy", "viscous"), _without_fixed_stress)}


def iterations(n: int, regime: dict) -> int | str:
    regime = dict(regime)
    dt = regime.pop("dt", None)
    s = gel_chamber(n, "iterative", GelParameters.viscous_units(Ca=3e-10, **regime), dt=dt)
    try:
        s.solve()
    except LinearSolveError:
        return "fail"
    return s.newton.solver.iterations[0]


def main() -> None:
    print(f"GMRES iterations of the first solve at {LEVELS} cells a side")
    print(f"{'variant':22s} " + " ".join(f"{r:>16s}" for r in REGIMES))
    for variant, (terms, builder) in VARIANTS.items():
        PressureSchur.terms = terms
        gel.solver.PoroelasticGelSolver._krylov_solver = builder
        row = [",".join(str(iterations(n, r)) for n in LEVELS) for r in REGIMES.values()]
        print(f"{variant:22s} " + " ".join(f"{c:>16s}" for c in row), flush=True)
    PressureSchur.terms = ("darcy", "viscous")
    gel.solver.PoroelasticGelSolver._krylov_solver = _DEFAULT


if __name__ == "__main__":
    main()
