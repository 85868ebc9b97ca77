"""A verification device: a free-fluid channel over a gel layer, with closed forms.

Derivation and measured errors: docs/verification-coupled.md.

Geometry (lengths in L0): the fluid fills 0 < y < H_f and the gel -H_g < y < 0,
both over 0 < x < length; the interface Gamma1 is the line y = 0 (n = +e_y,
out of the gel).  The device's own coupling machinery runs it: the real
``StokesSolver`` and ``PoroelasticGelSolver``, wrapped as the
``FluidParticipant`` and ``GelParticipant`` of ``gelcell.coupled.participants`` with its
``coupling_data`` and ``coupling_config``, iterated by ``coupling.build_scheme``.
Only the geometry and the outer boundary conditions are this module's.

The slab (``LayerDevice(..., depth=W)``): the same layer extruded to
0 < z < W on tetrahedra, with symmetry conditions on the z faces (tags
Tag.FLOOR z = 0 and Tag.SYMMETRY_MID z = W, as the 3D devices' slab): zero normal velocity, network displacement and
flux (V_z = v_f,z = u_z = 0) and zero tangential traction (natural).  The
fully developed solution has no z component and does not depend on z, so
it solves the slab exactly, and the 1D closed forms below hold unchanged.

Three fully developed (x-independent) steady flows (``LayerCase.flow``):

    "poiseuille"   a uniform body force G e_x drives both phases; lid at rest
    "couette"      the lid y = H_f moves at (U_w, 0)
    "compression"  the fluid enters through the lid at V = (0, -q), permeates
                   the gel and leaves through its rigid permeable support

In the first two the gel is bonded at y = -H_g (v_f = 0, u_s = 0); in the
third its support holds the network (u_s = 0) and lets the fluid out freely
(natural condition: p = 0 there).

A body force G e_x in both phases is the same problem as a pressure gradient
-G e_x in both: P and p then both differ by -G x, and every interface
condition I13-I17 involves only tractions and P - p, which do not change.
The body force keeps P = p = 0, which lets the ends below be exact.

End conditions, x = 0 and x = length (tags INLET and OUTLET in both meshes),
chosen so that the 1D solution solves the 2D problem exactly and the only
error is discretisation:

    poiseuille, couette:  V_y = 0, v_f,y = u_y = 0; the normal (x) tractions
                          are natural and vanish exactly (P = p = 0,
                          Sigma_xx = sigma_xx = 0)
    compression:          V_x = 0, v_f,x = u_x = 0; the shear (y) tractions
                          are natural and vanish exactly

Where the fluid's Gamma1 nodes meet an end, the fluid solver zeroes the
traction component fixed by the end's Dirichlet condition (fluid/solver.py);
with these ends that component of the exact traction is zero.

Units: the solvers' viscous units, s = d = Ca (stress mu V0/L0, displacement
Ca L0, velocity V0).  The closed forms are written in them and are
independent of Ca; multiply stresses by Ca for units of mu_s and
displacements by Ca for units of L0.  The closed form is that of the
linearised model (J -> 1), whose neglected terms are of relative size of
the strains, ~ Ca.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem, mesh as dmesh

import coupling as cp
from femtools.functions import integrate
from femtools.interface import InterfaceNodes
from femtools.timestepping import WindowClock
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from fluid import FluidInterface, StokesSolver
from gel import GelParameters, PoroelasticGelSolver
from gelcell.coupled.data import coupling_data
from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.monolithic import MonolithicCoefficients, MonolithicSolver
from gelcell.coupled.participants import FluidParticipant, GelParticipant
from gelcell.geometry import DeviceBoundaries, Tag

__all__ = ["FLOWS", "LayerCase", "LayerClosedForm", "LayerDevice", "LayerMonolithic",
           "layer_boundaries"]

FLOWS = ("poiseuille", "couette", "compression")
_ENDS = [int(Tag.INLET), int(Tag.OUTLET)]
#: the slab's symmetry faces z = 0 and z = depth (the 3D devices' floor and mid-height tags)
_FACES_Z = [int(Tag.FLOOR), int(Tag.SYMMETRY_MID)]


@dataclasses.dataclass(frozen=True)
class LayerCase:
    """A channel-over-gel-layer case (see the module docstring).

    Attributes:
        flow: ``"poiseuille"``, ``"couette"`` or ``"compression"``.
        drive: G (body force, stress per length), U_w (lid speed, V0) or q
            (flux through the lid, V0), by ``flow``.
        H_f, H_g, length: fluid depth, gel depth, channel length (L0).
        phi_s0, xi, lambda_s, beta, eta, Ca: the model's dimensionless groups.
    """

    flow: str
    drive: float = 1.0
    H_f: float = 1.0
    H_g: float = 1.0            # = 4 delta with the defaults below
    length: float = 0.25
    phi_s0: float = 0.2
    xi: float = 80.0            # delta = 1/sqrt(xi phi_s0) = 0.25
    lambda_s: float = 1.5
    beta: float = 0.02
    eta: float = 0.02
    Ca: float = 3e-10

    def __post_init__(self):
        if self.flow not in FLOWS:
            raise ValueError(f"LayerCase.flow must be one of {FLOWS}, got {self.flow!r}")
        for name in ("H_f", "H_g", "length"):
            if not getattr(self, name) > 0:
                raise ValueError(f"LayerCase.{name} must be > 0, got {getattr(self, name)!r}")
        self.gel_parameters()       # validates the model's groups

    @classmethod
    def table1(cls, flow: str, **changes) -> "LayerCase":
        """Table 1 of the source paper (model.md section 5): phi_s0, xi, lambda_s, beta, eta, Ca.

        The fluid is the shear device's channel (H_f = 0.2); the gel layer is
        4 Brinkman lengths deep, like the default case: delta = 1/sqrt(xi phi_s0)
        = 0.047, H_g = 0.189.  The Poiseuille drive G = 8/H_f^2 is the device's
        (a parabola of maximum V0 over a rigid wall); the others are 1.
        """
        t1, H_f = GelParameters(), 0.2          # GelParameters' defaults are Table 1
        H_g = 4.0 * t1.brinkman_length
        values = dict(phi_s0=t1.phi_s0, xi=t1.xi, lambda_s=t1.lambda_s, beta=t1.beta, eta=t1.eta, Ca=t1.Ca,
                      H_f=H_f, H_g=H_g, length=H_g / 4, drive=8.0 / H_f**2 if flow == "poiseuille" else 1.0)
        values.update(changes)
        return cls(flow, **values)

    def gel_parameters(self) -> GelParameters:
        """The gel solver's parameters, in viscous units (s = d = Ca)."""
        return GelParameters.viscous_units(phi_s0=self.phi_s0, xi=self.xi, lambda_s=self.lambda_s,
                                           beta=self.beta, eta=self.eta, Ca=self.Ca)

    @property
    def brinkman_length(self) -> float:
        """delta = 1/sqrt(xi phi_s0) (L0)."""
        return self.gel_parameters().brinkman_length

    @property
    def drivers(self) -> tuple[float, float, float]:
        """(G, U_w, q) of this flow."""
        return tuple(self.drive if self.flow == f else 0.0 for f in FLOWS)


