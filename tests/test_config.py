"""The configuration of a run: defaults < case file < command line, and the case.toml a run writes.

The precedence is :func:`gelcell.case.resolve`'s; the command line arrives
through the real parser (``gelcell.cli.parser``) so that every option is
tried with the key it sets.  The last tests run ``gelcell`` twice: a run
repeated from the case.toml it wrote gives the same summary.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tomllib

import pytest

from gelcell.case import CaseParameters, resolve
from gelcell.case.casefile import toml_text
from gelcell.cli.commands import run_config
from gelcell.cli.parser import OPTION_KEYS, build_parser
from gelcell.coupled.defaults import partitioned_config
from gelcell.errors import ParameterError


def config_of(argv: list[str], tmp_path=None, file_text: str | None = None):
    """The RunConfig of ``gelcell run ARGV`` (with ``--config`` of ``file_text`` if given)."""
    if file_text is not None:
        path = tmp_path / "case.toml"
        path.write_text(file_text)
        argv = argv + ["--config", str(path)]
    args = build_parser().parse_args(["run", *argv, "--out", "unused"])
    return run_config(args)


# --------------------------------------------------------------------------- precedence
def test_defaults_are_model_md_without_a_file():
    assert config_of(["shear"]).case == CaseParameters.default("shear")


def test_the_file_beats_the_defaults_and_the_command_line_beats_the_file(tmp_path):
    text = '[case]\nname = "shear"\n[physics]\nca = 2e-10\n[mesh]\nsize_factor = 3.0\n'
    from_file = config_of([], tmp_path, text)
    assert from_file.case.physics.ca == 2e-10 and from_file.case.mesh.size_factor == 3.0
    both = config_of(["--ca", "5e-4"], tmp_path, text)
    assert both.case.physics.ca == 5e-4 and both.case.mesh.size_factor == 3.0


def test_ca_on_the_command_line_replaces_the_files_v0(tmp_path):
    text = '[case]\nname = "shear"\n[dimensional]\nV0 = 300.0\n'
    given_v0 = config_of([], tmp_path, text).case.physics.ca
    assert given_v0 != CaseParameters.default("shear").physics.ca
    assert config_of(["--ca", "5e-4"], tmp_path, text).case.physics.ca == 5e-4


def test_the_command_lines_scheme_and_acceleration_beat_the_files_coupling_table(tmp_path):
    text = ('[case]\nname = "shear"\n[coupling]\nscheme = "parallel-implicit"\nmax_iterations = 77\n'
            '[coupling.acceleration]\ntype = "iqn-ils"\nmax_used_iterations = 9\n')
    config = config_of(["--scheme", "serial", "--acceleration", "aitken"], tmp_path, text)
    table = partitioned_config(config.case, config.coupling, gamma2=config.solver.gamma2)
    assert table["scheme"] == "serial-implicit"
    assert table["max_iterations"] == 77                                # the file's other keys stay
    # the file's acceleration keys belong to IQN-ILS: an Aitken table of the device's defaults instead
    assert table["acceleration"]["type"] == "aitken"
    assert "max_used_iterations" not in table["acceleration"]
    assert table["acceleration"] == partitioned_config(config.case, {"acceleration": {"type": "aitken"}},
                                                       gamma2=config.solver.gamma2)["acceleration"]


def test_an_acceleration_of_the_files_type_keeps_the_files_keys(tmp_path):
    text = '[case]\nname = "shear"\n[coupling.acceleration]\ntype = "iqn-ils"\nmax_used_iterations = 9\n'
    config = config_of(["--acceleration", "iqn-ils"], tmp_path, text)
    table = partitioned_config(config.case, config.coupling, gamma2=config.solver.gamma2)
    assert table["acceleration"]["type"] == "iqn-ils" and table["acceleration"]["max_used_iterations"] == 9


def test_a_device_on_the_command_line_replaces_the_files_geometry_file(tmp_path):
    (tmp_path / "dev.msh").write_text("")
    text = '[geometry]\nfile = "dev.msh"\n'
    assert config_of(["normal"], tmp_path, text).case.case == "normal"


def test_gamma2_and_monolithic_have_case_file_keys(tmp_path):
    text = '[case]\nname = "shear"\n[solver]\nmethod = "monolithic"\ngamma2 = "dirichlet"\n'
    config = config_of([], tmp_path, text)
    assert config.solver.monolithic and config.solver.gamma2 == "dirichlet"
    assert config_of(["--gamma2", "robin"], tmp_path, text).solver.gamma2 == "robin"


def test_every_option_that_configures_a_run_names_a_key_of_a_case_file_table():
    tables = {"case", "physics", "dimensional", "cell", "geometry", "mesh", "solver", "coupling", "time",
              "output", "sweep"}
    for dest, (key, _) in OPTION_KEYS.items():
        assert key.split(".")[0] in tables, (dest, key)
    where = {"out", "config", "resume", "debug", "help", "command"}        # where gelcell reads and writes
    for command in ("run", "sweep"):
        sub = build_parser()._subparsers._group_actions[0].choices[command]
        for action in sub._actions:
            if action.dest not in where:
                assert action.dest in OPTION_KEYS, (command, action.option_strings)


def test_an_unknown_key_is_refused_naming_it(tmp_path):
    with pytest.raises(ParameterError, match="solver.*speed|speed.*solver"):
        config_of([], tmp_path, '[case]\nname = "shear"\n[solver]\nspeed = 2\n')


# --------------------------------------------------------------------------- the written case file
def test_the_written_tables_read_back_as_the_same_configuration(tmp_path):
    config = config_of(["normal", "--ca", "3e-4", "--mesh-size", "2.5", "--cells", "1.0,0.3,0.05",
                        "--gamma2", "dirichlet", "--scheme", "parallel"])
    text = toml_text(config.to_tables(), header="# a test")
    assert tomllib.loads(text) == json.loads(json.dumps(config.to_tables()))
    again = resolve(tomllib.loads(text))
    assert again == config


def test_a_3d_device_from_the_command_line_reads_back_from_its_case_file():
    """--height, --walls and 4-entry --cells set the [geometry] keys of model.md section 10."""
    config = config_of(["shear", "--height", "0.4", "--walls", "symmetric", "--cells", "2.0,-0.2,0.2,0.06"])
    g = config.case.geometry
    assert (g.chip_height, g.walls, g.cell_list_3d()) == (0.4, "symmetric", [(2.0, -0.2, 0.2, 0.06)])
    assert resolve(tomllib.loads(toml_text(config.to_tables()))) == config
    with pytest.raises(ParameterError, match=r"--cells '2.0,-0.2': each cell is X,Y,D, or X,Y,Z,D"):
        config_of(["shear", "--height", "0.4", "--cells", "2.0,-0.2"])
    with pytest.raises(ParameterError, match=r"parameter 'cells\[0\].z'"):
        config_of(["shear", "--height", "0.4", "--cells", "2.0,-0.2,0.1,0.06"])      # not at mid-height


def test_toml_text_round_trips_what_toml_holds_and_refuses_the_rest():
    tables = {"physics": {"ca": 1e-300, "big": -math.inf, "none": None},
              "geometry": {"cells": [[1.0, -0.2, 0.06]], "file": 'a "quoted" näme.geo'},
              "coupling": {"acceleration": {"type": "aitken", "preconditioner": {"type": "value"}}}}
    back = tomllib.loads(toml_text(tables, header="two\nlines"))
    assert back == {"physics": {"ca": 1e-300, "big": -math.inf}, "geometry": tables["geometry"],
                    "coupling": tables["coupling"]}
    assert math.isnan(tomllib.loads(toml_text({"t": {"x": math.nan}}))["t"]["x"])
    with pytest.raises(TypeError, match="case.physics.ca"):
        toml_text({"physics": {"ca": object()}})


def _gelcell(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gelcell.cli", *argv], capture_output=True, text=True,
                          env=dict(os.environ, MPLBACKEND="Agg"), timeout=900)


def _numbers(node, path=""):
    """The summary's numbers by path, without what depends on the machine (timings, file lists, memory)."""
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            if key not in ("timing", "files", "wall_time", "peak_memory_mb", "peak_memory_mb_per_rank"):
                out.update(_numbers(value, f"{path}/{key}"))
        return out
    if isinstance(node, list):
        out = {}
        for i, value in enumerate(node):
            out.update(_numbers(value, f"{path}[{i}]"))
        return out
    return {path: node}


