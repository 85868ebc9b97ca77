"""gelcell: a perfused hydrogel with embedded cells, by finite elements (dolfinx 0.5.2).

The packages import one way, each only from those below it::

    cli        the gelcell command
    run        steady, time-dependent, sweep and study runs
    output     summary.json, XDMF fields, profiles, figures
    post       fields of a solved device, their quantities, checks and model limits
    coupled    the three field solvers as coupled participants; the monolithic reference
    geometry   tags, built-in devices, geometry files, meshes and their cache
    case       the parameters and configuration of a run (plain data)
    errors, diskcache, machine

The field solvers live in the top-level packages ``fluid``, ``gel`` and
``cell``, the coupling library in ``coupling``, shared finite-element
plumbing in ``femtools``.
"""

from gelcell.case import CaseParameters, RunConfig
from gelcell.errors import ParameterError

__all__ = ["CaseParameters", "RunConfig", "ParameterError", "__version__"]
__version__ = "0.1.0"
