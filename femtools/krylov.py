"""Krylov solvers with multigrid preconditioners, behind the interface of ``femtools.linalg.DirectSolver``.

A :class:`KrylovSolver` takes the place of a :class:`~femtools.linalg.DirectSolver` in
:class:`~femtools.linalg.LinearSolver` and :class:`~femtools.linalg.NewtonSolver`
(their ``linear_solver`` argument): ``set_operator(A)``, then ``factorize()``, which
here sets up the preconditioner (the cost a factorisation has for a direct solver,
paid when the operator changes and reused otherwise), then ``solve(b, x)`` for
many right-hand sides.

Tolerances.  A solve stops when the residual is ``rtol`` times the right-hand
side's: ``|b - A x| <= rtol |b|`` in the unpreconditioned norm where the method
supports it (CG, GMRES with right preconditioning), ``|B (b - A x)| <= rtol |B b|``
for MINRES (which supports only the preconditioned norm; B is the
preconditioner).  The absolute tolerance is zero: the device's loads are tiny
(model.md §5) and no absolute floor is safe for all of them.  The gel's default
is looser (``GEL_OPTIONS``: its solves are Newton steps that the next residual
corrects); the others' are for single linear solves.  A zero right-hand
side returns zero without iterating.  Warm start: the initial guess is the
previous solution when that leaves a smaller residual than zero does.

The factories build the solvers of the fields: :func:`elasticity_solver` (CG,
GAMG with the rigid-body near-null space), :func:`stokes_solver` (MINRES,
block-diagonal preconditioner: AMG on the velocity, the viscosity-scaled
pressure mass matrix for the Schur complement; :class:`PinnedPressure` for an
enclosed flow) and :func:`gel_solver` (GMRES, block lower-triangular
preconditioner over (w, u, p), :class:`PressureSchur` on the pressure).
"""

from __future__ import annotations

import contextlib
import itertools
import time
import typing

import numpy as np
import scipy.sparse

from mpi4py import MPI
from petsc4py import PETSc

from dolfinx import fem
from dolfinx.cpp.fem import petsc as cpp_petsc
from dolfinx.fem import petsc as fem_petsc

from femtools.errors import LinearSolveError

__all__ = ["KrylovSolver", "PinnedPressure", "LinearSolveError", "rigid_body_modes", "owned_index_set",
           "elasticity_solver", "stokes_solver", "gel_solver", "GelBlockKrylov", "PressureSchur",
           "linear_solver_choice", "SOLVER_KINDS"]

_counter = itertools.count()

#: the values of the field solvers' ``solver`` argument
SOLVER_KINDS = ("direct", "iterative")

#: default relative tolerance: far below the 1e-8 at which iterative and direct answers are compared
DEFAULT_RTOL = 1e-11

_REASONS: dict[int, str] = {}
for _name in sorted(dir(PETSc.KSP.ConvergedReason)):      # of two aliases, the first in alphabetical order names it
    if not _name.startswith("_") and isinstance(getattr(PETSc.KSP.ConvergedReason, _name), int):
        _REASONS.setdefault(getattr(PETSc.KSP.ConvergedReason, _name), _name)


def linear_solver_choice(solver: str, name: str) -> bool:
    """True for ``solver="iterative"``, False for "direct"; ValueError naming ``name`` otherwise."""
    if solver not in SOLVER_KINDS:
        raise ValueError(f"{name}: solver must be one of {SOLVER_KINDS}, got {solver!r}")
    return solver == "iterative"


def reason_name(reason: int) -> str:
    """petsc4py's name of a KSP converged reason, e.g. ``DIVERGED_MAX_IT``."""
    return _REASONS.get(int(reason), str(int(reason)))


