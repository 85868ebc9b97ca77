"""Convergence measure names: preCICE's are accepted, other frameworks' are answered by meaning.

Reference: a two-participant affine toy whose iterates are computed by hand
(``a = b/2 + 1``, ``b = a/2``, Gauss-Seidel without acceleration): the
backward data ``b`` takes x = 0, 0.5, 0.625, ... and writes x̃ = 0.5, 0.625,
0.65625, so ``‖r_k‖ = 0.5, 0.125, 0.03125`` and ``‖r_k‖/‖x̃_k‖ = 1, 0.2,
0.0476``.  Each measure stops at the first iteration its own formula
(preCICE's definition) meets.
"""

from __future__ import annotations

import numpy as np
import pytest

import coupling as cp


class Affine(cp.Participant):
    def __init__(self, name, read, write, gain, offset):
        self.name, self.read, self.write, self.gain, self.offset = name, read, write, gain, offset

    def interface_points(self, mesh_name):
        return np.zeros((1, 2))

    def solve(self, inputs):
        return {self.write: self.gain * inputs[self.read] + self.offset}


def iterations(kind, limit):
    data = [cp.Data("a", "G", 1, "A", ("B",)), cp.Data("b", "G", 1, "B", ("A",))]
    scheme = cp.build_scheme({"order": ["A", "B"], "verbose": False, "max_iterations": 10,
                              "convergence": [{"type": kind, "limit": limit, "data": "b"}]},
                             [Affine("A", "b", "a", 0.5, 1.0), Affine("B", "a", "b", 0.5, 0.0)], data)
    return scheme.solve().iterations_per_window[0]


@pytest.mark.parametrize("kind, limit, expected", [
    ("absolute-convergence-measure", 0.13, 2),            # ‖r_2‖ = 0.125
    ("relative-convergence-measure", 0.21, 2),            # ‖r_2‖ / ‖x̃_2‖ = 0.2
    ("residual-relative-convergence-measure", 0.21, 3),   # ‖r_2‖ / ‖r_1‖ = 0.25, ‖r_3‖ / ‖r_1‖ = 0.0625
])
def test_precice_names_are_precice_s_measures(kind, limit, expected):
    assert iterations(kind, limit) == expected
    short = cp.MEASURE_ALIASES[kind]
    assert iterations(short, limit) == expected
    assert cp.load_config({"convergence": [{"type": kind, "limit": limit}]}).convergence[0].type == short


def test_coconut_relative_norm_is_answered_with_residual_relative():
    """CoCoNuT's relative_norm is ‖r_k‖/‖r_1‖: the answer names residual-relative, never the look-alike."""
    for name in ("relative_norm", "convergence_criteria.relative_norm", "relative-norm"):
        with pytest.raises(ValueError, match=r"here 'residual-relative'") as info:
            cp.load_config({"convergence": [{"type": name, "limit": 1e-6}]})
        assert "did you mean" not in str(info.value)
    with pytest.raises(ValueError, match=r"absolute_norm is .*here 'absolute'"):
        cp.load_config({"convergence": [{"type": "absolute_norm", "limit": 1e-6}]})
    with pytest.raises(ValueError, match=r"set coupling\.max_iterations"):
        cp.load_config({"convergence": [{"type": "iteration_limit", "limit": 1}]})
    # the measure meant, given, stops where ‖r_k‖/‖r_1‖ does: iteration 3 (not 2 as 'relative' would)
    assert iterations("residual-relative", 0.21) == 3 != iterations("relative", 0.21)


def test_keys_of_other_frameworks_name_the_key_of_that_meaning():
    with pytest.raises(ValueError, match=r"unknown key 'tolerance' \(CoCoNuT's tolerance is the limit here: 'limit'\)"):
        cp.load_config({"convergence": [{"type": "relative", "tolerance": 1e-6, "limit": 1e-6}]})
    with pytest.raises(ValueError, match=r"suffices = true"):
        cp.load_config({"convergence": [{"type": "relative", "limit": 1e-6, "abs-limit": 1e-9}]})


def test_other_spellings_of_a_measure_and_near_typos():
    with pytest.raises(ValueError, match=r"the same measure is written 'residual-relative'"):
        cp.load_config({"convergence": [{"type": "residual_relative", "limit": 1e-6}]})
    with pytest.raises(ValueError, match=r"'relative': ‖r_k‖ / ‖x̃_k‖ < limit"):
        cp.load_config({"convergence": [{"type": "change", "limit": 1e-6}]})
    with pytest.raises(ValueError, match=r"did you mean 'absolute'\?"):
        cp.build_measure("absolut", "x", 1e-6)
