"""Two runs' summaries that must agree: every quantity to a relative tolerance."""

from __future__ import annotations

from gelcell.post.quantities import flat_quantities


def assert_quantities_agree(a: dict, b: dict, what, rtol: float) -> None:
    """Every summary quantity of ``a`` equals ``b``'s to ``rtol``, a vector's components relative to the vector."""
    qa, qb = flat_quantities(a), flat_quantities(b)
    assert qa.keys() == qb.keys()
    for key in qb:
        base = key.split("[")[0]
        scale = max(abs(v) for k, v in qb.items() if k.split("[")[0] == base)
        assert abs(qa[key] - qb[key]) <= rtol * scale, (what, key, qa[key], qb[key])
