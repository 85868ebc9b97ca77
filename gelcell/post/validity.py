"""What the model can answer: checks before solving and warnings after.

Before solving (:func:`check_case`, raising :class:`ModelLimitError`):

* the scaled problem must be representable in float64 (:func:`representable_ca`);
* the cell's stiffness must be within :data:`STIFFNESS_RATIO_RANGE` of the gel's
  (:func:`check_stiffness_ratio`);
* the mesh must fit in this machine's memory (:func:`estimate_mesh`), estimated
  from the element sizes and the closed-form areas and lengths (a 3D device's
  volumes and areas, :func:`estimate_mesh_3d`), before gmsh runs;
  a geometry file's mesh from coarse probe meshes of its own sizes
  (:func:`estimate_file_mesh`);

After solving (:func:`model_warnings`), by the case's kinematics
(``model.kinematics``):

* ``"small"``: the equations on the undeformed domain neglect geometric terms
  of relative size max |grad u_s| (``model.max_displacement_gradient``); above
  :data:`MAX_NEGLECTED` (1 %) the answer is reported with a warning, and the
  cell above :data:`MAX_CELL_STRAIN`, since the gel that loads it is not in
  finite strain;
* ``"finite"``: nothing geometric is neglected; above
  :data:`MAX_DISPLACEMENT_GRADIENT` (gel) or :data:`MAX_CELL_STRAIN` (cell)
  the warning is about the material laws: the neo-Hookean network and cell
  with the Table 1 constants, measured at small strain, are extrapolated.
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np

from gelcell.case import CaseParameters
from gelcell.errors import ModelLimitError
from gelcell.geometry import Tag, described
from gelcell.geometry.builtin import closed_form_measures, closed_form_measures_3d
from gelcell.geometry.files.read import estimated_elements, read_geometry
from gelcell.machine import MEMORY_SHARE, machine_memory

__all__ = ["representable_ca", "check_representable", "check_stiffness_ratio",
           "STIFFNESS_RATIO_RANGE", "estimate_mesh", "estimate_mesh_3d", "check_mesh_size", "estimate_file_mesh",
           "check_file_mesh_size", "check_case",
           "machine_memory", "model_warnings", "MAX_DISPLACEMENT_GRADIENT", "MAX_CELL_STRAIN", "MAX_NEGLECTED"]

# --------------------------------------------------------------------------- representable Ca
#: Headroom for the solver-unit values that multiply Ca.  With s = d = Ca every
#: physical quantity is Ca times a solver-unit value v: displacements Ca u_hat,
#: stresses Ca sigma_hat, displacement gradients Ca grad u_hat (|grad u_hat| ~ 5e3
#: at baseline), J = 1 + Ca theta, and the drag Ca xi (xi = 4.5e4).  The summary
#: and the forms also square them: von Mises measures and norms hold (Ca v)^2,
#: the Green-Lagrange strain H^T H with H = Ca grad u_hat, the forms d G G^T (a
#: Ca^2 term in paper units).  1e8 covers these values with x1e3 to spare.
SOLVER_VALUE_HEADROOM = 1e8


def representable_ca() -> tuple[float, float]:
    """The range of Ca whose scaled problem float64 represents.

    Every product above must stay a normal float64 number, squares included:
    (Ca V)^2 <= max and (Ca / V)^2 >= tiny for solver values within a factor
    V = SOLVER_VALUE_HEADROOM of 1, i.e.

        sqrt(tiny) V <= Ca <= sqrt(max) / V,   tiny = 2.2e-308, max = 1.8e308,

    about [1.5e-146, 1.3e146].  Outside it a squared strain underflows to an
    exact 0 (Ca = 1e-300 reports a zero cell strain) or a product overflows
    to inf (Ca = 1e300).
    """
    fi = sys.float_info
    return math.sqrt(fi.min) * SOLVER_VALUE_HEADROOM, math.sqrt(fi.max) / SOLVER_VALUE_HEADROOM


def check_representable(params: CaseParameters) -> None:
    """Raise :class:`ModelLimitError` if the case's Ca is outside :func:`representable_ca`."""
    lo, hi = representable_ca()
    ca = params.physics.ca
    if not lo <= ca <= hi:
        raise ModelLimitError(
            f"Ca = {ca:g} cannot be represented: the solvers work in units of Ca (stress Ca mu_s, "
            f"displacement Ca L0) and square Ca-sized quantities, which float64 holds only for "
            f"Ca in [{lo:.1e}, {hi:.1e}]; choose --ca (or --gel-moduli, which divides Ca) in that range")