class KrylovSolver:
    """A PETSc Krylov method with a preconditioner set up once per operator.

    ``ksp_type``: "cg", "minres", "gmres" (right preconditioned) or any PETSc KSP type.
    ``options``: PETSc options of this solve (without a prefix): the
    preconditioner's defaults of the factory, overridden by a user's
    ``petsc_options``; ``ksp_rtol`` and ``ksp_max_it`` set the tolerance and the
    iteration limit.  They are set in the options database under a unique
    prefix, read at the first set-up and then removed (the database is shared).
    ``preconditioner_form``: a bilinear form assembled (with ``bcs``, identity
    on their rows) into the matrix the preconditioner is built from, each time
    the operator changes; without it the operator itself.
    ``near_null_space``: attached to the operator (GAMG reads it).
    ``preconditioned_norm``: stop on |B r| <= rtol |B b| (B the preconditioner) also for CG and GMRES:
    for a system whose blocks have rows of very different scales, where |r| would weigh one block only.
    ``fields``: ``[(name, global indices owned by this rank (array or IS), near-null space or None)]``
    for PCFIELDSPLIT (the near-null space is that of the field's block, in the index set's order).
    ``interpolations``: ``{field position: P}``, the prolongation from a coarse space into that
    field's block (rows in the index set's order), for a block whose options make it a two-level
    PCMG (``pc_type mg``; another choice of the options leaves P unused); the key None for the
    KSP's own preconditioner (no field split).
    """

    def __init__(self, comm: MPI.Comm, name: str, ksp_type: str = "cg", options: dict | None = None,
                 preconditioner_form=None, bcs: typing.Sequence = (), near_null_space=None,
                 fields: typing.Sequence[tuple[str, np.ndarray]] = (), preconditioned_norm: bool = False,
                 interpolations: typing.Mapping[int, PETSc.Mat] | None = None):
        self.comm, self.name = comm, name
        self._interpolations = dict(interpolations or {})
        self._preconditioned_norm = bool(preconditioned_norm)
        options = {str(k).lstrip("-"): v for k, v in dict(options or {}).items()}
        self.rtol = float(options.pop("ksp_rtol", DEFAULT_RTOL))
        self.max_it = int(options.pop("ksp_max_it", 1000))
        if not (0.0 < self.rtol < 1.0):
            raise ValueError(f"{name}: ksp_rtol must be in (0, 1), got {self.rtol}")
        if self.max_it < 1:
            raise ValueError(f"{name}: ksp_max_it must be >= 1, got {self.max_it}")
        self.ksp = PETSc.KSP().create(comm)
        # a method the user chose is kept; CG and MINRES need a symmetric operator (else GMRES)
        self._symmetric_method = ksp_type if ("ksp_type" not in options and ksp_type in ("cg", "minres")) else None
        self.ksp.setType(str(options.pop("ksp_type", ksp_type)))
        self.ksp.setTolerances(rtol=self.rtol, atol=0.0, max_it=self.max_it)
        self._fields = [(label, _index_set(i, comm, null)) for label, i, null in fields]
        self._options, self._prefix = options, f"gelcell_krylov_{name}_{next(_counter)}_"
        self.ksp.setOptionsPrefix(self._prefix)
        self._P_form, self._bcs, self._P = preconditioner_form, list(bcs), None
        self.near_null_space = near_null_space
        self._A: PETSc.Mat | None = None
        self._configured = False
        self._last: PETSc.Vec | None = None
        self.iterations: list[int] = []      # Krylov iterations of each solve
        self.setups = 0
        self.setup_time = 0.0
        self.kind = "krylov"

    # -- the DirectSolver interface -----------------------------------------------------
    def set_operator(self, A: PETSc.Mat, reset: bool = False) -> None:
        """Use ``A`` (its preconditioner is set up at the next :meth:`factorize`)."""
        if reset or (self._A is not None and self._A.getSize() != A.getSize()):
            self._last = None
        if self.near_null_space is not None:
            A.setNearNullSpace(self.near_null_space)
        self._A = A

    def factorize(self) -> None:
        """Set up the preconditioner of the current operator (assembling its own matrix, if any)."""
        t0 = time.perf_counter()
        self.ksp.setOperators(self._A, self._preconditioner_matrix())
        if not self._configured:
            self._configure()
        else:
            self._set_up()
        self.setups += 1
        self.setup_time += time.perf_counter() - t0

    def factorize_symmetric_if_possible(self) -> None:
        """:meth:`factorize`; a CG solver whose operator is not symmetric to round-off switches to GMRES."""
        if self._symmetric_method is not None:
            from femtools.linalg import is_symmetric
            method = self._symmetric_method if is_symmetric(self._A) else "gmres"
            if method != self.ksp.getType():
                self.ksp.setType(method)
                self._set_norm()
        self.factorize()

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = A^-1 b to the relative tolerance; raises :class:`LinearSolveError` if the method fails."""
        b_norm = b.norm()
        if b_norm == 0.0:
            x.zeroEntries()              # the exact answer (PETSc would scale a warm start instead)
            self.iterations.append(0)
            return
        self._initial_guess(b, x, b_norm)
        self.ksp.solve(b, x)
        reason, its = self.ksp.getConvergedReason(), self.ksp.getIterationNumber()
        self.iterations.append(its)
        if reason <= 0:
            raise LinearSolveError(self.name, reason_name(reason), its)
        if self._last is None or self._last.getSizes() != x.getSizes():
            self._last = x.duplicate()
        x.copy(self._last)

    # -- helpers ----------------------------------------------------------------------
    def _preconditioner_matrix(self) -> PETSc.Mat:
        """The matrix the preconditioner is built from: ``preconditioner_form`` assembled, else the operator."""
        if self._P_form is None:
            return self._A
        if self._P is None:
            self._P = fem_petsc.create_matrix(self._P_form)
        self._P.zeroEntries()
        fem_petsc.assemble_matrix(self._P, self._P_form, bcs=self._bcs)
        self._P.assemble()
        return self._P

    def _initial_guess(self, b: PETSc.Vec, x: PETSc.Vec, b_norm: float) -> None:
        """Start from the last solution if its residual is below |b| (else from zero)."""
        warm = self._last is not None and self._last.getSizes() == x.getSizes()
        if warm:
            r = b.duplicate()
            self._A.mult(self._last, r)
            r.aypx(-1.0, b)
            warm = r.norm() < b_norm
            r.destroy()
        if warm:
            self._last.copy(x)
        self.ksp.setInitialGuessNonzero(bool(warm))

    def _set_norm(self) -> None:
        """The unpreconditioned residual norm where the method supports it (unless asked otherwise)."""
        if self._preconditioned_norm:
            return
        if self.ksp.getType() in ("gmres", "fgmres", "lgmres"):
            self.ksp.setPCSide(PETSc.PC.Side.RIGHT)         # GMRES then monitors the true residual
        if self.ksp.getType() in ("cg", "gmres", "fgmres", "lgmres", "bcgs"):
            self.ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)

    def _set_up(self) -> None:
        """Set up the preconditioner, and those of a field split's blocks (else done at the first solve)."""
        pc = self.ksp.getPC()
        if None in self._interpolations and pc.getType() == "mg":
            pc.setMGInterpolation(1, self._interpolations[None])
        self.ksp.setUp()
        if pc.getType() == "fieldsplit":
            self._attach_interpolations()
            for sub in pc.getFieldSplitSubKSP():
                sub.setUp()

    def _attach_interpolations(self, split: PETSc.PC | None = None) -> None:
        """Give each two-level PCMG block of ``split`` (default: the KSP's PC) its prolongation (after the
        field split's set-up, before the blocks')."""
        subs = (split or self.ksp.getPC()).getFieldSplitSubKSP()
        for position, P in self._interpolations.items():
            if position is None:
                continue
            block = subs[position].getPC()
            if block.getType() == "mg":
                block.setMGInterpolation(1, P)

    @contextlib.contextmanager
    def _options_in_database(self):
        """This solver's options in PETSc's database while its objects read them; removed afterwards."""
        opts = PETSc.Options()
        for k, v in self._options.items():
            opts[self._prefix + k] = v
        try:
            yield opts
        finally:
            for k in self._options:
                opts.delValue(self._prefix + k)

    def _configure(self) -> None:
        """Field splits, then the options (defaults and user's) from the database, then clean it."""
        pc = self.ksp.getPC()
        if self._fields:
            pc.setType("fieldsplit")
            pc.setFieldSplitIS(*self._fields)
        self._set_norm()
        with self._options_in_database():
            self.ksp.setFromOptions()
            self.ksp.setTolerances(rtol=self.rtol, atol=0.0, max_it=self.max_it)
            self._set_up()          # the preconditioners read their options here
        self._configured = True