class LayerClosedForm:
    """The fully developed solution of the layer, from model.md's equations and I13-I17.

    Linear model (phi = phi_s0 uniform, small strain), steady (v_s = 0), in the
    solvers' viscous units.  The tangential drivers (G, U_w) and the normal
    one (q) superpose.  Derivation: docs/verification-coupled.md.

    I16 and I17 share the model's beta.  ``beta_fluid`` (I16) and
    ``beta_network`` (I17) may be set apart, only to check the closed form
    against the literature's limits (beta_fluid = 0 and beta_network = inf
    is the Neale-Nader closure of verification.md 3b and 6b).

    Tangential part (delta = 1/sqrt(xi phi_s), X = H_g/delta, w_inf = G/(xi phi_s)):

        K   = phi_f coth(X)/delta + phi_s^2/beta_network
        W   = [U_w + G H_f^2/2 + (beta_fluid + H_f) phi_f w_inf tanh(X/2)/delta]
              / [1 + (beta_fluid + H_f) K]                       v_f,x at Gamma1
        tau = K W - phi_f w_inf tanh(X/2)/delta                  shear stress at Gamma1
        U_i = W + beta_fluid tau                                 V_x at Gamma1
        V_x = U_i + tau y - G y^2/2
        v_f,x = w_inf (1 - cosh s) + B sinh s,  s = (y + H_g)/delta,
                B = (W - w_inf (1 - cosh X))/sinh X
        u_x = [tau (y + H_g) - G (y^2 - H_g^2)/2 - phi_f v_f,x]/phi_s

    Normal part (M = 2 + lambda_s, g = xi phi_s q/phi_f):

        V_y = -q,  v_f,y = -q/phi_f,  p = g (y + H_g)
        Delta p_i = P - p(0) = q phi_s^2/(eta phi_f^2)
        P = g H_g + Delta p_i
        u_y = [g (y^2 - H_g^2)/2 - Delta p_i (y + H_g)]/(phi_s M)
    """

    def __init__(self, case: LayerCase, beta_fluid: float | None = None,
                 beta_network: float | None = None):
        self.case = c = case
        self.G, self.U_w, self.q = c.drivers
        self.beta_fluid = c.beta if beta_fluid is None else float(beta_fluid)
        self.beta_network = c.beta if beta_network is None else float(beta_network)
        phi_s = c.phi_s0
        phi_f = 1.0 - phi_s
        self.phi_s, self.phi_f = phi_s, phi_f
        # tangential part
        delta = c.brinkman_length
        X = c.H_g / delta
        w_inf = self.G / (c.xi * phi_s)
        K = phi_f / (delta * math.tanh(X)) + phi_s**2 / self.beta_network
        core = phi_f * w_inf * math.tanh(X / 2) / delta
        lever = self.beta_fluid + c.H_f
        self.delta, self.w_inf = delta, w_inf
        self.W = (self.U_w + self.G * c.H_f**2 / 2 + lever * core) / (1.0 + lever * K)
        self.tau = K * self.W - core
        self.U_i = self.W + self.beta_fluid * self.tau
        self.B = (self.W - w_inf * (1.0 - math.cosh(X))) / math.sinh(X)
        # normal part
        self.g = c.xi * phi_s * self.q / phi_f
        self.dp_i = self.q * phi_s**2 / (c.eta * phi_f**2)
        self.P = self.g * c.H_g + self.dp_i
        self.M = 2.0 + c.lambda_s

    # -- profiles ---------------------------------------------------------------------------
    def fluid(self, y) -> tuple:
        """(V_x, V_y, P) at height y > 0 (y a number, array, UFL or sympy expression)."""
        zero = 0 * y
        return (self.U_i + self.tau * y - self.G * y**2 / 2, zero - self.q, zero + self.P)

    def gel(self, y, m: types.ModuleType = np) -> tuple:
        """(v_f,x, v_f,y, u_x, u_y, p) at height y < 0; ``m`` supplies cosh and sinh (numpy, ufl or sympy)."""
        c, zero = self.case, 0 * y
        s = (y + c.H_g) / self.delta
        w = self.w_inf * (1 - m.cosh(s)) + self.B * m.sinh(s)
        u_x = (self.tau * (y + c.H_g) - self.G * (y**2 - c.H_g**2) / 2 - self.phi_f * w) / self.phi_s
        u_y = (self.g * (y**2 - c.H_g**2) / 2 - self.dp_i * (y + c.H_g)) / (self.phi_s * self.M)
        return (w, zero - self.q / self.phi_f, u_x, u_y, self.g * (y + c.H_g))

    def displacement_gradient(self, y):
        """(du_x/dy, du_y/dy) at heights y < 0 (numpy)."""
        c = self.case
        s = (y + c.H_g) / self.delta
        dw = (-self.w_inf * np.sinh(s) + self.B * np.cosh(s)) / self.delta
        return ((self.tau - self.G * y - self.phi_f * dw) / self.phi_s,
                (self.g * y - self.dp_i) / (self.phi_s * self.M))

    def max_strain(self) -> float:
        """max |F - I| over the layer in units of L0/L0 (u_s = Ca u).

        The size of what the linear closed form neglects.
        """
        y = np.linspace(-self.case.H_g, 0.0, 2001)
        return self.case.Ca * float(np.hypot(*self.displacement_gradient(y)).max())

    # -- interface values (n = e_y out of the gel, t = e_x) --------------------------------
    @property
    def interface(self) -> dict[str, np.ndarray]:
        """Exact values on Gamma1 of the quantities the coupling exchanges or the user asks for.

        velocity: V; slip: V - v_f (tangential: the I16 slip; normal: the
        I15 seepage jump); superficial_velocity: phi_f v_f, whose normal part
        is the flux into the fluid; displacement: u_s; traction: T_F =
        (Sigma - P I) n, the fluid's traction on the gel.
        """
        V = np.array(self.fluid(0.0)[:2])
        w, v, u_x, u_y, _ = self.gel(0.0)
        v_f = np.array([w, v])
        return {"velocity": V, "slip": V - v_f, "superficial_velocity": self.phi_f * v_f,
                "displacement": np.array([u_x, u_y]), "traction": np.array([self.tau, -self.P])}

    @property
    def flow_rates(self) -> tuple[float, float]:
        """(Q_f, Q_p): the fluid's flow rate int V_x dy and the gel's superficial one int phi_f v_f,x dy."""
        c = self.case
        X = c.H_g / self.delta
        Q_f = self.U_i * c.H_f + self.tau * c.H_f**2 / 2 - self.G * c.H_f**3 / 6
        Q_p = self.phi_f * (self.w_inf * (c.H_g - self.delta * math.sinh(X))
                            + self.B * self.delta * (math.cosh(X) - 1.0))
        return Q_f, Q_p

    @property
    def stress_scale(self) -> float:
        """max(|tau|, |P|): the scale of the pressure errors."""
        return max(abs(self.tau), abs(self.P))


