"""The Stokes solver on 3D tetrahedra: the same code as in 2D (fluid.StokesSolver, fluid.ale).

Pressure-driven channels along x (``tests/fluid3d_cases.py``: structured Kuhn
tetrahedra, inlet with t.n = -DP and no tangential velocity, outlet with
V_y = V_z = 0 and t_x = 0, G = DP / L).  Then V = u(y, z) e_x with

* a duct (no slip on y = 0, W and z = 0, H): -mu (u_yy + u_zz) = G, u = 0 on the
  walls, the series of ``gelcell.geometry.layout.duct_poiseuille``;
* a slab (no slip on y = 0, W, symmetry V_z = 0 and zero tangential traction on
  the z faces): plane Poiseuille u = G y (W - y) / (2 mu), in the P2/P1 space;

and P = G (L - x).  Every check reduces over MPI first; the file runs unchanged
on 2 ranks (``./scripts/pytest-2-ranks tests/test_fluid_3d.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.spatial

from mpi4py import MPI

import ufl
from dolfinx import fem

from femtools.functions import integrate
from femtools.mesh import rectangle_mesh
from femtools.mesh import BOTTOM as RECT_BOTTOM, LEFT as RECT_LEFT, RIGHT as RECT_RIGHT, TOP as RECT_TOP
from fluid import FluidInterface, StokesSolver
from fluid3d_cases import (BACK, DP, FLOOR, FRONT, INLET, LID, MU, OUTLET, PIPE_WALL, box_mesh, channel,  # noqa: I001
                           pipe_mesh, relative_errors)
from gelcell.geometry.layout import duct_poiseuille, duct_poiseuille_peak, plane_poiseuille

COMM = MPI.COMM_WORLD


def owned_nodes(u: fem.Function):
    """Coordinates (n, 3) and values (n, bs) of the owned nodes of ``u``."""
    V = u.function_space
    n, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
    return V.tabulate_dof_coordinates()[:n], u.x.array[:n * bs].reshape(n, bs)


def global_max(values) -> float:
    return COMM.allreduce(float(np.max(np.abs(values), initial=0.0)), op=MPI.MAX)


# --------------------------------------------------------------------------- the inflow profiles
def test_duct_series_against_its_flow_rate_and_limits():
    """The duct series against an independent closed form: its flow rate (White, Viscous Fluid Flow, 3-48)

        Q = G W H^3 / (12 mu) [1 - 192 H / (pi^5 W) sum_{n odd} tanh(n pi W / (2 H)) / n^5],

    integrated with 40 x 40 Gauss points per direction; the square duct's centre speed 0.0736713 G H^2 / mu
    (to the 7 digits tabulated); W >> H gives plane Poiseuille; the walls have u = 0.  The plane profile's
    mean is the given mean (Gauss, exact for a quadratic).
    """
    W, H, G = 1.3, 0.4, 1.0
    gy, wy = np.polynomial.legendre.leggauss(40)
    y, z = np.meshgrid(W / 2 * (gy + 1), H / 2 * (gy + 1), indexing="ij")
    weights = np.outer(wy, wy) * W * H / 4
    peak = duct_poiseuille_peak(W, H, G, MU)
    Q = float(np.sum(weights * duct_poiseuille(y, z, W, H, peak)))
    n = np.arange(1, 400, 2)
    series = np.sum(np.tanh(n * np.pi * W / (2 * H)) / n**5)
    Q_exact = G * W * H**3 / (12 * MU) * (1 - 192 * H / (np.pi**5 * W) * series)
    assert abs(Q - Q_exact) < 1e-9 * Q_exact, (Q, Q_exact)
    assert abs(duct_poiseuille_peak(1.0, 1.0, 1.0, 1.0) - 0.0736713) < 1e-7
    assert abs(duct_poiseuille_peak(200 * H, H, G, MU) - G * H**2 / (8 * MU)) < 1e-12
    assert abs(duct_poiseuille(W / 2, H / 2, W, H, 2.5) - 2.5) < 1e-14
    edges = np.linspace(0, 1, 11)
    walls = [duct_poiseuille(0 * edges, H * edges, W, H, 1.0), duct_poiseuille(W + 0 * edges, H * edges, W, H, 1.0),
             duct_poiseuille(W * edges, 0 * edges, W, H, 1.0), duct_poiseuille(W * edges, H + 0 * edges, W, H, 1.0)]
    assert np.abs(walls).max() < 1e-14
    outside = duct_poiseuille(np.array([-1.0, W / 2, 2 * W]), np.array([H / 2, -3.0, H / 2]), W, H, 1.0)
    assert np.abs(outside).max() < 1e-14
    gz, wz = np.polynomial.legendre.leggauss(3)
    assert abs(np.sum(wz * plane_poiseuille(H / 2 * (gz + 1), H, 0.8)) / 2 - 0.8) < 1e-14
    with pytest.raises(ValueError, match="height must be finite and > 0"):
        duct_poiseuille(0.0, 0.0, W, -1.0, 1.0)


# --------------------------------------------------------------------------- 1. duct against the series
def test_duct_against_the_series_at_the_taylor_hood_rate():
    """Duct W x H = 1 x 0.5, L = 0.5, at two levels: L2 errors against the series.

    Taylor-Hood gives O(h^3) for V and O(h^2) for P for a smooth solution; the duct's corners (right
    angles with G != 0 there) add an r^2 log r term, so V is in H^(3-eps): a rate just below 3.
    """
    W, H, L = 1.0, 0.5, 0.5
    peak = duct_poiseuille_peak(W, H, DP / L, MU)
    levels = [(2, 4, 2), (4, 8, 4)]
    errors = []
    for n in levels:
        msh, ft = box_mesh((L, W, H), n)
        solver = channel(msh, ft, walls=(FRONT, BACK, FLOOR, LID))
        errors.append(relative_errors(solver, lambda y, z: duct_poiseuille(y, z, W, H, peak), L))
    (eV0, eP0), (eV1, eP1) = errors
    rate_V, rate_P = np.log2(eV0 / eV1), np.log2(eP0 / eP1)
    print(f"duct: L2 errors V {eV0:.3e} -> {eV1:.3e} (rate {rate_V:.2f}), P {eP0:.3e} -> {eP1:.3e} "
          f"(rate {rate_P:.2f})")
    assert rate_V > 2.6 and rate_P > 1.8, errors
    assert eV1 < 1e-2 and eP1 < 1e-2, errors


def test_hagen_poiseuille_in_a_pipe_with_curved_p2_faces():
    """A circular pipe (radius R, unstructured gmsh tetrahedra with P2 geometry): V = G (R^2 - r^2) / (4 mu)
    e_x, P = G (L - x).  On the isoparametric P2 mesh the quadratic V is not in the space of the curved
    cells; Taylor-Hood with a P2 boundary converges at O(h^3) for V (observed: faster, ~3.7, on these
    coarse levels, the boundary's own error being O(h^4) in volume).  h_eff = (volume / cells)^(1/3)."""
    R, L = 0.5, 1.0
    G = DP / L
    errors, sizes = [], []
    for h in (0.5, 0.25):
        msh, ft = pipe_mesh(L, R, h)
        solver = channel(msh, ft, walls=(PIPE_WALL,))
        x = ufl.SpatialCoordinate(msh)
        V_exact = ufl.as_vector((G / (4 * MU) * (R**2 - x[1]**2 - x[2]**2), 0 * x[0], 0 * x[0]))
        P_exact = G * (L - x[0])
        dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 6})
        e = solver.velocity - V_exact
        errors.append((np.sqrt(integrate(ufl.inner(e, e), dx) / integrate(ufl.inner(V_exact, V_exact), dx)),
                       np.sqrt(integrate((solver.pressure - P_exact)**2, dx) / integrate(P_exact**2, dx))))
        volume = integrate(1.0 + 0 * x[0], dx)
        sizes.append((volume / msh.topology.index_map(3).size_global) ** (1 / 3))
        # curved faces: straight ones would miss ~ h^2 / (6 R^2) of the volume, 4e-2 at h = 0.25
        assert abs(volume - np.pi * R**2 * L) < 1e-3 * np.pi * R**2 * L
    (eV0, eP0), (eV1, eP1) = errors
    ratio = np.log(sizes[0] / sizes[1])
    rate_V, rate_P = np.log(eV0 / eV1) / ratio, np.log(eP0 / eP1) / ratio
    print(f"pipe: h_eff {sizes[0]:.3f} -> {sizes[1]:.3f}: L2 errors V {eV0:.2e} -> {eV1:.2e} (rate {rate_V:.2f}), "
          f"P {eP0:.2e} -> {eP1:.2e} (rate {rate_P:.2f})")
    assert rate_V > 2.7 and rate_P > 1.8, errors
    assert eV1 < 1e-2 and eP1 < 1e-2, errors


