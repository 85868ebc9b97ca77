"""No parameter value triggers form compilation once a case has run on the machine (issue 8, item 4).

Every coefficient that a parameter sets (Ca, the moduli, the units, the cell
position through the mesh) enters the compiled forms and expressions as a
``fem.Constant`` or through the mesh, never as a float baked into generated
code.  The test counts FFCx compilations (cache misses: ``_compile_objects``
runs only when the compiled module is not in the cache) during runs at new
parameter values, after one run that fills the cache, whatever state the
machine's cache was in before.  The runs write summaries, fields and
profiles; figures are left out (they draw Functions, no parameter enters
their compiled expressions) to keep the test short.
"""

from __future__ import annotations

import os

import pytest

from mpi4py import MPI

import ffcx.codegeneration.jit as ffcx_jit

from gelcell.case import CaseParameters, OutputSettings, RunConfig, SolverSettings
from gelcell.run.steady import run_case

COMM = MPI.COMM_WORLD


@pytest.fixture
def compilations(monkeypatch):
    """The names of the modules FFCx compiles (not loads from its cache) while the test runs."""
    names: list[str] = []
    original = ffcx_jit._compile_objects

    def counting(*args, **kwargs):
        names.append(str(args[1] if len(args) > 1 else kwargs.get("module_name")))
        return original(*args, **kwargs)

    monkeypatch.setattr(ffcx_jit, "_compile_objects", counting)
    return names


def _run(params, out, monolithic=False):
    with open(os.devnull, "w") as quiet:
        run_case(RunConfig(params, solver=SolverSettings(method="monolithic" if monolithic else "partitioned"),
                           output=OutputSettings(figures=False, progress=False)), out, stream=quiet)


@pytest.mark.parametrize("monolithic", [False, True], ids=["partitioned", "monolithic"])
def test_new_parameter_values_compile_nothing(shared_tmp_path, compilations, monolithic):
    base = CaseParameters.default("shear").with_mesh_size(3.0)
    _run(base, str(shared_tmp_path / "first"), monolithic=monolithic)       # fills the cache if needed
    compilations.clear()
    new = base.with_ca(7.7e-10).with_cell_moduli(3.3).with_gel_moduli(0.37).with_e(0.21)
    _run(new, str(shared_tmp_path / "new"), monolithic=monolithic)
    compiled = COMM.allreduce(len(compilations), op=MPI.SUM)
    assert compiled == 0, f"new parameter values compiled {compilations}"


def test_a_cached_form_loads_without_listing_the_cache(tmp_path, monkeypatch):
    """femtools.jitcache: a compiled form is loaded by its file name, not found by listing the cache.

    FFCx's own look-up builds an ``importlib.machinery.FileFinder`` on the cache
    directory, which lists the directory (thousands of files on a machine that
    has compiled many forms).  In an empty cache the first ``fem.form`` still
    compiles through FFCx; the second finds the finished module and must not
    build a finder.  Both forms assemble the exact integral.
    """
    import importlib.machinery

    import ufl
    from dolfinx import fem, mesh

    from femtools import jitcache

    assert jitcache.install() and jitcache.installed()
    cache = tmp_path / f"rank{COMM.rank}"
    msh = mesh.create_unit_square(MPI.COMM_SELF, 2, 2)
    x = ufl.SpatialCoordinate(msh)
    integrand = (x[0] ** 3 + 2.0 * x[1]) * ufl.dx        # int over the unit square = 1/4 + 1

    finders: list[str] = []
    original_finder = importlib.machinery.FileFinder

    class RecordingFinder(original_finder):
        def __init__(self, path, *loaders):
            finders.append(str(path))
            super().__init__(path, *loaders)

    monkeypatch.setattr(importlib.machinery, "FileFinder", RecordingFinder)
    values = []
    for _ in range(2):
        form = fem.form(integrand, jit_params={"cache_dir": str(cache)})
        values.append(fem.assemble_scalar(form))
        if not values[1:]:
            assert str(cache) in finders, "the first form was not compiled through FFCx"
            finders.clear()
    assert finders == [], f"the cached form was looked up by listing {finders}"
    assert values == pytest.approx([1.25, 1.25], rel=1e-13)


