"""Figures of a device run: the fields gathered on rank 0, drawn by :mod:`gelcell.output.drawing`.

``figure_data`` gathers everything a figure shows into plain arrays (a
collective call); ``gelcell.output.drawing.render_device_figures`` draws them on rank 0
(:func:`collect_figures`).  A serial run may instead hand them to a
:class:`FigureWorker`: a separate Python process
started before the solve, which imports matplotlib while the run solves and
draws while the run writes its other files (XDMF, profiles, records), the
figures shared among forked processes, one per core, since the run then only waits.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import signal
import subprocess
import sys
import threading
import types

import numpy as np

from dolfinx import fem

from femtools.functions import gather_owned_rows
from gelcell.output.fields import DerivedFields
from gelcell.post.fields import DeviceFields

__all__ = ["figure_data", "FigureWorker", "FigureWorkerError", "figure_worker", "collect_figures", "P1Gather"]

#: the package's parent directory, so that the worker imports this very gelcell
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def figure_data(fields: DeviceFields, profiles: dict, summary: dict, overlay: dict | None = None,
                derived: DerivedFields | None = None) -> dict | None:
    """Everything the figures of a run show, as plain arrays and numbers on rank 0 (None elsewhere).

    Collective.  The fields are interpolated into P1 and gathered; the cells are
    described by name, centre and diameter only, so the data can be pickled
    and drawn by a process that has neither dolfinx nor MPI.
    """
    p = fields.params
    derived = derived or DerivedFields(fields)
    gel = derived.gel
    on_gel = P1Gather(fields.gel_mesh).gather
    data = {"speed": on_gel(gel["v_f"]), "pressure": on_gel(gel["p"]), "disp": on_gel(gel["u_s"]),
            "vm": on_gel(gel["von_mises_network"]),
            "parts": {k: on_gel(gel[f"von_mises_{k}_part"]) for k in ("pressure", "brinkman", "network", "total")},
            "cell": None}
    if fields.cell_displacement is not None:
        data["cell"] = P1Gather(fields.cell_mesh).gather(derived.cell["u_c"])
    if fields.comm.rank != 0:
        return None
    data.update(
        V=p.to_report(1.0, "velocity"), L=p.to_report(1.0, "length"), S=p.to_report(1.0, "stress"),
        label=p.label, wide=bool(fields.layout.wide), profiles=profiles["Gamma1"], overlay=overlay,
        cells=[types.SimpleNamespace(name=c.name, centre=tuple(float(v) for v in c.centre),
                                     diameter=float(c.diameter)) for c in fields.cells],
        cells_summary=summary.get("cells") or [{"centroid_displacement": summary["cell.centroid_displacement"]}])
    return data


class FigureWorkerError(RuntimeError):
    """The figure worker process failed (its last line of stderr is the message)."""


class FigureWorker:
    """A Python process that draws one run's figures (``python -m gelcell.output.drawing``).

    Start it before the solve: it imports matplotlib (~0.5 s) on the other
    core meanwhile.  ``submit(directory, data)`` sends the data of
    :func:`figure_data`; ``result()`` waits for the file names.  For serial
    runs only: under MPI both cores already solve.  ``GELCELL_FIGURE_WORKER=0``
    turns it off (see :func:`use_worker`).
    """

    def __init__(self):
        env = dict(os.environ, MPLBACKEND="Agg",
                   PYTHONPATH=os.pathsep.join(filter(None, [_ROOT, os.environ.get("PYTHONPATH")])))
        # a process group of its own: close() stops the processes it forks to draw, too
        self.proc = subprocess.Popen([sys.executable, "-m", "gelcell.output.drawing"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                     start_new_session=True)

    def submit(self, directory: str, data: dict) -> None:
        stdin, self.proc.stdin = self.proc.stdin, None     # sent whole: communicate() must not flush it
        # PETSc's signal handler aborts the run on SIGPIPE: a worker that died must give EPIPE instead
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
        try:
            pickle.dump((directory, data), stdin, protocol=pickle.HIGHEST_PROTOCOL)
        except OSError:                 # the worker is gone; result() reports why
            pass
        finally:
            try:
                stdin.close()
            except OSError:
                pass

    def result(self, timeout: float = 600.0) -> list[str]:
        """The names of the figures written; FigureWorkerError if the worker failed or timed out."""
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.close()
            raise FigureWorkerError(f"the figure worker did not finish within {timeout:.0f} s") from None
        if self.proc.returncode != 0:
            lines = err.decode(errors="replace").strip().splitlines()
            raise FigureWorkerError(f"the figure worker failed (exit {self.proc.returncode}): "
                                    f"{lines[-1] if lines else 'no message'}")
        try:
            names = json.loads(out.decode().strip().splitlines()[-1])
        except (ValueError, IndexError):
            raise FigureWorkerError("the figure worker returned no file names") from None
        return [str(n) for n in names]

    def close(self) -> None:
        """Stop the worker and the processes it forked if they still run (an interrupted or failed run)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                self.proc.kill()
        self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None and not stream.closed:
                stream.close()

    @staticmethod
    def use_worker(comm) -> bool:
        """A worker for serial runs from the main thread (it sets a signal) unless ``GELCELL_FIGURE_WORKER=0``."""
        return (comm.size == 1 and threading.current_thread() is threading.main_thread()
                and os.environ.get("GELCELL_FIGURE_WORKER", "1").strip() != "0")


