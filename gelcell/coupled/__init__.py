"""A device as three coupled field solvers (the partitioned scheme), and the monolithic reference.

``data`` (what is exchanged) → ``participants`` (the solvers seen by the
coupling) → ``defaults`` (the device's coupling defaults) → ``device``
(:class:`~gelcell.coupled.device.Device`: meshes, solvers, the solve) with
``priorcache`` and ``reuse``; ``monolithic`` is every field in one system;
``layer`` a verification device with closed forms.
"""
