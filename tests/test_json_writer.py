"""``femtools.io.write_json``, the project's one JSON writer: strict JSON, UTF-8, atomic, rank 0.

NaN and ±inf (Python or numpy, scalars or inside lists, arrays and nested
dicts) are written as ``null``; a value JSON cannot hold raises a TypeError
naming its key path and writes nothing.  Runs on any number of ranks.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from femtools.io import write_json


def strict_loads(text: str):
    """``json.loads`` that refuses the non-standard constants NaN, Infinity and -Infinity."""
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def written(path) -> str:
    with open(path, encoding="utf-8") as f:
        return f.read()


NON_FINITE = [math.nan, math.inf, -math.inf, np.nan, np.inf, -np.inf,
              np.float64("nan"), np.float32("inf"), np.float64("-inf")]


def test_non_finite_numbers_are_null_everywhere(shared_tmp_path, comm):
    data = {"scalars": NON_FINITE,
            "array": np.array([1.5, np.nan, np.inf, -np.inf]),
            "matrix": np.array([[np.nan, 2.0], [3.0, -np.inf]], dtype=np.float32),
            "tuple": (np.nan, np.int64(3), np.bool_(False)),
            "nested": {"a": {"b": [math.inf, {"c": np.float64("nan")}]}, 7: -math.inf},
            "nan": np.nan, "inf": math.inf}
    path = shared_tmp_path / "out.json"
    write_json(str(path), data, comm)
    text = written(path)
    assert "NaN" not in text and "Infinity" not in text
    assert strict_loads(text) == {
        "scalars": [None] * len(NON_FINITE),
        "array": [1.5, None, None, None],
        "matrix": [[None, 2.0], [3.0, None]],
        "tuple": [None, 3, False],
        "nested": {"a": {"b": [None, {"c": None}]}, "7": None},
        "nan": None, "inf": None}
    assert text.endswith("}\n")


def test_non_ascii_text_is_written_as_utf8(shared_tmp_path, comm):
    data = {"unit": "µm", "Größe": "σ·n", "name": "Émile 中文"}
    path = shared_tmp_path / "text.json"
    write_json(str(path), data, comm)
    text = written(path)
    assert "µm" in text and "Größe" in text and "\\u" not in text      # ensure_ascii=False
    assert strict_loads(text) == data


class Opaque:
    pass


@pytest.mark.parametrize("data, where", [
    ({"runs": [{"ok": 1.0}, {"solver": Opaque()}]}, r"\['runs'\]\[1\]\['solver'\]"),
    ({"x": np.array([1 + 2j])}, r"\['x'\]\[0\]: an object of type complex"),
    (Opaque(), "the value: an object of type Opaque"),
])
def test_an_unrepresentable_value_raises_naming_its_key_and_writes_nothing(shared_tmp_path, comm, data,
                                                                           where):
    path = shared_tmp_path / "bad.json"
    with pytest.raises(TypeError, match=where):          # on every rank
        write_json(str(path), data, comm)
    comm.Barrier()
    assert os.listdir(shared_tmp_path) == []


def test_the_file_is_written_once_whole_by_rank_0(shared_tmp_path, comm):
    path = shared_tmp_path / "sub" / "summary.json"
    values = np.arange(20000, dtype=float)
    # every rank passes its own data: the file holds rank 0's, and only rank 0 writes
    write_json(str(path), {"rank": comm.rank, "values": values}, comm)
    comm.Barrier()
    data = strict_loads(written(path))
    assert data["rank"] == 0 and data["values"] == values.tolist()
    assert os.listdir(path.parent) == ["summary.json"]          # no temporary file left
    assert oct(os.stat(path).st_mode & 0o777) == oct(0o644)
    comm.Barrier()          # every rank has listed the directory before the next write's temporary file
    # a second write replaces the file as a whole
    write_json(str(path), {"rank": comm.rank}, comm)
    comm.Barrier()
    assert strict_loads(written(path)) == {"rank": 0}
    assert os.listdir(path.parent) == ["summary.json"]