@pytest.mark.skip_in_parallel
def test_a_run_repeated_from_its_case_toml_gives_the_same_summary(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    text = '[case]\nname = "shear"\n[coupling]\nscheme = "parallel-implicit"\n'
    (tmp_path / "in.toml").write_text(text)
    proc = _gelcell("run", "--config", str(tmp_path / "in.toml"), "--scheme", "serial", "--mesh-size", "3",
                    "--ca", "6e-10", "--no-figures", "--quiet", "--out", str(first))
    assert proc.returncode == 0, proc.stderr
    assert "partitioned (serial-implicit" in proc.stdout + proc.stderr        # the header says what ran
    written = tomllib.loads((first / "case.toml").read_text())
    assert written["coupling"]["scheme"] == "serial-implicit" and written["physics"]["ca"] == 6e-10
    proc = _gelcell("run", "--config", str(first / "case.toml"), "--quiet", "--out", str(second))
    assert proc.returncode == 0, proc.stderr
    a = _numbers(json.loads((first / "summary.json").read_text()))
    b = _numbers(json.loads((second / "summary.json").read_text()))
    assert a.keys() == b.keys()
    for key, x in a.items():
        if isinstance(x, float) and isinstance(b[key], float):
            assert b[key] == pytest.approx(x, rel=1e-12, abs=1e-300), key
        elif key.split("/")[-1] not in ("prior_source",):
            assert b[key] == x, key
    assert (second / "case.toml").read_text() == (first / "case.toml").read_text()