def layer_boundaries(case: LayerCase, dim: int = 2) -> DeviceBoundaries:
    """The layer's boundary conditions as a DeviceBoundaries (tags of :func:`_strip`), in ``dim`` = 2 or 3
    (the slab: V_z = 0, v_f,z = u_z = 0 on the faces z = 0 and z = depth).

    The compression support (u_s = 0, v_f free) is not expressible there;
    :class:`LayerDevice` adds it as extra gel data.
    """
    G, U_w, q = case.drivers
    compression = case.flow == "compression"
    slab = dim == 3
    lid = ((0.0, -q) if compression else (U_w, 0.0)) + (0.0,) * (dim - 2)
    return DeviceBoundaries(
        fluid_velocity=[([int(Tag.WALL)], lid)],
        fluid_component=[(_ENDS, 0 if compression else 1, 0.0)] + ([(_FACES_Z, 2, 0.0)] if slab else []),
        gel_no_slip=[] if compression else [int(Tag.BOWL)],
        gel_symmetry=[(_ENDS, 0 if compression else 1)] + ([(_FACES_Z, 2)] if slab else []),
        cell_symmetry=[],
        fluid_interfaces={"Gamma1": int(Tag.GAMMA1)},
        cell_interfaces={}, dim=dim)


def _strip(case: LayerCase, y0: float, y1: float, nx: int, ny: int, bottom: Tag, top: Tag,
           comm: MPI.Comm, depth: float | None = None, nz: int = 1):
    """A rectangle [0, length] x [y0, y1] tagged INLET (x = 0), OUTLET (x = length), ``bottom``, ``top``;
    with ``depth`` the box [0, length] x [y0, y1] x [0, depth] (nz cells along z), also FLOOR (z = 0) and
    SYMMETRY_MID (z = depth)."""
    if depth is not None:
        return _box(case, (y0, y1), (nx, ny, nz), depth, comm,
                    ((bottom, 1, y0), (top, 1, y1)))
    msh, ft = rectangle_mesh(0.0, y0, case.length, y1, nx, ny, comm)
    retag = {LEFT: Tag.INLET, RIGHT: Tag.OUTLET, BOTTOM: bottom, TOP: top}
    values = np.array([int(retag[int(v)]) for v in ft.values], dtype=np.int32)
    return msh, dmesh.meshtags(msh, 1, ft.indices, values)


