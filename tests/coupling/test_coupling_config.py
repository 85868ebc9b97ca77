"""Configuration validation: errors name the key, the value and what is allowed."""

from __future__ import annotations

import math
import textwrap

import pytest

import coupling as cp
from coupling.toys import two_bar_problem

MEASURE = [{"type": "relative", "limit": 1e-8}]


def test_defaults_are_explicit_and_valid():
    cfg = cp.load_config({"convergence": MEASURE})
    assert cfg.scheme == "serial-implicit"
    assert cfg.acceleration.type == "none"
    assert cfg.acceleration.filter.type == "qr2"
    assert cfg.acceleration.preconditioner.type == "none"
    assert cfg.max_iterations == 50 and cfg.min_iterations == 1
    assert math.isinf(cfg.acceleration.omega_max)


def test_full_toml_file_is_read(tmp_path):
    path = tmp_path / "case.toml"
    path.write_text(textwrap.dedent("""
        [fluid]
        anything = 1

        [coupling]
        scheme = "parallel-implicit"
        order = ["fluid", "gel"]
        max_iterations = 60
        on_max_iterations = "continue"
        divergence_factor = inf

        [[coupling.convergence]]
        data = "Gamma1/traction"
        type = "relative"
        limit = 1e-8

        [[coupling.convergence]]
        type = "residual-relative"
        limit = 1e-6
        suffices = true

        [coupling.acceleration]
        type = "iqn-ils"
        initial_relaxation = 0.1
        max_used_iterations = 40
        time_windows_reused = 8

        [coupling.acceleration.filter]
        type = "qr1"
        limit = 1e-6

        [coupling.acceleration.preconditioner]
        type = "constant"
        factors = { "Gamma1/traction" = 1e-7, "Gamma1/velocity" = 1e-6 }
        freeze_after = 3
    """))
    cfg = cp.load_config(path)
    assert cfg.scheme == "parallel-implicit"
    assert cfg.order == ("fluid", "gel")
    assert math.isinf(cfg.divergence_factor)
    assert len(cfg.convergence) == 2 and cfg.convergence[1].suffices
    assert cfg.convergence[1].data == "accelerated"      # the default (docs/coupling-study.md)
    assert cfg.acceleration.time_windows_reused == 8
    assert cfg.acceleration.filter == cp.FilterConfig(type="qr1", limit=1e-6)
    assert cfg.acceleration.preconditioner.factors["Gamma1/traction"] == 1e-7
    assert cfg.acceleration.preconditioner.freeze_after == 3


def test_missing_table_in_file(tmp_path):
    path = tmp_path / "case.toml"
    path.write_text("[gel]\nx = 1\n")
    with pytest.raises(ValueError, match=r"no \[coupling\] table"):
        cp.load_config(path)


@pytest.mark.parametrize("table, pattern", [
    ({"schme": "serial-implicit"}, r"coupling: unknown key 'schme' \(did you mean 'scheme'\?\)"),
    ({"scheme": "serial"}, r"coupling.scheme = 'serial' is not allowed.*'serial-implicit'"),
    ({"max_iterations": 0}, r"coupling.max_iterations = 0 must be >= 1"),
    ({"max_iterations": 2.5}, r"coupling.max_iterations = 2.5 must be an integer"),
    ({"min_iterations": 5, "max_iterations": 3}, r"min_iterations = 5 must be <= max_iterations = 3"),
    ({"on_max_iterations": "ignore"}, r"on_max_iterations = 'ignore' is not allowed.*'continue'"),
    ({"divergence_factor": 1.0}, r"divergence_factor = 1.0 must be > 1"),
    ({"state_reload": "never"}, r"coupling.state_reload = 'never' is not allowed.*'iteration', 'window'"),
    ({"verbose": "yes"}, r"coupling.verbose = 'yes' must be true or false"),
    ({"order": "fluid"}, r"coupling.order = 'fluid' must be a list"),
    ({"convergence": [{"type": "relative"}]}, r"coupling.convergence\[0\]: missing required key 'limit'"),
    ({"convergence": [{"type": "relativ", "limit": 1e-3}]},
     r"type = 'relativ' is not allowed \(did you mean 'relative'\?\)"),
    ({"convergence": [{"type": "relative", "limit": -1.0}]}, r"limit = -1.0 must be > 0"),
    ({"convergence": [{"type": "relative", "limit": 1e-3, "data_name": "x"}]},
     r"coupling.convergence\[0\]: unknown key 'data_name'"),
    ({"acceleration": {"type": "iqn-ils", "max_used_iteration": 5}},
     r"coupling.acceleration: unknown key 'max_used_iteration' \(did you mean 'max_used_iterations'\?\)"),
    ({"acceleration": {"type": "aitken", "max_used_iterations": 5}},
     r"coupling.acceleration.max_used_iterations is not an option of type = 'aitken'"),
    ({"acceleration": {"type": "iqn-imvj", "time_windows_reused": 2}},
     r"time_windows_reused is not an option of type = 'iqn-imvj'"),
    ({"acceleration": {"type": "constant", "relaxation": 0.0}},
     r"coupling.acceleration.relaxation = 0.0 must be > 0"),
    ({"acceleration": {"type": "aitken", "omega_min": 2.0, "omega_max": 1.0}},
     r"omega_min = 2.0 must be <= omega_max = 1.0"),
    ({"acceleration": {"type": "iqn-ils", "filter": {"type": "qr3"}}},
     r"coupling.acceleration.filter.type = 'qr3' is not allowed"),
    ({"acceleration": {"type": "iqn-ils", "filter": {"limit": 1.5}}},
     r"coupling.acceleration.filter.limit = 1.5 must be < 1"),
    ({"acceleration": {"type": "iqn-ils", "preconditioner": {"type": "constant"}}},
     r"factors must name every accelerated data"),
    ({"acceleration": {"type": "iqn-ils", "preconditioner": {"type": "value", "factors": {"a": 1.0}}}},
     r"factors is only allowed with type = 'constant'"),
    ({"acceleration": {"type": "iqn-ils", "preconditioner": {"type": "value", "freeze_after": 0}}},
     r"freeze_after = 0 must be -1 \(never\) or >= 1"),
    ({"acceleration": {"type": "iqn-ils", "preconditioner": {"kind": "value"}}},
     r"coupling.acceleration.preconditioner: unknown key 'kind'"),
    ({"scheme": "serial-explicit", "acceleration": {"type": "aitken"}},
     r"acceleration.type = 'aitken' is not allowed with scheme = 'serial-explicit'"),
])
def test_invalid_config_names_the_key(table, pattern):
    with pytest.raises(ValueError, match=pattern):
        cp.load_config(table)


