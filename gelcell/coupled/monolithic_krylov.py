"""The monolithic reference's iterative path: flexible GMRES with a block Gauss-Seidel preconditioner.

The monolithic Jacobian (on its active dofs, :class:`~gelcell.coupled.monolithic.MonolithicSolver`)
split into the gel's unknowns g = (w, p, u; u also in the cells) and the fluid's f = (V, P, lam, u_m):

    [A_gg A_gf] [x_g]   [b_g]
    [A_fg A_ff] [x_f] = [b_f]

is solved by FGMRES preconditioned by one sweep, gel first (the partitioned scheme's
Dirichlet-Neumann sweep, done on the whole system):

    y_g = S_g^-1 b_g,        y_f = A_ff^-1 (b_f - A_fg y_g).

S_g is the gel's own GMRES (:class:`femtools.krylov.GelBlockKrylov`: block lower-triangular
over (w, u, p), AMG on the flow and the network blocks with their rigid-body modes, the pressure
Schur complement as the Darcy + fixed-stress Laplacian and the viscous mass) to the loose
tolerance :data:`INNER_RTOL`: the preconditioner then varies from one application to the next,
hence the flexible method.  (The gel field solver's p-multigrid under AMG in 3D is not used
here: its P1 coarse space is built on a whole field space, here it would take nodes outside
the gel; AMG works on the P2 blocks directly.)  A_ff (Stokes with the interface multiplier and the mesh motion) is
factorised by MUMPS: the fluid is a quarter of a device's unknowns (docs/performance.md).

Why this order and this tolerance: on the 2D shear device (mesh-size 2, the exact Jacobian,
FGMRES to 1e-10) the sweep with both blocks exact takes 15 iterations gel first and 16 fluid
first, about the partitioned scheme's secant iterations; with the gel's inner GMRES at 1e-2 it
takes 19 gel first, and more than 300 fluid first (the gel then absorbs the fluid's error).
"""

from __future__ import annotations

import time

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

from femtools.errors import LinearSolveError
from femtools.krylov import GelBlockKrylov, reason_name, rigid_body_modes
from femtools.linalg import DirectSolver

__all__ = ["MonolithicKrylov", "INNER_RTOL", "OUTER_RTOL"]

#: the gel's inner GMRES (preconditioned residual): loose, the outer FGMRES corrects its error
INNER_RTOL = 1e-2
#: the fluid's block in the preconditioner is A_ff + FLUID_PRESSURE_SHIFT M_p / mu: A_ff alone is singular
#: where a channel's every boundary prescribes its normal velocity (the normal device: there the gel sets
#: the pressure's level), and M_p / mu is the scale of the block's pressure Schur complement.  On the
#: normal device (mesh-size 2) 1e-2 and 1e-4 take 17-18 FGMRES iterations per Newton step; 1 and 1e-8
#: fail (a perturbed block; the level's mode amplified beyond what FGMRES resolves)
FLUID_PRESSURE_SHIFT = 1e-4
#: the outer FGMRES (true residual, relative): each Newton step's linear error stays far below its 1e-12
OUTER_RTOL = 1e-10


def _exscan(comm: MPI.Comm, n: int) -> int:
    """This rank's offset in a distributed numbering where every rank holds ``n`` consecutive entries."""
    return comm.exscan(n) or 0


