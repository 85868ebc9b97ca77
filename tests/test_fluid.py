"""Verification of the Stokes field solver ``fluid.StokesSolver``.

Closed forms from shared/design/verification.md section 1 and 1D solutions
derived in the docstrings below.  Conventions of the solver: t = (Sigma - P I) n
is the traction ON the fluid, n the fluid's outward normal, Sigma = 2 mu D(V).

Runs under ``pytest`` and ``mpirun -n 2 python -m pytest`` (every check
reduces over MPI first); ``test_same_answer_on_two_ranks`` launches
``tests/mpi_scripts/fluid_parallel.py`` on 1 and 2 ranks.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
import pytest

from mpi4py import MPI

import ufl
from dolfinx import fem, mesh as dmesh

from femtools.functions import integrate, quadrature_measure
from fluid import FluidInterface, StokesSolver

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "mpi_scripts"))
from fluid_cases import (BALANCE, BOTTOM, HOLE, INLET, OUTLET, TOP, balance_case,  # noqa: E402
                         channel_mesh, hole_robin)
from mpi_run import run_mpi  # noqa: E402

comm = MPI.COMM_WORLD


# --------------------------------------------------------------------------- helpers
def owned_dofs(V: fem.FunctionSpace):
    """Coordinates (n_owned, 2) and owned unrolled values slice of a Lagrange space."""
    n = V.dofmap.index_map.size_local
    return V.tabulate_dof_coordinates()[:n, :2], n * V.dofmap.index_map_bs


def max_nodal_error(u: fem.Function, exact) -> float:
    """max over all owned nodes of |u - exact(X)|, exact: (n, 2) -> (n, bs)."""
    X, m = owned_dofs(u.function_space)
    bs = u.function_space.dofmap.index_map_bs
    err = np.abs(u.x.array[:m].reshape(-1, bs) - np.asarray(exact(X)).reshape(-1, bs))
    return comm.allreduce(float(err.max(initial=0.0)), op=MPI.MAX)


# --------------------------------------------------------------------------- 1. Poiseuille
def test_poiseuille_patch_and_wall_traction():
    """Plane Poiseuille (verification.md 1a), patch test on an unstructured mesh.

    0 < x < L, 0 < y < H; parabolic inflow u = 4 U y (H - y) / H^2 at x = 0;
    no slip at y = 0 (declared as interface "wall", full Dirichlet with zero
    data) and y = H; at x = L the parallel do-nothing outflow V_y = 0 and
    t_x = 0.  (The plain do-nothing t = 0 is not exact here: with the
    symmetric stress Sigma = 2 mu D(V) the Poiseuille flow has a shear
    traction mu u'(y) on x = L.)

    Exact: u = 4 U y (H - y) / H^2, P = G (L - x), G = 8 mu U / H^2, which lie
    in P2/P1, so nodal values must be exact to rounding.

    Wall traction on the fluid at y = 0 (n = (0, -1)): t = (-mu u'(0), P) =
    (-4 mu U / H, G (L - x)), again in P2.  lambda equals it except near the
    inflow end x = 0, whose velocity is fixed by the inflow's Dirichlet
    condition: there lambda = 0 is imposed and the error decays
    geometrically along the interface (by ~0.15 per element for the P2 mass
    matrix), so nodes with x >= L/2 (>= 20 elements away) must be exact to 1e-10.

    Total force.  With e = lambda - t: (M e)_i = 0 on the free rows, e_p = -t_p
    at the pinned end, hence int e ds = -S t_p with S = M_pp - M_pf M_ff^-1 M_fp,
    the Schur complement of the interface mass matrix, 0 < S <= M_pp = 2 h_e / 15
    (h_e the length of the end element).  So per component
    0 < (F_exact - F_lambda) / t_p(0) <= 2 h_e / 15: a local O(h) effect.  (At
    x = L only the y component is pinned, and t_y(L) = P(L) = 0.)
    """
    L, H, mu, U, h = 4.0, 1.0, 0.7, 1.3, 0.1
    G = 8 * mu * U / H**2
    msh, ft = channel_mesh(L, H, h)
    solver = StokesSolver(
        msh, ft, viscosity=mu,
        velocity_bcs=[(INLET, lambda x: np.vstack((4 * U * x[1] * (H - x[1]) / H**2, 0 * x[0]))),
                      (TOP, (0.0, 0.0))],
        component_bcs=[(OUTLET, 1, lambda x: 0.0 * x[0])],       # a callable value, for coverage
        interfaces={"wall": FluidInterface(BOTTOM, normal="dirichlet", tangential="dirichlet")})
    solver.solve()

    eu = max_nodal_error(solver.velocity, lambda X: np.column_stack(
        (4 * U * X[:, 1] * (H - X[:, 1]) / H**2, 0 * X[:, 0])))
    ep = max_nodal_error(solver.pressure, lambda X: G * (L - X[:, 0]))
    dp = G * L
    assert eu < 1e-10 * U, f"nodal velocity error {eu:.3e}"
    assert ep < 1e-10 * dp, f"nodal pressure error {ep:.3e} (pressure drop {dp})"

    X = solver.interface_points("wall")
    data = solver.interface_data("wall")
    t_exact = np.column_stack((np.full(len(X), -4 * mu * U / H), G * (L - X[:, 0])))
    assert np.abs(data["velocity"]).max() < 1e-12
    far = X[:, 0] >= L / 2
    e_far = np.abs(data["traction"][far] - t_exact[far]).max()
    assert e_far < 1e-10 * dp, f"traction error at nodes x >= L/2: {e_far:.3e}"
    assert np.all(data["traction"][0] == 0.0), "lambda must be pinned where the inflow fixes V"
    # the pollution near x = 0 is real and decays: O(|t|) at the end, tiny mid-way
    e_near = np.abs(data["traction"][X[:, 0] <= 2 * h] - t_exact[X[:, 0] <= 2 * h]).max()
    assert e_near > 1e3 * e_far

    F = solver.interface_force("wall")
    F_exact = np.array([-4 * mu * U / H * L, G * L**2 / 2])
    h_end = 2 * np.sort(X[:, 0])[1]                    # first node after x = 0 is the mid node
    ratio = (F_exact - F) / t_exact[0]
    assert np.all(ratio > 0) and np.all(ratio <= 2 * h_end / 15 * (1 + 1e-8)), \
        f"(F_exact - F) / t(0) = {ratio}, expected in (0, 2 h_e / 15 = {2 * h_end / 15:.4f}]"


# --------------------------------------------------------------------------- 2. manufactured solution
def _mms_errors(N: int, mu: float = 1.0):
    """Errors of verification.md 1b on create_unit_square(N, N)."""
    msh = dmesh.create_unit_square(comm, N, N)
    fdim = 1
    msh.topology.create_connectivity(fdim, 2)
    facets = dmesh.exterior_facet_indices(msh.topology)
    ft = dmesh.meshtags(msh, fdim, facets, np.full(facets.size, 1, dtype=np.int32))
    x = ufl.SpatialCoordinate(msh)
    pi, sin, cos = np.pi, ufl.sin, ufl.cos
    u_ex = ufl.as_vector((pi * sin(pi * x[0])**2 * sin(2 * pi * x[1]),
                          -pi * sin(2 * pi * x[0]) * sin(pi * x[1])**2))
    p_ex = cos(pi * x[0]) * cos(pi * x[1])
    f = ufl.as_vector((pi * (2 * pi**2 * mu * (1 - 2 * cos(2 * pi * x[0])) * sin(2 * pi * x[1])
                             - sin(pi * x[0]) * cos(pi * x[1])),
                       pi * (-2 * pi**2 * mu * (1 - 2 * cos(2 * pi * x[1])) * sin(2 * pi * x[0])
                             - cos(pi * x[0]) * sin(pi * x[1]))))
    solver = StokesSolver(msh, ft, viscosity=mu, velocity_bcs=[(1, (0.0, 0.0))], body_force=f,
                          pressure_pin=(0.0, 0.0))
    solver.solve()
    V, P = solver.velocity, solver.pressure
    dx = quadrature_measure("dx", msh, degree=8)
    area = integrate(fem.Constant(msh, 1.0), dx)
    p_mean = integrate(P, dx) / area
    e_u = np.sqrt(integrate(ufl.inner(V - u_ex, V - u_ex), dx))
    e_h1 = np.sqrt(integrate(ufl.inner(ufl.grad(V - u_ex), ufl.grad(V - u_ex)), dx))
    e_p = np.sqrt(integrate((P - p_mean - p_ex)**2, dx))
    return e_u, e_h1, e_p


def test_manufactured_solution_rates():
    """Taylor–Hood rates on verification.md 1b: u L2 >= 2.8, H1 >= 1.9, p L2 >= 1.9.

    Also compares the errors on N = 8 with the reference table of
    verification.md (the same mesh family, a different diagonal): within 30 %.
    """
    Ns = [8, 16, 32]
    errors = np.array([_mms_errors(N) for N in Ns])
    h = 1.0 / np.array(Ns)
    rates = [np.polyfit(np.log(h), np.log(errors[:, k]), 1)[0] for k in range(3)]
    msg = (f"rates u_L2 {rates[0]:.3f}, u_H1 {rates[1]:.3f}, p_L2 {rates[2]:.3f}; "
           f"errors {errors.tolist()}")
    assert rates[0] >= 2.8 and rates[1] >= 1.9 and rates[2] >= 1.9, msg
    reference = np.array([1.139e-2, 5.899e-1, 6.126e-2])
    assert np.all(np.abs(errors[0] / reference - 1) < 0.3), msg


# --------------------------------------------------------------------------- 3. Robin conditions
@pytest.mark.parametrize("alpha_t,g_t", [(0.0, 0.5), (3.0, 0.0), (3.0, -0.4)])
def test_tangential_robin_slip_wall(alpha_t, g_t):
    """Pressure-driven channel over a tangential Robin (slip) wall: exact 1D profile.

    0 < x < L, 0 < y < H.  Inlet x = 0 and outlet x = L: interfaces with a
    normal traction (Robin, alpha_n = 0) and tangential Dirichlet V_y = 0;
    data g_N = P_in (1, 0) at the inlet (t.n = -P there, n = (-1, 0), so
    P = P_in) and g_N = 0 at the outlet.  Wall y = 0: normal Dirichlet V_y = 0,
    tangential Robin t_x + alpha_t V_x = g_t.  Wall y = H: no slip.

    With G = P_in / L the parallel flow u(y) solves mu u'' = -G, u(H) = 0 and,
    since t_x = -mu u'(0) on y = 0 (n = (0, -1)), -mu u'(0) + alpha_t u(0) = g_t:

        u = -G y^2 / (2 mu) + A y + B,   A = (alpha_t G H^2 / (2 mu) - g_t) / (mu + alpha_t H),
        B = G H^2 / (2 mu) - A H,        P = P_in (1 - x / L).

    alpha_t = 0 is a prescribed shear traction, alpha_t -> inf recovers
    Poiseuille.  u and P lie in P2/P1: nodal errors must be rounding.
    """
    L, H, mu, P_in, h = 2.0, 1.0, 0.9, 3.0, 0.2
    msh, ft = channel_mesh(L, H, h)
    ends = dict(normal="robin", tangential="dirichlet")
    solver = StokesSolver(
        msh, ft, viscosity=mu, velocity_bcs=[(TOP, (0.0, 0.0))],
        interfaces={"in": FluidInterface(INLET, **ends), "out": FluidInterface(OUTLET, **ends),
                    "slip": FluidInterface(BOTTOM, normal="dirichlet", tangential="robin", alpha_t=alpha_t)})
    assert solver.input_names("slip") == {"velocity": 2, "robin_tangential": 2}
    n_in = len(solver.interface_points("in"))
    solver.set_interface_data("in", robin_normal=np.tile([P_in, 0.0], (n_in, 1)))
    n_slip = len(solver.interface_points("slip"))
    # a normal component in g_T must be ignored (only its tangential part enters)
    solver.set_interface_data("slip", robin_tangential=np.tile([g_t, 7.0], (n_slip, 1)))
    solver.solve()

    G = P_in / L
    A = (alpha_t * G * H**2 / (2 * mu) - g_t) / (mu + alpha_t * H)
    B = G * H**2 / (2 * mu) - A * H

    def u_exact(X):
        y = X[:, 1]
        return np.column_stack((-G * y**2 / (2 * mu) + A * y + B, 0 * y))

    eu = max_nodal_error(solver.velocity, u_exact)
    ep = max_nodal_error(solver.pressure, lambda X: P_in * (1 - X[:, 0] / L))
    scale = abs(B) + abs(A) + G
    assert eu < 1e-10 * scale, f"velocity error {eu:.3e}"
    assert ep < 1e-10 * P_in, f"pressure error {ep:.3e}"
    slip = solver.interface_data("slip")["velocity"]
    assert np.allclose(slip[:, 0], B, rtol=1e-10, atol=1e-12 * scale), "slip velocity u(0) = B"


def test_normal_robin_pressure_level():
    """Enclosed slip channel closed by normal Robin conditions: closed-form U and P.

    0 < x < L, 0 < y < H; slip walls V_y = 0 on y = 0, H (component_bcs).
    Inlet x = 0 (n = (-1, 0)): t.n + a_in V.n = g_in.n, tangential traction
    free (Robin, alpha_t = 0, data with a normal part that must be ignored).
    Outlet x = L (n = (1, 0)): t.n + a_out V.n = g_out.n, tangential V_y = 0.
    Without the Robin terms the normal velocity would be Dirichlet data on
    the whole boundary (the incompressibility dilemma, model.md section 6).

    Plug flow V = (U, 0) with a uniform P solves the Stokes equations; then
    t.n = -P on both ends and V.n = -U (inlet), +U (outlet):

        -P - a_in U = g_in.n,   -P + a_out U = g_out.n
        => U = (g_out.n - g_in.n) / (a_in + a_out),   P = -g_in.n - a_in U.
    """
    L, H, mu, h = 2.0, 1.0, 1.3, 0.25
    a_in, a_out = 2.0, 0.5
    g_in, g_out = np.array([-2.0, 0.7]), np.array([0.5, -0.3])      # g.n = 2.0 and 0.5
    msh, ft = channel_mesh(L, H, h)
    solver = StokesSolver(
        msh, ft, viscosity=mu, component_bcs=[((BOTTOM, TOP), 1, 0.0)],
        interfaces={"in": FluidInterface(INLET, alpha_n=a_in, alpha_t=0.0),
                    "out": FluidInterface(OUTLET, tangential="dirichlet", alpha_n=a_out)})
    n_in, n_out = len(solver.interface_points("in")), len(solver.interface_points("out"))
    solver.set_interface_data("in", robin_normal=np.tile(g_in, (n_in, 1)),
                              robin_tangential=np.tile([4.0, 0.0], (n_in, 1)))
    solver.set_interface_data("out", robin_normal=np.tile(g_out, (n_out, 1)))
    gn_in, gn_out = -g_in[0], g_out[0]
    # the second pass changes a_in through set_robin_coefficients (one more factorisation)
    for alpha in (a_in, 5.0):
        if alpha != 2.0:
            solver.set_robin_coefficients("in", alpha_n=alpha)
        solver.solve()
        U = (gn_out - gn_in) / (alpha + a_out)
        P = -gn_in - alpha * U
        eu = max_nodal_error(solver.velocity, lambda X, U=U: np.column_stack((np.full(len(X), U), 0 * X[:, 0])))
        ep = max_nodal_error(solver.pressure, lambda X, P=P: np.full(len(X), P))
        assert eu < 1e-10 * abs(U), f"a_in = {alpha}, U = {U}: velocity error {eu:.3e}"
        assert ep < 1e-10 * abs(P), f"a_in = {alpha}, P = {P}: pressure error {ep:.3e}"
        # consistent traction on the outlet: t.n = -P (its y component is pinned at the walls)
        tr = solver.interface_data("out")["traction"]
        assert np.allclose(tr[:, 0], -P, rtol=1e-10), "outlet traction t_x = -P"
    assert solver.stats["stokes"]["factorizations"] == 2


# --------------------------------------------------------------------------- 4. force balance
def test_global_force_balance():
    """Reactions + Robin forces + body force = 0 over the whole boundary.

    Plate with a hole (curved P2 geometry).  Outer boundary: one interface
    with full Dirichlet data; hole: Robin in both parts with data; constant
    body force f.  Testing the discrete equations with the constant fields
    e_x, e_y (in the P2 space, D(e) = 0, div e = 0): the bulk residual sums to
    R(e) = -int f.e dx, free rows vanish, so

        int lambda_outer ds + int lambda_hole ds + int f dx = 0

    exactly (no interface has rows pinned by another boundary, so
    int lambda ds is the sum of its reaction rows).  Independently, the Robin
    force on the hole is int (g_N.n - a_n V.n) n + (g_T - a_t V)_tau ds,
    computed here from the velocity field.
    """
    solver, r = balance_case(h=0.15)
    total = r["F_outer"] + r["F_hole"] + r["body"]
    scale = max(np.abs(r["F_outer"]).max(), np.abs(r["body"]).max())
    assert np.abs(total).max() < 1e-10 * scale, f"force balance residual {total} (scale {scale:.3g})"

    msh = solver.mesh
    V2 = fem.FunctionSpace(msh, ufl.VectorElement("Lagrange", msh.ufl_cell(), 2))
    gN, gT = fem.Function(V2), fem.Function(V2)
    gN.interpolate(lambda x: hole_robin(x[:2].T)[0].T)
    gT.interpolate(lambda x: hole_robin(x[:2].T)[1].T)
    n = ufl.FacetNormal(msh)
    Vh = solver.velocity
    ds = quadrature_measure("ds", msh, solver.facet_tags, degree=solver.quadrature_degree)(HOLE)
    tn = ufl.dot(gN, n) - BALANCE["alpha_n"] * ufl.dot(Vh, n)
    tt = (gT - ufl.dot(gT, n) * n) - BALANCE["alpha_t"] * (Vh - ufl.dot(Vh, n) * n)
    robin = np.array([integrate((tn * n + tt)[c], ds) for c in range(2)])
    assert np.abs(r["F_hole"] - robin).max() < 1e-10 * scale, f"{r['F_hole']} vs Robin force {robin}"
    assert np.abs(robin).max() > 1e-2 * scale      # the Robin force is not trivially zero


# --------------------------------------------------------------------------- 5. MPI
@pytest.mark.skip_in_parallel
def test_same_answer_on_two_ranks():
    """tests/mpi_scripts/fluid_parallel.py on 1 and 2 ranks: same numbers to 1e-9 (relative)."""
    serial = run_mpi("fluid_parallel.py", 1)
    parallel = run_mpi("fluid_parallel.py", 2)
    assert serial.keys() == parallel.keys()
    assert parallel.pop("ranks") == 2 and serial.pop("ranks") == 1
    for key in serial:
        a, b = np.asarray(serial[key], dtype=float), np.asarray(parallel[key], dtype=float)
        assert np.allclose(a, b, rtol=1e-9, atol=1e-12 * (1 + np.abs(a).max())), f"{key}: {a} vs {b}"


# --------------------------------------------------------------------------- errors
def test_errors_are_clear():
    """Bad arguments raise errors naming the argument and the allowed values."""
    with pytest.raises(ValueError, match="normal must be one of"):
        FluidInterface(1, normal="neumann")
    with pytest.raises(ValueError, match="alpha_t must be finite and >= 0"):
        FluidInterface(1, alpha_t=-1.0)
    with pytest.raises(ValueError, match="only used with normal='robin'"):
        FluidInterface(1, normal="dirichlet", alpha_n=1.0)
    msh, ft = channel_mesh(1.0, 1.0, 0.5)
    with pytest.raises(ValueError, match="no facet of the mesh has it"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(99, (0, 0))])
    with pytest.raises(ValueError, match="viscosity must be finite and > 0"):
        StokesSolver(msh, ft, viscosity=0.0)
    with pytest.raises(ValueError, match="pressure_pin"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[((INLET, OUTLET, TOP), (0, 0))],
                     component_bcs=[(BOTTOM, 1, 0.0)])
    with pytest.raises(ValueError, match="used by velocity_bcs and by interface"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(INLET, (0, 0))],
                     interfaces={"a": FluidInterface(INLET)})


def test_single_dirichlet_part_needs_axis_aligned_interface():
    """normal='dirichlet' alone on the (curved) hole is refused with a clear message."""
    from fluid_cases import plate_with_hole_mesh, OUTER
    msh, ft = plate_with_hole_mesh(0.4)
    with pytest.raises(ValueError, match="axis-aligned"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(OUTER, (1, 0))],
                     interfaces={"hole": FluidInterface(HOLE, normal="dirichlet")})


def test_solve_reuses_the_factorisation():
    """New interface data -> new solution, no new factorisation (counted by ``stats``)."""
    solver, _ = balance_case(h=0.3)
    before = solver.stats
    X = solver.interface_points("hole")
    gN, gT = hole_robin(X)
    solver.set_interface_data("hole", robin_normal=2 * gN, robin_tangential=gT)
    old = solver.interface_data("hole")["velocity"]
    solver.solve()
    after = solver.stats
    assert after["stokes"]["factorizations"] == before["stokes"]["factorizations"] == 1
    assert after["traction"]["factorizations"] == before["traction"]["factorizations"] == 2
    assert after["stokes"]["solves"] == before["stokes"]["solves"] + 1
    assert np.abs(solver.interface_data("hole")["velocity"] - old).max() > 1e-3


# --------------------------------------------------------------------------- timing (not run by default)
@pytest.mark.benchmark
def test_factorise_once_saving():
    """Time of solve() with new interface data vs a solve that refactorises (reported, not asserted)."""
    solver, _ = balance_case(h=0.02)
    X = solver.interface_points("hole")
    gN, gT = hole_robin(X)
    times = {"reuse": [], "refactorise": []}
    for k in range(3):
        solver.set_interface_data("hole", robin_normal=(1 + k) * gN, robin_tangential=gT)
        t0 = time.perf_counter()
        solver.solve()
        solver.interface_data("hole")
        times["reuse"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        solver.update_operator()        # re-assemble and re-factorise, then the same solve
        solver.solve()
        solver.interface_data("hole")
        times["refactorise"].append(time.perf_counter() - t0)
    dofs = solver.W.dofmap.index_map.size_global * solver.W.dofmap.index_map_bs
    if comm.rank == 0:
        print(f"\nStokes dofs {dofs}: solve reusing the factorisation {min(times['reuse']):.3f} s, "
              f"with refactorisation {min(times['refactorise']):.3f} s")