# --------------------------------------------------------------------------- 2. symmetry planes
def test_half_duct_with_a_symmetry_plane_equals_the_full_duct():
    """The half height 0 < z < H/2 with V_z = 0 and zero tangential traction at z = H/2 equals the full
    duct on its mirror-symmetric mesh, node by node, to round-off: the full discrete solution is
    symmetric (unique, symmetric data) and its restriction solves the half problem (a half test function
    with v_z = 0 on the plane extends by mirroring to a full one), so the two discrete problems agree."""
    W, H, L = 1.0, 0.5, 0.5
    n = (2, 4, 2)
    half = channel(*box_mesh((L, W, H / 2), n), walls=(FRONT, BACK, FLOOR), symmetric=(LID,))
    full = channel(*box_mesh((L, W, H / 2), n, mirror=True), walls=(FRONT, BACK, FLOOR, LID))
    # the half's inlet nodes are the full inlet's nodes with z <= H/2, in the same (x, y, z) order
    points, below = full.interface_points("inlet"), full.interface_points("inlet")[:, 2] <= H / 2 + 1e-12
    assert np.allclose(half.interface_points("inlet"), points[below], rtol=0, atol=1e-12)
    scale = np.abs(full.interface_data("inlet")["velocity"]).max()
    diff = np.abs(half.interface_data("inlet")["velocity"] - full.interface_data("inlet")["velocity"][below]).max()
    # in the bulk: the half's nodal V and P against the full solution evaluated at them
    err = _difference_at_nodes(half, full)
    print(f"half vs full duct: inlet V {diff:.1e}, bulk V, P {err[0]:.1e}, {err[1]:.1e} (|V| {scale:.2f})")
    assert diff < 1e-10 * scale and err[0] < 1e-10 * scale and err[1] < 1e-10 * DP
    peak = duct_poiseuille_peak(W, H, DP / L, MU)
    e_half = relative_errors(half, lambda y, z: duct_poiseuille(y, z, W, H, peak), L)
    e_full = relative_errors(full, lambda y, z: duct_poiseuille(y, z, W, H, peak), L)
    print(f"against the series: half {e_half}, full {e_full}")
    assert np.allclose(e_half, e_full, rtol=1e-6)


