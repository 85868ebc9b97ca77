"""``coupling.serialization``: the strict-JSON converter and the records written through it."""

from __future__ import annotations

import json
import math

import numpy as np

from coupling.convergence import MeasureValue
from coupling.records import IterationRecord, WindowRecord, write_records
from coupling.serialization import to_jsonable


def _strict_load(path):
    def refuse(name):
        raise AssertionError(f"{path}: non-standard JSON constant {name}")
    with open(path) as fh:
        return json.load(fh, parse_constant=refuse)


def test_to_jsonable_gives_plain_python_for_strict_json():
    obj = {1: np.float64("nan"), (2, 3): [np.inf, -math.inf, np.float32(0.5)],
           "a": np.arange(3).reshape(3, 1), "b": (np.int64(4), np.bool_(True), True, None, "s"),
           "c": np.array([1.0, np.nan])}
    out = to_jsonable(obj)
    assert out == {"1": None, "(2, 3)": [None, None, 0.5], "a": [[0], [1], [2]],
                   "b": [4, True, True, None, "s"], "c": [1.0, None]}
    assert type(out["b"][0]) is int and type(out["b"][1]) is bool and type(out["a"][0][0]) is int
    assert type(out["(2, 3)"][2]) is float
    json.dumps(out, allow_nan=False)
    assert to_jsonable(out) == out            # plain Python passes unchanged


def test_records_are_strict_json_with_non_finite_numbers_as_null(tmp_path):
    measure = MeasureValue("d", "relative", math.inf, 1e-8, False, False)
    iteration = IterationRecord(window=0, iteration=1, time=None, dt=None, residual_norms={"d": 1.0},
                                value_norms={"d": 0.0}, measure_values={"d": math.inf}, measures=[measure],
                                relaxation=np.float64("nan"), solve_time={"p": np.float64(0.25)})
    window = WindowRecord(window=0, time=None, dt=None, iterations=1, reason="max_iterations",
                          records=[iteration])
    paths = write_records(tmp_path, [window], ["d"], ["p"])
    rows = _strict_load(paths["convergence_json"])
    assert rows[0]["measure_values"] == {"d": None} and rows[0]["relaxation"] is None
    assert rows[0]["measures"][0]["value"] is None and rows[0]["solve_time"] == {"p": 0.25}
    assert _strict_load(paths["iterations_json"])[0]["reason"] == "max_iterations"