@contextlib.contextmanager
def figure_worker(wanted: bool, comm):
    """A started :class:`FigureWorker` if ``wanted`` and :meth:`FigureWorker.use_worker` (else None),
    stopped when the block is left, however it is left."""
    worker = FigureWorker() if wanted and FigureWorker.use_worker(comm) else None
    try:
        yield worker
    finally:
        if worker is not None:
            worker.close()


class P1Gather:
    """Vertex coordinates and triangles of a mesh gathered on rank 0 once, and field values at the vertices.

    ``gather(f)`` interpolates a Function (any Lagrange space on this mesh,
    scalar or vector; no form compilation) into P1 and returns
    ``(x, triangles, values)`` on rank 0 and ``None`` elsewhere.
    """

    def __init__(self, msh):
        self.msh, self.comm = msh, msh.comm
        self._spaces: dict[bool, fem.FunctionSpace] = {}
        Q = self._space(False)
        imap = Q.dofmap.index_map
        n_owned = imap.size_local
        self._n_owned, self._start, self._n = n_owned, imap.local_range[0], imap.size_global
        x = Q.tabulate_dof_coordinates()[:n_owned, :2]
        gidx = imap.local_to_global(np.arange(n_owned + imap.num_ghosts, dtype=np.int32))
        n_cells = msh.topology.index_map(2).size_local
        tri = gidx[Q.dofmap.list.array.reshape(-1, 3)[:n_cells]]
        self.x = gather_owned_rows(self.comm, self._start, x, self._n)
        triangles = self.comm.gather(tri, root=0)
        self.triangles = np.vstack(triangles) if self.comm.rank == 0 else None

    def _space(self, vector: bool) -> fem.FunctionSpace:
        if vector not in self._spaces:
            element = ("Lagrange", 1)
            self._spaces[vector] = (fem.VectorFunctionSpace(self.msh, element) if vector
                                    else fem.FunctionSpace(self.msh, element))
        return self._spaces[vector]

    def gather(self, f: fem.Function):
        Q = self._space(bool(f.ufl_shape))
        g = fem.Function(Q)
        g.interpolate(f)
        bs = Q.dofmap.index_map_bs
        V = gather_owned_rows(self.comm, self._start, g.x.array.reshape(-1, bs)[:self._n_owned], self._n)
        if self.comm.rank != 0:
            return None
        return self.x, self.triangles, (V[:, 0] if bs == 1 else V)


def collect_figures(tmp: str, data: dict, worker: FigureWorker | None) -> list[str]:
    """The figures drawn by ``worker``, or here if there is none or it failed (rank 0's data)."""
    if worker is not None:
        try:
            return worker.result()
        except FigureWorkerError as exc:
            print(f"gelcell: warning: {exc}; drawing the figures in this process", file=sys.stderr, flush=True)
    from gelcell.output.drawing import render_device_figures      # imports matplotlib
    return render_device_figures(tmp, data)