def test_dataclasses_validate_on_construction():
    with pytest.raises(ValueError, match="coupling.acceleration.type = 'IQN' is not allowed"):
        cp.AccelerationConfig(type="IQN")
    with pytest.raises(ValueError, match="initial_relaxation = nan must be finite"):
        cp.AccelerationConfig(type="aitken", initial_relaxation=float("nan"))


def _build(config):
    problem = two_bar_problem(10.0)
    participants, data = problem.build()
    return cp.build_scheme(config, participants, data)


def test_scheme_level_errors_name_the_key():
    with pytest.raises(ValueError, match=r"coupling.convergence\[0\].data = 'Gamma/forces' is not a "
                                         r"coupling data; allowed values: '\*', 'accelerated', 'Gamma/force'"):
        _build({"convergence": [{"data": "Gamma/forces", "type": "relative", "limit": 1e-8}]})
    with pytest.raises(ValueError, match="an implicit scheme needs at least one convergence measure"):
        _build({})
    with pytest.raises(ValueError, match=r"coupling.order = \['dirichlet_bar', 'neumann'\] names "
                                         r"unknown participants \['neumann'\]"):
        _build({"order": ["dirichlet_bar", "neumann"], "convergence": MEASURE})
    with pytest.raises(ValueError, match="misses participants"):
        _build({"order": ["dirichlet_bar"], "convergence": MEASURE})
    with pytest.raises(ValueError, match=r"factors must name exactly the accelerated data "
                                         r"\['Gamma/displacement'\]; missing \['Gamma/displacement'\], "
                                         r"not accelerated \['Gamma/force'\]"):
        _build({"convergence": MEASURE,
                "acceleration": {"type": "iqn-ils",
                                 "preconditioner": {"type": "constant", "factors": {"Gamma/force": 1.0}}}})


def test_measured_data_selectors():
    """'*' measures every data; 'accelerated' the accelerated ones (serial: read before written), all if parallel."""
    def measured(scheme, data):
        built = _build({"scheme": scheme, "verbose": False,
                        "convergence": [{"type": "relative", "limit": 1e-8, "data": data}]})
        return sorted(m.data for m in built.measures), sorted(built.accelerated)
    names, accelerated = measured("serial-implicit", "accelerated")
    assert names == accelerated == ["Gamma/displacement"]
    assert measured("serial-implicit", "*")[0] == ["Gamma/displacement", "Gamma/force"]
    assert measured("parallel-implicit", "accelerated")[0] == ["Gamma/displacement", "Gamma/force"]


def test_explicit_scheme_needs_no_measure():
    scheme = _build({"scheme": "serial-explicit", "verbose": False})
    assert isinstance(scheme, cp.SerialExplicitScheme)
    assert scheme.accelerated == ()


def test_data_validation():
    with pytest.raises(ValueError, match="writer 'a' cannot also be a reader"):
        cp.Data("x", "m", 1, "a", ("a",))
    with pytest.raises(ValueError, match="mapping = 'cubic' is not allowed"):
        cp.Data("x", "m", 1, "a", ("b",), mapping="cubic")
    with pytest.raises(ValueError, match="dim = 0 must be a positive integer"):
        cp.Data("x", "m", 0, "a", ("b",))
    assert cp.Data("x", "m", 1, "a", "b").readers == ("b",)
