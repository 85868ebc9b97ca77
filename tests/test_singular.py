"""Singular systems stop with the field and its likely missing condition (issue 12 item 4).

Every factorisation counts MUMPS's null pivots (INFOG(28)); the device's own
systems have none (every device test runs through that check).  The fluid's
pressure must be determined in each connected part of its mesh.  Serial and
on 2 ranks.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

from cell import NeoHookeanCellSolver
from cell import meshes
from femtools.errors import SingularSystemError
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, connected_components, rectangle_mesh
from fluid import FluidInterface, StokesSolver
from gel import GelParameters, PoroelasticGelSolver
from gelcell.geometry.builtin import device_boundaries
from gelcell.geometry.meshes import build_meshes
from gelcell.case import CaseParameters


def _column(**anchoring):
    """A gel column pushed down by the fluid on top, its sides symmetry lines (u_x = 0)."""
    msh, ft = rectangle_mesh(0.0, -1.0, 0.1, 0.0, 2, 8)
    gel = PoroelasticGelSolver(msh, ft, GelParameters.viscous_units(), symmetry=[((LEFT, RIGHT), 0)],
                               fluid_interfaces={"top": TOP}, **anchoring)
    X = gel.interface_points("top")
    gel.set_interface_data("top", traction=np.column_stack([0 * X[:, 0], -1.0 + 0 * X[:, 0]]),
                           velocity=np.zeros_like(X))
    return gel


def test_unanchored_gel_network_is_refused():
    """Nothing holds u_y: today MUMPS patched the null pivot and returned an arbitrary displacement."""
    with pytest.raises(SingularSystemError, match=r"^gel: the linear system is singular .*not anchored") as info:
        _column().solve()
    assert info.value.null_pivots >= 1


def test_anchored_gel_network_solves():
    gel = _column(dirichlet=[(BOTTOM, "u", 0.0)])
    gel.solve()
    assert gel.newton.stats["factorizations"] >= 1


def test_cell_free_to_slide_is_refused():
    """A quarter ring held only on the x axis (u_y = 0) can still translate along x."""
    msh, ft = meshes.annulus(1.0, 2.0, 0.4, quarter=True)
    cell = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.0, symmetry=[(meshes.XAXIS, 1)],
                                tractions=[(meshes.OUTER, np.array([0.0, -1e-6]))])
    with pytest.raises(SingularSystemError, match=r"^cell: the linear system is singular .*not held"):
        cell.solve()


@pytest.fixture(scope="module")
def normal_fluid():
    dev = build_meshes(CaseParameters.default("normal", False).with_mesh_size(3), MPI.COMM_WORLD,
                       regions=["fluid"], whole=False)
    return dev.region("fluid")


def _normal_fluid_solver(msh, ft, kind: str) -> StokesSolver:
    b = device_boundaries("normal", False)
    return StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=b.fluid_velocity, component_bcs=b.fluid_component,
                        interfaces={name: FluidInterface(tag, kind, kind)
                                    for name, tag in b.fluid_interfaces.items()})


def test_connected_fluid_parts():
    assert connected_components(build_meshes(CaseParameters.default("shear", False).with_mesh_size(3),
                                             MPI.COMM_WORLD, regions=["fluid"], whole=False)
                                .region("fluid")[0])[1] == 1


def test_pressure_is_checked_in_each_fluid_part(normal_fluid):
    """Normal-flow device: the upstream part enclosed by inflow, symmetry lines and a Dirichlet Gamma1.

    The downstream part has a free outlet, which used to let the whole mesh pass.
    """
    msh, ft = normal_fluid
    labels, count = connected_components(msh)
    assert count == 2 and set().union(*msh.comm.allgather(set(labels.tolist()))) == {0, 1}
    _normal_fluid_solver(msh, ft, "robin")               # the device's own conditions: fine
    with pytest.raises(ValueError, match=r"whole boundary of 1 of its 2 connected part") as info:
        _normal_fluid_solver(msh, ft, "dirichlet")
    x = float(str(info.value).split("near (")[1].split(",")[0])
    assert -1.0 < x < 0.0                                # the upstream part, x in [-1, 0]


@pytest.mark.parametrize("delta, singular", [(1e-15, True), (1e-6, False)])
def test_a_pivot_at_round_off_is_null(delta, singular):
    """[[1, 1], [1, 1 + delta]]: its second pivot is delta.  At delta = 1e-15 (round-off of the
    unit entries) the matrix is singular to working precision and refused; MUMPS's own default
    threshold (1e-5 machine epsilons) let such a pivot pass.  At 1e-6 it is regular and solves."""
    from petsc4py import PETSc

    from femtools.linalg import DirectSolver

    comm = MPI.COMM_WORLD
    A = PETSc.Mat().createAIJ(((None, 2), (None, 2)), nnz=2, comm=comm)
    start, end = A.getOwnershipRange()
    full = np.array([[1.0, 1.0], [1.0, 1.0 + delta]])
    for i in range(start, end):
        A.setValues([i], [0, 1], full[i])
    A.assemble()
    solver = DirectSolver(comm, "toy")
    solver.set_operator(A)
    if singular:
        with pytest.raises(SingularSystemError, match="^toy: the linear system is singular"):
            solver.factorize_symmetric_if_possible()
    else:
        solver.factorize_symmetric_if_possible()
        b, x = A.createVecLeft(), A.createVecRight()
        b.setValues(range(start, end), (full @ np.ones(2))[start:end])
        b.assemble()
        solver.solve(b, x)
        assert np.allclose(x.array_r, 1.0, rtol=1e-8)


def test_tags_are_normalised_in_one_place_and_bad_ones_named():
    """Every field solver reads its facet tags through femtools.mesh.as_tags: an int or ints, named
    in the error otherwise (a string is not read digit by digit)."""
    from femtools.mesh import as_tags

    assert as_tags(3) == (3,) and as_tags(np.int32(4)) == (4,) and as_tags(np.array([5, 6])) == (5, 6)
    with pytest.raises(TypeError, match="^no_slip: tags must be an int or an iterable of ints, got '12'"):
        as_tags("12", "no_slip")
    with pytest.raises(ValueError, match="^symmetry: empty tag list"):
        as_tags([], "symmetry")
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 1.0, 2, 2)
    with pytest.raises(TypeError, match="^no_slip: tags must be"):
        PoroelasticGelSolver(msh, ft, GelParameters.viscous_units(), no_slip="1")
    with pytest.raises(ValueError, match="^FluidInterface.tags: empty tag list"):
        FluidInterface(tags=[])


def test_boundary_values_are_read_in_one_place_and_bad_ones_named():
    """Dirichlet data and loads of every field go through femtools.functions.set_function: a number,
    one per component or a callable; another size or NaN is refused with the input's name."""
    from dolfinx import fem

    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 1.0, 2, 2)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    from femtools.functions import set_function

    assert np.all(set_function(fem.Function(V), 2.0, "g").x.array == 2.0)
    g = set_function(fem.Function(V), (1.0, -1.0), "g")
    assert np.all(g.x.array.reshape(-1, 2) == [1.0, -1.0])
    g = set_function(fem.Function(V), lambda x: np.vstack([x[0], 0 * x[0]]), "g")
    assert np.allclose(g.x.array.reshape(-1, 2)[:, 0], V.tabulate_dof_coordinates()[:, 0])
    with pytest.raises(ValueError, match=r"^g: must be a number, 2 numbers or a callable"):
        set_function(fem.Function(V), (1.0, 2.0, 3.0), "g")
    with pytest.raises(FloatingPointError, match="^g: contains NaN or Inf"):
        set_function(fem.Function(V), (np.nan, 0.0), "g")
    with pytest.raises(ValueError, match=r"^gel: Dirichlet value for 'u': must be a number, 2 numbers"):
        PoroelasticGelSolver(msh, ft, GelParameters.viscous_units(), no_slip=[LEFT],
                             dirichlet=[((RIGHT,), "u", (1.0, 2.0, 3.0))])
    with pytest.raises(FloatingPointError, match=r"^fluid: velocity_bcs value for tags \(1,\): contains NaN"):
        StokesSolver(msh, ft, velocity_bcs=[(LEFT, (np.nan, 0.0))], viscosity=1.0)