class _GelFirstSweep:
    """The preconditioner's one sweep (a python PC): y_g = S_g^-1 x_g, y_f = A_ff^-1 (x_f - A_fg y_g)."""

    def __init__(self, groups, gel: GelBlockKrylov, fluid: DirectSolver, A_fg: PETSc.Mat):
        self.gel, self.fluid, self.A_fg = gel, fluid, A_fg
        self.inner_iterations = 0
        self._x = [A_fg.createVecRight(), A_fg.createVecLeft()]       # gel, fluid parts
        self._y = [v.duplicate() for v in self._x]
        self._work = self._x[1].duplicate()
        full = PETSc.Vec().createMPI((sum(g.getLocalSize() for g in groups), PETSc.DETERMINE),
                                     comm=A_fg.getComm())
        self._scatters = [PETSc.Scatter().create(full, g, v, None) for g, v in zip(groups, self._x)]
        full.destroy()

    def apply(self, pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        forward, reverse, insert = PETSc.ScatterMode.FORWARD, PETSc.ScatterMode.REVERSE, PETSc.InsertMode.INSERT
        for scatter, part in zip(self._scatters, self._x):
            scatter.scatter(x, part, insert, forward)
        self.gel.ksp.solve(self._x[0], self._y[0])
        self.inner_iterations += self.gel.ksp.getIterationNumber()
        self.A_fg.mult(self._y[0], self._work)
        self._x[1].axpy(-1.0, self._work)
        self.fluid.solve(self._x[1], self._y[1])
        for scatter, part in zip(self._scatters, self._y):
            scatter.scatter(part, y, insert, reverse)


class MonolithicKrylov:
    """The monolithic Jacobian's solver on the iterative path (module docstring); the
    :class:`femtools.linalg.DirectSolver` interface (``set_operator``, ``factorize``, ``solve``).

    Args:
        W: the monolithic mixed space; ``active``: the sorted local dofs of W that have an equation
            (the operator's rows, in that order).
        fields: ``{name: local dofs of W}`` of ``w``, ``u``, ``p`` (the gel's block) and of the fluid's
            fields (any other names).
        vectors: ``{name: (collapsed space, its map into W)}`` of ``w`` and ``u`` (their rigid-body modes).
        darcy: a compiled bilinear form on W: the pressure Schur complement's Darcy and fixed-stress
            part, added to the operator's gel block for its preconditioner; ``mass``: its viscous part.
        options: PETSc options of the gel's inner GMRES (``femtools.krylov.gel_options``'s keys).
    """

    kind = "krylov"

    def __init__(self, W, active: np.ndarray, fields: dict, vectors: dict, darcy, mass, fluid_mass,
                 name: str = "monolithic", options: dict | None = None, max_it: int = 500):
        self.name, self.comm, self.max_it = name, W.mesh.comm, int(max_it)
        self.iterations: list[int] = []
        self.inner_iterations: list[int] = []
        self._darcy, self._mass, self._fluid_mass = darcy, mass, fluid_mass
        n_owned = W.dofmap.index_map.size_local * W.dofmap.index_map_bs
        self._start = W.dofmap.index_map.local_range[0] * W.dofmap.index_map_bs
        self._active = np.asarray(active, dtype=np.int64)
        self._active = self._active[self._active < n_owned]
        offset = _exscan(self.comm, self._active.size)
        gel_names = ("w", "u", "p")
        gel = np.sort(np.intersect1d(np.hstack([fields[f] for f in gel_names]), self._active))
        fluid = np.setdiff1d(self._active, gel)
        self._groups = [self._index_set(offset + np.searchsorted(self._active, d)) for d in (gel, fluid)]
        gel_offset = _exscan(self.comm, gel.size)
        blocks = [self._vector_block(name, vectors[name], gel, gel_offset) for name in ("w", "u")]
        p_dofs = np.intersect1d(fields["p"], gel)
        blocks.append(("p", self._index_set(gel_offset + np.searchsorted(gel, p_dofs)), None))
        self.gel = GelBlockKrylov(self.comm, f"{name}_gel", blocks, W.mesh.geometry.dim,
                                  {"ksp_rtol": INNER_RTOL, **dict(options or {})})
        self.fluid = DirectSolver(self.comm, f"{name}_fluid")
        self.ksp = PETSc.KSP().create(self.comm)
        self.ksp.setType("fgmres")
        self.ksp.setGMRESRestart(self.max_it)
        self.ksp.setTolerances(rtol=OUTER_RTOL, atol=0.0, max_it=self.max_it)
        self._A = self._D = self._M = self._Mf = None
        self._sub: dict[str, PETSc.Mat] = {}
        self.setup_time = 0.0

    def _index_set(self, indices) -> PETSc.IS:
        return PETSc.IS().createGeneral(np.asarray(indices, dtype=PETSc.IntType), comm=self.comm)

    def _vector_block(self, name, space, gel: np.ndarray, gel_offset: int):
        """``(name, IS in the gel block's numbering, rigid-body modes)`` of the P2 vector field ``name``:
        its active owned nodes in the order of their dofs in W (a node's components consecutive)."""
        V, V_to_W = space
        bs = V.dofmap.index_map_bs
        pairs = np.asarray(V_to_W, dtype=np.int64)[:V.dofmap.index_map.size_local * bs].reshape(-1, bs)
        nodes = np.flatnonzero(np.isin(pairs[:, 0], gel))
        nodes = nodes[np.argsort(pairs[nodes, 0])]
        if np.any(np.diff(pairs[nodes], axis=1) != 1):
            raise RuntimeError(f"{self.name}: the components of a node of {name} are not consecutive dofs")
        index_set = self._index_set(gel_offset + np.searchsorted(gel, pairs[nodes].ravel()))
        index_set.setBlockSize(bs)
        return name, index_set, rigid_body_modes(V, nodes)

    # -- the DirectSolver interface -------------------------------------------------------
    def set_operator(self, A: PETSc.Mat, reset: bool = False) -> None:
        self._A = A

    def factorize_symmetric_if_possible(self) -> None:
        self.factorize()

    def factorize(self) -> None:
        """Assemble the Darcy and mass parts, set up the gel's inner solver, factorise the fluid's block."""
        from dolfinx.fem import petsc as fem_petsc
        t0 = time.perf_counter()
        for attr, form in (("_D", self._darcy), ("_M", self._mass), ("_Mf", self._fluid_mass)):
            if getattr(self, attr) is None:
                setattr(self, attr, fem_petsc.create_matrix(form))
            matrix = getattr(self, attr)
            matrix.zeroEntries()
            fem_petsc.assemble_matrix(matrix, form)
            matrix.assemble()
        active = self._index_set(self._active + self._start)
        gel, fluid = self._groups
        sub = self._sub
        D = self._D.createSubMatrix(active, active)
        sub["P"] = self._A.duplicate(copy=True)
        sub["P"].axpy(1.0, D, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        Mf = self._Mf.createSubMatrix(active, active)
        sub["P"].axpy(FLUID_PRESSURE_SHIFT, Mf, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        M = self._M.createSubMatrix(active, active)
        for key, (matrix, rows, cols) in {"A_gg": (self._A, gel, gel), "P_gg": (sub["P"], gel, gel),
                                          "M_gg": (M, gel, gel), "A_fg": (self._A, fluid, gel),
                                          "A_ff": (sub["P"], fluid, fluid)}.items():
            sub[key] = matrix.createSubMatrix(rows, cols)
        for obj in (D, M, Mf, active):
            obj.destroy()
        self.gel.set_matrices(sub["A_gg"], sub["P_gg"], sub["M_gg"])
        self.gel.factorize()
        self.gel.ksp.setInitialGuessNonzero(False)
        self.fluid.set_operator(sub["A_ff"], reset=True)
        self.fluid.factorize()
        self.ksp.setOperators(self._A)
        pc = self.ksp.getPC()
        pc.setType("python")
        self._sweep = _GelFirstSweep(self._groups, self.gel, self.fluid, sub["A_fg"])
        pc.setPythonContext(self._sweep)
        self.ksp.setUp()
        self.setup_time += time.perf_counter() - t0

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = A^-1 b to :data:`OUTER_RTOL`; raises :class:`LinearSolveError` naming the monolithic system."""
        if b.norm() == 0.0:
            x.zeroEntries()
            self.iterations.append(0)
            self.inner_iterations.append(0)
            return
        before = self._sweep.inner_iterations
        self.ksp.solve(b, x)
        reason, its = self.ksp.getConvergedReason(), self.ksp.getIterationNumber()
        self.iterations.append(its)
        self.inner_iterations.append(self._sweep.inner_iterations - before)
        if reason <= 0:
            raise LinearSolveError(self.name, reason_name(reason), its)
