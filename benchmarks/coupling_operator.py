"""The steady coupling map of a device as a matrix: its spectrum, and what IQN variants make of it.

    .venv/bin/python benchmarks/coupling_operator.py shear --mesh-size 3 --surrogate-mesh-size 4
    .venv/bin/python benchmarks/coupling_operator.py normal --cell-moduli 10

The serial fixed-point map x -> G(x) of the accelerated data (docs/coupling.md,
"Iterations of the device runs") is affine to the size of the strains.  This
script converges the partitioned solve, then extracts G's Jacobian A column by
column (one coupling sweep per unknown, finite differences of 1 % of each
data's typical entry) for the case and for a coarser surrogate of it, and runs
IQN on the affine model ``x -> xs + A (x - xs)`` from zero, to a relative
residual of 1e-10 on every accelerated data:

* ``iqn-ils``: the previous default (value scaling, QR2 1e-3);
* ``prior``: with the Gamma2 relaxation prior 1/(1 + rho) (the default);
* ``surrogate exact``: the surrogate's exact inverse Jacobian A_s (A_s - I)^-1,
  mapped to the fine interface (linear interpolation; nodal loads through
  their densities), its solution as the initial guess, the Gamma2 prior on
  the rest;
* ``surrogate iqn``: the same with the surrogate's own IQN secant model
  instead of its exact inverse Jacobian (what a cheap surrogate provides);
* ``exact interface blocks``: the prior holds, for each interface's data, the
  exact inverse Jacobian of that interface's diagonal block of A (what an
  operator-valued Robin or interface Schur-complement preconditioner per
  interface could at best provide; the fluid-gel interfaces Gamma1 and Gamma3
  as one block, or only Gamma2's), the Gamma2 prior where no block is exact;
  ``exact`` is the whole inverse Jacobian (2-3 iterations: the check);
* ``condensed``: IQN-ILS on the map with one interface's block eliminated
  exactly, x1 -> A11 x1 + A12 (I - A22)^-1 A21 x1: the Gamma2 block (the
  cell's stiffness carried by the gel, ``gamma2="schur"``, the default split)
  or the fluid-gel block (the fluid's, a model: not built).

The operator is that of the Dirichlet-Neumann split on Gamma2 (``gamma2="dirichlet"``).

Then a second solve reuses the first one's secant columns (as a Ca sweep does,
``time_windows_reused``), from the first solution, for a fixed point moved by
a relative 1e-5: along the solution itself (a change of scale, which the
columns span) and in a random direction (what they do not span).

A surrogate is fed to the accelerator through the coupling library's generic
prior (``IQNIMVJ`` with ``jacobian`` set = IQN-ILS with the prior ``J0``).
Iteration counts of the affine model reproduce the real runs (21 = 21 for the
shear baseline at mesh 3).  Costs: one sweep per unknown (mesh 3: 760
unknowns, ~15 s).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from coupling.acceleration import build_acceleration, relaxation_prior_diagonal
from coupling.config import load_config
from coupling.layout import VectorLayout
from coupling.mapping import build_mapping, order_along_curve
from gelcell.coupled.defaults import coupling_config, default_relaxation_prior
from gelcell.coupled.device import Device
from gelcell.case import CaseParameters
from gelcell.run.study import StudyCase

IQN = {"type": "iqn-ils", "initial_relaxation": 0.5, "max_used_iterations": 100,
       "filter": {"type": "qr2", "limit": 1e-3}, "preconditioner": {"type": "value"}}
NODAL = ("normal_flux", "force")          # consistent nodal loads: mapped through their densities


def extract(params: CaseParameters):
    """(A, xs, layout, points per data) of the converged steady map."""
    # the Dirichlet-Neumann split: the map whose Gamma2 block the default split condenses
    device = Device(params, MPI.COMM_WORLD, gamma2="dirichlet")
    device.solve(coupling_config(with_cell=params.with_cell, gamma2="dirichlet"), verbose=False)
    scheme = device.scheme
    layout = scheme.layout
    xs = layout.concat(scheme.values)

    def sweep(x):
        scheme.values.update(layout.split(x))
        scheme._sweep(0, 2, None, None, {})
        return layout.concat(scheme.values)

    g0 = sweep(xs)
    step = np.repeat(1e-2 * layout.norms(xs) / np.sqrt(np.diff(layout.offsets)), np.diff(layout.offsets))
    a = np.zeros((layout.size, layout.size))
    for i in range(layout.size):
        e = xs.copy()
        e[i] += step[i]
        a[:, i] = (sweep(e) - g0) / step[i]
    points = {n: scheme.points(scheme.data[n].writer, scheme.data[n].mesh) for n in layout.names}
    return a, xs, layout, points


def p2_weights(points: np.ndarray) -> np.ndarray:
    """int psi_i ds of quadratic elements along the curve (vertices and midpoints alternate)."""
    perm, closed = order_along_curve(points)
    q = points[perm]
    m = len(q)
    parity = 0
    if closed:
        r = np.linalg.norm(q - q.mean(axis=0), axis=1)
        parity = 0 if r[0::2].mean() > r[1::2].mean() else 1     # vertices lie on the circle
    w = np.zeros(m)
    for a in range(parity, m - (0 if closed else 2), 2):
        b, c = (a + 1) % m, (a + 2) % m
        h = np.linalg.norm(q[c] - q[a])
        w[a] += h / 6
        w[b] += 2 * h / 3
        w[c] += h / 6
    out = np.zeros(m)
    out[perm] = w
    return out


def transfer(fine_points, coarse_points, names):
    """Prolongation P (fine x coarse) and restriction R (coarse x fine) of the accelerated vectors."""
    pb, rb = [], []
    for n in names:
        pf, pc = fine_points[n], coarse_points[n]
        p = build_mapping("linear", pc, pf).matrix
        r = build_mapping("linear", pf, pc).matrix
        if n.endswith(NODAL):
            wf, wc = p2_weights(pf), p2_weights(pc)
            p = sp.diags(wf) @ p @ sp.diags(1 / wc)
            r = sp.diags(wc) @ r @ sp.diags(1 / wf)
        dim = 2
        pb.append(sp.kron(p, sp.eye(dim)))
        rb.append(sp.kron(r, sp.eye(dim)))
    return sp.block_diag(pb).toarray(), sp.block_diag(rb).toarray()


def acceleration_config(limit: float, **settings):
    """The ``IQN`` acceleration with ``settings`` on top, of a serial scheme converging to ``limit``."""
    return load_config({"scheme": "serial-implicit", "acceleration": {**IQN, **settings},
                        "convergence": [{"type": "relative", "limit": limit}]}).acceleration


def iterate(a, xs, layout, prior=None, x0=None, limit=1e-10, max_iterations=300, acc=None, close=False):
    """IQN on x -> xs + a (x - xs); returns (iterations or None, the accelerator, the last x).

    ``acc``: an accelerator to go on with (its kept columns), else a new one; ``close``: end the
    solve as a converged window (the columns kept for the next one, as a sweep does) instead of
    leaving the accelerator as it is after the last iteration (its secant columns, for a model)."""
    if acc is None:
        acc = build_acceleration(acceleration_config(limit, type="iqn-imvj" if prior is not None else "iqn-ils"),
                                 layout)
        if prior is not None:
            acc.jacobian = prior
            acc.windows_completed = 1        # use the prior from the first iteration
    x = np.zeros_like(xs) if x0 is None else x0.copy()
    for k in range(1, max_iterations + 1):
        xt = xs + a @ (x - xs)
        r = xt - x
        if max(np.linalg.norm(r[s]) / np.linalg.norm(xt[s]) for s in layout.slices()) < limit:
            if close:
                acc.window_converged(x, xt)
            return k, acc, x
        x = acc.compute(x, xt)
    return None, acc, x


def exact_blocks(a, layout, groups, elsewhere):
    """A prior: the exact inverse Jacobian b (b - I)^-1 of each group's diagonal block b of ``a``
    (a group: the interface names whose data form one block), ``elsewhere`` (a diagonal) on the rest."""
    j = np.diag(elsewhere)
    for group in groups:
        ix = np.hstack([np.arange(a.shape[0])[s] for name, s in zip(layout.names, layout.slices())
                        if name.split("/")[0] in group])
        b = a[np.ix_(ix, ix)]
        j[np.ix_(ix, ix)] = b @ np.linalg.inv(b - np.eye(len(ix)))
    return j


def condensed_rows(a, xs, layout, prior):
    """Iterations on the map with one interface's block eliminated exactly (that field condensed
    into the gel, as ``gamma2="schur"`` does with the cell): IQN-ILS on the other interfaces' data."""
    n = layout.size
    slices = dict(zip(layout.names, layout.slices()))
    groups = {"Gamma2": lambda name: name.startswith("Gamma2/")}
    groups["fluid-gel"] = lambda name: not name.startswith("Gamma2/")
    rows = {}
    for label, (kept, _) in {"Gamma2 condensed (the cell in the gel: the default split)": ("fluid-gel", "Gamma2"),
                                "fluid-gel condensed (the fluid in the gel)": ("Gamma2", "fluid-gel")}.items():
        names = [name for name in layout.names if groups[kept](name)]
        if len(names) == len(layout.names):
            continue
        i = np.hstack([np.arange(n)[slices[name]] for name in names])
        j = np.setdiff1d(np.arange(n), i)
        reduced = a[np.ix_(i, i)] + a[np.ix_(i, j)] @ np.linalg.solve(np.eye(j.size) - a[np.ix_(j, j)], a[np.ix_(j, i)])
        sub = VectorLayout(names, [layout.shapes[layout.names.index(name)] for name in names])
        rows[label] = iterate(reduced, xs[i], sub)[0]
        if kept == "Gamma2":
            rows[label + ", Gamma2 prior"] = iterate(reduced, xs[i], sub, prior=np.diag(
                relaxation_prior_diagonal(prior, sub)))[0]
    return rows