def _difference_at_nodes(half, full) -> tuple[float, float]:
    """max |half - full| of V and P over the half's nodes, which are the full mesh's nodes with z <= H/2
    (its lower cells are the half's cells)."""
    out = []
    for mine, other in ((half.velocity, full.velocity), (half.pressure, full.pressure)):
        (X, values), (X_full, values_full) = (_gathered(u) for u in (mine, other))
        dist, idx = scipy.spatial.cKDTree(X_full).query(X)
        assert dist.max() < 1e-12
        out.append(float(np.abs(values - values_full[idx]).max()))
    return out[0], out[1]


def _gathered(u: fem.Function):
    """Coordinates and values of every node of ``u``, on every rank."""
    X, values = owned_nodes(u)
    return np.vstack(COMM.allgather(X)), np.vstack(COMM.allgather(values))


def test_slab_with_symmetric_z_faces_is_the_2d_plane_poiseuille():
    """Symmetry on z = 0 and z = Z (V_z = 0, zero tangential traction): plane Poiseuille in y, exact in
    P2/P1 (to round-off), and equal to the 2D solver's solution on the rectangle of the same (x, y) mesh."""
    W, Z, L, n = 1.0, 0.3, 1.0, (4, 4, 2)
    G = DP / L
    slab = channel(*box_mesh((L, W, Z), n), walls=(FRONT, BACK), symmetric=(FLOOR, LID))

    def exact(X):
        return np.column_stack([G * X[:, 1] * (W - X[:, 1]) / (2 * MU), 0 * X[:, 0], 0 * X[:, 0]])
    X, V = owned_nodes(slab.velocity)
    Xp, P = owned_nodes(slab.pressure)
    eV, eP = global_max(V - exact(X)), global_max(P[:, 0] - G * (L - Xp[:, 0]))
    U = G * W**2 / (8 * MU)
    assert eV < 1e-10 * U and eP < 1e-10 * DP, (eV, eP)

    # the 2D solver on the rectangle with the same (x, y) nodes: the same solution at the same points
    msh2, ft2 = rectangle_mesh(0.0, 0.0, L, W, n[0], n[1])
    plane = StokesSolver(msh2, ft2, viscosity=MU, velocity_bcs=[((RECT_BOTTOM, RECT_TOP), (0.0, 0.0))],
                         component_bcs=[(RECT_RIGHT, 1, 0.0)],
                         interfaces={"inlet": FluidInterface(RECT_LEFT, normal="robin", tangential="dirichlet")})
    plane.set_interface_data("inlet", robin_normal=np.tile([DP, 0.0], (len(plane.interface_points("inlet")), 1)))
    plane.solve()
    pts3, pts2 = slab.interface_points("inlet"), plane.interface_points("inlet")
    assert pts3.shape[1] == 3 and pts2.shape[1] == 2
    v3, v2 = slab.interface_data("inlet")["velocity"], plane.interface_data("inlet")["velocity"]
    layers = np.unique(np.round(pts3[:, 2], 12))
    assert len(layers) == 2 * n[2] + 1
    for z in layers:
        layer = np.isclose(pts3[:, 2], z)
        assert np.allclose(pts3[layer, :2], pts2, rtol=0, atol=1e-12)
        assert np.abs(v3[layer, :2] - v2).max() < 1e-10 * U and np.abs(v3[layer, 2]).max() < 1e-10 * U
    print(f"slab: errors V {eV:.1e}, P {eP:.1e}; = 2D at the inlet nodes of its {len(layers)} layers")