def _box(case: LayerCase, ys: tuple[float, float], n: tuple[int, int, int], depth: float, comm: MPI.Comm,
         planes) -> tuple:
    """Tetrahedra (dolfinx's ``create_box``) on [0, length] x [ys] x [0, depth], tagged INLET, OUTLET,
    FLOOR (z = 0), SYMMETRY_MID (z = depth) and, for each ``(tag, axis, value)`` of ``planes``, the
    facets on that plane (interior ones too)."""
    msh = dmesh.create_box(comm, [np.array([0.0, ys[0], 0.0]), np.array([case.length, ys[1], depth])],
                           list(n), dmesh.CellType.tetrahedron)
    sides = ((int(Tag.INLET), 0, 0.0), (int(Tag.OUTLET), 0, case.length), (int(Tag.FLOOR), 2, 0.0),
             (int(Tag.SYMMETRY_MID), 2, depth))
    return msh, _plane_tags(msh, tuple(sides) + tuple((int(t), a, v) for t, a, v in planes))


def _plane_tags(msh, planes) -> dmesh.MeshTags:
    """Facet tags: ``tag`` on every facet lying in the plane x[axis] = value, for each (tag, axis, value)."""
    fdim = msh.topology.dim - 1
    tol = 1e-10 * np.abs(msh.geometry.x).max()
    idx, val = [], []
    for tag, axis, value in planes:
        facets = dmesh.locate_entities(msh, fdim, lambda x, a=axis, c=value: np.abs(x[a] - c) <= tol)
        idx.append(facets)
        val.append(np.full(facets.size, tag, dtype=np.int32))
    idx, val = np.hstack(idx), np.hstack(val)
    order = np.argsort(idx)
    return dmesh.meshtags(msh, fdim, idx[order].astype(np.int32), val[order])


