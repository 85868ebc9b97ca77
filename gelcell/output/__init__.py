"""What a run writes: summary.json and its table, XDMF fields, interface profiles, figures.

``summary`` (the layout of summary.json), ``fields`` (XDMF), ``profiles``
(Gamma profiles), ``figures`` (the figures' data, gathered on rank 0, and the
worker process that draws them) and ``drawing`` (numpy and matplotlib only).
JSON files are written by :func:`femtools.io.write_json`.
"""
