"""Element sizes of a built-in device, in units of L0.
"""

from __future__ import annotations

import dataclasses
import typing

from gelcell.case.ranges import check_range, out_of_range, raise_problems, range_text

__all__ = ["MeshSizes"]


@dataclasses.dataclass(frozen=True)
class MeshSizes:
    """Element sizes in units of L0.  ``size_factor`` multiplies every size.

    * far field: ``h_fluid`` in the perfusate, ``h_gel`` in the gel;
    * cell: ``h_cell = π d / n_cell_edges`` on Γ2, inside the cell and in a
      band of width ``cell_band · d`` around it;
    * Brinkman layer δ = 1/sqrt(ξ φ_s0) (≈ 0.047 at baseline):
      ``h_layer = δ / layer_elements`` on Γ1/Γ3 and on the gel's no-slip walls
      (bowl, posts) and in a band of width ``layer_width · δ`` next to them;
    * beyond the bands the size grows linearly with distance, by ``growth``
      per unit distance, up to the far-field size.
    """

    size_factor: float = 1.0
    h_fluid: float = 0.04
    h_gel: float = 0.06
    n_cell_edges: int = 48
    layer_elements: float = 3.0
    layer_width: float = 1.0
    cell_band: float = 0.5
    growth: float = 0.25

    MIN_CELL_EDGES: typing.ClassVar[int] = 8

    def __post_init__(self):
        raise_problems(self.problems())

    def problems(self) -> list[str]:
        p: list[str] = []
        check_range(p, "size_factor", self.size_factor, 0.0)
        for name in ("h_fluid", "h_gel", "layer_elements", "layer_width", "growth"):
            check_range(p, name, getattr(self, name), 0.0)
        check_range(p, "cell_band", self.cell_band, 0.0, lo_closed=True)
        check_range(p, "n_cell_edges", self.n_cell_edges, self.MIN_CELL_EDGES, lo_closed=True,
               integer=True)
        if not p and self.n_cell_edges / self.size_factor < self.MIN_CELL_EDGES:
            p.append(out_of_range(
                "size_factor", self.size_factor,
                range_text(0, self.n_cell_edges / self.MIN_CELL_EDGES, hi_closed=True),
                why=f"it would leave fewer than {self.MIN_CELL_EDGES} edges around the cell"))
        return p