def reuse_rows(a, xs, layout, prior, shift=1e-5):
    """Iterations of a second solve from the first solution with the first solve's columns kept,
    for the fixed point moved by a relative ``shift`` along xs and in a random direction."""
    config = acceleration_config(1e-10, time_windows_reused=4, relaxation_prior=prior)
    acc = build_acceleration(config, layout)
    _, acc, x1 = iterate(a, xs, layout, acc=acc, close=True)
    rng = np.random.default_rng(0)
    rows = {}
    for label, direction in (("along the solution", xs), ("random", rng.standard_normal(xs.size) * np.abs(xs))):
        acc_k = build_acceleration(config, layout)
        acc_k.load_state_dict(acc.state_dict())
        moved = xs + shift * np.linalg.norm(xs) / np.linalg.norm(direction) * direction
        rows[f"second solve, fixed point moved {shift:g} {label}, columns kept"] = \
            iterate(a, moved, layout, x0=x1, acc=acc_k, close=True)[0]
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("case", choices=["shear", "normal"])
    ap.add_argument("--mesh-size", type=float, default=3.0)
    ap.add_argument("--surrogate-mesh-size", type=float, default=4.0)
    ap.add_argument("--cell-moduli", type=float, default=1.0)
    ap.add_argument("--gel-moduli", type=float, default=1.0)
    args = ap.parse_args()

    # the study's case builder: the same parameters as `gelcell study` for this stiffness variant
    params = StudyCase(args.case, args.case, args.cell_moduli, args.gel_moduli).parameters

    t0 = time.perf_counter()
    a, xs, layout, pts = extract(params(args.mesh_size))
    ac, xc, layout_c, pts_c = extract(params(args.surrogate_mesh_size))
    n, nc = layout.size, layout_c.size
    ev = np.linalg.eigvals(a)
    print(f"{args.case} cell x{args.cell_moduli:g} gel x{args.gel_moduli:g}: {n} unknowns (surrogate {nc}), "
          f"eigenvalues in [{ev.real.min():.2f}, {ev.real.max():.2f}], max |imag| {abs(ev.imag).max():.1e}, "
          f"extracted in {time.perf_counter() - t0:.0f} s")
    # the device's Gamma2 relaxation prior, as the accelerator's J0 (a diagonal) on either layout
    prior = default_relaxation_prior(params(args.mesh_size))

    def relax(lay):
        return np.diag(relaxation_prior_diagonal(prior, lay))

    prolong, restrict = transfer(pts, pts_c, layout.names)
    rest = relax(layout) @ (np.eye(n) - prolong @ restrict)
    exact_c = ac @ np.linalg.inv(ac - np.eye(nc))
    its_c, acc_c, _ = iterate(ac, xc, layout_c, prior=relax(layout_c))
    w = acc_c.preconditioner.weights
    q, r = np.linalg.qr(w[:, None] * acc_c.V)
    z = np.linalg.solve(r, q.T) * w[None, :]
    j0 = relax(layout_c)
    secant_c = j0 + (acc_c.W - j0 @ acc_c.V) @ z
    rows = {
        "iqn-ils": iterate(a, xs, layout)[0],
        "prior": iterate(a, xs, layout, prior=relax(layout))[0],
        "surrogate exact": iterate(a, xs, layout, prior=prolong @ exact_c @ restrict + rest, x0=prolong @ xc)[0],
        "surrogate exact, no prior": iterate(a, xs, layout, prior=prolong @ exact_c @ restrict, x0=prolong @ xc)[0],
        f"surrogate iqn ({its_c} coarse iterations)":
            iterate(a, xs, layout, prior=prolong @ secant_c @ restrict + rest, x0=prolong @ xc)[0],
    }
    interfaces = sorted({name.split("/")[0] for name in layout.names})
    fluid_gel = {g for g in interfaces if g != "Gamma2"}
    gamma2 = relaxation_prior_diagonal(prior, layout)
    rows.update({
        "exact fluid-gel block, Gamma2 prior": iterate(a, xs, layout, prior=exact_blocks(
            a, layout, [fluid_gel], gamma2))[0],
        "exact Gamma2 block only": iterate(a, xs, layout, prior=exact_blocks(a, layout, [{"Gamma2"}],
                                                                             0 * gamma2))[0],
        "exact interface blocks (fluid-gel, Gamma2)": iterate(a, xs, layout, prior=exact_blocks(
            a, layout, [fluid_gel, {"Gamma2"}], gamma2))[0],
        "exact": iterate(a, xs, layout, prior=a @ np.linalg.inv(a - np.eye(n)))[0],
    })
    rows.update(condensed_rows(a, xs, layout, prior))
    rows.update(reuse_rows(a, xs, layout, prior))
    for name, its in rows.items():
        print(f"  {name:72s} {its if its is not None else '>300'}")


if __name__ == "__main__":
    main()
