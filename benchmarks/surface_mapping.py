"""Cost of building the surface mappings between non-matching spheres, and their error.

    .venv/bin/python benchmarks/surface_mapping.py
    .venv/bin/python benchmarks/surface_mapping.py --levels 4 5 6 --reader hull --repeat 3

The writer is an icosphere of the unit sphere (an icosahedron whose faces are
split in four ``level`` times, nodes on the sphere), with linear or quadratic
(P2, edge nodes on the sphere) triangles; the reader, with triangles of the
same degree, is either the writer's icosphere turned by a random rotation
(``--reader rotated``: non-matching, of the same quality) or the convex hull
of as many random points on the sphere (``--reader hull``: slivers and a wide
range of triangle sizes, a worst case for the search).  Per
case it prints the number of points and triangles, the time to build the
consistent ``"surface"`` matrix (the reader's points onto the writer's
triangles) and the conservative ``"surface-conservative"`` one (the writer's
points onto the reader's triangles), as wall and CPU time (the best of
``--repeat``), and the consistent map's RMS error on a smooth field against
its exact values at the reader's points (the sphere's geometric error
included).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
from scipy.spatial import ConvexHull

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "coupling"))

import coupling as cp  # noqa: E402
from test_surface_mapping import field, icosphere, quadratic, random_on_sphere  # noqa: E402


def best_time(build, repeat: int) -> tuple[float, float, object]:
    """The best wall and CPU times of ``repeat`` calls of ``build()``, and its result."""
    wall, cpu = np.inf, np.inf
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        result = build()
        wall, cpu = min(wall, time.perf_counter() - w0), min(cpu, time.process_time() - c0)
    return wall, cpu, result


def reader_sphere(kind: str, level: int) -> tuple[np.ndarray, np.ndarray]:
    """The reader's points and linear triangles on the unit sphere."""
    if kind == "rotated":
        points, triangles = icosphere(level)
        rotation = np.linalg.qr(np.random.default_rng(level).normal(size=(3, 3)))[0]
        return points @ rotation.T, triangles
    points = random_on_sphere(10 * 4 ** level + 2, seed=level)
    return points, ConvexHull(points).simplices


def case(level: int, degree: int, reader_kind: str, repeat: int) -> str:
    writer, writer_tri = icosphere(level)
    reader, reader_tri = reader_sphere(reader_kind, level)
    if degree == 2:
        writer, writer_tri = quadratic(writer, writer_tri, on_sphere=True)
        reader, reader_tri = quadratic(reader, reader_tri, on_sphere=True)
    t_cons = best_time(lambda: cp.build_mapping("surface", writer, reader, data_name="u", triangles=writer_tri),
                       repeat)
    t_conservative = best_time(lambda: cp.build_mapping("surface-conservative", writer, reader, data_name="f",
                                                        triangles=reader_tri), repeat)
    error = np.sqrt(np.mean((t_cons[2](field(writer)) - field(reader)) ** 2))
    return (f"P{degree} level {level}: writer {writer.shape[0]:7d} points {writer_tri.shape[0]:7d} triangles, "
            f"reader {reader.shape[0]:7d} points | surface {t_cons[0]:.3f} s (cpu {t_cons[1]:.3f}) | "
            f"surface-conservative {t_conservative[0]:.3f} s (cpu {t_conservative[1]:.3f}) | "
            f"rms error {error:.3e}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[4, 5, 6], help="icosphere levels")
    parser.add_argument("--reader", choices=["rotated", "hull"], default="rotated", help="the reader's sphere")
    parser.add_argument("--repeat", type=int, default=3, help="builds per case (the best time is printed)")
    args = parser.parse_args(argv)
    for degree in (1, 2):
        for level in args.levels:
            print(case(level, degree, args.reader, args.repeat), flush=True)


if __name__ == "__main__":
    main()
