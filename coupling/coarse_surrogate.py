"""The quasi-Newton prior of a fine coupled problem from a coarse model of the same problem.

A dense prior (:class:`coupling.LinearizedPrior`) costs one participant solve
per interface unknown and a dense factorisation: affordable for a few
thousand unknowns, not for the tens of thousands of a 3D interface.  The
same coupled problem on coarser meshes has far fewer unknowns, and its
interface operator has the slow modes of the fine one (they are smooth on
the interface), so its prior, carried over, is the two-level prior

    J0 r = P J0_c (R r)

with ``R`` the restriction of a fine interface vector to the coarse points
and ``P`` the prolongation back, data by data.  The secant columns of IQN
then model what the coarse prior misses (the fine model's own short waves
and the two meshes' discretisation difference); in the directions nobody
models, the step is the plain fixed-point step.

Transfers, per data, between the two writers' triangulated surfaces
(:func:`coupling.surface_mapping.surface_interpolation_matrix`): an
*intensive* data (a traction, a velocity, a displacement: nodal values of a
field) is interpolated at the closest points of the other surface; an
*extensive* one (consistent nodal integrals: nodal forces, nodal fluxes) is
turned into its density with the surface mass matrix, interpolated, and
integrated again on the other surface (``M_c I M_f^-1``), so that the
corner nodes of quadratic triangles, whose consistent integrals vanish,
do not alias.  Both transfers are consistent (a constant density maps to
itself); the sum of an extensive data is kept to the interpolation's error.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from coupling.surface_mapping import participant_triangles, surface_interpolation_matrix, surface_mass_matrix

__all__ = ["CoarseSurrogate"]


class _Transfer:
    """One data's map between two surfaces: ``apply(values)`` on ``(N_from dim, k)`` columns.

    ``free_from``/``free_to`` (``(N, dim)`` booleans, optional): the components
    that are unknowns of the problem; the others (a wall's no-slip, a symmetry
    plane's normal component) are zero by construction.  Interpolation then
    uses the free nodes of each component only, its weights renormalised, so
    that a field is not pulled towards the zeros of a constrained edge, and
    writes zeros where the target is constrained.
    """

    def __init__(self, interpolation: sp.csr_matrix, dim: int, mass_from=None, mass_to=None,
                 free_from: np.ndarray | None = None, free_to: np.ndarray | None = None):
        self._dim = dim
        self._components = [_masked(interpolation, None if free_from is None else free_from[:, c],
                                    None if free_to is None else free_to[:, c]) for c in range(dim)]
        self._from_lu = None if mass_from is None else spla.splu(sp.csc_matrix(mass_from))
        self._to = mass_to

    def apply(self, columns: np.ndarray) -> np.ndarray:
        if self._from_lu is not None:
            columns = self._per_node(columns, self._from_lu.solve)   # nodal integrals -> density
        n, k = columns.shape[0] // self._dim, columns.shape[1]
        nodal = columns.reshape(n, self._dim, k)
        out = np.stack([M @ nodal[:, c, :] for c, M in enumerate(self._components)], axis=1)
        out = out.reshape(-1, k)
        if self._to is not None:
            out = self._per_node(out, lambda v: self._to @ v)           # density -> nodal integrals
        return out

    def _per_node(self, columns: np.ndarray, op) -> np.ndarray:
        n, k = columns.shape[0] // self._dim, columns.shape[1]
        blocks = columns.reshape(n, self._dim * k)                 # row = node, columns = (component, column)
        return np.asarray(op(blocks)).reshape(n * self._dim, k)


def _masked(M: sp.csr_matrix, free_from: np.ndarray | None, free_to: np.ndarray | None) -> sp.csr_matrix:
    """``M`` restricted to the free source nodes (rows renormalised) and to the free target nodes."""
    M = sp.csr_matrix(M)
    if free_from is not None:
        M = M @ sp.diags(free_from.astype(float))
        sums = np.asarray(M.sum(axis=1)).ravel()
        M = sp.diags(np.divide(1.0, sums, out=np.zeros_like(sums), where=np.abs(sums) > 1e-12)) @ M
    if free_to is not None:
        M = sp.diags(free_to.astype(float)) @ M
    return M.tocsr()


class CoarseSurrogate:
    """``J0 r = P J0_c (R r)``: a coarse scheme's prior, carried to a fine scheme of the same data.

    Pass it to :func:`coupling.build_scheme` as ``surrogate`` of the fine
    scheme (IQN-ILS or IQN-IMVJ).  Lifecycle: build the coarse scheme and let
    its prior be set up (solve it once, which also gives :meth:`prolong`'s
    initial guess); build the fine participants; then
    ``CoarseSurrogate.on_surfaces(...)``.  Both schemes' data must lie on
    3-D surfaces whose writers give :meth:`~coupling.Participant.interface_triangles`.

    Args:
        prior: the coarse model's ``inverse_jacobian`` holder (a
            :class:`~coupling.LinearizedPrior`, say).
        restriction, prolongation: per accelerated data (in the fine
            layout's order) the transfer fine -> coarse and coarse -> fine.
        fine_layout, coarse_layout: the two schemes' accelerated layouts.
    """

    accepts_matrices = True

    def __init__(self, prior: Any, restriction: dict[str, _Transfer], prolongation: dict[str, _Transfer],
                 fine_layout: Any, coarse_layout: Any):
        if list(fine_layout.names) != list(coarse_layout.names):
            raise ValueError(f"coarse surrogate: the coarse scheme accelerates {list(coarse_layout.names)}, "
                             f"the fine one {list(fine_layout.names)}; they must accelerate the same data")
        if not callable(getattr(prior, "inverse_jacobian", None)):
            raise TypeError("coarse surrogate: prior must have a method inverse_jacobian(r)")
        self.prior = prior
        self._restriction, self._prolongation = restriction, prolongation
        self.fine_layout, self.coarse_layout = fine_layout, coarse_layout

    @classmethod
    def on_surfaces(cls, fine: Any, coarse: Any, prior: Any = None, extensive: Iterable[str] = (),
                    free: Callable[[Any, str], np.ndarray | None] | None = None) -> "CoarseSurrogate":
        """The surrogate between two schemes of the same data on 3-D surfaces.

        Args:
            fine, coarse: the two :class:`~coupling.CouplingScheme` objects.
            prior: the coarse prior; default the coarse scheme's acceleration's
                (its ``surrogate``: the linearized prior of ``jacobian_prior =
                "linearized"``).
            extensive: names of data that are nodal integrals (see the module
                docstring); the others are nodal values.
            free: ``free(scheme, name)``: an ``(N, dim)`` boolean array of the
                data's components that are unknowns (False: zero by a
                constraint of its writer), or None for all free (:class:`_Transfer`).

        Raises:
            ValueError: if the coarse scheme has no prior, the schemes
                accelerate different data, or a writer gives no triangles.
        """
        prior = getattr(coarse.acceleration, "surrogate", None) if prior is None else prior
        if prior is None:
            raise ValueError("coarse surrogate: the coarse scheme has no prior; build it with "
                             "coupling.acceleration.jacobian_prior = 'linearized'")
        extensive = set(extensive)
        unknown = extensive - set(fine.data)
        if unknown:
            raise ValueError(f"coarse surrogate: extensive data {sorted(unknown)} are not data of the scheme")
        restriction, prolongation = {}, {}
        for name in fine.layout.names:
            fine_side, coarse_side = _surface(fine, name), _surface(coarse, name)
            dim = fine.data[name].dim
            masks = (None, None) if free is None else (free(fine, name), free(coarse, name))
            to_coarse = surface_interpolation_matrix(*fine_side, coarse_side[0], what=f"{name} (to coarse)")
            to_fine = surface_interpolation_matrix(*coarse_side, fine_side[0], what=f"{name} (to fine)")
            if name in extensive:
                mf = surface_mass_matrix(*fine_side, what=name)
                mc = surface_mass_matrix(*coarse_side, what=name)
                restriction[name] = _Transfer(to_coarse, dim, mf, mc, *masks)
                prolongation[name] = _Transfer(to_fine, dim, mc, mf, *masks[::-1])
            else:
                restriction[name] = _Transfer(to_coarse, dim, None, None, *masks)
                prolongation[name] = _Transfer(to_fine, dim, None, None, *masks[::-1])
        return cls(prior, restriction, prolongation, fine.layout, coarse.layout)

    def restrict(self, r: np.ndarray) -> np.ndarray:
        """A fine accelerated vector (or columns of them) on the coarse layout."""
        return self._carry(r, self._restriction, self.fine_layout, self.coarse_layout)

    def prolong(self, r: np.ndarray) -> np.ndarray:
        """A coarse accelerated vector (or columns of them) on the fine layout."""
        return self._carry(r, self._prolongation, self.coarse_layout, self.fine_layout)

    def inverse_jacobian(self, r: np.ndarray) -> np.ndarray:
        """``J0 r = P J0_c R r`` (a vector, or a matrix of them as columns)."""
        return self.prolong(self.prior.inverse_jacobian(self.restrict(r)))

    @staticmethod
    def _carry(r: np.ndarray, transfers: dict[str, _Transfer], source: Any, target: Any) -> np.ndarray:
        vector = r.ndim == 1
        columns = r[:, None] if vector else r
        if columns.shape[0] != source.size:
            raise ValueError(f"coarse surrogate: a vector of {columns.shape[0]} values, the layout has {source.size}")
        out = np.zeros((target.size, columns.shape[1]))
        for name, s_from, s_to in zip(source.names, source.slices(), target.slices()):
            out[s_to] = transfers[name].apply(columns[s_from])
        return out[:, 0] if vector else out


def _surface(scheme: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The writer's points and triangles of data ``name`` in ``scheme``."""
    d = scheme.data[name]
    triangles = participant_triangles(scheme.participants[d.writer], d.mesh, f"coarse surrogate: data {name!r}")
    return scheme.points(d.writer, d.mesh), triangles
