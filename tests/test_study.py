"""The quick coupling study, checked against what the theory of partitioned schemes says.

* Dirichlet-Neumann on Gamma2 amplifies the interface error by about the
  ratio of the cell's stiffness to the drained gel network's, so without
  acceleration it diverges for a cell ten times stiffer than the network,
  and the data that blows up is Gamma2's.
* Aitken and IQN-ILS converge in every case.
* IQN-ILS (a least-squares secant method on the whole interface) needs no
  more iterations than Aitken (one scalar relaxation) on the baseline cases.
* With the linearized prior (the device default) IQN-ILS's first step is the
  Newton step on the coupled map linearised at rest; the map is linear up to
  strain-sized terms, so a few iterations remain, far fewer than the secant
  model alone needs.
* Every converged partitioned result is the monolithic solution (1e-6).
"""

import pytest

from gelcell.run.study import run_study

# serial only: the study is 24 device runs and 4 monolithic ones (~20 s), each of them a path
# whose 1- and 2-rank answers are compared in test_device.py, test_iterations.py and test_transient.py
pytestmark = pytest.mark.skip_in_parallel


@pytest.fixture(scope="module")
def study():
    return run_study(None, quick=True, log=lambda msg: None)


def _runs(study, **match):
    return [r for r in study["records"] if all(r[k] == v for k, v in match.items())]


@pytest.mark.parametrize("case", ["shear cell x10", "normal cell x10"])
def test_unaccelerated_dirichlet_neumann_diverges_for_a_stiff_cell(study, case):
    (run,) = _runs(study, case=case, scheme="serial", acceleration="none dirichlet gamma2")
    assert run["status"] == "diverged", run
    assert "Gamma2" in (run["diverged_data"] or "") or "solver failed" in (run["diverged_data"] or ""), run
    # the growth is fast: well before the iteration limit
    assert run["iterations"] <= 20, run


def test_aitken_and_iqn_ils_converge_in_every_case(study):
    for r in study["records"]:
        if r["acceleration"] in ("aitken", "iqn-ils", "iqn-ils linearized prior"):
            assert r["converged"], (r["case"], r["scheme"], r["acceleration"], r["reason"])
            assert r["final_residual"] <= 1e-10, r


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_iqn_ils_needs_no_more_iterations_than_aitken_on_the_baseline(study, case):
    (iqn,) = _runs(study, case=case, scheme="serial", acceleration="iqn-ils")
    (aitken,) = _runs(study, case=case, scheme="serial", acceleration="aitken")
    assert iqn["iterations"] <= aitken["iterations"], (iqn["iterations"], aitken["iterations"])


@pytest.mark.parametrize("case", ["shear", "normal", "shear cell x10", "normal cell x10"])
def test_the_linearized_prior_leaves_a_few_iterations(study, case):
    """Two corrections of the strain-sized remainder plus the sweeps that confirm the forward data
    (tests/test_iterations.py), against the secant model's 15-17."""
    (prior,) = _runs(study, case=case, scheme="serial", acceleration="iqn-ils linearized prior")
    (secant,) = _runs(study, case=case, scheme="serial", acceleration="iqn-ils")
    assert prior["iterations"] <= 6 and 2 * prior["iterations"] < secant["iterations"], (prior, secant)


def test_every_converged_result_matches_the_monolithic_one(study):
    converged = [r for r in study["records"] if r["converged"]]
    assert converged
    for r in converged:
        assert r["error_quantities"] <= 1e-6 and r["error_fields"] <= 1e-6, r