class LayerDevice:
    """The layer device: two meshes, the two field solvers, their participants and data.

    Args:
        case: the case.
        n: cells across the gel, h = H_g/n; the fluid and the length get
            cells of (about) the same size.
        comm: MPI communicator.
        robin_coefficient: alpha_n of the fluid's Robin form of I13; default
            the gel's Darcy resistance over its depth, (Ca/s) xi phi_s0 H_g / phi_f0
            (as the device's default_robin_coefficient with C = 1).
        depth: None for the planar device; W > 0 for the slab 0 < z < W on
            tetrahedra (cells of about the same size h along z).
        transient: the time-dependent gel (v_s = du/dt by ``time_scheme``,
            ``"be"`` or ``"bdf2"``), started from rest and stepped by
            :meth:`advance`; Stokes is quasi-static (the device's windows).
    """

    def __init__(self, case: LayerCase, n: int = 8, comm: MPI.Comm = MPI.COMM_WORLD,
                 robin_coefficient: float | None = None, depth: float | None = None,
                 transient: bool = False, time_scheme: str = "be"):
        if depth is not None and not depth > 0:
            raise ValueError(f"LayerDevice: depth must be > 0 (the slab's extent along z) or None, got {depth!r}")
        self.case, self.comm, self.depth, self.transient = case, comm, depth, bool(transient)
        self.closed_form = LayerClosedForm(case)
        prm = case.gel_parameters()
        viscosity = prm.viscosity
        self.h = case.H_g / n
        self.cells = layer_cells(case, n, depth)
        nx, n_fluid, nz = self.cells
        self.fluid_mesh, self.fluid_tags = _strip(case, 0.0, case.H_f, nx, n_fluid, Tag.GAMMA1, Tag.WALL, comm,
                                                  depth, nz)
        self.gel_mesh, self.gel_tags = _strip(case, -case.H_g, 0.0, nx, n, Tag.BOWL, Tag.GAMMA1, comm, depth, nz)
        self.dim = dim = self.fluid_mesh.geometry.dim
        self.boundaries = b = layer_boundaries(case, dim)
        self.alpha_n = (viscosity * case.xi * case.phi_s0 * case.H_g / (1.0 - case.phi_s0)
                        if robin_coefficient is None else float(robin_coefficient))
        self.alpha_t = viscosity / case.beta
        G = self.closed_form.G
        self.fluid = StokesSolver(
            self.fluid_mesh, self.fluid_tags, viscosity=viscosity, velocity_bcs=b.fluid_velocity,
            component_bcs=b.fluid_component, body_force=_vector((G, 0.0), dim) if G else None,
            interfaces={name: FluidInterface(tag, "robin", "robin", self.alpha_n, self.alpha_t)
                        for name, tag in b.fluid_interfaces.items()})
        body_forces = None
        if G:
            # the fluid phase feels phi_f G, the mixture G (= -grad of the pressure -G x)
            body_forces = (ufl.as_vector(_vector(((1 - prm.phi_s0) * G, 0.0), dim)),
                           ufl.as_vector(_vector((G, 0.0), dim)), ufl.as_ufl(0.0))
        self.gel = PoroelasticGelSolver(
            self.gel_mesh, self.gel_tags, prm, no_slip=b.gel_no_slip, symmetry=b.gel_symmetry,
            fluid_interfaces=b.fluid_interfaces,
            dirichlet=[([int(Tag.BOWL)], "u", 0.0)] if case.flow == "compression" else (),
            body_forces=body_forces, transient=self.transient)
        if not np.allclose(self.fluid.interface_points("Gamma1"), self.gel.interface_points("Gamma1"),
                           rtol=0.0, atol=1e-12):
            raise RuntimeError("layer: the fluid and gel nodes on Gamma1 differ")
        self.participants = [FluidParticipant(self.fluid, b.fluid_interfaces, self.alpha_n, self.alpha_t),
                             GelParticipant(self.gel, b.fluid_interfaces, b.cell_interfaces,
                                            time_scheme=time_scheme)]
        self.data = coupling_data(b, dim=dim)
        self.scheme: cp.CouplingScheme | None = None
        self.result: cp.CouplingResult | None = None

    def solve(self, config: typing.Mapping | None = None) -> cp.CouplingResult:
        """Couple the two solvers to convergence (default: the device's serial IQN-ILS to 1e-10)."""
        config = dict(config or coupling_config(with_cell=False))
        config.setdefault("verbose", False)
        self.scheme = cp.build_scheme(config, self.participants, self.data, comm=self.comm)
        self.result = self.scheme.solve()
        return self.result

    def advance(self, dt: float, config: typing.Mapping | None = None) -> cp.WindowRecord:
        """One time window [t, t + dt] of the transient device, coupled to convergence (default: the
        device's time-dependent serial IQN-ILS to 1e-10); ``config`` is read by the first window only."""
        if not self.transient:
            raise ValueError("LayerDevice.advance: build the device with transient=True")
        if self.scheme is None:
            config = dict(config or coupling_config(with_cell=False, transient=True))
            config.setdefault("verbose", False)
            self.scheme = cp.build_scheme(config, self.participants, self.data, comm=self.comm)
        return self.scheme.advance_window(dt)

    # -- errors against the closed form ------------------------------------------------------
    def field_errors(self) -> dict[str, float]:
        """L2 errors of the fields, relative to the exact field's L2 norm.

        Pressures (exactly zero in the tangential flows) are measured against
        ``stress_scale`` times the square root of the region's area.
        """
        cf, c, dim = self.closed_form, self.case, self.dim
        out = {}
        y = ufl.SpatialCoordinate(self.fluid_mesh)[1]
        Vx, Vy, P = cf.fluid(y)
        area = c.length * c.H_f * self.width
        out["V"] = _relative_l2(self.fluid.velocity, ufl.as_vector(_vector((Vx, Vy), dim)), self.fluid_mesh)
        out["P"] = _relative_l2(self.fluid.pressure, P, self.fluid_mesh, cf.stress_scale * math.sqrt(area))
        y = ufl.SpatialCoordinate(self.gel_mesh)[1]
        w, v, u_x, u_y, p = cf.gel(y, ufl)
        area = c.length * c.H_g * self.width
        out["v_f"] = _relative_l2(self.gel.interstitial_velocity(), ufl.as_vector(_vector((w, v), dim)), self.gel_mesh)
        out["u"] = _relative_l2(self.gel.displacement(), ufl.as_vector(_vector((u_x, u_y), dim)), self.gel_mesh)
        out["p"] = _relative_l2(self.gel.pore_pressure(), p, self.gel_mesh, cf.stress_scale * math.sqrt(area))
        return out

    def flow_rates(self) -> tuple[float, float]:
        """(Q_f, Q_p) of the discrete solution: mean over x (and z) of int V_x dy and int phi_f0 v_f,x dy."""
        Q_f = integrate(self.fluid.velocity[0], ufl.dx(domain=self.fluid_mesh))
        Q_p = integrate((1.0 - self.case.phi_s0) * self.gel.interstitial_velocity()[0], ufl.dx(domain=self.gel_mesh))
        section = self.case.length * self.width
        return Q_f / section, Q_p / section

    @property
    def width(self) -> float:
        """The extent across the flow: the slab's depth, 1 in the plane."""
        return 1.0 if self.depth is None else float(self.depth)

    def interface_values(self) -> dict[str, np.ndarray]:
        """The coupled solution's nodal values on Gamma1 (N, dim), as in ``LayerClosedForm.interface``."""
        if self.scheme is None:
            raise RuntimeError("layer: call solve() first")
        V = self.scheme.latest("Gamma1/velocity")
        v_f = self.scheme.latest("Gamma1/interstitial_velocity")
        u = self.gel.displacement()
        nodes = InterfaceNodes(u.function_space, self.gel_tags, int(Tag.GAMMA1))
        return {"velocity": V, "slip": V - v_f,
                # steady (v_s = 0): the exchanged mixture velocity phi_f v_f + phi_s v_s is phi_f v_f
                "superficial_velocity": self.scheme.latest("Gamma1/mixture_velocity"),
                "displacement": nodes.from_function(u), "traction": self.scheme.latest("Gamma1/traction")}

    def interface_errors(self) -> dict[str, float]:
        """max over the Gamma1 nodes of |value - exact| / |exact| for each interface quantity.

        ``flux``: the normal part of the superficial velocity (the volume flux
        into the fluid, exactly 0 in the tangential flows), relative to the
        exact superficial speed.
        """
        exact = {k: np.array(_vector(v, self.dim)) for k, v in self.closed_form.interface.items()}
        values = self.interface_values()
        out = {k: float(np.linalg.norm(v - exact[k], axis=1).max() / np.linalg.norm(exact[k]))
               for k, v in values.items()}
        q, q_exact = values["superficial_velocity"], exact["superficial_velocity"]
        out["flux"] = float(np.abs(q[:, 1] - q_exact[1]).max() / np.linalg.norm(q_exact))
        return out

    def errors(self) -> dict[str, float]:
        """Field, interface (keys ``Gamma1/...``) and, in the tangential flows, flow-rate errors."""
        out = self.field_errors()
        out.update({f"Gamma1/{k}": v for k, v in self.interface_errors().items()})
        if self.case.flow != "compression":
            for key, h, exact in zip(("Q_f", "Q_p"), self.flow_rates(), self.closed_form.flow_rates):
                out[key] = abs(h - exact) / abs(exact)
        return out


