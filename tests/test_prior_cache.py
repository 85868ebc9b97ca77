"""The device default's linearized prior and its disk cache (``gelcell.coupled.priorcache``).

A hit must give the run a miss gives (the same factorisation, hence the same
iterates), and the cache must never fail a run.  Every test points
``GELCELL_PRIOR_CACHE_DIR`` at a temporary directory (the same on every rank;
rank 0 reads and writes, the other ranks receive the arrays), so none depends
on the user's cache.  The answers themselves are checked against the monolithic
reference in tests/test_iterations.py.
"""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

from mpi4py import MPI

from gelcell.coupled import device as device_module
from gelcell import diskcache
from gelcell.coupled import priorcache
from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device
from gelcell.case import CaseParameters
from test_transient import relative_difference
from transient_cases import run, tau

COMM = MPI.COMM_WORLD
MESH = 3.0


@pytest.fixture
def cache(empty_cache):
    return empty_cache("GELCELL_PRIOR_CACHE_DIR", "GELCELL_PRIOR_CACHE")


def entries(path) -> list[str]:
    names = COMM.bcast(sorted(os.listdir(path)) if COMM.rank == 0 and path.exists() else None, root=0)
    return names or []


def solve(params: CaseParameters, config: dict | None = None) -> Device:
    device = Device(params, COMM)
    device.solve(config or coupling_config(with_cell=params.with_cell, params=params), verbose=False)
    assert device.result.converged
    return device


def interface_values(device: Device) -> np.ndarray:
    return np.concatenate([device.scheme.values[n].ravel() for n in sorted(device.scheme.values)])


def base(case: str = "shear") -> CaseParameters:
    return CaseParameters.default(case, True).with_mesh_size(MESH)


@pytest.mark.parametrize("case", ["shear", "normal"])
def test_a_hit_repeats_the_computed_run(cache, case):
    """Computed once, stored; the next run loads it and takes the same iterates.

    Serial runs are bitwise repeatable, so a hit must repeat the miss exactly; on 2 ranks two
    equal runs already differ by round-off (~3e-15, MUMPS's parallel reductions), far below what
    another prior would change (the coupling stops at a relative residual of 1e-10).
    """
    first = solve(base(case))
    assert first.prior_source == "computed" and first.linearized_prior.setup_time > 0
    assert len(entries(cache)) == 1
    second = solve(base(case))
    assert second.prior_source == "disk cache" and second.linearized_prior.setup_time == 0
    assert second.result.iterations == first.result.iterations
    a, b = interface_values(second), interface_values(first)
    tolerance = 0.0 if COMM.size == 1 else 1e-13
    assert np.max(np.abs(a - b)) <= tolerance * np.max(np.abs(b))


def test_one_entry_serves_every_ca_and_no_other_problem(cache):
    """The scaled problem does not depend on Ca: another Ca hits; another cell stiffness does not."""
    p = base()
    keys = {}
    for name, q in (("ca", p), ("other ca", p.with_ca(3.0 * p.physics.ca)), ("cell x10", p.with_cell_moduli(10.0)),
                    ("mesh", p.with_mesh_size(4.0))):
        d = Device(q, COMM)
        d.scheme = device_module.cp.build_scheme(
            {**coupling_config(params=q), "acceleration": {"type": "iqn-ils", "jacobian_prior": "linearized"},
             "verbose": False}, d.participants, d.data, comm=COMM)
        keys[name] = priorcache.cache_key(d, d.scheme)
    assert keys["ca"] == keys["other ca"]
    assert len({keys["ca"], keys["cell x10"], keys["mesh"]}) == 3


def test_a_time_dependent_run_keeps_one_entry_per_operator(cache):
    """BDF2 from rest (dt/4 BE, dt/2 and dt with omega = 2, dt: four operators, and a last step cut short):
    each operator computed once and stored; the repeated run loads every one and takes the same
    windows, iteration for iteration (serial: bitwise; 2 ranks: MUMPS's round-off, as above).
    Another Ca is another entry (its time unit is not part of the steady argument)."""
    p = base()
    kw = dict(dt=tau(p) / 20, t_end=4.5 * tau(p) / 20, scheme="bdf2")
    first = run(p, **kw)
    prior = first["run"].backend.scheme.linearized_prior
    assert (prior.factorizations, prior.loaded) == (5, 0)
    assert len(entries(cache)) == 5
    second = run(p, **kw)
    prior = second["run"].backend.scheme.linearized_prior
    assert (prior.factorizations, prior.loaded) == (0, 5)
    np.testing.assert_array_equal(second["series"]["iterations"], first["series"]["iterations"])
    tolerance = 0.0 if COMM.size == 1 else 1e-12
    assert relative_difference(second["series"], first["series"]) <= tolerance
    other = run(p.with_ca(3.0 * p.physics.ca), dt=tau(p) / 20, t_end=tau(p) / 20, scheme="be")
    assert other["run"].backend.scheme.linearized_prior.loaded == 0


