"""Stokes on a moving domain (fluid/ale.py) and the mesh motion (femtools/meshmotion.py).

* The pulled-back form equals the form assembled on the physically moved
  mesh (isoparametric P2 mesh, P2 mesh displacement): the ALE pull-back is
  the current configuration, not an approximation of it.
* Poiseuille flow in a channel whose walls were displaced: the channel of
  reference height H becomes one of height H' = (1 + eps) H (and, in the
  first case, sheared into a parallelogram); the closed form
  V = 4 U y (H' - y) / H'^2, dP/dx = -8 mu U / H'^2 holds on the CURRENT
  configuration.  An affine motion keeps it in the P2/P1 space (exact to
  round-off); a motion that slides the wall's nodes along it (a distorted,
  curved mesh of the same rectangle) converges at the P2 rate.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

import scipy.spatial
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from cell import meshes
from cell.meshes import BOTTOM, LEFT, RIGHT, TOP
from femtools.functions import integrate
from fluid import forms
from fluid.ale import MovingStokesSolver, ale_bulk_residual

COMM = MPI.COMM_WORLD
L, H, U, MU = 2.0, 1.0, 1.0, 0.7


def _move_geometry(msh, u_m, sign=1.0):
    """x <- x + sign * u_m at the geometry nodes (the P2 nodes of an isoparametric P2 mesh)."""
    X = u_m.function_space.tabulate_dof_coordinates()[:, :2]
    dist, idx = scipy.spatial.cKDTree(X).query(msh.geometry.x[:, :2])
    assert dist.max() < 1e-12
    msh.geometry.x[:, :2] += sign * u_m.x.array.reshape(-1, 2)[idx]


def test_pull_back_equals_the_moved_mesh():
    """The ALE residual on the reference mesh = the Stokes residual assembled on the moved mesh."""
    msh, ft = meshes.rectangle(L, H, 0.3)
    P2 = ufl.VectorElement("Lagrange", msh.ufl_cell(), 2)
    P1 = ufl.FiniteElement("Lagrange", msh.ufl_cell(), 1)
    W = fem.FunctionSpace(msh, ufl.MixedElement([P2, P1]))
    w = fem.Function(W)
    w.sub(0).interpolate(lambda x: np.vstack([np.sin(x[0]) * x[1], np.cos(x[1]) + x[0]]))
    w.sub(1).interpolate(lambda x: x[0] * x[1] - 0.3)
    u_m = fem.Function(fem.VectorFunctionSpace(msh, ("Lagrange", 2)))
    u_m.interpolate(lambda x: np.vstack([0.1 * np.sin(np.pi * x[0] / L) * x[1], 0.15 * x[1] * x[0] ** 2 / L ** 2]))
    V, P = ufl.split(w)
    v, q = ufl.TestFunctions(W)
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 6})
    mu, d = fem.Constant(msh, MU), fem.Constant(msh, 1.0)
    pulled = fem_petsc.assemble_vector(fem.form(ale_bulk_residual(V, P, v, q, mu, u_m, d, dx)))
    _move_geometry(msh, u_m)
    try:
        moved = fem_petsc.assemble_vector(fem.form(forms.bulk_residual(V, P, v, q, mu, dx)))
    finally:
        _move_geometry(msh, u_m, -1.0)
    for vec in (pulled, moved):
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    diff = pulled.copy()
    diff.axpy(-1.0, moved)
    rel = diff.norm() / moved.norm()
    print(f"pull-back vs moved mesh: relative difference {rel:.1e}")
    assert rel < 1e-12


def channel(h, shear):
    """The channel with its walls moved: the top by (shear H + slide(x), eps H), the ends by (shear y, eps y)."""
    eps = 0.2
    msh, ft = meshes.rectangle(L, H, h)

    def motion(X):
        slide = 0.0 if shear else 0.15 * np.sin(np.pi * X[0] / L) * X[1] / H
        return np.vstack([shear * X[1] + slide, eps * X[1]])

    def current(X):
        return X[:2] + motion(X)

    Hc = (1 + eps) * H

    def profile(X):
        y = current(X)[1]
        return np.vstack([4 * U * y * (Hc - y) / Hc**2, 0 * y])
    solver = MovingStokesSolver(msh, ft, viscosity=MU, velocity_bcs=[((LEFT, RIGHT), profile),
                                                                      ((BOTTOM, TOP), (0.0, 0.0))],
                                mesh_boundaries={"walls": (LEFT, RIGHT, TOP)}, pressure_pin=(0.0, 0.0))
    solver.set_boundary_displacement("walls", motion)
    solver.solve()
    return solver, Hc, current


def errors(solver, Hc, current):
    """Relative L2 errors of V and of P - P(0) against the closed form on the current configuration."""
    msh = solver.mesh
    x = ufl.SpatialCoordinate(msh) + solver.mesh_displacement       # the current position
    V_ex = ufl.as_vector((4 * U * x[1] * (Hc - x[1]) / Hc**2, 0.0 * x[1]))
    P_ex = -8 * MU * U / Hc**2 * (x[0] - current(np.zeros((2, 1)))[0, 0])
    J = ufl.det(ufl.Identity(2) + ufl.grad(solver.mesh_displacement))
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 8})
    eV = solver.velocity - V_ex
    eP = solver.pressure - P_ex
    return (np.sqrt(integrate(J * ufl.inner(eV, eV), dx) / integrate(J * ufl.inner(V_ex, V_ex), dx)),
            np.sqrt(integrate(J * eP**2, dx) / integrate(J * P_ex**2, dx)))


def test_poiseuille_in_a_sheared_and_stretched_channel():
    """Affine motion (shear 0.3, stretch 1.2): the closed form is in the P2/P1 space of the moved mesh."""
    solver, Hc, current = channel(0.25, shear=0.3)
    eV, eP = errors(solver, Hc, current)
    print(f"sheared channel: errors V {eV:.1e}, P {eP:.1e}; Newton {solver.newton.history}")
    # round-off only; the pressure gradient is that of the current height (the reference one is 1.44 x larger)
    assert eV < 1e-9 and eP < 1e-9


def test_poiseuille_with_nodes_sliding_along_the_wall():
    """The top wall's nodes slide along it (a curved, distorted mesh of the taller rectangle): rate ~3."""
    hs = (0.5, 0.25, 0.125)
    res = [errors(*channel(h, shear=0.0)) for h in hs]
    eV = [r[0] for r in res]
    eP = [r[1] for r in res]
    rV = np.polyfit(np.log(hs), np.log(eV), 1)[0]
    rP = np.polyfit(np.log(hs), np.log(eP), 1)[0]
    print(f"sliding wall nodes: errors V {eV}, P {eP}; rates {rV:.2f}, {rP:.2f}")
    assert rV >= 2.7 and rP >= 1.8, (eV, eP)
    assert eV[-1] < 1e-4


