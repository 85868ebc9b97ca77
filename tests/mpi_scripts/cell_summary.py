"""The numbers a cell MPI script reports of one solve (shared by cell_mpi.py and cell3d_mpi.py)."""


def record(out: dict, prefix: str, s) -> None:
    """Store ``s``'s centroid displacement, largest displacement, von Mises ranges and Newton count."""
    vm = s.von_mises_range()
    out[f"{prefix}_centroid"] = s.centroid_displacement().tolist()
    out[f"{prefix}_umax"] = s.max_displacement()
    out[f"{prefix}_vm"] = [*vm["stress"], *vm["strain"]]
    out[f"{prefix}_iterations"] = s.stats["newton_iterations"]