def test_a_time_dependent_run_writes_at_most_its_budget(cache, monkeypatch):
    """An adaptive run's tens of operators must not evict the cache: one run writes at most
    MAX_RUN_BYTES (none with a budget of 0; of two operators one with a budget of 1.5 entries)."""
    p = base()
    kw = dict(dt=tau(p) / 20, t_end=1.5 * tau(p) / 20, scheme="be")      # dt, then dt/2 to t_end
    monkeypatch.setattr(priorcache, "MAX_RUN_BYTES", 0)
    prior = run(p, **kw)["run"].backend.scheme.linearized_prior
    assert prior.factorizations == 2 and entries(cache) == []
    entry = sum(a.nbytes for a in priorcache._to_npz(prior.state()).values())
    monkeypatch.setattr(priorcache, "MAX_RUN_BYTES", int(1.5 * entry))
    prior = run(p, **kw)["run"].backend.scheme.linearized_prior
    assert prior.factorizations == 2 and len(entries(cache)) == 1
    assert prior.store.written == (entry if COMM.rank == 0 else 0)
    prior = run(p, **kw)["run"].backend.scheme.linearized_prior
    assert (prior.factorizations, prior.loaded) == (1, 1)


def test_a_corrupt_entry_is_a_miss_and_is_replaced(cache):
    solve(base())
    [name] = entries(cache)
    if COMM.rank == 0:
        (cache / name).write_bytes(b"not an npz file")
    COMM.Barrier()
    again = solve(base())
    assert again.prior_source == "computed"
    fixed = solve(base())
    assert fixed.prior_source == "disk cache" and fixed.result.iterations == again.result.iterations


def test_disabled_or_unwritable_cache_does_not_fail_the_run(cache, monkeypatch, shared_tmp_path):
    monkeypatch.setenv("GELCELL_PRIOR_CACHE", "0")
    assert solve(base()).prior_source == "computed"
    assert entries(cache) == []
    monkeypatch.delenv("GELCELL_PRIOR_CACHE")
    blocker = shared_tmp_path / "a file"
    if COMM.rank == 0:
        blocker.write_text("a file where the cache directory would be")
    COMM.Barrier()
    monkeypatch.setenv("GELCELL_PRIOR_CACHE_DIR", str(blocker / "priors"))
    assert solve(base()).prior_source == "computed"


def test_the_device_default_has_the_prior_only_where_it_pays(cache, monkeypatch):
    """Steady IQN runs of the built-in devices with a small interface; an explicit choice is kept."""
    p = base()
    assert solve(p).linearized_prior is not None
    assert solve(p, coupling_config(params=p, jacobian_prior="none")).linearized_prior is None
    explicit = coupling_config(params=p, overrides={"acceleration": {"relaxation_prior": {"Gamma2/force": 0.5}}})
    assert solve(p, explicit).linearized_prior is None
    assert solve(p, coupling_config(acceleration="aitken", params=p)).linearized_prior is None
    robin = Device(p, COMM, gamma2="robin")
    robin.solve(coupling_config(params=p), verbose=False)
    assert robin.result.converged and robin.linearized_prior is None
    bound = device_module.AUTO_PRIOR_MAX_UNKNOWNS
    monkeypatch.setattr(device_module, "AUTO_PRIOR_MAX_UNKNOWNS", 10)
    small = solve(p)
    assert small.linearized_prior is None and small.scheme.layout.size > 10
    monkeypatch.setattr(device_module, "AUTO_PRIOR_MAX_UNKNOWNS", bound)

    def no_memory(n, m):
        raise MemoryError("too large")
    monkeypatch.setattr(device_module.cp.LinearizedPrior, "check_memory", staticmethod(no_memory))
    assert solve(p).linearized_prior is None           # the default falls back; it does not fail


def test_a_geometry_file_is_keyed_by_its_content(cache, shared_tmp_path):
    """A user's device has the prior too; an edited file (here: its inflow speed) is another problem."""
    source = open(os.path.join(os.path.dirname(__file__), "geometry_files", "small.geo")).read()
    path = shared_tmp_path / "device.geo"
    if COMM.rank == 0:
        path.write_text(source)
    COMM.Barrier()
    p = CaseParameters.from_dict({"geometry": {"file": str(path)}})
    first = solve(p)
    assert first.prior_source == "computed" and entries(cache)[0].startswith("file-")
    assert solve(p).prior_source == "disk cache"
    edited = source.replace("uniform:0.5", "uniform:0.7")
    assert edited != source
    if COMM.rank == 0:
        path.write_text(edited)
    COMM.Barrier()
    assert solve(CaseParameters.from_dict({"geometry": {"file": str(path)}})).prior_source == "computed"
    assert len(entries(cache)) == 2


def test_prune_keeps_the_most_recent_entries_within_the_byte_budget(tmp_path):
    pattern = re.compile(r"^shear-\d\.npz$")
    for i in range(5):
        path = tmp_path / f"shear-{i}.npz"
        path.write_bytes(b"x" * 100)
        os.utime(path, (1000 + i, 1000 + i))
    (tmp_path / "other.txt").write_bytes(b"x" * 1000)         # not an entry: never removed
    diskcache.prune(str(tmp_path), pattern, max_entries=4, max_bytes=250)
    assert sorted(os.listdir(tmp_path)) == ["other.txt", "shear-3.npz", "shear-4.npz"]
    diskcache.prune(str(tmp_path), pattern, max_entries=1)
    assert sorted(os.listdir(tmp_path)) == ["other.txt", "shear-4.npz"]