# --------------------------------------------------------------------------- stiffness ratio
#: The cell's shear modulus in multiples of the gel's drained modulus, mu_c / (phi_s0 mu_s), that the
#: solvers answer.  The paper's cells are within a factor 10 of the gel; at 1e6 the partitioned
#: coupling already needs its 200 iterations (shear device, --mesh-size 3), beyond it the gel's
#: Newton iteration fails (1e7, 1e9) and its systems lose their pivots (1e12).
STIFFNESS_RATIO_RANGE = (1e-6, 1e6)


def check_stiffness_ratio(params: CaseParameters) -> None:
    """Raise :class:`ModelLimitError` if the cell is far stiffer or softer than the gel (before meshing)."""
    if not params.with_cell:
        return
    lo, hi = STIFFNESS_RATIO_RANGE
    ratio = params.cell_moduli_multiple
    if not lo <= ratio <= hi:
        raise ModelLimitError(
            f"the cell is {ratio:.3g} times as stiff as the gel (mu_c / (phi_s0 mu_s), set by --cell-moduli, "
            f"and divided by --gel-moduli): far outside the model's range, which solves stiffness ratios in "
            f"[{lo:g}, {hi:g}]; choose --cell-moduli and --gel-moduli so that their ratio is in that range")


# --------------------------------------------------------------------------- mesh size
#: Area of a triangle of target size h: (sqrt(3)/4) h^2 (equilateral).
_TRIANGLE = math.sqrt(3.0) / 4.0
#: Peak memory of a run: BASE_MEMORY + MEMORY_PER_ELEMENT N log2(N) bytes for N elements (the
#: direct solvers' fill grows like N log N in 2-D).  Fitted to the peak resident memory of
#: ``gelcell run shear --monolithic`` (the heaviest run) at size factors 3, 1 and 0.5: 0.28,
#: 0.68 and 2.09 GB for 1.6e3, 9.1e3 and 3.0e4 elements; the partitioned run needs about half.
BASE_MEMORY = 0.25e9
MEMORY_PER_ELEMENT = 4.2e3


def _band_elements(length: float, sides: int, size: float, band: float, far: float, growth: float) -> float:
    """Elements in a refinement band of ``length`` (uniform ``size`` over ``band``, then growing
    linearly by ``growth`` per unit distance up to ``far``), on one or two ``sides``."""
    uniform = band / (_TRIANGLE * size * size)
    graded = (1.0 / size - 1.0 / far) / (_TRIANGLE * growth) if far > size else 0.0
    return sides * length * (uniform + graded)


def estimate_mesh(params: CaseParameters, solver: str = "direct") -> dict:
    """Estimated element count of the device mesh (fluid + gel + cell) from its size field.

    The far field holds area / (sqrt(3)/4 h^2) elements; each refinement band
    (Gamma1/Gamma3 on both sides, the gel's walls on one side, the cell surface
    on the gel's side) adds its uniform part and the graded part that grows to the
    far-field size.  Against the meshes of both devices at size factors 3 to 0.5
    it is within 20 %.  Returns the element count and the memory a run needs.
    A 3D device (a geometry with ``chip_height``): :func:`estimate_mesh_3d`.  The 2D memory law is
    the direct solvers' for every ``solver`` (an upper bound for the iterative path).
    """
    if getattr(params.geometry, "dimension", 2) == 3:
        return estimate_mesh_3d(params, solver)
    h = params.element_sizes()
    m = closed_form_measures(params)
    far = max(h["h_fluid"], h["h_gel"])
    count = (m["fluid"]["area"] / (_TRIANGLE * h["h_fluid"] ** 2)
             + m["gel"]["area"] / (_TRIANGLE * h["h_gel"] ** 2))
    gel_lengths = m["gel"]["length"]
    interfaces = gel_lengths.get(Tag.GAMMA1, 0.0) + gel_lengths.get(Tag.GAMMA3, 0.0)
    walls = gel_lengths.get(Tag.BOWL, 0.0) + gel_lengths.get(Tag.POST, 0.0)
    for length, sides in ((interfaces, 2), (walls, 1)):
        count += _band_elements(length, sides, h["h_layer"], h["layer_band"], far, h["growth"])
    if params.with_cell:
        count += m["cell"]["area"] / (_TRIANGLE * h["h_cell"] ** 2)
        count += _band_elements(gel_lengths[Tag.GAMMA2], 1, h["h_cell"], h["cell_band"], far, h["growth"])
    return {"elements": count, "memory_bytes": _memory(count)}


