"""A dropped device's PETSc objects are destroyed (``femtools.petscgarbage``).

petsc4py 3.18 puts the objects of a collected wrapper on its communicator's
garbage list when that communicator is a mesh's duplicate; before
``femtools.petscgarbage`` they stayed there for good (each solved device left its
factorisations: 25 MB at mesh-size 3).  The probe: a PC taken from a solver's KSP
holds a reference of its own, so its reference count falls from 2 to 1 exactly
when the KSP is destroyed.  Runs on 1 and 2 ranks (the cleanup is collective).
"""

from __future__ import annotations

import gc

from mpi4py import MPI

from femtools import petscgarbage
from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device
from gelcell.case import CaseParameters

COMM = MPI.COMM_WORLD


def test_a_dropped_device_s_factorisations_are_destroyed():
    p = CaseParameters.default("shear", True).with_mesh_size(4)
    device = Device(p, COMM)
    device.solve(coupling_config(params=p, jacobian_prior="none"), verbose=False)
    probes = [solver.ksp.getPC() for solver in (device.gel.newton.solver, device.cell._newton.solver)]
    assert all(pc.getRefCount() == 2 for pc in probes)       # the KSP's and the probe's
    del device
    gc.collect()
    assert all(pc.getRefCount() == 2 for pc in probes)       # the KSPs wait on the garbage list
    petscgarbage.collect(COMM)
    counts = [pc.getRefCount() for pc in probes]
    for pc in probes:
        pc.destroy()
    assert counts == [1, 1], counts                          # the KSPs are destroyed