def _index_set(indices, comm: MPI.Comm, near_null_space=None) -> PETSc.IS:
    """An IS of the global ``indices`` (or the IS itself), carrying the block's near-null space
    (PCFIELDSPLIT attaches it to the block's matrix)."""
    if not isinstance(indices, PETSc.IS):
        indices = PETSc.IS().createGeneral(np.asarray(indices, dtype=PETSc.IntType), comm=comm)
    if near_null_space is not None:
        indices.compose("nearnullspace", near_null_space)
    return indices


def owned_index_set(V: fem.FunctionSpace, local_dofs: np.ndarray) -> np.ndarray:
    """The global indices of the owned entries of ``local_dofs`` (local unrolled dofs of V's vector)."""
    imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    local = np.asarray(local_dofs, dtype=np.int64)
    local = np.sort(local[local < imap.size_local * bs])
    return (local + imap.local_range[0] * bs).astype(PETSc.IntType)


def rigid_body_modes(V: fem.FunctionSpace, nodes: np.ndarray | None = None) -> PETSc.NullSpace:
    """The rigid-body motions of a vector space as an orthonormal near-null space.

    gdim translations and gdim (gdim - 1) / 2 rotations (3 modes in 2D, 6 in 3D),
    interpolated at the dof coordinates; ``nodes``: the owned nodes in the order
    of the vectors (default V's own; a subset: the modes of a block of those nodes only).
    """
    gdim = V.mesh.geometry.dim
    bs = V.dofmap.index_map_bs
    if bs != gdim:
        raise ValueError(f"rigid_body_modes: the space must be a {gdim}-vector space, its block size is {bs}")
    n = V.dofmap.index_map.size_local
    X = V.tabulate_dof_coordinates()[:n, :gdim]
    if nodes is not None:
        X = X[nodes]
        n = len(X)
    fields = []
    for i in range(gdim):
        t = np.zeros((n, gdim))
        t[:, i] = 1.0
        fields.append(t)
    for i, j in itertools.combinations(range(gdim), 2):
        r = np.zeros((n, gdim))
        r[:, i], r[:, j] = -X[:, j], X[:, i]
        fields.append(r)
    vecs = []
    for f in fields:
        v = PETSc.Vec().createMPI((n * bs, PETSc.DETERMINE), bsize=bs, comm=V.mesh.comm)
        v.array[:] = f.ravel()
        vecs.append(v)
    _orthonormalize(vecs)
    return PETSc.NullSpace().create(vectors=vecs, comm=V.mesh.comm)