# --------------------------------------------------------------------------- 3. interface data on a 3D face
def test_wall_traction_on_a_3d_face():
    """The wall y = 0 of the slab as an interface (no slip, full Dirichlet with zero data), the flow driven
    by a body force f = G e_x (the pressure drop's gradient, with P = 0): V = G y (W - y) / (2 mu) e_x
    and the traction ON the fluid, n = -e_y,

        t = (Sigma - P I) n = (-mu dV_x/dy, P, 0) = (-G W / 2, 0, 0)        at y = 0,

    constant, so in the P2 trace space.  The components that the other boundaries fix (V_y at the ends,
    V_z on the symmetry faces) are zero in t as well, so lambda = t at EVERY node (no end pollution)
    and the total force is (-G W L Z / 2, 0, 0)."""
    W, Z, L, G = 1.0, 0.3, 1.0, 1.7
    msh, ft = box_mesh((L, W, Z), (3, 4, 2))
    solver = StokesSolver(msh, ft, viscosity=MU, body_force=(G, 0.0, 0.0), velocity_bcs=[(BACK, (0.0, 0.0, 0.0))],
                          component_bcs=[(INLET, 1, 0.0), (INLET, 2, 0.0), (OUTLET, 1, 0.0), (OUTLET, 2, 0.0),
                                         ((FLOOR, LID), 2, 0.0)],
                          interfaces={"wall": FluidInterface(FRONT, normal="dirichlet", tangential="dirichlet")})
    assert solver.input_names("wall") == {"velocity": 3}
    solver.solve()
    X = solver.interface_points("wall")
    data = solver.interface_data("wall")
    assert X.shape == (len(X), 3) and np.abs(X[:, 1]).max() < 1e-12
    assert data["velocity"].shape == data["traction"].shape == (len(X), 3)
    t = np.tile([-G * W / 2, 0.0, 0.0], (len(X), 1))
    err = np.abs(data["traction"] - t).max()
    F, F_exact = solver.interface_force("wall"), np.array([-G * W * L * Z / 2, 0.0, 0.0])
    print(f"wall traction: nodal error {err:.1e} at {len(X)} nodes; force {F} (exact {F_exact})")
    assert np.abs(data["velocity"]).max() < 1e-12
    assert err < 1e-10 * G * W
    assert np.abs(F - F_exact).max() < 1e-10 * abs(F_exact[0])


