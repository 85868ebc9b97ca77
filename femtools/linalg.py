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

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from femtools.errors import NewtonError, SingularSystemError

__all__ = ["DirectSolver", "LinearSolver", "NewtonSolver", "SolverStats", "direct_solver",
           "assemble_residual_vector", "global_norm", "jacobian_at_rest", "SingularSystemError",
           "NewtonError"]

_counter = itertools.count()
_ICNTL = re.compile(r"^mat_mumps_icntl_(\d+)$")

#: MUMPS controls applied to every factorisation: more workspace slack (14) and
#: null-pivot detection (24).  With detection on, MUMPS does not stop at a zero
#: pivot: it patches it and counts it in INFOG(28), which ``DirectSolver.factorize``
#: reads to refuse a singular system (none of the device systems has a null pivot).
DEFAULT_ICNTL = {14: 100, 24: 1}


class SolverStats(dict):
    """Counts and wall times of a solver: factorisations, solves, assemblies."""

    def __init__(self):
        super().__init__(factorizations=0, solves=0, factor_time=0.0, solve_time=0.0,
                         assemble_time=0.0, newton_iterations=0, rejected_steps=0)


class DirectSolver:
    """LU factorisation (MUMPS by default) of one operator, reused for many right-hand sides.

    Options are set through the API, not the global PETSc options database,
    whose 512 entries a long test session would otherwise fill:
    ``mat_mumps_icntl_N`` entries of ``options`` become MUMPS controls,
    ``pc_factor_mat_solver_type`` selects the factorisation package, and any
    other entry goes to the options database under a unique prefix.
    """

    def __init__(self, comm: MPI.Comm, name: str, options: dict | None = None):
        self.name = name
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType("lu")
        options = dict(options or {})
        pc.setFactorSolverType(options.pop("pc_factor_mat_solver_type", "mumps"))
        options.pop("ksp_type", None)
        options.pop("pc_type", None)
        self.icntl = dict(DEFAULT_ICNTL)
        for key in list(options):
            m = _ICNTL.match(key)
            if m:
                self.icntl[int(m.group(1))] = int(options.pop(key))
        if options:
            prefix = f"gelcell_{name}_{next(_counter)}_"
            self.ksp.setOptionsPrefix(prefix)
            opts = PETSc.Options()
            for k, v in options.items():
                opts[prefix + k] = v
            self.ksp.setFromOptions()

    def set_operator(self, A: PETSc.Mat, reset: bool = False) -> None:
        """Use ``A``; ``reset`` drops an earlier factorisation of a matrix of another size."""
        if reset:
            self.ksp.reset()
        self.ksp.setOperators(A)

    def factorize(self) -> None:
        """(Re)factorise the current operator."""
        pc = self.ksp.getPC()
        pc.setFactorSetUpSolverType()
        mumps = pc.getFactorSolverType() == "mumps"
        if mumps:
            F = pc.getFactorMatrix()
            for k, v in self.icntl.items():
                F.setMumpsIcntl(k, v)
        self.ksp.setUp()
        if mumps:
            # INFOG is global: every rank sees the same values and raises alike
            F = pc.getFactorMatrix()
            if F.getMumpsInfog(1) == -10 or (self.icntl.get(24) == 1 and F.getMumpsInfog(28) > 0):
                raise SingularSystemError(self.name, max(F.getMumpsInfog(28), 1))

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        self.ksp.solve(b, x)
        reason = self.ksp.getConvergedReason()
        if reason <= 0:
            raise RuntimeError(f"{self.name}: linear solve failed (PETSc KSP reason {reason})")