def _orthonormalize(vecs: list[PETSc.Vec]) -> None:
    """Modified Gram-Schmidt, in place."""
    for i, v in enumerate(vecs):
        for w in vecs[:i]:
            v.axpy(-w.dot(v), w)
        v.scale(1.0 / v.norm())


def _merged(defaults: dict, options: dict | None) -> dict:
    """The factory's defaults overridden by a user's options (keys without a leading dash)."""
    out = dict(defaults)
    out.update({str(k).lstrip("-"): v for k, v in dict(options or {}).items()})
    return out


#: CG with smoothed-aggregation AMG: Chebyshev-Jacobi smoothing (symmetric: a fixed SPD preconditioner)
#: Chebyshev's upper bound 1.5 x the estimated largest eigenvalue (PETSc: 1.1 x): with 1.1 x the
#: finite-strain hollow sphere's GAMG preconditioner came out indefinite (CG: DIVERGED_INDEFINITE_PC)
ELASTICITY_OPTIONS = {"pc_type": "gamg", "pc_gamg_type": "agg", "pc_gamg_threshold": 0.02,
                      "pc_gamg_square_graph": 0, "mg_levels_ksp_type": "chebyshev",
                      "mg_levels_ksp_chebyshev_esteig": "0,0.1,0,1.5",
                      "mg_levels_pc_type": "jacobi", "mg_levels_ksp_max_it": 2}


#: in 3D GAMG coarsens on the squared graph: on the unsquared graph of a P2 vector block its coarse
#: levels came out denser than the fine one (operator complexity 3.9-5.1 on the 3D shear device's gel
#: blocks; 1.13-1.15 squared), which made the set-up 7 x and each V-cycle 2-3 x as expensive
AMG_3D_OPTIONS = {"pc_gamg_square_graph": 1}


def elasticity_options(dim: int) -> dict:
    """:data:`ELASTICITY_OPTIONS` for a ``dim``-dimensional vector block (:data:`AMG_3D_OPTIONS` in 3D)."""
    return {**ELASTICITY_OPTIONS, **(AMG_3D_OPTIONS if dim == 3 else {})}


def _prefixed(prefix: str, options: dict) -> dict:
    return {prefix + k: v for k, v in options.items()}


def elasticity_solver(V: fem.FunctionSpace, name: str, options: dict | None = None,
                      ksp_type: str = "cg") -> KrylovSolver:
    """CG (or ``ksp_type``) with GAMG and the rigid-body near-null space of the vector space ``V``
    (a P2 space in 3D: :data:`P2_MULTIGRID_3D`)."""
    if _p_multigrid(V):
        nodes = np.arange(V.dofmap.index_map.size_local)
        return KrylovSolver(V.mesh.comm, name, ksp_type, _merged(P2_MULTIGRID_3D, options),
                            near_null_space=rigid_body_modes(V), interpolations={None: p1_prolongation(V, nodes)})
    defaults = elasticity_options(V.mesh.geometry.dim)
    return KrylovSolver(V.mesh.comm, name, ksp_type, _merged(defaults, options),
                        near_null_space=rigid_body_modes(V))


#: block-diagonal preconditioner diag(AMG(A_uu), SSOR(M_p / mu)): SPD, as MINRES needs
#: MINRES stops on the preconditioned residual, which weighs the pressure's near-null mode heavily:
#: 1e-12 keeps the error below 1e-8 of the direct answer with a pinned pressure (1e-11 did not at 64^2)
STOKES_OPTIONS = {"ksp_rtol": 1e-12, "pc_fieldsplit_type": "additive",
                  "fieldsplit_u_ksp_type": "preonly",
                  **{"fieldsplit_u_" + k: v for k, v in ELASTICITY_OPTIONS.items()},
                  "fieldsplit_p_ksp_type": "preonly", "fieldsplit_p_pc_type": "sor"}


#: a P2 vector block in 3D (the Stokes velocity, the gel's flow and network, the cell, the mesh motion):
#: p-multigrid, Chebyshev-Jacobi on P2 and one BoomerAMG V-cycle on the Galerkin P1 operator. GAMG on the
#: P2 block itself degrades with refinement (3D duct, (4, 8, 4) to (8, 16, 8) cubes: MINRES 135, 157, 176
#: with it; 117, 121, 124 and 2.1 x faster per solve with this)
P2_MULTIGRID_3D = {"pc_type": "mg", "pc_mg_levels": 2, "pc_mg_galerkin": "both",
                      "mg_levels_ksp_type": "chebyshev", "mg_levels_ksp_max_it": 2,
                      "mg_levels_ksp_chebyshev_esteig": "0,0.1,0,1.5", "mg_levels_pc_type": "jacobi",
                      "mg_coarse_ksp_type": "preonly", "mg_coarse_pc_type": "hypre",
                      "mg_coarse_pc_hypre_type": "boomeramg"}


