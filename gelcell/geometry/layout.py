"""What the solvers and the reports need to know of a device besides its meshes: conditions and cells.

:class:`DeviceBoundaries` says which boundary condition holds on which
tagged boundary (model.md section 3), shared by the partitioned solvers and
the monolithic reference so that both solve the same problem; Gamma2
(steady): v_f = 0 on the gel side.  :class:`DeviceLayout` adds the cells
(:class:`CellSpec`) and the fluid-gel interfaces.  The built-in devices'
layouts come from :mod:`gelcell.geometry.builtin`, a geometry file's from
:mod:`gelcell.geometry.files` (docs/geometry-files.md).
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

__all__ = ["DeviceBoundaries", "DeviceLayout", "CellSpec", "ParabolicInflow", "SegmentInflow", "ChipInflow",
           "duct_poiseuille", "duct_poiseuille_peak", "plane_poiseuille"]


@dataclasses.dataclass
class DeviceBoundaries:
    """Boundary conditions of a device case, by facet tag."""

    fluid_velocity: list[tuple[list[int], typing.Any]]       # full-vector Dirichlet (tags, value)
    fluid_component: list[tuple[list[int], int, float]]      # one-component Dirichlet (tags, comp, value)
    gel_no_slip: list[int]                                   # v_f = 0 and u_s = 0
    gel_symmetry: list[tuple[list[int], int]]                # v_f[c] = 0 and u_s[c] = 0
    cell_symmetry: list[tuple[list[int], int]]               # u_c[c] = 0
    fluid_interfaces: dict[str, int]                         # Gamma1, Gamma3
    cell_interfaces: dict[str, int]                          # Gamma2
    dim: int = 2                                             # components of a full vector

    def fluid_dirichlet_tags(self) -> list[tuple[list[int], tuple[int, ...]]]:
        """Every fluid Dirichlet boundary with the velocity components it fixes."""
        out = [(tags, tuple(range(self.dim))) for tags, _ in self.fluid_velocity]
        out += [(tags, (c,)) for tags, c, _ in self.fluid_component]
        return out


class ParabolicInflow:
    """V = (4 y (H - y) / H^2, 0): plane Poiseuille profile with maximum 1."""

    def __init__(self, height: float):
        self.height = float(height)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        H = self.height
        return np.vstack((4.0 * x[1] * (H - x[1]) / H**2, np.zeros_like(x[0])))


class SegmentInflow:
    """Inflow through a straight inlet from ``a`` to ``b``: ``speed`` times the inward unit ``normal``,
    times 4 s (1 - s) (parabolic, maximum ``speed``) or 1 (uniform), s the position along the segment."""

    def __init__(self, a, b, normal, speed: float, profile: str):
        self.a, self.b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
        self.normal, self.speed, self.profile = np.asarray(normal, float)[:2], float(speed), profile

    def __call__(self, x: np.ndarray) -> np.ndarray:
        t = self.b - self.a
        s = ((x[0] - self.a[0]) * t[0] + (x[1] - self.a[1]) * t[1]) / float(t @ t)
        shape = 4.0 * s * (1.0 - s) if self.profile == "parabolic" else np.ones_like(s)
        return np.vstack((self.speed * self.normal[0] * shape, self.speed * self.normal[1] * shape))


class ChipInflow:
    """The inflow (V_x, 0, 0) of a 3D device (model.md section 10), ``profile`` of the point (x, y, z):

    * ``"duct"``: the series of :func:`duct_poiseuille` in the channel 0 < y < W, 0 < z < H, maximum 1
      on its centre line (shear device, no-slip floor and lid);
    * ``"plane"``: :func:`plane_poiseuille` between floor and lid with mean 1, uniform in y (normal device);
    * ``"parabolic"``: 4 y (W - y) / W^2, uniform in z (shear slab); ``"uniform"``: 1 (normal slab).
    """

    PROFILES = ("duct", "plane", "parabolic", "uniform")

    def __init__(self, profile: str, width: float, height: float):
        if profile not in self.PROFILES:
            raise ValueError(f"profile must be one of {self.PROFILES}, got {profile!r}")
        self.profile, self.width, self.height = profile, _positive("width", width), _positive("height", height)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        W, H, y, z = self.width, self.height, x[1], x[2]
        if self.profile == "duct":
            v = duct_poiseuille(y, z, W, H, 1.0)
        elif self.profile == "plane":
            v = plane_poiseuille(z, H, 1.0)
        elif self.profile == "parabolic":
            v = 4.0 * y * (W - y) / W**2
        else:
            v = np.ones_like(x[0])
        return np.vstack((v, np.zeros_like(x[0]), np.zeros_like(x[0])))


def _positive(name: str, value) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value}")
    return value


def plane_poiseuille(z, height: float, mean: float) -> np.ndarray:
    """Plane Poiseuille flow between a floor z = 0 and a lid z = H with mean speed ``mean`` (V_m):

        u(z) = 6 V_m z (H - z) / H^2,      max u = u(H/2) = 3 V_m / 2,

    so the flux per unit width is V_m H (model.md section 10, the normal device's inflow).
    """
    H = _positive("height", height)
    z = np.asarray(z, dtype=float)
    return 6.0 * float(mean) * z * (H - z) / H**2


def _duct_series(a, b, A, B) -> np.ndarray:
    """s(a, b) solving -(s_aa + s_bb) = 1 on (0, A) x (0, B), s = 0 on the boundary, as

        s = b (B - b) / 2
            - (4 B^2 / pi^3) sum_{n odd} n^-3 sin(n pi b / B) cosh(n pi (a - A/2) / B) / cosh(n pi A / (2 B)).

    Term n is bounded by (8 B^2 / pi^3) n^-3 exp(-n pi delta / B), delta = min(a, A - a) the distance to
    the walls a = 0, A; the sum stops when that bound, summed over the rest, is below 1e-15 B^2, or at
    n = 20001 (tail < 2e-10 B^2; reached only within about B / 5000 of a wall a = 0, A).
    """
    delta = np.minimum(a, A - a)
    s = np.where(delta > 0, 0.5 * b * (B - b), 0.0)       # s = 0 on the walls a = 0, A
    active = delta > 0
    n = 1
    while np.any(active) and n <= 20001:
        k = n * np.pi / B
        # cosh(k (a - A/2)) / cosh(k A/2) without overflow (|a - A/2| <= A/2)
        ratio = np.exp(-k * delta[active]) * (1 + np.exp(-2 * k * np.abs(a[active] - A / 2))) / (1 + np.exp(-k * A))
        s[active] -= 4 * B**2 / (np.pi**3 * n**3) * np.sin(k * b[active]) * ratio
        n += 2
        d = delta[active]
        tail = 8 * B**2 / (np.pi**3 * n**3) * np.exp(-n * np.pi * d / B) / (-np.expm1(-2 * np.pi * d / B) + 1e-300)
        active[active] = tail > 1e-15 * B**2
    return s


def _duct_shape(y, z, W: float, H: float) -> np.ndarray:
    """s with -(s_yy + s_zz) = 1 in (0, W) x (0, H), s = 0 on the walls: the series in the direction in
    which the point is further from the walls (geometric convergence everywhere but at the corners)."""
    y, z = np.broadcast_arrays(np.asarray(y, dtype=float), np.asarray(z, dtype=float))
    y, z = np.clip(y.ravel(), 0.0, W), np.clip(z.ravel(), 0.0, H)
    s = np.zeros(y.shape)
    in_y = np.minimum(y, W - y) / H >= np.minimum(z, H - z) / W     # cosh along y, sine series along z
    s[in_y] = _duct_series(y[in_y], z[in_y], W, H)
    s[~in_y] = _duct_series(z[~in_y], y[~in_y], H, W)
    return s


def duct_poiseuille_peak(width: float, height: float, gradient: float, viscosity: float) -> float:
    """The centre-line speed G s_c / mu of fully developed flow in a W x H duct driven by dP/dx = -G.

    s_c = s(W/2, H/2) of the series of :func:`duct_poiseuille`; for W >> H it tends to H^2/8
    (plane Poiseuille).
    """
    W, H = _positive("width", width), _positive("height", height)
    mu = _positive("viscosity", viscosity)
    return float(gradient) / mu * float(_duct_shape(W / 2, H / 2, W, H)[0])


def duct_poiseuille(y, z, width: float, height: float, peak: float) -> np.ndarray:
    """Fully developed Poiseuille flow in a rectangular duct 0 < y < W, 0 < z < H, no slip on its four walls.

    The axial speed solves -mu (u_yy + u_zz) = G (G = -dP/dx), u = 0 on the walls.  Its series
    (a sine series in z, each term's y dependence solved exactly):

        u = (G / mu) s(y, z),
        s = z (H - z) / 2
            - (4 H^2 / pi^3) sum_{n odd} n^-3 sin(n pi z / H) cosh(n pi (y - W/2) / H) / cosh(n pi W / (2 H)),

    scaled here so that its maximum, on the centre line (W/2, H/2), is ``peak`` (V0):
    u = V0 s(y, z) / s(W/2, H/2).  Points closer to the walls y = 0, W than (relatively) to
    z = 0, H use the same series with the roles of (y, W) and (z, H) swapped, which converges
    geometrically there.  ``y``, ``z``: arrays (broadcast together) of positions in the duct's
    cross-section, measured from one corner; returns the speeds, of their broadcast shape.  Points
    outside the cross-section take the value of the nearest point of it (finite everywhere, as
    ``Function.interpolate`` evaluates a boundary profile at every node of the mesh).
    """
    W, H = _positive("width", width), _positive("height", height)
    shape = np.broadcast(np.asarray(y), np.asarray(z)).shape
    s = _duct_shape(y, z, W, H)
    return (float(peak) / float(_duct_shape(W / 2, H / 2, W, H)[0]) * s).reshape(shape)


@dataclasses.dataclass
class DeviceLayout:
    """What the solvers and the reports need to know of a device besides its meshes."""

    boundaries: DeviceBoundaries
    cells: list[CellSpec]
    #: profile interfaces in order (Gamma1, Gamma3, ...): name -> facet tag
    fluid_interfaces: dict[str, int]
    #: display size of the figures: True for a device much wider than high
    wide: bool = False
    #: names of the facet tags in the file's convention (geometry files), for messages and counts
    tag_names: dict[int, str] = dataclasses.field(default_factory=dict)

    @property
    def cell_region_tags(self) -> list[int]:
        return [c.region_tag for c in self.cells]


@dataclasses.dataclass(frozen=True)
class CellSpec:
    """One cell of a device: its tags, its coupling interface and its nominal shape.

    ``centre`` and ``diameter`` are those of the whole cell (a circle of the
    same area for a cell of another shape); ``symmetry`` lists the components
    fixed on its flat edges (a half cell on a symmetry line: its centroid
    moves along the line).
    """

    index: int                 #: 1-based
    name: str                  #: "cell" (single cell) or "cell_k"
    region_tag: int
    facet_tag: int             #: its Gamma2
    interface: str             #: coupling name of its Gamma2
    centre: tuple[float, float]
    diameter: float
    symmetry: tuple[int, ...] = ()