def test_sliding_lid_as_a_tangential_dirichlet_interface():
    """Couette flow: the lid z = Z an interface with a tangential Dirichlet part (its data (N, 3) = (U, 0, 0):
    the two tangential components of a z = const plane) and a traction-free normal part; no slip on the
    floor, V_y = 0 on the y faces and V_y = V_z = 0 with t_x = 0 at the ends.  Exact: V = U z / Z e_x,
    P = 0 (in P2/P1), the lid's traction ON the fluid t = (mu U / Z, 0, 0) (n = e_z, t_z = -P = 0): it drags
    the fluid along."""
    W, Z, L, U = 0.8, 0.5, 1.0, 1.3
    msh, ft = box_mesh((L, W, Z), (2, 2, 2))
    solver = StokesSolver(msh, ft, viscosity=MU, velocity_bcs=[(FLOOR, (0.0, 0.0, 0.0))],
                          component_bcs=[((FRONT, BACK), 1, 0.0), ((INLET, OUTLET), 1, 0.0),
                                         ((INLET, OUTLET), 2, 0.0)],
                          interfaces={"lid": FluidInterface(LID, normal="robin", tangential="dirichlet")})
    assert solver.input_names("lid") == {"velocity": 3, "robin_normal": 3}
    X = solver.interface_points("lid")
    solver.set_interface_data("lid", velocity=np.tile([U, 0.0, 0.0], (len(X), 1)))
    solver.solve()
    Xv, V = owned_nodes(solver.velocity)
    eV = global_max(V - np.column_stack([U * Xv[:, 2] / Z, 0 * Xv[:, 0], 0 * Xv[:, 0]]))
    eP = global_max(owned_nodes(solver.pressure)[1])
    t = solver.interface_data("lid")["traction"]
    # the ends fix V_y, V_z of the lid's edge nodes and the y faces V_y: exact t_y = t_z = 0 there
    e_t = np.abs(t - np.tile([MU * U / Z, 0.0, 0.0], (len(X), 1))).max()
    print(f"sliding lid: errors V {eV:.1e}, P {eP:.1e}, lid traction {e_t:.1e}")
    assert eV < 1e-10 * U and eP < 1e-10 * MU * U / Z and e_t < 1e-10 * MU * U / Z


def test_3d_input_errors_name_the_dimension():
    msh, ft = box_mesh((1.0, 1.0, 1.0), (1, 1, 1))
    with pytest.raises(ValueError, match=r"component must be 0 \(x\), 1 \(y\) or 2 \(z\) in 3D, got 3"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(INLET, (1.0, 0.0, 0.0))], component_bcs=[(LID, 3, 0.0)])
    with pytest.raises(ValueError, match="body_force must be a UFL 3-vector"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(INLET, (1.0, 0.0, 0.0))], body_force=(1.0, 0.0))
    with pytest.raises(ValueError, match=r"pressure_pin must be a point \(x, y, z\)"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[((INLET, OUTLET, FRONT, BACK, FLOOR, LID), 0.0)],
                     pressure_pin=(0.0, 0.0))
    with pytest.raises(ValueError, match="flat, axis-aligned interface .* dz=1"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(INLET, (1.0, 0.0, 0.0))],
                     interfaces={"bent": FluidInterface((FRONT, FLOOR), tangential="dirichlet")})
    with pytest.raises(ValueError, match=r"pass pressure_pin=\(x, y, z\)"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[((INLET, OUTLET, FRONT, BACK, FLOOR, LID), 0.0)])
    # V_z on the z faces is their normal component: enclosed; V_x there is tangential: the normal flow is free
    sides = [((INLET, OUTLET, FRONT, BACK), (1.0, 0.0, 0.0))]
    with pytest.raises(ValueError, match="prescribed on the whole boundary of 1 of its 1 connected part"):
        StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=sides, component_bcs=[((FLOOR, LID), 2, 0.0)])
    StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=sides, component_bcs=[((FLOOR, LID), 0, 0.0)])