class LayerMonolithic:
    """The layer device's monolithic reference: one mesh of fluid and gel, every condition in one system.

    The mesh is the union of :class:`LayerDevice`'s two (the same cells, so
    the same discrete problem): regions Tag.FLUID (y > 0) and Tag.GEL
    (y < 0), Gamma1 their interior facets on y = 0, and the same outer
    boundaries.  Solved by ``MonolithicSolver`` (Newton on V, P, w, u, p and
    the multiplier lam = T_F on Gamma1).  It has no body forces and no
    support that holds u_s but not v_f, so only the ``couette`` flow.
    With ``transient`` it has the partitioned gel's time discretisation
    (``time_scheme``) and is stepped by :meth:`advance`, one Newton solve per
    window, from rest.
    """

    def __init__(self, case: LayerCase, n: int = 8, comm: MPI.Comm = MPI.COMM_WORLD,
                 depth: float | None = None, transient: bool = False, time_scheme: str = "be"):
        if case.flow != "couette":
            raise ValueError(f"LayerMonolithic: flow must be 'couette' (no body force, bonded support), "
                             f"got {case.flow!r}")
        self.case, self.depth = case, depth
        self.mesh, self.cell_tags, self.facet_tags = _two_region_mesh(case, n, depth, comm)
        dim = self.mesh.geometry.dim
        self.boundaries = layer_boundaries(case, dim)
        coefficients = MonolithicCoefficients(
            phi_s0=case.phi_s0, xi=case.xi, lambda_s=case.lambda_s, beta=case.beta, eta=case.eta, Ca=case.Ca,
            mu_c=1.0, lambda_c=1.0, stress_scale=case.Ca, displacement_scale=case.Ca)   # viscous units s = d = Ca
        self.solver = MonolithicSolver(self.mesh, self.cell_tags, self.facet_tags, self.boundaries, coefficients,
                                       transient=transient)
        self.clock = WindowClock(time_scheme)
        self.time = 0.0

    def solve(self) -> int:
        """Newton to its tolerance; returns the number of iterations."""
        return self.solver.solve()

    def advance(self, dt: float) -> int:
        """One window [t, t + dt] (transient): the state at t becomes the newest past one; Newton's iterations."""
        scheme, dt_previous = self.clock.enter(self.time, dt, self.solver.push_history)
        self.solver.set_time_step(dt, scheme, dt_previous)
        iterations = self.solver.solve()
        self.time += dt
        return iterations

    def field(self, name: str) -> fem.Function:
        """``V``, ``P``, ``v_f``, ``u``, ``p`` or ``lam`` on the whole mesh (each meaningful on its region)."""
        return self.solver.field(name)