def _assemble_and_factorize(A: PETSc.Mat, form, bcs, solver: DirectSolver, stats: SolverStats,
                            sub=None) -> PETSc.Mat:
    """Assemble ``form`` into ``A`` (Dirichlet rows: identity), factorise it; returns the factorised matrix.

    ``sub = (IS, previous submatrix)`` factorises only the rows and columns in the IS.
    """
    t0 = time.perf_counter()
    A.zeroEntries()
    fem_petsc.assemble_matrix(A, form, bcs=bcs)
    A.assemble()
    operator = A
    if sub is not None:
        rows, previous = sub
        operator = A.createSubMatrix(rows, rows, submat=previous)
        solver.set_operator(operator, reset=previous is None)  # the KSP saw the full-size matrix
    else:
        solver.set_operator(A)
    stats["assemble_time"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    solver.factorize()
    stats["factor_time"] += time.perf_counter() - t0
    stats["factorizations"] += 1
    return operator


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

    ``solve()`` re-assembles only ``L`` (and the lifting of the current
    Dirichlet values), so changing coefficients of ``L`` or Dirichlet data
    between calls is cheap.  Call ``update_operator()`` if ``a`` changed.
    """

    def __init__(self, a: ufl.Form, L: ufl.Form, u: fem.Function, bcs: list, name: str = "linear",
                 petsc_options: dict | None = None, form_compiler_params: dict | None = None):
        fcp = form_compiler_params or {}
        self.a = fem.form(a, form_compiler_params=fcp)
        self.L = fem.form(L, form_compiler_params=fcp)
        self.u, self.bcs, self.name = u, bcs, name
        self.stats = SolverStats()
        comm = u.function_space.mesh.comm
        self.A = fem_petsc.create_matrix(self.a)
        self.b = fem_petsc.create_vector(self.L)
        self.solver = DirectSolver(comm, name, petsc_options)
        self.ksp = self.solver.ksp
        self._operator_ready = False

    def update_operator(self) -> None:
        """Re-assemble the matrix and factorise it."""
        _assemble_and_factorize(self.A, self.a, self.bcs, self.solver, self.stats)
        self._operator_ready = True

    def assemble_rhs(self) -> PETSc.Vec:
        """Right-hand side with the current Dirichlet values lifted and set."""
        with self.b.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self.b, self.L)
        fem_petsc.apply_lifting(self.b, [self.a], bcs=[self.bcs])
        self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
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
        self.stats["solves"] += 1
        _nan_check(self.u.vector, self.name)
        self.u.x.scatter_forward()
        return self.u


class NewtonSolver:
    """Newton's method for ``F(u; v) = 0`` with the exact Jacobian ``J = dF/du``.

    Converged when the correction satisfies ``|du| <= rtol |u|`` (a relative,
    scale-free criterion: the device unknowns are O(1e-6) in paper units).

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
    """

    def __init__(self, F: ufl.Form, u: fem.Function, bcs: list, J: ufl.Form | None = None,
                 name: str = "newton", rtol: float = 1e-11, max_it: int = 30,
                 reuse: str = "adaptive", contraction: float = 0.1,
                 petsc_options: dict | None = None, form_compiler_params: dict | None = None,
                 active_dofs: np.ndarray | None = None, J_reference: ufl.Form | None = None):
        if reuse not in ("never", "adaptive"):
            raise ValueError(f"reuse must be 'never' or 'adaptive', got {reuse!r}")
        fcp = form_compiler_params or {}
        if J is None:
            J = ufl.derivative(F, u)
        self.F = fem.form(F, form_compiler_params=fcp)
        self.J = fem.form(J, form_compiler_params=fcp)
        self.J_reference = None if J_reference is None else fem.form(J_reference, form_compiler_params=fcp)
        self.u, self.bcs, self.name = u, bcs, name
        self.rtol, self.max_it, self.reuse, self.contraction = rtol, max_it, reuse, contraction
        self.stats = SolverStats()
        self.history: list[float] = []
        comm = u.function_space.mesh.comm
        self.A = fem_petsc.create_matrix(self.J)
        self.b = fem_petsc.create_vector(self.F)
        self.du = self.A.createVecRight()
        self._active = None
        self._A_active = None
        if active_dofs is not None:
            imap, bs = u.function_space.dofmap.index_map, u.function_space.dofmap.index_map_bs
            owned = np.asarray(active_dofs, dtype=np.int64)
            owned = owned[owned < imap.size_local * bs]
            self._active = PETSc.IS().createGeneral((owned + imap.local_range[0] * bs).astype(PETSc.IntType),
                                                    comm=comm)
        self.solver = DirectSolver(comm, name, petsc_options)
        self.ksp = self.solver.ksp
        self._have_jacobian = False
        self._exact = self.J_reference is None or reuse == "never"   # which Jacobian is (to be) kept
        self._load_dofs, self._load_values = np.empty(0, dtype=np.int32), np.empty(0)

    @property
    def num_active_dofs(self) -> int:
        """Global number of dofs the linear solves act on."""
        if self._active is None:
            return self.A.getSize()[0]
        return self.u.function_space.mesh.comm.allreduce(self._active.getLocalSize(), op=MPI.SUM)

    def invalidate_jacobian(self) -> None:
        """Factorise again at the next iteration (e.g. coefficients of J changed)."""
        self._have_jacobian = False
        self._exact = self.J_reference is None or self.reuse == "never"

    @property
    def uses_reference_jacobian(self) -> bool:
        """True while the kept Jacobian is ``J_reference``."""
        return not self._exact

    def _assemble_jacobian(self) -> None:
        sub = None if self._active is None else (self._active, self._A_active)
        form = self.J if self._exact else self.J_reference
        try:
            operator = _assemble_and_factorize(self.A, form, self.bcs, self.solver, self.stats, sub)
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
        reaction on Gamma2) rather than as a field to integrate.
        """
        self._load_dofs = np.asarray(dofs, dtype=np.int32)
        self._load_values = np.asarray(values, dtype=float)

    def residual(self) -> PETSc.Vec:
        """``F(u)`` - nodal loads, with Dirichlet rows holding ``u - g`` (the Newton convention)."""
        with self.b.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self.b, self.F)
        fem_petsc.apply_lifting(self.b, [self.J], bcs=[self.bcs], x0=[self.u.vector], scale=-1.0)
        self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if self._load_dofs.size:
            # after the ghost update, so that each global dof receives its load exactly once
            with self.b.localForm() as loc:
                loc.array[self._load_dofs] -= self._load_values
        fem_petsc.set_bc(self.b, self.bcs, self.u.vector, -1.0)
        return self.b

    def _linear_solve(self) -> None:
        if self._active is None:
            self.solver.solve(self.b, self.du)
            return
        self.du.zeroEntries()
        b_sub, du_sub = self.b.getSubVector(self._active), self.du.getSubVector(self._active)
        self.solver.solve(b_sub, du_sub)
        self.b.restoreSubVector(self._active, b_sub)
        self.du.restoreSubVector(self._active, du_sub)

    def solve(self) -> int:
        """Iterate to convergence; return the number of iterations."""
        self.history = []
        previous = None
        if self.reuse == "never":
            self._have_jacobian = False
        for it in range(1, self.max_it + 1):
            t0 = time.perf_counter()
            self.residual()
            self.stats["assemble_time"] += time.perf_counter() - t0
            fresh = not self._have_jacobian
            if fresh:
                self._assemble_jacobian()
            # the reference Jacobian is not the one at this iterate: test its steps like stale ones
            stale = not fresh or not self._exact
            t0 = time.perf_counter()
            self._linear_solve()
            self.stats["solve_time"] += time.perf_counter() - t0
            self.stats["solves"] += 1
            self.u.vector.axpy(-1.0, self.du)
            self.u.x.scatter_forward()
            du, un = self.du.norm(), self.u.vector.norm()
            if not (np.isfinite(du) and np.isfinite(un)):
                raise NewtonError(self.name, f"the iterate contains NaN or Inf at iteration {it}",
                                  self.history)
            rel = du / un if un > 0 else du
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
            if du <= self.rtol * un or du == 0.0:
                return it
            # at the round-off floor the correction stops shrinking; accept it there
            if previous is not None and rel > 0.5 * previous and rel < 1e3 * self.rtol:
                return it
            if self.reuse == "never" or (previous is not None and rel > self.contraction * previous):
                self._have_jacobian = False
                self._exact = True
            previous = rel
        raise NewtonError(self.name, f"no convergence in {self.max_it} iterations", self.history)


def jacobian_at_rest(F: ufl.Form, u: fem.Function, coefficients=()) -> ufl.Form:
    """dF/du with ``u`` and ``coefficients`` replaced by zero Functions: the linearisation at rest.

    A ``J_reference`` for :class:`NewtonSolver` that depends on no state or
    interface data (only on Constants), so its matrix is the same whenever
    it is assembled.
    """
    J = ufl.derivative(F, u)
    zeros = {c: fem.Function(c.function_space) for c in (u, *coefficients)}
    return ufl.replace(J, zeros)


def assemble_residual_vector(form) -> PETSc.Vec:
    """Assemble a linear form with no boundary conditions and add ghost contributions."""
    vec = fem_petsc.assemble_vector(form)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return vec


def global_norm(values: np.ndarray) -> float:
    """Euclidean norm of a replicated interface array."""
    return float(np.linalg.norm(np.asarray(values).ravel()))
