"""Shared finite-element plumbing for the field solvers (dolfinx 0.5.2).

Meshes from a gmsh model (``mesh``), interface nodes and their data arrays
(``interface``), factorise-once linear and Newton solvers (``linalg``),
global reductions and small mechanics helpers (``functions``),
all-or-nothing output (``io``), and FFCx's cache look-up by file name
(``jitcache``).  No physics lives here.
"""