def _two_region_mesh(case: LayerCase, n: int, depth: float | None, comm: MPI.Comm):
    """[0, length] x [-H_g, H_f] (x [0, depth]) with LayerDevice's cells: (mesh, cell tags, facet tags)."""
    nx, n_fluid, nz = layer_cells(case, n, depth)
    ny = n + n_fluid
    if depth is None:
        msh = dmesh.create_rectangle(comm, [np.array([0.0, -case.H_g]), np.array([case.length, case.H_f])],
                                     [nx, ny], dmesh.CellType.triangle, diagonal=dmesh.DiagonalType.right)
    else:
        msh = dmesh.create_box(comm, [np.array([0.0, -case.H_g, 0.0]), np.array([case.length, case.H_f, depth])],
                               [nx, ny, nz], dmesh.CellType.tetrahedron)
    # the uniform rows j = 0..ny moved onto the two strips' rows: h_g = H_g/n below y = 0, H_f/n_fluid above
    x = msh.geometry.x
    row = (x[:, 1] + case.H_g) * ny / (case.H_g + case.H_f)
    x[:, 1] = np.where(row <= n, -case.H_g + row * case.H_g / n, (row - n) * case.H_f / n_fluid)
    tdim = msh.topology.dim
    tol = 1e-10 * np.abs(x).max()
    fluid = dmesh.locate_entities(msh, tdim, lambda X: X[1] >= -tol)
    gel = dmesh.locate_entities(msh, tdim, lambda X: X[1] <= tol)
    cells = np.hstack([fluid, gel]).astype(np.int32)
    values = np.hstack([np.full(fluid.size, int(Tag.FLUID)), np.full(gel.size, int(Tag.GEL))]).astype(np.int32)
    order = np.argsort(cells)
    cell_tags = dmesh.meshtags(msh, tdim, cells[order], values[order])
    planes = [(int(Tag.INLET), 0, 0.0), (int(Tag.OUTLET), 0, case.length), (int(Tag.BOWL), 1, -case.H_g),
              (int(Tag.GAMMA1), 1, 0.0), (int(Tag.WALL), 1, case.H_f)]
    if depth is not None:
        planes += [(int(Tag.FLOOR), 2, 0.0), (int(Tag.SYMMETRY_MID), 2, depth)]
    return msh, cell_tags, _plane_tags(msh, planes)


def layer_cells(case: LayerCase, n: int, depth: float | None = None) -> tuple[int, int, int]:
    """Cells along x, across the fluid and (slab; else 1) along z, of about the gel's size h = H_g/n."""
    h = case.H_g / n
    return tuple(max(1, round(extent / h)) for extent in (case.length, case.H_f, depth or h))


def _vector(components, dim: int) -> tuple:
    """The planar ``components`` (x, y) as a vector of ``dim`` components (z = 0 in the slab)."""
    return tuple(components) + (0 * components[0],) * (dim - 2)


def _relative_l2(u_h, exact, msh, norm: float | None = None, degree: int = 8) -> float:
    """||u_h - exact||_L2 / ||exact||_L2, or / ``norm`` if given."""
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": degree})
    e = u_h - exact
    err = math.sqrt(integrate(ufl.inner(e, e), dx))
    return err / (math.sqrt(integrate(ufl.inner(exact, exact), dx)) if norm is None else norm)