#: the dimensions whose P2 vector blocks take :data:`P2_MULTIGRID_3D`. Not 2D: there GAMG on P2 is the
#: better (the gel's GMRES 30 -> 78 iterations per solve with p-multigrid on the shear device's default
#: mesh; the Stokes channel of tests/test_krylov.py, h = 0.2, 0.1, 0.05: MINRES 64, 66, 68 with GAMG,
#: 64, 71, 99 with it)
P2_MULTIGRID_DIMENSIONS = (3,)


def _p_multigrid(V: fem.FunctionSpace) -> bool:
    return V.mesh.geometry.dim in P2_MULTIGRID_DIMENSIONS and V.ufl_element().degree() == 2


def p1_prolongation(V: fem.FunctionSpace, nodes: np.ndarray) -> PETSc.Mat:
    """The interpolation of the vector P1 space into the vector P2 space ``V`` on the same mesh (exact:
    P1 is in P2), its rows the owned nodes of V in the order ``nodes`` (components consecutive)."""
    msh, bs = V.mesh, V.dofmap.index_map_bs
    V1 = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    M = cpp_petsc.interpolation_matrix(V1._cpp_object, V._cpp_object)
    M.assemble()
    indptr, indices, values = M.getValuesCSR()          # owned rows, global columns
    local = scipy.sparse.csr_matrix((values, indices, indptr), shape=(indptr.size - 1, M.getSize()[1]))
    rows = local[(np.asarray(nodes, dtype=np.int64)[:, None] * bs + np.arange(bs)).ravel()]
    P = PETSc.Mat().createAIJ(size=M.getSizes(), comm=msh.comm,
                              csr=(rows.indptr.astype(PETSc.IntType), rows.indices.astype(PETSc.IntType), rows.data))
    P.assemble()
    M.destroy()
    return P


def _with_p_multigrid(defaults: dict, prefix: str) -> dict:
    """``defaults`` with the block of options ``prefix`` replaced by :data:`P2_MULTIGRID_3D` (as one solve)."""
    kept = {k: v for k, v in defaults.items() if not k.startswith(prefix)}
    return {**kept, prefix + "ksp_type": "preonly", **_prefixed(prefix, P2_MULTIGRID_3D)}


def stokes_solver(W: fem.FunctionSpace, name: str, preconditioner_form, bcs, options: dict | None = None,
                  velocity: int = 0, pressure: int = 1, pinned: bool = False) -> KrylovSolver:
    """MINRES with PCFIELDSPLIT over the sub-spaces ``velocity`` and ``pressure`` of the mixed space ``W``.

    ``preconditioner_form``: the block-diagonal form a(u, v) + (1/mu) (p, q), whose
    pressure block (the mass matrix over the viscosity) is spectrally equivalent
    to the Schur complement B A^-1 B^T of Taylor-Hood Stokes.  ``pinned``: the
    velocity's normal component is prescribed on the whole boundary and a
    Dirichlet condition in ``bcs`` pins the pressure at a node; the pressure
    block is then :class:`PinnedPressure` (the mass alone leaves the near-constant
    pressure mode an eigenvalue O(h^2) and the iterations and the error grow as 1/h).
    """
    V, V_to_W = W.sub(velocity).collapse()
    velocity_set, nodes = _node_ordered(W, V, V_to_W)
    pressure_set = owned_index_set(W, W.sub(pressure).collapse()[1])
    fields = [("u", velocity_set, rigid_body_modes(V, nodes)), ("p", pressure_set, None)]
    defaults = {**STOKES_OPTIONS, **_prefixed("fieldsplit_u_", elasticity_options(W.mesh.geometry.dim))}
    interpolations = None
    if _p_multigrid(V):
        defaults, interpolations = _with_p_multigrid(defaults, "fieldsplit_u_"), {0: p1_prolongation(V, nodes)}
    if not pinned:
        return KrylovSolver(W.mesh.comm, name, "minres", _merged(defaults, options),
                            preconditioner_form=preconditioner_form, bcs=bcs, fields=fields,
                            interpolations=interpolations)
    n_owned, start = W.dofmap.index_map.size_local * W.dofmap.index_map_bs, W.dofmap.index_map.local_range[0]
    constrained = np.concatenate([bc.dof_indices()[0] for bc in bcs] + [np.empty(0, np.int32)])
    constrained = constrained[constrained < n_owned] + start
    pins = np.flatnonzero(np.isin(pressure_set, constrained)).astype(PETSc.IntType)
    return _PinnedStokes(W.mesh.comm, name, "minres", _merged(defaults, options),
                         preconditioner_form=preconditioner_form, bcs=bcs, fields=fields, pins=pins,
                         interpolations=interpolations)