def test_a_first_compilation_leaves_the_arguments_of_a_settled_mesh_equal(tmp_path):
    """FFCx 0.5 gives the compiled form's mesh the equispaced coordinate variant at its first
    compilation (a cache miss), so a test function made after it differs from one made before and
    a form holding both fails; a mesh settled up front (the field solvers' meshes) keeps them equal.

    The regression: the finite-strain gel with two fluid interfaces on a dolfinx rectangle failed
    exactly so, on a machine whose cache lacked its interface flux form.
    """
    import ufl
    from dolfinx import fem, mesh

    from femtools.mesh import LEFT, RIGHT, rectangle_mesh, settle_coordinate_element
    from gel.parameters import GelParameters
    from gel.solver import PoroelasticGelSolver

    def made_before_and_after_a_compilation(msh, cache):
        V = fem.FunctionSpace(msh, ("Lagrange", 1))
        before = ufl.TestFunction(V)
        fem.form(before * ufl.dx, jit_params={"cache_dir": str(cache)})    # an empty cache: it compiles
        return before, ufl.TestFunction(V)

    before, after = made_before_and_after_a_compilation(mesh.create_unit_square(MPI.COMM_SELF, 2, 2),
                                                        tmp_path / f"plain{COMM.rank}")
    assert hash(before) != hash(after), "FFCx no longer changes the mesh at a compilation: drop the settling"
    with pytest.raises(Exception, match="different Arguments"):
        ((before + after) * ufl.dx).arguments()
    msh = settle_coordinate_element(mesh.create_unit_square(MPI.COMM_SELF, 2, 2))
    before, after = made_before_and_after_a_compilation(msh, tmp_path / f"settled{COMM.rank}")
    assert before == after and hash(before) == hash(after)
    form = (before + after) * ufl.dx
    assert len(form.arguments()) == 1
    # the field solvers settle the mesh they are given
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.25, 2, 1)
    assert msh.ufl_domain().ufl_coordinate_element().variant() is None
    PoroelasticGelSolver(msh, ft, GelParameters(phi_s0=0.1, lambda_s=1.5, xi=4.5e4, eta=0.02, Ca=1e-6),
                         fluid_interfaces={"in": LEFT, "out": RIGHT}, kinematics="finite", no_slip=[RIGHT])
    assert msh.ufl_domain().ufl_coordinate_element().variant() == "equispaced"


def test_form_signature_does_not_depend_on_how_many_constants_came_before():
    """The same form built twice, with the process's Constant count below 10 and above it: the same
    signature, so FFCx compiles it once (femtools.jitcache.sort_constants_by_count; UFL sorts the
    operands of a sum by comparing Constants, by their text "...(), 10)" < "...(), 9)" otherwise)."""
    import ufl
    from dolfinx import fem, mesh

    from femtools import jitcache

    assert jitcache.install()
    msh = mesh.create_unit_square(MPI.COMM_SELF, 1, 1)

    def form():
        a, b = fem.Constant(msh, 1.0), fem.Constant(msh, 2.0)
        return (a + b) * ufl.dx

    signatures = []
    for _ in range(3):
        signatures.append(form().signature())
        for _ in range(7):                      # the counts of the next pair gain a digit (or more)
            fem.Constant(msh, 0.0)
    assert len(set(signatures)) == 1, signatures


def test_a_form_another_process_is_compiling_is_awaited_past_ffcx_s_ten_seconds(tmp_path, monkeypatch):
    """A process that finds a form half-compiled by another (its ``.c`` file without the ``.c.cached``
    marker: parallel test workers on an empty cache) waits for it; FFCx's own 10 polls of 1 s would
    give up while a 3D form compiles.  The other process is simulated: the marker reappears at the
    15th poll (the polls do not sleep here)."""
    import ufl
    from dolfinx import fem, mesh

    from femtools import jitcache

    assert jitcache.install()
    cache = tmp_path / f"cache{COMM.rank}"
    msh = mesh.create_unit_square(MPI.COMM_SELF, 1, 1)
    integrand = (ufl.SpatialCoordinate(msh)[0] + 3.0) * ufl.dx
    fem.form(integrand, jit_params={"cache_dir": str(cache)})            # compiled: library and marker
    (marker,) = cache.glob("*.c.cached")
    hidden = marker.rename(marker.with_suffix(".hidden"))                 # as while another compiles it
    polls = []

    def poll(seconds):
        polls.append(seconds)
        if len(polls) == 15:
            hidden.rename(marker)                                         # the other process finished

    monkeypatch.setattr(ffcx_jit.time, "sleep", poll)
    form = fem.form(integrand, jit_params={"cache_dir": str(cache)})
    assert len(polls) == 15 and jitcache.WAIT_FOR_OTHER_COMPILATION > 15
    assert fem.assemble_scalar(form) == pytest.approx(3.5, rel=1e-13)
