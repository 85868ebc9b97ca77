"""Devices from gmsh geometry files: read, then analysed against the naming convention, then built.

``read`` (gmsh, no meshing) → ``names`` (groups by name) → ``analyse``
(checks, tags, conditions; ``cells`` and ``shapes`` help it) → ``build``
(tags and mesh, rank 0).  The convention: docs/geometry-files.md.
"""