def _memory(elements: float) -> float:
    return BASE_MEMORY + MEMORY_PER_ELEMENT * elements * math.log2(max(elements, 2.0))


# 3D devices (model.md section 10)
#: Volume of a regular tetrahedron of edge h: h^3 / (6 sqrt(2)).
_TETRAHEDRON = 1.0 / (6.0 * math.sqrt(2.0))
#: gmsh's Delaunay tetrahedra per regular-tetrahedron volume of the target size, fitted to the
#: devices' meshes (chip height 0.4; no-slip walls at size factors 5 to 1, symmetric at 3 and 2);
#: a unit cube has 0.55 at h = 0.05, 0.59 at h = 0.1 (its surfaces' share), 0.69 at h = 0.2.
GMSH_TETRAHEDRA = 0.63
#: Quadrature points across a band (distance) and across the half height of a 3D device.
_BAND_POINTS, _HEIGHT_POINTS = 201, 101
#: Peak memory of a 3D run: BASE_MEMORY_3D + MEMORY_LINEAR_3D N + MEMORY_FILL_3D N^(4/3) bytes for N
#: tetrahedra: the matrices and fields grow like N, the sparse LU's fill of a 3D mesh like N^(4/3)
#: (nested dissection) and faster.  Fitted to the peak resident memory of the partitioned 3D runs
#: (finite kinematics, default cell, chip height 0.4; docs/performance.md, "3D devices").
BASE_MEMORY_3D = 0.25e9
MEMORY_LINEAR_3D = 3.7e4
MEMORY_FILL_3D = 2.6e3
#: Peak memory of a 3D run on the iterative path (``--solver iterative``: Krylov solvers with algebraic
#: multigrid, no factorisation): BASE_MEMORY_3D_ITERATIVE + MEMORY_ITERATIVE_3D N bytes for N tetrahedra,
#: through the peak resident memory of the shear device's iterative runs at mesh sizes 6 and 4 (492 MiB
#: at 3,540 tetrahedra, 901 MiB at 7,489; docs/performance.md, "3D devices").  ``auto`` is
#: estimated by the direct law, an upper bound (its fields of more than 100 000 unknowns go iterative).
BASE_MEMORY_3D_ITERATIVE = 0.13e9
MEMORY_ITERATIVE_3D = 1.09e5


def _graded_size(distance, size: float, band: float, far: float, growth: float):
    """A Threshold size field of :mod:`gelcell.geometry.builtin_model3d` at ``distance`` from its surface:
    ``size`` within the band (at least one element wide), then growing by ``growth`` up to ``far``."""
    return np.minimum(far, size + growth * np.maximum(distance - max(band, size), 0.0))


def _band_distances(size: float, band: float, far: float, growth: float):
    """Quadrature points from the surface to where the field reaches ``far``."""
    return np.linspace(0.0, max(band, size) + max(far - size, 0.0) / growth, _BAND_POINTS)


def _extra_density(size, beneath):
    """Regular tetrahedra per volume that a field of ``size`` adds where the mesh is ``beneath``
    anyway (gmsh meshes at the minimum of the fields)."""
    return (1.0 / np.minimum(size, beneath) ** 3 - 1.0 / beneath ** 3) / _TETRAHEDRON


