"""gelcell: a perfused hydrogel with an embedded cell, by finite elements (dolfinx 0.5.2).

``gelcell.parameters`` holds the parameters of a case and their units,
``gelcell.geometry`` builds the two device geometries and their meshes, and
``gelcell.cli`` is the ``gelcell`` command.  The field solvers live in the
top-level packages ``fluid``, ``gel`` and ``cell``; the coupling in ``coupling``.
"""

from gelcell.parameters import CaseParameters, ParameterError

__all__ = ["CaseParameters", "ParameterError", "__version__"]
__version__ = "0.1.0"
