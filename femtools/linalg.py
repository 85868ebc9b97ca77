"""Linear and Newton solvers that factorise once and reuse the factorisation.

In a coupling loop only the interface data of a field problem change, not
its operator.  ``LinearSolver`` assembles and factorises the matrix once and
afterwards only re-assembles the right-hand side; ``NewtonSolver`` keeps the
factorised Jacobian of an earlier state for as long as the (modified) Newton
iteration contracts fast, which at the tiny strains of the device cases is
for good.  Both report what they did in ``stats``.
"""

from __future__ import annotations

import itertools
import re
import time
import typing

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem

if typing.TYPE_CHECKING:
    import scipy.sparse
from dolfinx.fem import petsc as fem_petsc

from femtools.errors import NewtonError, SingularSystemError

__all__ = ["DirectSolver", "BlockTriangularSolver", "is_symmetric", "LinearSolver", "NewtonSolver", "SolverStats",
           "direct_solver", "assemble_residual_vector", "jacobian_at_rest", "SingularSystemError",
           "NewtonError", "schur_complement", "gather_submatrix", "gather_entries",
           "condensed_matrix", "distributed_schur_complement", "split_by_integral_type"]

_counter = itertools.count()
_ICNTL = re.compile(r"^mat_mumps_icntl_(\d+)$")

#: MUMPS controls applied to every factorisation: more workspace slack (14) and
#: null-pivot detection (24).  With detection on, MUMPS does not stop at a zero
#: pivot: it patches it and counts it in INFOG(28), which ``DirectSolver.factorize``
#: reads to refuse a singular system (none of the device systems has a null pivot).
DEFAULT_ICNTL = {14: 100, 24: 1}

#: CNTL(3): a pivot below this times the norm of MUMPS's scaled matrix counts as null.  MUMPS's own
#: default (1e-5 machine epsilons) is far below round-off: a rigid mode left free by the boundary
#: conditions then leaves a pivot of ~1e-15 and passes, depending on the elimination order (the
#: gel's displacement block on 2 ranks did); regular device systems pass with 1e-9
NULL_PIVOT_THRESHOLD = 1e-12

#: MUMPS's fill-reducing orderings (ICNTL(7)) in Debian's build, which has neither METIS nor SCOTCH
MUMPS_ORDERINGS = {0: "AMD", 2: "AMF", 4: "PORD", 6: "QAMD", 7: "automatic"}

#: MUMPS's automatic choice (PORD for some of the device's matrices, AMF for others).
#: AMF analyses faster (PORD calls clock(), a system call, at every elimination
#: stage) but its elimination trees back-substitute more slowly, which a
#: time-dependent run, with many back-substitutions per factorisation, pays for
#: (docs/femtools-costs.md).  Steady device runs, which factorise once and
#: back-substitute a few times, ask for AMF (gelcell.coupled.defaults.STEADY_SOLVER_OPTIONS).
DEFAULT_ORDERING = 7


class SolverStats(dict):
    """Counts and wall times of a solver: factorisations, solves, assemblies."""

    def __init__(self):
        super().__init__(factorizations=0, solves=0, factor_time=0.0, solve_time=0.0,
                         assemble_time=0.0, newton_iterations=0, rejected_steps=0,
                         state_assemblies=0, linear_steps=0, linear_fallbacks=0, krylov_iterations=0)

    def count_solve(self, solver) -> None:
        """One more linear solve by ``solver``: its Krylov iterations (none for a factorisation)."""
        self["solves"] += 1
        if getattr(solver, "kind", None) == "krylov":
            self["krylov_iterations"] += solver.iterations[-1]


class FactorizationError(RuntimeError):
    """A factorisation failed for another reason than a singular matrix (e.g. MUMPS workspace)."""

    def __init__(self, message: str, infog1: int = 0):
        super().__init__(message)
        self.infog1 = infog1


def _check_kind(kind: str) -> None:
    if kind not in ("lu", "cholesky"):
        raise ValueError(f"kind must be 'lu' or 'cholesky' (LDL^T of a symmetric matrix), got {kind!r}")


def _with_more_workspace(attempt, icntl14: int):
    """``attempt(0, icntl14)``; while MUMPS asks for more workspace (:attr:`DirectSolver.WORKSPACE_ERRORS`),
    up to three times, ``attempt(k, icntl14)`` again with ICNTL(14) = 2 icntl14 + 100."""
    for retry in range(4):
        try:
            return attempt(retry, icntl14)
        except FactorizationError as exc:
            if retry == 3 or exc.infog1 not in DirectSolver.WORKSPACE_ERRORS:
                raise
            icntl14 = 2 * icntl14 + 100


class DirectSolver:
    """LU or LDL^T factorisation (MUMPS by default) of one operator, reused for many right-hand sides.

    ``kind`` is "lu" or "cholesky" (LDL^T, for a symmetric operator);
    :meth:`factorize_symmetric_if_possible` chooses it from the matrix.

    Options are set through the API, not the global PETSc options database,
    whose 512 entries a long test session would otherwise fill:
    ``mat_mumps_icntl_N`` entries of ``options`` become MUMPS controls,
    ``pc_factor_mat_solver_type`` selects the factorisation package, and any
    other entry goes to the options database under a unique prefix.
    ICNTL(7), the ordering (``mat_mumps_icntl_7``, default :data:`DEFAULT_ORDERING`),
    is passed through the options database for the analysis only and removed
    after it: PETSc 3.18 resets an ICNTL(7) set through the API before the analysis.
    """

    def __init__(self, comm: MPI.Comm, name: str, options: dict | None = None, kind: str = "lu"):
        _check_kind(kind)
        self.name, self.kind = name, kind
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType(kind)
        options = dict(options or {})
        pc.setFactorSolverType(options.pop("pc_factor_mat_solver_type", "mumps"))
        options.pop("ksp_type", None)
        options.pop("pc_type", None)
        self.icntl = dict(DEFAULT_ICNTL)
        self.ordering = int(options.pop("mat_mumps_icntl_7", DEFAULT_ORDERING))
        if self.ordering not in MUMPS_ORDERINGS:
            raise ValueError(f"{name}: mat_mumps_icntl_7 (the ordering) must be one of {sorted(MUMPS_ORDERINGS)}, "
                             f"got {self.ordering}")
        if comm.size > 1:
            self.icntl[20] = 10         # distributed right-hand side: no gather onto the host before each solve
        for key in list(options):
            m = _ICNTL.match(key)
            if m:
                self.icntl[int(m.group(1))] = int(options.pop(key))
        self._prefixed = bool(options)
        if options:
            prefix = f"gelcell_{name}_{next(_counter)}_"
            self.ksp.setOptionsPrefix(prefix)
            opts = PETSc.Options()
            for k, v in options.items():
                opts[prefix + k] = v
            self.ksp.setFromOptions()

    def set_kind(self, kind: str) -> None:
        """Factorise by ``kind`` ("lu" or "cholesky") from the next factorisation on."""
        _check_kind(kind)
        if kind != self.kind:
            pc = self.ksp.getPC()
            solver_type = pc.getFactorSolverType()
            A = self.ksp.getOperators()[0]
            self.ksp.reset()
            self.ksp.setType("preonly")
            pc.setType(kind)
            pc.setFactorSolverType(solver_type)
            if self._prefixed:
                self.ksp.setFromOptions()       # the options of the new factorisation
            self.ksp.setOperators(A)
            self.kind = kind

    def factorize_symmetric_if_possible(self) -> None:
        """Factorise the current operator by LDL^T if it is symmetric to round-off, else by LU.

        LDL^T has about half the flops and fill of LU.  A symmetric indefinite
        matrix can still defeat it (MUMPS's workspace with badly scaled rows):
        LU with pivoting is then used.
        """
        A = self.ksp.getOperators()[0]
        kind = "cholesky" if is_symmetric(A) else "lu"
        A.setOption(PETSc.Mat.Option.SYMMETRIC, kind == "cholesky")     # never a stale flag
        self.set_kind(kind)
        try:
            self.factorize()
        except FactorizationError:
            if kind == "lu":
                raise
            self.set_kind("lu")
            self.factorize()

    def set_operator(self, A: PETSc.Mat, reset: bool = False) -> None:
        """Use ``A``; ``reset`` drops an earlier factorisation of a matrix of another size."""
        if reset:
            self.ksp.reset()
        self.ksp.setOperators(A)

    #: MUMPS errors that more workspace (ICNTL(14)) cures, e.g. -9 when badly scaled rows delay pivots
    WORKSPACE_ERRORS = (-8, -9, -11, -14, -15, -17, -20)

    def factorize(self) -> None:
        """(Re)factorise the current operator (with more workspace, up to three times, if MUMPS asks)."""
        def attempt(retry: int, icntl14: int) -> None:
            if retry:                       # start again from the operator, with the larger workspace
                self.icntl[14] = icntl14
                A = self.ksp.getOperators()[0]
                self.ksp.reset()
                self.ksp.setOperators(A)
            self._factorize()
        _with_more_workspace(attempt, self.icntl.get(14, 20))

    def _factorize(self) -> None:
        pc = self.ksp.getPC()
        pc.setFactorSetUpSolverType()
        mumps = pc.getFactorSolverType() == "mumps"
        if mumps:
            F = pc.getFactorMatrix()
            for k, v in self.icntl.items():
                F.setMumpsIcntl(k, v)
            F.setMumpsCntl(3, NULL_PIVOT_THRESHOLD)
        if mumps:
            # read by the analysis, under the operator's prefix; removed again, so that no other solver sees it
            ordering = (self.ksp.getOperators()[0].getOptionsPrefix() or "") + "mat_mumps_icntl_7"
            options = PETSc.Options()
            options[ordering] = self.ordering
            try:
                self.ksp.setUp()
            finally:
                options.delValue(ordering)
        else:
            self.ksp.setUp()
        if mumps:
            # INFOG is global: every rank sees the same values and raises alike
            F = pc.getFactorMatrix()
            if F.getMumpsInfog(1) == -10 or (self.icntl.get(24) == 1 and F.getMumpsInfog(28) > 0):
                raise SingularSystemError(self.name, max(F.getMumpsInfog(28), 1))
            if F.getMumpsInfog(1) < 0:
                raise FactorizationError(f"{self.name}: MUMPS {self.kind} factorisation failed "
                                         f"(INFOG(1) = {F.getMumpsInfog(1)}, INFOG(2) = {F.getMumpsInfog(2)})",
                                         F.getMumpsInfog(1))

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        self.ksp.solve(b, x)
        reason = self.ksp.getConvergedReason()
        if reason <= 0:
            raise RuntimeError(f"{self.name}: linear solve failed (PETSc KSP reason {reason})")