def _wall_band(area: float, height, beneath, sizes: tuple) -> float:
    """Tetrahedra a band adds on one side of a vertical surface of ``area`` spanning the half height
    (Γ1, Γ3, bowl, posts): the integral of the extra density over distance and height."""
    d = _band_distances(*sizes)
    extra = _extra_density(_graded_size(d, *sizes)[:, None], beneath[None, :])
    return area / height[-1] * np.trapz(np.trapz(extra, height), d)


def _cell_band(r: float, zc: float, share: float, height, beneath, sizes: tuple) -> float:
    """Tetrahedra the band around a half-sphere cell (radius ``r``, flat face at ``zc``) adds.

    At distance d the band is the spherical zone of radius rho = r + d between
    max(0, zc - rho) and zc, of area 2 pi rho per unit height; ``share`` = 1/2
    for a cell halved by a symmetry plane.  The band of a cell a few tenths wide
    reaches far beyond the cell (about (h_gel - h_cell) / growth).
    """
    d = _band_distances(*sizes)
    rho = (r + d)[:, None]
    inside = (height[None, :] >= zc - rho) & (height[None, :] <= zc)
    extra = np.where(inside, _extra_density(_graded_size(d, *sizes)[:, None], beneath[None, :]), 0.0)
    return share * np.trapz(2.0 * math.pi * rho[:, 0] * np.trapz(extra, height), d)


def estimate_mesh_3d(params: CaseParameters, solver: str = "direct") -> dict:
    """Estimated tetrahedra of a 3D device mesh (fluid + gel + cells) from the size fields of
    :mod:`gelcell.geometry.builtin_model3d`, before gmsh runs.

    GMSH_TETRAHEDRA times the integral of 1 / (h^3 / (6 sqrt 2)) over the device,
    h the minimum of the fields: in the gel the floor's layer h_z(z) (no-slip
    walls; h_gel with symmetric ones) over the whole gel volume, plus what the
    bands of ``h_layer`` on Γ1/Γ3 and the gel's walls and the band of
    ``h_cell`` around each cell add beneath h_z; the fluid at ``h_fluid`` plus
    its Γ1/Γ3 band; the cells at ``h_cell``.  The closed-form volumes and areas
    (:func:`gelcell.geometry.builtin.closed_form_measures_3d`) and a quadrature
    over distance and height.  Against gmsh's meshes of both devices (chip
    height 0.4) it is within 11 % with no-slip walls (size factors 5 to 1) and
    17 % with symmetric ones (3 and 2).  Returns the element count and the
    memory a run needs with ``solver`` (``[solver] kind``: the direct law for
    "direct" and "auto", the iterative law for "iterative").
    """
    h = params.element_sizes()
    m = closed_form_measures_3d(params)
    g = params.geometry
    height = np.linspace(0.0, 0.5 * g.chip_height, _HEIGHT_POINTS)
    hf, hg, grow = h["h_fluid"], h["h_gel"], h["growth"]
    layer_gel, layer_fluid = (h["h_layer"], h["layer_band"], hg, grow), (h["h_layer"], h["layer_band"], hf, grow)
    floor = _graded_size(height, *layer_gel) if g.walls == "noslip" else np.full_like(height, hg)
    gel = m["gel"]["area"]
    interfaces = gel.get(Tag.GAMMA1, 0.0) + gel.get(Tag.GAMMA3, 0.0)
    walls = gel.get(Tag.BOWL, 0.0) + gel.get(Tag.POST, 0.0)
    count = m["fluid"]["volume"] / (_TETRAHEDRON * hf ** 3)
    count += _wall_band(interfaces, height, np.full_like(height, hf), layer_fluid)
    count += m["gel"]["volume"] / height[-1] * np.trapz(1.0 / (_TETRAHEDRON * floor ** 3), height)
    count += _wall_band(interfaces + walls, height, floor, layer_gel)
    if params.with_cell:
        count += m["cell"]["volume"] / (_TETRAHEDRON * h["h_cell"] ** 3)
        for _, y, z, d in g.cell_list_3d():
            share = 0.5 if params.case == "normal" and g.on_symmetry_line(y) else 1.0
            count += _cell_band(0.5 * d, z, share, height, floor, (h["h_cell"], h["cell_band"], hg, grow))
    count *= GMSH_TETRAHEDRA
    return {"elements": count, "memory_bytes": _memory_3d(count, solver)}