def test_mesh_motion_reuses_its_factorisation():
    solver, _, _ = channel(0.5, shear=0.3)
    for k in range(3):
        solver.set_boundary_displacement("walls", lambda X, k=k: np.vstack([(0.1 + 0.05 * k) * X[1], 0.1 * X[1]]))
        solver.solve()
    assert solver.motion.stats["factorizations"] == 1


def test_linear_path_with_a_moving_mesh_reaches_the_exact_solution():
    """``linear_path``: a solve that continues from the previous solution takes one step with the
    Jacobian at rest, the new mesh position and data being data of the step; repeated at a fixed
    mesh position (a coupling loop's fixed point) it reaches the exact path's solution (1e-10)."""
    def solver_at(linear_path):
        msh, ft = meshes.rectangle(L, H, 0.25)
        s = MovingStokesSolver(msh, ft, viscosity=MU,
                               velocity_bcs=[((LEFT,), lambda X: np.vstack([4 * U * X[1] * (H - X[1]) / H**2,
                                                                            0 * X[1]])),
                                             ((BOTTOM, TOP), (0.0, 0.0))],
                               mesh_boundaries={"walls": (TOP, RIGHT)}, linear_path=linear_path)
        return s

    def moved(a):
        return lambda X: np.vstack([a * X[1] * X[0], 0.5 * a * X[1] * np.sin(X[0])])
    exact, loop = solver_at(False), solver_at(True)
    exact.set_boundary_displacement("walls", moved(2e-4))
    exact.solve()
    loop.set_boundary_displacement("walls", moved(1e-4))
    loop.solve()
    loop.set_boundary_displacement("walls", moved(2e-4))
    errors = []
    for _ in range(4):
        loop.solve()
        errors.append(np.linalg.norm(loop.w.x.array - exact.w.x.array) / np.linalg.norm(exact.w.x.array))
    print(f"moving mesh, linear path: errors {errors}, linear steps {loop.newton.stats['linear_steps']}")
    # (a solve whose first step is already below the tolerance ends there, not counted as a linear step)
    assert loop.newton.stats["linear_steps"] >= 2 and exact.newton.stats["linear_steps"] == 0
    assert errors[0] > 1e-9            # one step leaves the nonlinear remainder ...
    assert errors[-1] < 1e-10          # ... which the continued solves remove