#: asymmetry, relative to the largest row sum, below which a matrix is factorised as symmetric (LDL^T)
SYMMETRY_TOLERANCE = 1e-12


def is_symmetric(M: PETSc.Mat, tolerance: float = SYMMETRY_TOLERANCE) -> bool:
    """max_ij |M_ij - M_ji| <= tolerance ||M||_inf, on a symmetric sparsity pattern (collective).

    Entrywise, without forming M^T (which takes a parallel transpose and an axpy
    of different patterns; docs/femtools-costs.md): PETSc's own walk
    through the rows of the sequential matrix, or of each rank's diagonal
    block; on several ranks the entries whose column another rank owns are
    sent to that rank as (j, i, M_ij) and compared with its own.  A pattern
    that is not symmetric counts as asymmetric (LU); an assembled square
    form's pattern always is.
    """
    limit = tolerance * M.norm(PETSc.NormType.INFINITY)
    if M.comm.size == 1:
        return bool(M.isSymmetric(limit))
    comm = M.comm.tompi4py()
    same = bool(M.getDiagonalBlock().isSymmetric(limit))
    start, end = M.getOwnershipRange()
    ranges = M.getOwnershipRanges()
    n = np.int64(M.getSize()[0])
    indptr, cols, values = M.getValuesCSR()
    rows = np.repeat(np.arange(start, end, dtype=np.int64), np.diff(indptr))
    off = (cols < start) | (cols >= end)
    rows, cols, values = rows[off], cols[off].astype(np.int64), values[off]
    owner = np.searchsorted(ranges, cols, side="right") - 1
    # to the owner of column j: the transposed entry (j, i, M_ij), keyed j n + i
    sent = [(cols[owner == r] * n + rows[owner == r], values[owner == r]) for r in range(comm.size)]
    received = comm.alltoall(sent)
    theirs_keys = np.concatenate([k for k, _ in received])
    theirs = np.concatenate([v for _, v in received])
    mine_keys = rows * n + cols
    a, b = np.argsort(mine_keys, kind="stable"), np.argsort(theirs_keys, kind="stable")
    same = same and np.array_equal(mine_keys[a], theirs_keys[b]) and (
        a.size == 0 or np.abs(values[a] - theirs[b]).max() <= limit)
    return bool(comm.allreduce(same, op=MPI.LAND))


class BlockTriangularSolver:
    """Direct solves with a block lower-triangular matrix, by block forward substitution.

    For ``A = [[A00, 0], [A10, A11]]`` (rows and columns split by the index
    sets ``blocks``): x0 = A00^-1 b0, x1 = A11^-1 (b1 - A10 x0).  Each diagonal
    block is factorised on its own, by LDL^T (MUMPS Cholesky) if it is
    symmetric to round-off and by LU otherwise: far less fill, and faster
    factorisations and back-solves, than one LU of A.  The solution is that of
    A itself (exact, not a preconditioner).  ``factorize(A)`` first checks that
    the upper block is zero and returns False, factorising nothing, if it is not.
    """

    def __init__(self, comm: MPI.Comm, name: str, blocks: typing.Sequence[np.ndarray], options: dict | None = None):
        if len(blocks) != 2:
            raise ValueError(f"{name}: two blocks are needed, got {len(blocks)}")
        self.comm, self.name, self.options = comm, name, dict(options or {})
        blocks = [np.asarray(b, dtype=PETSc.IntType) for b in blocks]
        self.sets = [PETSc.IS().createGeneral(b, comm=comm) for b in blocks]
        self._local: list[np.ndarray] | None = None         # owned positions of each block's entries
        self._global = blocks
        self.solvers: list[DirectSolver | None] = [None, None]
        self.diagonal: list[PETSc.Mat | None] = [None, None]
        self.lower: PETSc.Mat | None = None
        self._vecs = None

    def factorize(self, A: PETSc.Mat) -> bool:
        """Extract and factorise the diagonal blocks of ``A``; False if ``A`` is not block lower-triangular."""
        upper = A.createSubMatrix(self.sets[0], self.sets[1])
        zero = upper.norm(PETSc.NormType.FROBENIUS) == 0.0
        upper.destroy()
        if not zero:
            return False
        self.lower = A.createSubMatrix(self.sets[1], self.sets[0], submat=self.lower)
        for k, rows in enumerate(self.sets):
            self.diagonal[k] = A.createSubMatrix(rows, rows, submat=self.diagonal[k])
            if self.solvers[k] is None:
                self.solvers[k] = DirectSolver(self.comm, self.name, self.options)      # errors name the field
            self.solvers[k].set_operator(self.diagonal[k])
            self.solvers[k].factorize_symmetric_if_possible()
        start = A.getOwnershipRange()[0]
        self._local = [b - start for b in self._global]
        # right-hand sides and solutions of the blocks, and the work vector A10 x0
        self._vecs = ([(D.createVecLeft(), D.createVecRight()) for D in self.diagonal]
                      + [self.diagonal[1].createVecLeft()])
        return True

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        (b0, x0), (b1, x1), work = self._vecs
        i0, i1 = self._local
        rhs = b.array_r
        b0.array[:] = rhs[i0]
        self.solvers[0].solve(b0, x0)
        self.lower.mult(x0, work)                 # r1 = b1 - A10 x0
        b1.array[:] = rhs[i1] - work.array_r
        self.solvers[1].solve(b1, x1)
        out = x.array
        out[i0] = x0.array_r
        out[i1] = x1.array_r