def _memory_3d(elements: float, solver: str = "direct") -> float:
    if solver == "iterative":
        return BASE_MEMORY_3D_ITERATIVE + MEMORY_ITERATIVE_3D * elements
    return BASE_MEMORY_3D + MEMORY_LINEAR_3D * elements + MEMORY_FILL_3D * elements ** (4.0 / 3.0)


def _round_up(size: float) -> float:
    """``size`` rounded up to two significant digits (the suggested size factor must fit itself)."""
    scale = 10.0 ** (math.floor(math.log10(size)) - 1)
    return math.ceil(size / scale - 1e-9) * scale


def check_mesh_size(params: CaseParameters, memory: int | None = None, solver: str = "direct") -> dict:
    """Raise :class:`ModelLimitError` if the estimated mesh does not fit in ``memory`` with ``solver``."""
    est = estimate_mesh(params, solver)
    memory = machine_memory() if memory is None else memory
    fits = lambda p: estimate_mesh(p, solver)["memory_bytes"] <= MEMORY_SHARE * memory   # noqa: E731
    if not fits(params):
        coarsest = params.mesh.n_cell_edges / params.mesh.MIN_CELL_EDGES
        if not fits(params.with_mesh_size(coarsest)):
            raise ModelLimitError(f"even the coarsest mesh (--mesh-size {coarsest:g}) needs more than this "
                                  f"machine's {memory / 2**30:.3g} GiB")
        lo, hi = params.mesh.size_factor, coarsest
        for _ in range(40):             # bisect for the finest size factor that fits
            mid = math.sqrt(lo * hi)
            lo, hi = (lo, mid) if fits(params.with_mesh_size(mid)) else (mid, hi)
        raise ModelLimitError(
            f"--mesh-size {params.mesh.size_factor:g} would make about {est['elements']:.2g} elements, "
            f"which need about {est['memory_bytes'] / 2**30:.3g} GiB{_with(solver)}; this machine has "
            f"{memory / 2**30:.3g} GiB: choose --mesh-size {_round_up(hi):g} or larger"
            f"{_iterative_hint(params, solver, memory)}")
    return est


def _with(solver: str) -> str:
    return " with the iterative solvers" if solver == "iterative" else ""


def _iterative_hint(params: CaseParameters, solver: str, memory: int) -> str:
    """``, or --solver iterative (about X GiB)`` where a 3D direct run is refused and the iterative one fits."""
    if solver == "iterative" or getattr(params.geometry, "dimension", 2) != 3:
        return ""
    need = estimate_mesh(params, "iterative")["memory_bytes"]
    return f", or --solver iterative (about {need / 2**30:.3g} GiB)" if need <= MEMORY_SHARE * memory else ""


def estimate_file_mesh(params: CaseParameters, solver: str = "direct") -> dict:
    """Estimated element count of a geometry file's mesh, from the sizes the file gives.

    A ``.msh`` file's count is its own.  For a ``.geo`` file gmsh makes coarse
    probe meshes (:func:`gelcell.geometry.files.read.reference_elements`: the
    triangles or tetrahedra at ``--mesh-size 1``, predicted); the count
    scales as the inverse square (cube, a file with volumes) of the size factor,
    and the memory by the 2D or the 3D law.  None if gmsh could not make the
    probes (the file's meshing is bounded in its child process all the same).
    """
    dim = read_geometry(params.geometry.file).dimension
    count = estimated_elements(params.geometry.file, params.mesh.size_factor)
    if count is None:
        return {"elements": None, "memory_bytes": None, "dimension": dim}
    return {"elements": count, "memory_bytes": _file_memory(dim, solver)(count), "dimension": dim}


def _file_memory(dim: int, solver: str):
    """The memory law of a geometry file's mesh by its dimension and the solvers."""
    return (lambda n: _memory_3d(n, solver)) if dim == 3 else _memory