class PinnedPressure:
    """The pressure block of an enclosed flow whose pressure is pinned at a node (a python PC).

    S ~ (M - m m^T / |Omega|) / mu on all pressure dofs (m = M 1: the mass has no
    constant mode in S); with the pinned rows removed this is the free lumped mass
    D' = diag(m') / mu minus a rank-one term, whose inverse (Sherman-Morrison) is
    D'^-1 + z z^T mu / m_pin, z the indicator of the free dofs and m_pin the lumped
    mass of the pinned ones.  The pinned rows are identities.
    """

    def __init__(self, lumped: PETSc.Vec, pins: np.ndarray):
        self.inverse = lumped.copy()
        self.z = lumped.duplicate()
        self.z.set(1.0)
        self.z.array[pins] = 0.0
        m_pin = lumped.comm.tompi4py().allreduce(float(lumped.array_r[pins].sum()), op=MPI.SUM)
        self.inverse.reciprocal()
        self.inverse.array[pins] = 1.0
        self.weight = 1.0 / m_pin

    def apply(self, pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        y.pointwiseMult(x, self.inverse)
        y.axpy(self.weight * self.z.dot(x), self.z)


class _PinnedStokes(KrylovSolver):
    """The Stokes solver whose pressure block is :class:`PinnedPressure` (see :func:`stokes_solver`)."""

    def __init__(self, *args, pins: np.ndarray, **kwargs):
        super().__init__(*args, **kwargs)
        self._pins = pins

    def _set_up(self) -> None:
        self.ksp.setUp()
        pc = self.ksp.getPC()
        u_ksp, p_ksp = pc.getFieldSplitSubKSP()
        free = fem_petsc.assemble_matrix(self._P_form)        # the mass without the pin's identity row
        free.assemble()
        block = free.createSubMatrix(self._fields[1][1], self._fields[1][1])
        lumped = block.getRowSum()
        p_pc = p_ksp.getPC()
        p_pc.setType("python")
        p_pc.setPythonContext(PinnedPressure(lumped, self._pins))
        for obj in (free, block, lumped):
            obj.destroy()
        self._attach_interpolations()
        u_ksp.setUp()
        p_ksp.setUp()


def _node_ordered(W: fem.FunctionSpace, V: fem.FunctionSpace, V_to_W) -> tuple[PETSc.IS, np.ndarray]:
    """The sorted global indices in W of V's owned dofs, an IS of block size gdim (a node's components
    are consecutive in W), and the owned nodes of V in that order."""
    bs = V.dofmap.index_map_bs
    pairs = np.asarray(V_to_W, dtype=np.int64)[:V.dofmap.index_map.size_local * bs].reshape(-1, bs)
    n_owned_W = W.dofmap.index_map.size_local * W.dofmap.index_map_bs
    if pairs.size and (pairs.max() >= n_owned_W or np.any(np.diff(pairs, axis=1) != 1)):
        raise RuntimeError("the velocity dofs of a node are not consecutive owned dofs of the mixed space")
    nodes = np.argsort(pairs[:, 0])
    is_ = PETSc.IS().createGeneral((pairs[nodes].ravel() + W.dofmap.index_map.local_range[0])
                                   .astype(PETSc.IntType), comm=W.mesh.comm)
    is_.setBlockSize(bs)
    return is_, nodes



#: block Gauss-Seidel over (w, u, p): AMG on the flow and the network blocks, PressureSchur on p
#: GMRES restarts after 100 iterations (PETSc: 30: 94 instead of 82 iterations on the 3D shear device)
#: rtol 1e-8: the gel is always solved by Newton, whose every step takes the exact residual, so the
#: Krylov error (about 100 x rtol in the preconditioned norm here) sets a step's contraction (1e-6, far
#: below the 0.1 of the reuse test and the 1e-3 of the linear path), not the answer's accuracy
GEL_OPTIONS = {"ksp_rtol": 1e-8, "pc_fieldsplit_type": "multiplicative", "ksp_gmres_restart": 100,
               **{f"fieldsplit_{f}_ksp_type": "preonly" for f in ("w", "u", "p")},
               **{f"fieldsplit_{f}_" + k: v for f in ("w", "u") for k, v in ELASTICITY_OPTIONS.items()}}


#: the gel's blocks in 3D: AMG_3D_OPTIONS, and no graph threshold (82 instead of 96 GMRES iterations
#: on the 3D shear device at mesh-size 6)
GEL_3D_OPTIONS = {f"fieldsplit_{f}_" + k: v for f in ("w", "u")
                  for k, v in {**AMG_3D_OPTIONS, "pc_gamg_threshold": 0.0}.items()}


def gel_options(dim: int) -> dict:
    """The gel solver's defaults in ``dim`` dimensions (:data:`GEL_3D_OPTIONS` in 3D)."""
    return {**GEL_OPTIONS, **(GEL_3D_OPTIONS if dim == 3 else {})}


def gel_solver(W: fem.FunctionSpace, name: str, preconditioner_form, mass_form, bcs,
               options: dict | None = None) -> KrylovSolver:
    """GMRES for the gel's mixture (w, u, p) = sub-spaces 0, 1, 2 of ``W``, block lower-triangular
    preconditioner (PCFIELDSPLIT multiplicative): AMG on the flow block, AMG on the network block,
    :class:`PressureSchur` on the pressure.

    ``preconditioner_form``: the Jacobian plus, on the pressure block, the Darcy and
    fixed-stress part of the Schur complement, (phi_f^2 / k) grad p . grad q + beta p q;
    ``mass_form``: its viscous (Brinkman) part, (phi_f^2 / nu_e + beta) p q.  Stops on the
    preconditioned residual (the blocks' rows have unrelated scales: model.md §5).
    """
    fields, interpolations = [], {}
    defaults = gel_options(W.mesh.geometry.dim)
    for label, k in (("w", 0), ("u", 1)):
        V, V_to_W = W.sub(k).collapse()
        index_set, nodes = _node_ordered(W, V, V_to_W)
        fields.append((label, index_set, rigid_body_modes(V, nodes)))
        if _p_multigrid(V):
            defaults, interpolations[k] = _with_p_multigrid(defaults, f"fieldsplit_{label}_"), p1_prolongation(V, nodes)
    fields.append(("p", owned_index_set(W, W.sub(2).collapse()[1]), None))
    return _GelKrylov(W.mesh.comm, name, "gmres", _merged(defaults, options),
                      preconditioner_form=preconditioner_form, bcs=bcs, fields=fields,
                      preconditioned_norm=True, mass_form=mass_form, interpolations=interpolations)



class PressureSchur:
    """y = -(AMG(L_beta)^-1 x + D^-1 x): the gel's pressure Schur complement, inverted as a sum (a python PC).

    S = B_w A_ww^-1 B_w^T + c0 B_u K^-1 B_u^T.  The Brinkman flow block A_ww = nu_e (viscous) + k
    (drag) has S_flow^-1 ~ nu_e / phi_f^2 M^-1 + k / phi_f^2 L^-1 (the viscous and the Darcy
    limits, summed: robust across the Brinkman length); the network adds the fixed-stress term
    beta M, beta = c0 / K_dr.  L_beta = (phi_f^2 / k) L + beta M is solved by AMG, D is the
    diagonal of (phi_f^2 / nu_e + beta) M.  The sign: S of the saddle point is negative.
    """

    def __init__(self, comm, L_beta: PETSc.Mat, diagonal: PETSc.Vec, options_prefix: str):
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(options_prefix)
        self.ksp.setType("preonly")
        self.ksp.getPC().setType("gamg")
        self.ksp.setOperators(L_beta)
        self.ksp.setFromOptions()
        self.update(L_beta, diagonal)

    def update(self, L_beta: PETSc.Mat, diagonal: PETSc.Vec) -> None:
        """Set up for new operators (the AMG's options are kept)."""
        self.ksp.setOperators(L_beta)
        self.ksp.setUp()
        self.inverse = diagonal.copy()
        self.inverse.reciprocal()
        self.work = diagonal.duplicate()

    #: the terms of the sum applied (the benchmark measures each alone)
    terms = ("darcy", "viscous")

    def apply(self, pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        y.zeroEntries()
        if "darcy" in self.terms:
            self.ksp.solve(x, y)
        if "viscous" in self.terms:
            self.work.pointwiseMult(x, self.inverse)
            y.axpy(1.0, self.work)
        y.scale(-1.0)


class BlockLowerTriangular:
    """The block Gauss-Seidel sweep over (w, u, p) with the off-diagonal blocks only (a python PC).

    y_w = K_w^-1 x_w, y_u = K_u^-1 (x_u - A_uw y_w), y_p = K_p^-1 (x_p - A_pw y_w - A_pu y_u), the
    K_i the sub-solvers of ``inner`` (a PCFIELDSPLIT set up on the same operators).  PCFIELDSPLIT's
    own multiplicative sweep multiplies by the whole operator for each split after the first, about
    as much work as the three sub-solvers.  ``sweep=False``: ``inner``'s own apply (another split type).
    """

    def __init__(self, inner: PETSc.PC, fields: typing.Sequence[PETSc.IS], sweep: bool = True):
        self.inner, self.fields, self.sweep = inner, list(fields), sweep
        self._blocks: dict[tuple[int, int], PETSc.Mat] = {}
        self._scatters: list = []

    def setUp(self, pc) -> None:
        """Extract A_uw, A_pw, A_pu of the operator (the sub-solvers are set up by the caller)."""
        if not self.sweep:
            return
        A = pc.getOperators()[0]
        for i, j in ((1, 0), (2, 0), (2, 1)):
            self._blocks[i, j] = A.createSubMatrix(self.fields[i], self.fields[j], submat=self._blocks.get((i, j)))
        if not self._scatters:
            x = A.createVecRight()
            self._y = [self._blocks[2, 0].createVecRight(), self._blocks[2, 1].createVecRight(),
                       self._blocks[2, 0].createVecLeft()]
            self._r, self._work = [v.duplicate() for v in self._y], [v.duplicate() for v in self._y]
            self._scatters = [PETSc.Scatter().create(x, f, v, None) for f, v in zip(self.fields, self._y)]
            x.destroy()

    def apply(self, pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        if not self.sweep:
            self.inner.apply(x, y)
            return
        subs, r = self.inner.getFieldSplitSubKSP(), self._r
        for k, scatter in enumerate(self._scatters):
            scatter.scatter(x, r[k], PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
            for j in range(k):
                self._blocks[k, j].mult(self._y[j], self._work[k])
                r[k].axpy(-1.0, self._work[k])
            subs[k].solve(r[k], self._y[k])
            scatter.scatter(self._y[k], y, PETSc.InsertMode.INSERT, PETSc.ScatterMode.REVERSE)


class _GelKrylov(KrylovSolver):
    """The gel's solver: :class:`PressureSchur` on the pressure block (see :func:`gel_solver`), and
    :class:`BlockLowerTriangular` for the multiplicative split."""

    def __init__(self, *args, mass_form, **kwargs):
        super().__init__(*args, **kwargs)
        self._mass_form = mass_form
        self._pressure: PressureSchur | None = None
        self._inner: PETSc.PC | None = None

    def _configure(self) -> None:
        """The field split as an inner PC read from the options, under the KSP's
        :class:`BlockLowerTriangular` (its sweep if the split is multiplicative, the default)."""
        self._set_norm()
        with self._options_in_database() as opts:
            self.ksp.setFromOptions()
            self.ksp.setTolerances(rtol=self.rtol, atol=0.0, max_it=self.max_it)
            inner = self._inner = PETSc.PC().create(self.comm)
            inner.setOptionsPrefix(self._prefix)
            inner.setType("fieldsplit")
            inner.setFieldSplitIS(*self._fields)
            inner.setOperators(*self.ksp.getOperators())
            inner.setFromOptions()
            sweep = opts.getString(self._prefix + "pc_fieldsplit_type", "multiplicative") == "multiplicative"
            pc = self.ksp.getPC()
            pc.setType("python")
            pc.setPythonContext(BlockLowerTriangular(inner, [f for _, f in self._fields], sweep))
            self._set_up()
        self._configured = True

    def _set_up(self) -> None:
        inner = self._inner
        inner.setOperators(*self.ksp.getOperators())
        inner.setUp()
        self._attach_interpolations(inner)
        subs = inner.getFieldSplitSubKSP()
        p_set = self._fields[2][1]
        self._L_beta = self._P.createSubMatrix(p_set, p_set, submat=getattr(self, "_L_beta", None))
        diagonal = self._pressure_mass_diagonal(p_set)
        if self._pressure is None:
            self._pressure = PressureSchur(self.comm, self._L_beta, diagonal, self._prefix + "fieldsplit_p_schur_")
            p_pc = subs[2].getPC()
            p_pc.setType("python")
            p_pc.setPythonContext(self._pressure)
        else:
            self._pressure.update(self._L_beta, diagonal)
        for sub in subs:
            sub.setUp()
        self.ksp.setUp()

    def _pressure_mass_diagonal(self, p_set: PETSc.IS) -> PETSc.Vec:
        """The diagonal of the viscous mass form's pressure block (:class:`PressureSchur`'s D)."""
        mass = fem_petsc.assemble_matrix(self._mass_form)
        mass.assemble()
        block = mass.createSubMatrix(p_set, p_set)
        diagonal = block.getDiagonal()
        for obj in (mass, block):
            obj.destroy()
        return diagonal


class GelBlockKrylov(_GelKrylov):
    """:func:`gel_solver`'s GMRES for a gel block that is part of a larger system: its operator, its
    preconditioner matrix (the operator plus the Darcy and fixed-stress terms on p) and its viscous mass
    matrix are given as matrices (:meth:`set_matrices`), its ``fields`` (w, u, p) in the block's numbering."""

    def __init__(self, comm: MPI.Comm, name: str, fields, dim: int, options: dict | None = None):
        super().__init__(comm, name, "gmres", _merged(gel_options(dim), options), fields=fields,
                         preconditioned_norm=True, mass_form=None)

    def set_matrices(self, A: PETSc.Mat, P: PETSc.Mat, mass: PETSc.Mat) -> None:
        """The block's operator, preconditioner matrix and viscous mass; set up at :meth:`factorize`."""
        self.set_operator(A)
        self._P, self._mass = P, mass

    def _preconditioner_matrix(self) -> PETSc.Mat:
        return self._P

    def _pressure_mass_diagonal(self, p_set: PETSc.IS) -> PETSc.Vec:
        block = self._mass.createSubMatrix(p_set, p_set)
        diagonal = block.getDiagonal()
        block.destroy()
        return diagonal