def _parts(form) -> tuple:
    """A compiled form, or the compiled parts of one form (:func:`split_by_integral_type`), as a tuple."""
    return tuple(form) if isinstance(form, (tuple, list)) else (form,)


def _assemble_into(A: PETSc.Mat, form, bcs) -> None:
    """Assemble ``form`` (a compiled form or a tuple of its parts) into ``A``, Dirichlet rows of
    ``bcs`` set to the identity."""
    A.zeroEntries()
    for k, part in enumerate(_parts(form)):
        if k:
            A.assemble(PETSc.Mat.AssemblyType.FLUSH)    # the previous part set the diagonal by insertion
        fem_petsc.assemble_matrix(A, part, bcs=bcs)
    A.assemble()


def _assemble_and_factorize(A: PETSc.Mat, form, bcs, solver: DirectSolver, stats: SolverStats,
                            sub=None, assemble=None) -> PETSc.Mat:
    """Assemble ``form`` into ``A`` (Dirichlet rows: identity), factorise it; returns the factorised matrix.

    ``sub = (IS, previous submatrix)`` factorises only the rows and columns in the IS;
    ``assemble(A, form)`` replaces the plain assembly.
    """
    t0 = time.perf_counter()
    if assemble is not None:
        assemble(A, form)
    else:
        _assemble_into(A, form, bcs)
    operator = A
    if sub is not None:
        rows, previous = sub
        operator = A.createSubMatrix(rows, rows, submat=previous)
        solver.set_operator(operator, reset=previous is None)  # the KSP saw the full-size matrix
    else:
        solver.set_operator(A)
    stats["assemble_time"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    solver.factorize_symmetric_if_possible()
    stats["factor_time"] += time.perf_counter() - t0
    stats["factorizations"] += 1
    return operator


def _unchanged(key: list[np.ndarray], old: list[np.ndarray] | None, comm: MPI.Comm) -> bool:
    """True on every rank if the arrays ``key`` equal the stored copies ``old`` on every rank."""
    same = old is not None and len(key) == len(old) and all(np.array_equal(a, b) for a, b in zip(key, old))
    return comm.allreduce(same, op=MPI.LAND) if comm.size > 1 else same


def _bc_values(bc) -> np.ndarray:
    """The values of a Dirichlet condition (its Function's array or its Constant's value)."""
    g = bc.g
    if hasattr(g, "x"):
        return g.x.array
    return np.asarray(g.value if hasattr(g, "value") else g)


def direct_solver(comm: MPI.Comm, A: PETSc.Mat, name: str, petsc_options: dict | None = None) -> DirectSolver:
    """A factorised :class:`DirectSolver` for ``A``."""
    solver = DirectSolver(comm, name, petsc_options)
    solver.set_operator(A)
    solver.factorize()
    return solver


def _nan_check(vec: PETSc.Vec, what: str) -> None:
    if not np.isfinite(vec.norm()):
        raise FloatingPointError(f"{what}: the solution contains NaN or Inf")


class LinearSolver:
    """Solve ``a(u, v) = L(v)`` with Dirichlet ``bcs``; assemble and factorise ``a`` once.

    ``solve()`` re-assembles only ``L`` (and the lifting of the Dirichlet
    values when they changed), so changing coefficients of ``L`` or Dirichlet
    data between calls is cheap.  Call ``update_operator()`` if ``a`` changed.
    ``linear_solver``: an object of the :class:`DirectSolver` interface (e.g. a
    ``femtools.krylov.KrylovSolver``) used instead of MUMPS.
    """

    def __init__(self, a: ufl.Form, L: ufl.Form, u: fem.Function, bcs: list, name: str = "linear",
                 petsc_options: dict | None = None, form_compiler_params: dict | None = None,
                 linear_solver=None):
        fcp = form_compiler_params or {}
        self.a = fem.form(a, form_compiler_params=fcp)
        self.L = fem.form(L, form_compiler_params=fcp)
        self.u, self.bcs, self.name = u, bcs, name
        self.stats = SolverStats()
        comm = u.function_space.mesh.comm
        self.A = fem_petsc.create_matrix(self.a)
        self.b = fem_petsc.create_vector(self.L)
        self._lift = fem_petsc.create_vector(self.L)      # - A g of the Dirichlet values g (owned entries)
        self._lift_key: list[np.ndarray] | None = None
        # a solver of the DirectSolver interface (e.g. femtools.krylov.KrylovSolver) replaces MUMPS
        self.solver = DirectSolver(comm, name, petsc_options) if linear_solver is None else linear_solver
        self.ksp = self.solver.ksp
        self._operator_ready = False

    def update_operator(self) -> None:
        """Re-assemble the matrix and factorise it."""
        _assemble_and_factorize(self.A, self.a, self.bcs, self.solver, self.stats)
        self._operator_ready = True
        self._lift_key = None

    def _lifting(self) -> PETSc.Vec:
        """The lifting of the Dirichlet values, re-assembled only when they (or the operator) changed."""
        key = [_bc_values(bc) for bc in self.bcs]
        if not _unchanged(key, self._lift_key, self.u.function_space.mesh.comm):
            with self._lift.localForm() as loc:
                loc.set(0.0)
            fem_petsc.apply_lifting(self._lift, [self.a], bcs=[self.bcs])
            self._lift.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            self._lift_key = [k.copy() for k in key]
        return self._lift

    def assemble_rhs(self) -> PETSc.Vec:
        """Right-hand side with the current Dirichlet values lifted and set."""
        lift = self._lifting()
        with self.b.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self.b, self.L)
        self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.b.axpy(1.0, lift)
        fem_petsc.set_bc(self.b, self.bcs)
        return self.b

    def solve(self) -> fem.Function:
        if not self._operator_ready:
            self.update_operator()
        t0 = time.perf_counter()
        self.assemble_rhs()
        self.stats["assemble_time"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        self.solver.solve(self.b, self.u.vector)
        self.stats["solve_time"] += time.perf_counter() - t0
        self.stats.count_solve(self.solver)
        _nan_check(self.u.vector, self.name)
        self.u.x.scatter_forward()
        return self.u


class NewtonSolver:
    """Newton's method for ``F(u; v) = 0`` with the exact Jacobian ``J = dF/du``.

    Converged when the correction satisfies ``|du| <= rtol |u|`` (a relative,
    scale-free criterion: the device unknowns are O(1e-6) in paper units), or
    when the contraction of the iteration says that the error left is below
    it (see "Convergence" below).

    Jacobian reuse (``reuse``):
      * ``"never"``: full Newton, a new factorisation every iteration;
      * ``"adaptive"`` (default): keep the factorised Jacobian, also across
        calls to ``solve()``, for as long as every correction is at most
        ``contraction`` times the previous one.  A step with a kept (stale)
        Jacobian that fails this test is undone and retaken with a Jacobian
        at the current iterate: a stale first step of a strongly nonlinear
        solve could otherwise leave Newton's basin.  At small strains the
        first factorisation serves the whole coupling loop.

    ``J_reference`` (optional): a Jacobian form whose coefficients do not
    depend on the state (e.g. ``J`` with the state and the interface data
    replaced by zero: the linearisation at rest).  It is then the kept
    Jacobian (reuse ``"adaptive"``): the same matrix whatever the iterate it
    is first needed at, so a run restarted from a checkpoint repeats the
    uninterrupted run's iterates exactly.  When it stops contracting (large
    loads) the solver switches to the exact Jacobian at the current iterate
    until ``invalidate_jacobian()``.

    ``active_dofs`` (local dof indices) restricts the linear solves to those
    dofs: the others have no equation (e.g. a field outside its subdomain in
    the monolithic system) and keep their value.

    ``linear_solver`` (optional): an object of the :class:`DirectSolver` interface
    (``set_operator``, ``factorize``, ``solve``), e.g. a ``femtools.krylov.KrylovSolver``,
    that solves every Jacobian instead of MUMPS (``reference_blocks`` is then unused).

    ``reference_blocks`` (optional): two arrays of local dofs splitting the
    unknowns.  If ``J_reference`` is block lower-triangular in that split
    (checked whenever it is assembled: the first block's equations do not
    contain the second block's unknowns, e.g. the gel's flow at rest does not
    depend on the network displacement), it is solved by block forward
    substitution (:class:`BlockTriangularSolver`) with a factorisation per
    diagonal block; otherwise, and for the exact Jacobian, by one LU.

    Interface stiffness (:meth:`set_interface_stiffness`): a dense matrix K
    over a few dofs (e.g. the Steklov-Poincare operator of a neighbouring
    body on a shared interface) added to the residual, ``F(u) + K u_I``, and
    to every Jacobian; a Robin condition whose operator is not a form.

    Cheap residuals.  ``F_data`` (optional) is the part of the residual that
    carries interface or load data (boundary integrals, cheap to assemble);
    the residual is ``F + F_data``.  The state part ``F`` (the bulk) is
    assembled only when the state or one of its coefficients or Constants
    changed since its last assembly, so a solve that starts where the previous
    one ended re-assembles only ``F_data``.  It is kept for two states: the
    one the last solve started from and the latest iterate, so that solves
    which all start from one state (a time window's checkpoint, to which every
    coupling iteration returns) assemble it there once.  The lifting of Dirichlet values is
    skipped when the iterate already satisfies them (it would add nothing), and made with the
    Jacobian the step solves with (:meth:`residual`).

    Convergence: ``|du| <= rtol |u|``, or the remaining error estimated from
    the contraction of the last two corrections, theta / (1 - theta) |du| with
    theta = |du_k| / |du_(k-1)|, is below ``rtol |u|`` (Newton with a kept
    Jacobian contracts linearly; this spares the step that would only confirm
    it).

    The linear path (``solve(linear_path=True)``), for a loop of solves that
    each continue from the previous one (a steady coupling loop): when the
    state is still the previous solve's solution (same values of the state
    and of every coefficient and Constant of ``F``; only ``F_data``, loads or
    Dirichlet values changed), take ONE step with the kept Jacobian, then
    test whether the nonlinear remainder matters: the residual at the new
    iterate relative to the residual the step removed, rho = |F(u_1)| /
    |F(u_0)|.  For a linear problem rho is round-off and the step is the
    solution.  For weak nonlinearity (rho <= ``linear_tolerance``) the step
    is accepted; its error, about rho |du| (measured: a further step
    contracts by 1-10 rho), is left to the loop: the next solve starts from
    it, so at the loop's fixed point the step is zero and the state solves
    ``F = 0`` exactly.  Above it, or when the state was set otherwise (a first
    solve, a restored state, new Constants), the solve is the exact Newton path
    to ``rtol``.  ``data_coefficients``: coefficients of ``F`` that may change
    between the solves of such a loop like its data (e.g. the mesh position of
    a domain that follows its interfaces): at the loop's fixed point they stop
    changing too, so the same argument holds.
    """

    def __init__(self, F: ufl.Form, u: fem.Function, bcs: list, J: ufl.Form | None = None,
                 name: str = "newton", rtol: float = 1e-11, max_it: int = 30,
                 reuse: str = "adaptive", contraction: float = 0.1,
                 petsc_options: dict | None = None, form_compiler_params: dict | None = None,
                 active_dofs: np.ndarray | None = None, J_reference: ufl.Form | None = None,
                 F_data: ufl.Form | None = None, linear_tolerance: float = 1e-3,
                 reference_blocks: typing.Sequence[np.ndarray] | None = None,
                 data_coefficients: typing.Sequence[fem.Function] = (), linear_solver=None):
        if reuse not in ("never", "adaptive"):
            raise ValueError(f"reuse must be 'never' or 'adaptive', got {reuse!r}")
        if not (0.0 < linear_tolerance < 1.0):
            raise ValueError(f"linear_tolerance must be in (0, 1), got {linear_tolerance!r}")
        fcp = form_compiler_params or {}
        if isinstance(F_data, (int, float)) and F_data == 0:
            F_data = None
        if J is None:
            J = ufl.derivative(F if F_data is None else F + F_data, u)
        self.F = fem.form(F, form_compiler_params=fcp)
        self.F_data = None if F_data is None else fem.form(F_data, form_compiler_params=fcp)
        self._J_ufl, self._fcp, self._J = J, fcp, None
        self.linear_tolerance = float(linear_tolerance)
        self.last_linear_ratio: float | None = None
        self._track_sources(F, data_coefficients, name)
        self.J_reference = None if J_reference is None else fem.form(J_reference, form_compiler_params=fcp)
        self.u, self.bcs, self.name = u, bcs, name
        self.rtol, self.max_it, self.reuse, self.contraction = rtol, max_it, reuse, contraction
        self.stats = SolverStats()
        self.history: list[float] = []
        comm = u.function_space.mesh.comm
        # (the first part of J: its cell integrals, which hold the pattern of its other part)
        pattern = self.J_reference if _pattern_covers(J_reference, J) else self.J[0]
        self.A = fem_petsc.create_matrix(pattern)
        self.b = fem_petsc.create_vector(self.F)
        self._bc_check = self.A.createVecRight()
        self.du = self.A.createVecRight()
        self._active = None
        self._A_active = None
        if active_dofs is not None:
            self._active = self._owned_index_set(active_dofs)
        self.solver = DirectSolver(comm, name, petsc_options) if linear_solver is None else linear_solver
        self.ksp = self.solver.ksp
        self._blocks = None
        if reference_blocks is not None and self.J_reference is not None and linear_solver is None:
            if active_dofs is not None:
                raise ValueError(f"{name}: reference_blocks cannot be combined with active_dofs")
            self._blocks = self._block_solver(reference_blocks, petsc_options)
        self._linear = self.solver                 # what the current Jacobian is solved with
        self._have_jacobian = False
        self._exact = self.J_reference is None or reuse == "never"   # which Jacobian is (to be) kept
        self._load_dofs, self._load_values = np.empty(0, dtype=np.int32), np.empty(0)
        self._stiffness = None

    def _track_sources(self, F: ufl.Form, data_coefficients, name: str) -> None:
        """What the state part depends on, what the linear path asks to be unchanged, and the empty
        records of the states the residual was assembled at."""
        # what the state part depends on: its coefficients' values and its Constants
        self._state_sources = (list(F.coefficients()), list(F.constants()))
        # what the linear path asks to be unchanged: the same but for the data coefficients
        data = {id(c) for c in data_coefficients}
        if not data <= {id(c) for c in self._state_sources[0]}:
            raise ValueError(f"{name}: data_coefficients must be coefficients of F")
        self._path_sources = ([c for c in self._state_sources[0] if id(c) not in data], self._state_sources[1])
        # (key, F(u)) at the state the last solve started from and at the latest other state
        self._state_residuals: dict[str, tuple[list[np.ndarray], PETSc.Vec] | None] = {"start": None,
                                                                                       "latest": None}
        self._solution_key: list[np.ndarray] | None = None    # where the last solve ended

    def _owned_index_set(self, active_dofs: np.ndarray) -> PETSc.IS:
        """The global index set of the owned entries of ``active_dofs`` (local unrolled dofs of u)."""
        imap, bs = self.u.function_space.dofmap.index_map, self.u.function_space.dofmap.index_map_bs
        owned = np.asarray(active_dofs, dtype=np.int64)
        owned = owned[owned < imap.size_local * bs]
        return PETSc.IS().createGeneral((owned + imap.local_range[0] * bs).astype(PETSc.IntType),
                                        comm=self.u.function_space.mesh.comm)

    def _block_solver(self, reference_blocks, petsc_options) -> "BlockTriangularSolver":
        """The block-triangular solver of the kept Jacobian, on the owned (global) dofs of each block."""
        imap, bs = self.u.function_space.dofmap.index_map, self.u.function_space.dofmap.index_map_bs
        n_owned, start = imap.size_local * bs, imap.local_range[0] * bs
        owned = [np.sort(np.asarray(d, dtype=np.int64)) for d in reference_blocks]
        owned = [d[d < n_owned] + start for d in owned]
        return BlockTriangularSolver(self.u.function_space.mesh.comm, self.name, owned, petsc_options)

    @property
    def num_active_dofs(self) -> int:
        """Global number of dofs the linear solves act on."""
        if self._active is None:
            return self.A.getSize()[0]
        return self.u.function_space.mesh.comm.allreduce(self._active.getLocalSize(), op=MPI.SUM)

    @property
    def J(self) -> tuple:
        """The exact Jacobian, compiled when first needed: with a ``J_reference`` a solve at
        small loads never needs it, and a finite-strain 3D Jacobian takes tens of seconds to compile.
        A tuple of compiled forms whose sum it is: its cell integrals and its boundary terms
        (:func:`split_by_integral_type`), compiled apart so that the cell kernel is shared."""
        if self._J is None:
            self._J = tuple(fem.form(part, form_compiler_params=self._fcp)
                            for part in split_by_integral_type(self._J_ufl))
        return self._J

    def _lifting_jacobian(self, exact: bool) -> tuple:
        """The compiled parts of the Jacobian that lifts the Dirichlet values: the exact one if
        ``exact``, else the one the next step solves with (held, or to be assembled)."""
        return _parts(self.J if exact or self._exact else self.J_reference)

    def invalidate_jacobian(self) -> None:
        """Factorise again at the next iteration (e.g. coefficients of J changed)."""
        self._have_jacobian = False
        self._exact = self.J_reference is None or self.reuse == "never"

    @property
    def uses_reference_jacobian(self) -> bool:
        """True while the kept Jacobian is ``J_reference``."""
        return not self._exact

    def _factorize_blocks(self) -> bool:
        """Assemble J_reference; factorise it block by block if it is block lower-triangular."""
        t0 = time.perf_counter()
        self._assemble_matrix(self.A, self.J_reference)
        self.stats["assemble_time"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        if not self._blocks.factorize(self.A):
            return False
        self.stats["factor_time"] += time.perf_counter() - t0
        self.stats["factorizations"] += 1
        return True

    def _assemble_jacobian(self) -> None:
        sub = None if self._active is None else (self._active, self._A_active)
        form = self.J if self._exact else self.J_reference
        try:
            if not self._exact and self._blocks is not None and self._factorize_blocks():
                self._linear = self._blocks
                self._have_jacobian = True
                return
            self._linear = self.solver
            operator = _assemble_and_factorize(self.A, form, self.bcs, self.solver, self.stats, sub,
                                               assemble=self._assemble_matrix)
        except SingularSystemError as exc:
            if self.stats["factorizations"] == 0:
                raise           # singular from the start: a missing boundary condition
            # an operator that was regular before lost rank at the current iterate: the
            # deformation degenerates (e.g. elements fold over), not a missing condition
            raise NewtonError(self.name, f"the Jacobian became singular ({exc.null_pivots} null pivots) at "
                                         f"the current iterate", self.history) from exc
        if self._active is not None:
            self._A_active = operator
        self._have_jacobian = True

    def set_nodal_loads(self, dofs: np.ndarray, values: np.ndarray) -> None:
        """Loads applied as nodal values: subtracted from the residual at these local *owned* dofs.

        For data that arrive as consistent nodal forces (e.g. the cell's
        reaction on Gamma2) rather than as a field to integrate.  A dof given
        more than once (a node shared by two interfaces) takes the sum.
        """
        dofs, where = np.unique(np.asarray(dofs, dtype=np.int32), return_inverse=True)
        self._load_dofs = dofs.astype(np.int32)
        self._load_values = np.bincount(where, weights=np.asarray(values, dtype=float).ravel(), minlength=dofs.size)

    def set_interface_stiffness(self, dofs: np.ndarray, K: np.ndarray) -> None:
        """Add ``K u_I`` to the residual and ``K`` to the Jacobian, ``u_I = u[dofs]``.

        ``dofs`` (M,): GLOBAL dof indices, the same on every rank; a negative
        entry leaves that row and column out (e.g. a Dirichlet dof).  ``K``:
        (M, M), replicated.  Each rank adds the rows it owns.  The kept
        Jacobian is factorised again at the next solve.
        """
        dofs = np.asarray(dofs, dtype=np.int64)
        K = np.array(K, dtype=float)
        if K.shape != (dofs.size, dofs.size):
            raise ValueError(f"{self.name}: the interface stiffness is {K.shape}, its dofs {dofs.shape}")
        if self.stats["factorizations"]:
            raise RuntimeError(f"{self.name}: set the interface stiffness before the first solve")
        use = dofs >= 0
        K, dofs = K[np.ix_(use, use)], dofs[use]
        start, end = self.A.getOwnershipRange()
        mine = (dofs >= start) & (dofs < end)
        # K alone, as a matrix of A's layout: added to every assembly of A, and K u_I = (K alone) u
        nnz = np.zeros(end - start, dtype=PETSc.IntType)
        nnz[dofs[mine] - start] = dofs.size
        alone = PETSc.Mat().createAIJ(self.A.getSizes(), nnz=(nnz, nnz), comm=self.A.getComm())
        alone.setValues(dofs[mine].astype(PETSc.IntType), dofs.astype(PETSc.IntType), K[mine],
                        addv=PETSc.InsertMode.ADD_VALUES)
        alone.assemble()
        self._stiffness = dict(matrix=alone, force=alone.createVecLeft(),
                               structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        self.invalidate_jacobian()

    def reference_matrix(self) -> PETSc.Mat:
        """The kept linearisation at rest as the solves factorise it: a new distributed matrix
        (each rank its own rows; the caller destroys it).

        ``J_reference`` with Dirichlet rows and the interface stiffness: a copy of the held
        matrix if the solver keeps it now, else assembled anew into a copy of its pattern.
        """
        if self.J_reference is None:
            raise RuntimeError(f"{self.name}: no J_reference")
        if self._have_jacobian and not self._exact:
            return self.A.copy()
        A = self.A.duplicate(copy=False)
        _assemble_into(A, self.J_reference, self.bcs)
        if self._stiffness is not None:
            # into the copy only: the solver's own first sum still extends its pattern
            A.axpy(1.0, self._stiffness["matrix"], structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        return A

    def _assemble_matrix(self, A: PETSc.Mat, form) -> None:
        """Assemble ``form`` into ``A`` (Dirichlet rows: identity), plus the interface stiffness."""
        _assemble_into(A, form, self.bcs)
        st = self._stiffness
        if st is not None:
            # the first sum extends A's pattern by K's (setting K's entries into dolfinx's matrix
            # would reallocate its storage once per overflowing row); A keeps that pattern
            A.axpy(1.0, st["matrix"], structure=st["structure"])
            st["structure"] = PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN

    def _current_state_key(self, sources=None) -> list[np.ndarray]:
        functions, constants = sources or self._state_sources
        return [f.x.array for f in functions] + [np.asarray(c.value) for c in constants]

    def _same_key(self, key: list[np.ndarray], other: list[np.ndarray] | None) -> bool:
        return _unchanged(key, other, self.u.function_space.mesh.comm)

    def state_residual(self, start: bool = False) -> PETSc.Vec:
        """The state part F(u) without boundary conditions or loads (owned entries; do not modify).

        Re-assembled only if the state or a coefficient or Constant of F differs from both states
        it is kept for; ``start``: u is where a solve starts (kept until the next solve's start).
        """
        key = self._current_state_key()
        for kept in self._state_residuals.values():
            if kept is not None and self._same_key(key, kept[0]):
                return kept[1]
        slot = "start" if start else "latest"
        kept = self._state_residuals[slot]
        vec = fem_petsc.create_vector(self.F) if kept is None else kept[1]
        with vec.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(vec, self.F)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self._state_residuals[slot] = ([a.copy() for a in key], vec)
        self.stats["state_assemblies"] += 1
        return vec

    def _dirichlet_satisfied(self) -> bool:
        """True if u already holds every Dirichlet value (then lifting adds nothing), on every rank."""
        if not self.bcs:
            return True
        x = self._bc_check
        self.u.vector.copy(x)
        fem_petsc.set_bc(x, self.bcs)
        ok = bool(np.array_equal(x.array_r, self.u.vector.array_r))
        comm = self.u.function_space.mesh.comm
        return comm.allreduce(ok, op=MPI.LAND) if comm.size > 1 else ok

    def residual(self, start: bool = False, exact_lifting: bool = False) -> PETSc.Vec:
        """``F(u)`` - nodal loads, with Dirichlet rows holding ``u - g`` (the Newton convention);
        ``start``: at the state a solve starts from (see :meth:`state_residual`).

        Where u does not hold the Dirichlet values g yet, the other rows get the lifting J (g - u)
        with the Jacobian the next step solves with (the step is then that of the kept matrix with
        its Dirichlet columns: Newton's with the exact one), or with the exact one if ``exact_lifting``
        (the linear path's step, whose acceptance test was set with it)."""
        state = self.state_residual(start)
        with self.b.localForm() as loc:
            loc.set(0.0)
        if self.F_data is not None:
            fem_petsc.assemble_vector(self.b, self.F_data)
        if not self._dirichlet_satisfied():
            # (a small-load solve with the kept linearisation at rest then compiles no exact Jacobian)
            for part in self._lifting_jacobian(exact_lifting):
                fem_petsc.apply_lifting(self.b, [part], bcs=[self.bcs], x0=[self.u.vector], scale=-1.0)
        self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.b.axpy(1.0, state)
        if self._load_dofs.size:
            # after the ghost update, so that each global dof receives its load exactly once
            with self.b.localForm() as loc:
                loc.array[self._load_dofs] -= self._load_values
        if self._stiffness is not None:
            self._stiffness["matrix"].mult(self.u.vector, self._stiffness["force"])
            self.b.axpy(1.0, self._stiffness["force"])
        fem_petsc.set_bc(self.b, self.bcs, self.u.vector, -1.0)
        return self.b

    def _linear_solve(self) -> None:
        if self._active is None:
            self._linear.solve(self.b, self.du)
            if getattr(self._linear, "kind", None) == "krylov":
                # the Dirichlet rows of du exactly (a Krylov method leaves them to round-off): the
                # iterate then holds the values, and the next residuals skip the lifting
                fem_petsc.set_bc(self.du, self.bcs, self.u.vector, -1.0)
            return
        self.du.zeroEntries()
        b_sub, du_sub = self.b.getSubVector(self._active), self.du.getSubVector(self._active)
        self.solver.solve(b_sub, du_sub)
        self.b.restoreSubVector(self._active, b_sub)
        self.du.restoreSubVector(self._active, du_sub)

    def solve(self, linear_path: bool = False) -> int:
        """Iterate to convergence; return the number of iterations.

        ``linear_path``: if the state is the previous solve's solution, one
        step with the kept Jacobian when the nonlinear remainder is small
        enough (see the class docstring); otherwise the exact path.
        """
        key = self._current_state_key(self._path_sources)
        iterations = self._iterate(linear_path and self._same_key(key, self._solution_key))
        self._solution_key = [a.copy() for a in self._current_state_key(self._path_sources)]
        return iterations

    def checkpoint_state(self) -> dict:
        """What the next solve takes from the past besides the unknowns and the coefficients (collective).

        Whether they are still where the last solve ended: the linear path then
        takes its one step (:meth:`solve`).  The kept Jacobian at rest needs
        nothing: it is the same matrix whenever it is factorised.
        """
        key = self._current_state_key(self._path_sources)
        return {"at_solution": bool(self._same_key(key, self._solution_key))}

    def load_checkpoint_state(self, state: typing.Mapping) -> None:
        """Continue as the solver that wrote ``state``, once the unknowns and coefficients are restored."""
        at_solution = bool(state.get("at_solution", False))
        self._solution_key = ([a.copy() for a in self._current_state_key(self._path_sources)]
                              if at_solution else None)

    def _iterate(self, linear_path: bool) -> int:
        self.history = []
        previous = None
        initial_residual = None
        if self.reuse == "never":
            self._have_jacobian = False
        for it in range(1, self.max_it + 1):
            t0 = time.perf_counter()
            self.residual(start=it == 1, exact_lifting=linear_path)
            self.stats["assemble_time"] += time.perf_counter() - t0
            if linear_path and initial_residual is None:
                initial_residual = self.b.norm()
            elif linear_path and len(self.history) == 1 and previous is not None:
                # after the one step: does the nonlinear remainder matter?
                if self._linear_step_accepted(initial_residual):
                    return it - 1
                linear_path = False                 # strongly nonlinear: the exact path
            du, un, rel, stale = self._newton_step(it)
            if (stale and previous is not None and rel > self.contraction * previous
                    and rel >= 1e3 * self.rtol):
                # the kept Jacobian does not contract: undo the step, refactorise here
                self.u.vector.axpy(1.0, self.du)
                self.u.x.scatter_forward()
                self._have_jacobian = False
                self._exact = True
                self.stats["rejected_steps"] += 1
                continue
            self.history.append(rel)
            self.stats["newton_iterations"] += 1
            if self._converged(du, un, rel, previous):
                return it
            if self.reuse == "never" or (previous is not None and rel > self.contraction * previous):
                self._have_jacobian = False
                self._exact = True
            previous = rel
        raise NewtonError(self.name, f"no convergence in {self.max_it} iterations", self.history)

    def _linear_step_accepted(self, initial_residual: float) -> bool:
        """After the one step of the linear path (``self.b`` the new residual): is rho small enough?"""
        rho = self.b.norm() / initial_residual if initial_residual > 0 else 0.0
        self.last_linear_ratio = rho
        if rho <= self.linear_tolerance:
            self.stats["linear_steps"] += 1
            return True
        self.stats["linear_fallbacks"] += 1
        return False

    def _newton_step(self, it: int) -> tuple[float, float, float, bool]:
        """u -= J^-1 F (the Jacobian assembled and factorised if none is held); returns
        ``(|du|, |u|, relative correction, whether the Jacobian was not this iterate's)``."""
        fresh = not self._have_jacobian
        if fresh:
            self._assemble_jacobian()
        # the reference Jacobian is not the one at this iterate: test its steps like stale ones
        stale = not fresh or not self._exact
        t0 = time.perf_counter()
        self._linear_solve()
        self.stats["solve_time"] += time.perf_counter() - t0
        self.stats.count_solve(self._linear)
        self.u.vector.axpy(-1.0, self.du)
        self.u.x.scatter_forward()
        du, un = self.du.norm(), self.u.vector.norm()
        if not (np.isfinite(du) and np.isfinite(un)):
            raise NewtonError(self.name, f"the iterate contains NaN or Inf at iteration {it}",
                              self.history)
        rel = du / un if un > 0 else du
        return du, un, rel, stale

    def _converged(self, du: float, un: float, rel: float, previous: float | None) -> bool:
        """The stopping tests: |du| <= rtol |u|, the round-off floor, or a small enough linear tail."""
        if du <= self.rtol * un or du == 0.0:
            return True
        if previous is not None:
            # at the round-off floor the correction stops shrinking; accept it there
            if rel > 0.5 * previous and rel < 1e3 * self.rtol:
                return True
            # linear contraction theta: the error left is about theta / (1 - theta) |du|
            theta = rel / previous
            if theta < 0.5 and theta / (1.0 - theta) * rel <= self.rtol:
                return True
        return False


def _petsc_library():
    """ctypes handle of the PETSc library petsc4py runs on (for the few calls petsc4py 3.18 lacks)."""
    import ctypes
    import os
    global _LIBPETSC
    if _LIBPETSC is None:
        with open("/proc/self/maps") as f:     # the very library already loaded, whatever its file name
            loaded = {line.split()[-1] for line in f if "/libpetsc" in line and ".so" in line}
        if not loaded:
            import petsc4py
            loaded = {os.path.join(petsc4py.get_config()["PETSC_DIR"], "lib", "libpetsc_real.so")}
        _LIBPETSC = ctypes.CDLL(sorted(loaded)[0])
    return _LIBPETSC


_LIBPETSC = None


def schur_complement(K: "scipy.sparse.spmatrix", keep: np.ndarray) -> np.ndarray:
    """S = K_kk - K_kr K_rr^-1 K_rk: a sparse matrix condensed onto the rows and columns ``keep``.

    By MUMPS's Schur-complement option (ICNTL(19)) in one sequential LU of K
    with ``keep`` eliminated last: the cost of one factorisation, against one
    back-substitution per kept index (docs/femtools-costs.md).  Local to the calling
    rank (``K`` replicated, e.g. a matrix that is whole on one rank); petsc4py 3.18 does not
    wrap PETSc's Schur calls, so they are called through ctypes.  MUMPS does
    not report a singular eliminated block on this path (a zero row there
    passes): the caller's own factorisation of K's system is the check.  When
    MUMPS asks for more workspace (badly scaled rows delay pivots), it is
    retried with a larger ICNTL(14), up to three times, as
    :meth:`DirectSolver.factorize` does.
    """
    keep = np.asarray(keep, dtype=PETSc.IntType)
    if keep.size == 0:
        return np.zeros((0, 0))
    K = K.tocsr()
    return _with_more_workspace(lambda retry, icntl14: _schur_complement(K, keep, icntl14), DEFAULT_ICNTL[14])


def _schur_complement(K: "scipy.sparse.csr_matrix", keep: np.ndarray, icntl14: int) -> np.ndarray:
    """One attempt of :func:`schur_complement` with the workspace control ICNTL(14) = ``icntl14``."""
    import ctypes
    lib = _petsc_library()
    M = PETSc.Mat().createAIJ(K.shape, csr=(K.indptr.astype(PETSc.IntType), K.indices.astype(PETSc.IntType),
                                            K.data.astype(PETSc.ScalarType)), comm=PETSc.COMM_SELF)
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(M)
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("lu")
    pc.setFactorSolverType("mumps")
    pc.setFactorSetUpSolverType()
    F = pc.getFactorMatrix()
    F.setMumpsIcntl(14, icntl14)
    kept = PETSc.IS().createGeneral(keep, comm=PETSc.COMM_SELF)
    handle = ctypes.c_void_p(F.handle)
    try:
        if lib.MatFactorSetSchurIS(handle, ctypes.c_void_p(kept.handle)) != 0:
            raise RuntimeError("MatFactorSetSchurIS failed")
        ksp.setUp()
        if F.getMumpsInfog(1) < 0:
            raise FactorizationError(f"schur_complement: MUMPS failed (INFOG(1) = {F.getMumpsInfog(1)})",
                                     F.getMumpsInfog(1))
        S, status = ctypes.c_void_p(), ctypes.c_int()
        if lib.MatFactorGetSchurComplement(handle, ctypes.byref(S), ctypes.byref(status)) != 0:
            raise RuntimeError("MatFactorGetSchurComplement failed")
        values = ctypes.POINTER(ctypes.c_double)()
        lib.MatDenseGetArrayRead(S, ctypes.byref(values))
        out = np.ctypeslib.as_array(values, shape=(keep.size * keep.size,)).reshape(keep.size, keep.size,
                                                                                     order="F").copy()
        lib.MatDenseRestoreArrayRead(S, ctypes.byref(values))
        lib.MatFactorRestoreSchurComplement(handle, ctypes.byref(S), status)
    finally:
        # the references to the PC and its factor too: either keeps MUMPS's factors alive
        for obj in (F, pc, ksp, M, kept):
            obj.destroy()
    if not np.isfinite(out).all():
        raise FactorizationError("schur_complement: the condensed matrix has NaN or Inf entries")
    return out


def _pattern_covers(reference: ufl.Form | None, J: ufl.Form) -> bool:
    """Whether the matrix pattern of ``reference`` holds that of ``J`` (same spaces): it has an
    integral of every kind (type, subdomain) J has (a pattern depends on where forms integrate,
    not on what), or a cell integral over every cell, which couples all dofs of a cell, and each
    of J's interior facet integrals (exterior facet couplings lie within one cell)."""
    if reference is None or reference.arguments() != J.arguments():
        return False
    def kinds(form):
        return {(itg.integral_type(), itg.subdomain_id()) for itg in form.integrals()}
    mine, theirs = kinds(reference), kinds(J)
    return theirs <= mine or (("cell", "everywhere") in mine
                              and all(t != "interior_facet" or (t, s) in mine for t, s in theirs))


def split_by_integral_type(J: ufl.Form) -> list[ufl.Form]:
    """``J`` as two forms, its cell integrals and its other integrals, derivatives expanded; ``[J]``
    if either is empty or the cell integrals' pattern does not hold the others' (:func:`_pattern_covers`).

    The form compiler caches a form by its signature: the cell part of a problem's Jacobian is then
    compiled once for every set of boundary terms (interfaces, loads, their facet tags), and a
    manufactured solution's source terms, whose derivative is zero, drop out of it.  A 3D
    finite-strain cell kernel is the costly one (docs/performance.md).
    """
    J = ufl.algorithms.expand_derivatives(J)
    cells = [itg for itg in J.integrals() if itg.integral_type() == "cell"]
    others = [itg for itg in J.integrals() if itg.integral_type() != "cell"]
    if not cells or not others or not _pattern_covers(ufl.Form(cells), J):
        return [J]
    return [ufl.Form(cells), ufl.Form(others)]


def jacobian_at_rest(F: ufl.Form, u: fem.Function, coefficients=()) -> ufl.Form:
    """dF/du with ``u`` and ``coefficients`` replaced by zero Functions: the linearisation at rest.

    A ``J_reference`` for :class:`NewtonSolver` that depends on no state or
    interface data (only on Constants), so its matrix is the same whenever
    it is assembled.
    """
    J = ufl.derivative(F, u)
    try:
        # UFL zeros fold the kinematics at rest (F = I, J = 1) before code generation: a kernel
        # that compiles and assembles like a linear one (the 3D finite-strain forms' cost)
        return ufl.replace(J, {c: ufl.zero(*c.ufl_shape) for c in (u, *coefficients)})
    except (ZeroDivisionError, ufl.log.UFLException):
        # an expression singular at zero (e.g. 1/|v|): zero-valued Functions give its value at rest
        zeros = {c: fem.Function(c.function_space) for c in (u, *coefficients)}
        return ufl.replace(J, zeros)


def assemble_residual_vector(form) -> PETSc.Vec:
    """Assemble a linear form with no boundary conditions and add ghost contributions."""
    vec = fem_petsc.assemble_vector(form)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return vec


#: when a list, every gather of this module appends ``(what, rows, columns, nnz)`` of the object it
#: gathers (an instrumentation hook: tests check that no run gathers a global matrix)
GATHERED: list | None = None


def _record(what: str, shape: tuple, nnz: int) -> None:
    if GATHERED is not None:
        GATHERED.append((what, int(shape[0]), int(shape[1]), int(nnz)))


def gather_submatrix(A: PETSc.Mat, rows: np.ndarray, cols: np.ndarray) -> "scipy.sparse.csr_matrix":
    """``A[rows][:, cols]`` of a distributed matrix as a scipy CSR matrix on every rank (collective).

    ``rows`` and ``cols`` (global indices, the same on every rank; ``cols`` without repeats) are
    small (interface dofs): each rank sends only the entries of its own rows among ``rows`` in the
    columns ``cols``, so nothing of the size of ``A`` is held or sent.
    """
    import scipy.sparse
    rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    start, end = A.getOwnershipRange()
    indptr, indices, values = A.getValuesCSR()
    mine = np.flatnonzero((rows >= start) & (rows < end))
    local = rows[mine] - start
    counts = indptr[local + 1] - indptr[local]
    at = np.repeat(indptr[local], counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    r, c, v = np.repeat(mine, counts), indices[at].astype(np.int64), values[at]
    order = np.argsort(cols, kind="stable")
    k = np.minimum(np.searchsorted(cols[order], c), max(cols.size - 1, 0))
    hit = cols[order][k] == c if cols.size else np.zeros(c.size, bool)
    r, c, v = r[hit], order[k[hit]], v[hit]
    comm = A.getComm().tompi4py()
    if comm.size > 1:
        parts = comm.allgather((r, c, v))
        r, c, v = (np.concatenate([p[j] for p in parts]) for j in range(3))
    out = scipy.sparse.csr_matrix((v, (r, c)), shape=(rows.size, cols.size))
    _record("submatrix", out.shape, out.nnz)
    return out


def gather_entries(vec: PETSc.Vec, dofs: np.ndarray) -> np.ndarray:
    """The entries ``dofs`` (global, the same on every rank) of a distributed vector, on every rank."""
    dofs = np.asarray(dofs, dtype=np.int64)
    start, end = vec.getOwnershipRange()
    mine = np.flatnonzero((dofs >= start) & (dofs < end))
    out = np.zeros(dofs.size)
    out[mine] = vec.array_r[dofs[mine] - start]
    comm = vec.getComm().tompi4py()
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, out, op=MPI.SUM)      # each entry has one owner
    _record("entries", (dofs.size, 1), dofs.size)
    return out


#: columns of the condensed matrix computed per block of back-substitutions
SCHUR_BLOCK = 64


def condensed_matrix(A: PETSc.Mat, keep: np.ndarray, name: str = "schur") -> np.ndarray:
    """S = A_kk - A_kr A_rr^-1 A_rk onto the global indices ``keep``, dense, on every rank (collective).

    On one rank by :func:`schur_complement` (one sequential factorisation: A is the whole
    matrix there, nothing is gathered); on several by :func:`distributed_schur_complement`
    (A stays distributed; the price is one back-substitution per kept index).
    """
    if A.getComm().getSize() > 1:
        return distributed_schur_complement(A, keep, name)
    import scipy.sparse
    indptr, indices, values = A.getValuesCSR()
    S = schur_complement(scipy.sparse.csr_matrix((values, indices, indptr), shape=A.getSize()), keep)
    _record("schur", S.shape, S.size)
    return S


def _kept_columns(A: PETSc.Mat, keep: np.ndarray):
    """``columns(j0, width)``: -A[:, keep[j0:j0 + width]] on this rank's rows, dense, from its own CSR."""
    indptr, indices, values = A.getValuesCSR()
    order = np.argsort(keep, kind="stable")
    k = np.minimum(np.searchsorted(keep[order], indices), keep.size - 1)
    hit = keep[order][k] == indices
    rows = np.repeat(np.arange(indptr.size - 1), np.diff(indptr))[hit]
    position, entries = order[k[hit]], values[hit]

    def columns(j0: int, width: int) -> np.ndarray:
        out = np.zeros((indptr.size - 1, width))
        sel = (position >= j0) & (position < j0 + width)
        np.add.at(out, (rows[sel], position[sel] - j0), -entries[sel])
        return out
    return columns


def distributed_schur_complement(A: PETSc.Mat, keep: np.ndarray, name: str = "schur") -> np.ndarray:
    """S = A_kk - A_kr A_rr^-1 A_rk of a distributed matrix onto the global indices ``keep`` (collective).

    The same S as :func:`schur_complement`, without gathering A: A_rr is factorised
    distributed (MUMPS, each rank its own rows) as D, A with the rows and columns ``keep``
    replaced by the identity.  Column j of S is (A y)_k, with D y = [-A_rk e_j; e_j]
    (y_k = e_j, y_r = -A_rr^-1 A_rk e_j), for :data:`SCHUR_BLOCK` columns per
    back-substitution.  Returns the dense (nk, nk) S on every rank: besides A's
    own rows, each rank holds (rows it owns) x SCHUR_BLOCK and S.  A singular
    A_rr raises :class:`SingularSystemError` (unlike :func:`schur_complement`).
    """
    keep = np.asarray(keep, dtype=np.int64)
    nk = keep.size
    if nk == 0:
        return np.zeros((0, 0))
    comm = A.getComm().tompi4py()
    start, end = A.getOwnershipRange()
    mine = np.flatnonzero((keep >= start) & (keep < end))
    D = A.duplicate(copy=True)
    D.zeroRowsColumns(keep[mine].astype(PETSc.IntType), diag=1.0)
    solver = DirectSolver(A.getComm(), name)
    solver.set_operator(D)
    solver.factorize_symmetric_if_possible()
    F = solver.ksp.getPC().getFactorMatrix()
    columns = _kept_columns(A, keep)
    # the kept rows of A (each rank its own, sorted), with A's column layout: (A y)_k without A y
    rows = mine[np.argsort(keep[mine])]
    is_rows = PETSc.IS().createGeneral(keep[rows].astype(PETSc.IntType), comm=A.getComm())
    is_cols = PETSc.IS().createStride(end - start, start, 1, comm=A.getComm())
    A_k = A.createSubMatrix(is_rows, is_cols)
    S = np.zeros((nk, nk))
    for j0 in range(0, nk, SCHUR_BLOCK):
        width = min(SCHUR_BLOCK, nk - j0)
        B, Y = (PETSc.Mat().createDense(((end - start, A.getSize()[0]), (PETSc.DECIDE, width)), comm=A.getComm())
                for _ in range(2))
        B.setUp()
        Y.setUp()
        rhs = B.getDenseArray()
        rhs[:] = columns(j0, width)                         # -A e_j on the rows of A_rr
        rhs[keep[mine] - start] = 0.0
        here = (mine >= j0) & (mine < j0 + width)
        rhs[keep[mine[here]] - start, mine[here] - j0] = 1.0        # the identity rows of D: y_k = e_j
        B.assemble()
        F.matSolve(B, Y)
        Z = A_k.matMult(Y)
        block = np.zeros((nk, width))
        block[rows] = Z.getDenseArray()
        if comm.size > 1:
            comm.Allreduce(MPI.IN_PLACE, block, op=MPI.SUM)     # each kept row has one owner
        S[:, j0:j0 + width] = block
        for M in (Y, B, Z):
            M.destroy()
    for obj in (F, solver.ksp, D, A_k, is_rows, is_cols):      # F: its reference keeps the factors alive
        obj.destroy()
    _record("schur", S.shape, S.size)
    return S