def check_file_mesh_size(params: CaseParameters, memory: int | None = None, solver: str = "direct") -> dict:
    """Raise :class:`ModelLimitError` if the estimated mesh of a geometry file does not fit in ``memory``."""
    est = estimate_file_mesh(params, solver)
    memory = machine_memory() if memory is None else memory
    budget = MEMORY_SHARE * memory
    if est["memory_bytes"] is None or est["memory_bytes"] <= budget:
        return est
    name = os.path.basename(params.geometry.file)
    need = f"about {est['elements']:.2g} elements, which need about {est['memory_bytes'] / 2**30:.3g} GiB"
    if params.geometry.file.lower().endswith(".msh"):
        raise ModelLimitError(f"the mesh of geometry file {name} has {need}; this machine has "
                              f"{memory / 2**30:.3g} GiB: mesh the file more coarsely")
    law, dim, size = _file_memory(est["dimension"], solver), est["dimension"], params.mesh.size_factor
    fits = lambda factor: law(est["elements"] * (size / factor) ** dim) <= budget   # noqa: E731
    lo, hi = size, 2.0 * size
    while not fits(hi):
        hi *= 2.0
    for _ in range(40):             # bisect for the finest size factor that fits
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    raise ModelLimitError(
        f"--mesh-size {size:g} would make {need} (estimated from the sizes of geometry file "
        f"{name}); this machine has {memory / 2**30:.3g} GiB: choose --mesh-size {_round_up(hi):g} or larger")


def check_case(params: CaseParameters, solver: str = "direct") -> None:
    """Every check that must pass before a case is meshed or solved (a geometry file is read and checked);
    ``solver``: the fields' solvers (``[solver] kind``), whose memory the mesh must fit."""
    described(params)
    check_representable(params)
    check_stiffness_ratio(params)
    if params.case == "file":
        check_file_mesh_size(params, solver=solver)
    else:
        check_mesh_size(params, solver=solver)


# --------------------------------------------------------------------------- after solving
#: Small-strain path: the largest displacement gradient |grad u_s| (Frobenius norm, paper units) for
#: which it is reported without a warning.  The geometric terms it drops (the first Piola stress, the
#: spatial gradients, the moving interfaces and fluid domain) are of relative size |F - I|: above 1 %
#: the small-strain answer differs from the finite-strain one by more than 1 % (measured on the shear
#: device: docs/finite-strain.md).
MAX_NEGLECTED = 0.01
#: Finite-strain path: the largest displacement gradient of the gel reported without a warning about
#: its material law: the neo-Hookean network with the Table 1 constants, which come from small-strain
#: measurements, is extrapolated beyond it.
MAX_DISPLACEMENT_GRADIENT = 0.05
#: Largest von Mises Green-Lagrange strain of the cell reported without a warning (both paths).
MAX_CELL_STRAIN = 0.05


def _exceeds(value, limit) -> bool:
    return value is not None and not value <= limit


def model_warnings(model: dict) -> list[str]:
    """Warnings for a solved case whose ``model`` block (of summary.json) exceeds the thresholds.

    ``model["kinematics"]`` selects the path (missing: ``"small"``).
    """
    finite = model.get("kinematics", "small") == "finite"
    grad, strain = model.get("max_displacement_gradient"), model.get("max_cell_strain")
    grad_limit = MAX_DISPLACEMENT_GRADIENT if finite else MAX_NEGLECTED
    if finite:
        grad_why = ("the finite-strain model holds, but its neo-Hookean network with the Table 1 constants "
                    "(measured at small strain) is extrapolated; lower Ca (--ca) or the load if that matters")
        strain_why = "its neo-Hookean law is extrapolated beyond the small strains its moduli describe"
    else:
        grad_why = ("the small-strain path (--kinematics small) neglects geometric terms of this relative size; "
                    "use --kinematics finite, or lower Ca (--ca) or the load")
        strain_why = ("the gel that loads it is modelled in small deformation; use --kinematics finite, or lower "
                      "Ca (--ca) or the load")
    out = []
    if _exceeds(grad, grad_limit):
        out.append(f"the gel's largest displacement gradient is {grad:.3g} (> {grad_limit:g}): {grad_why}")
    if _exceeds(strain, MAX_CELL_STRAIN):
        out.append(f"the cell's largest von Mises Green-Lagrange strain is {strain:.3g} (> {MAX_CELL_STRAIN:g}): "
                   f"{strain_why}")
    return out