# --------------------------------------------------------------------------- 4. the moving domain (fluid.ale)
def test_moving_slab_sheared_and_stretched():
    """fluid.ale on tetrahedra: the slab's walls and ends displaced by the affine motion
    u_m = (a x + s y, e y, 0) (a = 0.1, shear s = 0.3, stretch e = 0.2; the z faces sliding: u_m,z = 0).
    Its gradient has rank 2, so the 3D terms of the kinematics count: J = 1 + tr G + I2 + det G =
    (1 + a)(1 + e) (I2 = a e), and cof F has the a e entry.  The harmonic extension reproduces the
    motion exactly, and on the current slab of width W' = (1 + e) W the plane Poiseuille flow
    V = 4 U y' (W' - y') / W'^2 e_x, P = -8 mu U / W'^2 x' (x' = X + u_m; inflow and outflow given as
    that profile) lies in the P2/P1 space of the moved mesh: exact to round-off, with the pressure
    gradient of the current width (1.44 x smaller than that of the reference one)."""
    from fluid.ale import MovingStokesSolver
    W, Z, L, U, a, shear, eps = 1.0, 0.3, 1.5, 1.0, 0.1, 0.3, 0.2
    msh, ft = box_mesh((L, W, Z), (3, 3, 1))

    def motion(X):
        return np.vstack([a * X[0] + shear * X[1], eps * X[1], 0 * X[2]])
    Wc = (1 + eps) * W

    def profile(X):
        y = X[1] + motion(X)[1]
        return np.vstack([4 * U * y * (Wc - y) / Wc**2, 0 * y, 0 * y])
    solver = MovingStokesSolver(msh, ft, viscosity=MU, velocity_bcs=[((INLET, OUTLET), profile),
                                                                      ((FRONT, BACK), (0.0, 0.0, 0.0))],
                                component_bcs=[((FLOOR, LID), 2, 0.0)],
                                mesh_boundaries={"walls": (INLET, OUTLET, FRONT, BACK)},
                                pressure_pin=(0.0, 0.0, 0.0))
    solver.set_boundary_displacement("walls", motion)
    solver.solve()
    u_m = solver.mesh_displacement
    X, values = owned_nodes(u_m)
    e_motion = global_max(values - motion(X.T).T)
    x = ufl.SpatialCoordinate(msh) + u_m
    V_ex = ufl.as_vector((4 * U * x[1] * (Wc - x[1]) / Wc**2, 0.0 * x[1], 0.0 * x[1]))
    P_ex = -8 * MU * U / Wc**2 * x[0]
    J = ufl.det(ufl.Identity(3) + ufl.grad(u_m))
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 6})
    eV, eP = solver.velocity - V_ex, solver.pressure - P_ex
    errV = np.sqrt(integrate(J * ufl.inner(eV, eV), dx) / integrate(J * ufl.inner(V_ex, V_ex), dx))
    errP = np.sqrt(integrate(J * eP**2, dx) / integrate(J * P_ex**2, dx))
    volume, exact_volume = integrate(J, dx), (1 + a) * (1 + eps) * L * W * Z
    print(f"moving slab: mesh motion error {e_motion:.1e}, errors V {errV:.1e}, P {errP:.1e}, "
          f"volume {volume:.6f} (exact {exact_volume:.6f}); Newton {solver.newton.history}")
    assert e_motion < 1e-12 and abs(volume - exact_volume) < 1e-12
    assert errV < 1e-9 and errP < 1e-9


# --------------------------------------------------------------------------- 5. the linearised interface map
@pytest.mark.parametrize("moving", [False, True], ids=["fixed", "moving_at_rest"])
def test_interface_jacobian_in_3d(moving):
    """interface_jacobian() on tetrahedra against the solver: the outputs are affine in the Robin data,
    so out(g + delta) - out(g) = J delta to round-off (tests/test_fluid_jacobian.py in 2D); the moving
    solver at zero displacement with its normal_flux input too.  Inlet and outlet of a no-slip duct are
    Robin interfaces (3-component data) whose edges lie on the walls."""
    from fluid.ale import MovingStokesSolver
    msh, ft = box_mesh((1.0, 0.6, 0.4), (2, 2, 1))
    solver = (MovingStokesSolver if moving else StokesSolver)(
        msh, ft, viscosity=MU, velocity_bcs=[((FRONT, BACK, FLOOR, LID), (0.0, 0.0, 0.0))],
        interfaces={"in": FluidInterface(INLET, alpha_n=1.0, alpha_t=0.5),
                    "out": FluidInterface(OUTLET, alpha_n=0.0, alpha_t=2.0)})
    rng = np.random.default_rng(1)
    names = solver.interface_names()
    keys = {name: [k for k in solver.input_names(name) if k != "displacement"] for name in names}
    assert all(solver.input_names(name)[k] == 3 for name in names for k in solver.input_names(name))
    shape = {name: (len(solver.interface_points(name)), 3) for name in names}
    base = {name: {k: rng.standard_normal(shape[name]) for k in keys[name]} for name in names}
    delta = {name: {k: rng.standard_normal(shape[name]) for k in keys[name]} for name in names}

    def outputs(data):
        for name, arrays in data.items():
            solver.set_interface_data(name, **arrays)
        solver.solve()
        return {name: solver.interface_data(name) for name in names}
    out0 = outputs(base)
    out1 = outputs({n: {k: base[n][k] + delta[n][k] for k in keys[n]} for n in names})
    J = solver.interface_jacobian()
    for o in names:
        for ok in ("velocity", "traction"):
            predicted = sum(J[((o, ok), (i, ik))] @ delta[i][ik].ravel() for i in names for ik in keys[i])
            change = (out1[o][ok] - out0[o][ok]).ravel()
            assert J[((o, ok), (o, "robin_normal"))].shape == (3 * shape[o][0], 3 * shape[o][0])
            assert np.abs(predicted - change).max() < 1e-9 * np.abs(change).max(), (o, ok)
