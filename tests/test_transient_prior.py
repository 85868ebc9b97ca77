"""The per-dt linearized prior of time-dependent runs (issue 31 target 2), on the test-sized meshes.

Reference: the monolithic reference with the same time discretisation, in every window.

Iteration bound.  At a fixed dt a window's fixed-point map x -> G(x) is affine up to the
strain-sized nonlinearity the participants' Jacobians at rest leave out (the neo-Hookean
cell, the fluid's mesh motion): G(x) = G(x*) + A (x - x*) + O(rho |x - x*|), rho ~ 1e-6.
With the exact A of that dt the serial scheme needs, for an exactly affine map, 3 sweeps:
the first gives the residual, the Newton step x* - x0 = (I - A)^-1 r0 lands on the fixed
point, the second sweep's accelerated data are then unchanged but the data the scheme does
not accelerate (the fluid's outputs, read by the gel in the same sweep) were computed from
x0 the first time and change, so a third sweep confirms (tests/coupling/
test_coupling_linearization.py has the same count on the affine toys).  The remainder
leaves rho r0 after the Newton step, and each further step (prior and secant columns) at
most rho times the last: the accelerated data meet the tolerance 1e-10 after m steps with
rho^m r0 <= 1e-10, the others one sweep later, so 2 + m sweeps (m = 1 for an affine map).
With rho < 3e-5 (shear) or 3e-4 (normal) and r0 <= 1 (relative; windows start from the
extrapolation of the last three) that is 5 (measured: 4 and 5).
"""

from __future__ import annotations

import math
from unittest import mock

import numpy as np
import pytest

from gelcell.run.transient import BDF2_START
from test_transient import relative_difference
from transient_cases import case, run, tau

#: the coupling's tolerance (relative, every data)
TOLERANCE = 1e-10
#: the largest contraction of the Newton step per device: the strain-sized remainder of the map
#: (measured on these meshes: shear up to 1.1e-5, normal up to 1.6e-4)
CONTRACTION = {"shear": 3e-5, "normal": 3e-4}


def bound(name: str, r0: float = 1.0) -> int:
    """Sweeps per window (module docstring): 2 + the steps m with CONTRACTION^m r0 <= TOLERANCE."""
    return 2 + math.ceil(math.log(r0 / TOLERANCE) / math.log(1.0 / CONTRACTION[name]))


def operators(prior) -> int:
    """The distinct operators a run's prior factorised or took from the disk cache."""
    return prior.factorizations + prior.loaded


def _newton_contraction(scheme, window) -> float:
    """The largest relative residual (|r| / |value| per data, as the convergence measure) of the
    accelerated fluid-gel data after the Newton step over that of the window's first sweep.

    The Gamma2 data are left out: in the normal device the cell's force drops by only ~0.1-0.5
    per step (not analysed; a suspect: the components a symmetry condition fixes are reactions,
    which the cell's Jacobian leaves out), and that device's bound counts the step it costs.
    """
    names = [n for n in scheme.accelerated if not n.startswith("Gamma2/")]

    def largest(record):
        return max(record.residual_norms[n] / record.value_norms[n] for n in names if record.value_norms[n] > 0)
    return largest(window.records[1]) / largest(window.records[0])


@pytest.mark.parametrize("name,scheme,start", [("shear", "be", None), ("normal", "bdf2", ())])
def test_per_dt_prior_equals_monolithic_in_few_iterations(name, scheme, start):
    """Both devices, BE and BDF2 (its first step BE: two operators): every window = monolithic to 1e-6,
    the Newton step contracts by the remainder only, and the sweeps keep the bound (module docstring).

    BDF2 on equal steps (``start = ()``, no graded start): the operators of the schemes themselves;
    the graded start is the next test."""
    p = case(name)
    kw = dict(dt=tau(p) / 20, t_end=4 * tau(p) / 20, scheme=scheme)
    with mock.patch("gelcell.run.transient.BDF2_START", BDF2_START if start is None else start):
        partitioned = run(p, **kw)
        monolithic = run(p, monolithic=True, **kw)
    assert relative_difference(partitioned["series"], monolithic["series"]) < 1e-6
    coupling = partitioned["run"].backend.scheme
    prior = coupling.linearized_prior
    assert prior is not None
    assert operators(prior) == (2 if scheme == "bdf2" else 1)
    for window in coupling.history:
        assert _newton_contraction(coupling, window) < CONTRACTION[name], window.window
        r0 = max(window.records[0].measure_values.values())
        assert window.iterations <= bound(name, max(r0, 1.0)), (window.window, r0, window.iterations)


def test_per_dt_prior_through_the_graded_bdf2_start():
    """BDF2 from rest (dt/4 BE, dt/2 and dt with omega = 2, dt, and dt/4 to t_end: five operators):
    every window = monolithic to 1e-6 and within the sweep bound.

    Not asserted: the contraction of the third window (dt after dt/2, omega = 2), measured 4e-3
    on the normal device against <= 1.6e-4 in the others (its first residual 2.2, the others'
    <= 1.3): an open question of the coupling (issue 31), which costs it one sweep (5, not 4)."""
    p = case("normal")
    kw = dict(dt=tau(p) / 20, t_end=4 * tau(p) / 20, scheme="bdf2")
    partitioned = run(p, **kw)
    monolithic = run(p, monolithic=True, **kw)
    assert relative_difference(partitioned["series"], monolithic["series"]) < 1e-6
    coupling = partitioned["run"].backend.scheme
    assert operators(coupling.linearized_prior) == 5
    for window in coupling.history:
        if window.window != 2:
            assert _newton_contraction(coupling, window) < CONTRACTION["normal"], window.window
        r0 = max(window.records[0].measure_values.values())
        assert window.iterations <= bound("normal", max(r0, 1.0)), (window.window, r0, window.iterations)


def test_a_new_step_size_gets_its_own_prior():
    """A step cut short to land on t_end is a new operator: it is factorised for it, and converges as fast."""
    p = case("shear")
    dt = tau(p) / 20
    # backward Euler: one operator of dt, one of the last step (BDF2's start would add its own)
    partitioned = run(p, dt=dt, t_end=2.5 * dt, scheme="be")
    coupling = partitioned["run"].backend.scheme
    assert operators(coupling.linearized_prior) == 2
    assert np.all(partitioned["series"]["iterations"][1:] <= bound("shear"))
    assert _newton_contraction(coupling, coupling.history[-1]) < CONTRACTION["shear"]
