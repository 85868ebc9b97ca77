"""The data the three participants of a device exchange on its interfaces.

Data (per fluid interface G in Gamma1, Gamma3, all on matching nodes):

    G/traction               fluid -> gel   T_F, the fluid's traction on the gel
    G/velocity               fluid -> gel   V
    G/gel_traction           gel -> fluid   T_G (total traction the gel applies)
    G/mixture_velocity       gel -> fluid   phi_f v_f + phi_s v_s (normal part = flux q_G, I13)
    G/interstitial_velocity  gel -> fluid   v_f (tangential part enters I16)
    Gamma2/displacement      gel -> cell    u_s
    Gamma2/force             cell -> gel    nodal force of the cell on the gel

Units inside the solvers: velocity V0, length L0, stress Ca mu_s (= mu V0/L0),
displacement Ca L0 (CaseParameters.stress_scale / displacement_scale).

Finite kinematics (``params.kinematics == "finite"``, docs/finite-strain.md):
the gel is total Lagrangian (``gel.lagrangian``) and the fluid domain
follows the gel's surface (``fluid.ale.MovingStokesSolver``: a harmonic
extension of the gel's interface displacement, Stokes on the current
configuration).  Tractions are then nominal (per unit reference length of
the interface) and the data on Gamma1/Gamma3 are

    G/traction, G/velocity   fluid -> gel   as above (T_F nominal)
    G/gel_traction           gel -> fluid   T_G (nominal)
    G/normal_flux            gel -> fluid   int j (phi_f v_f + phi_s v_s).n (psi_i n) dA, the gel's
                                            consistent nodal volume flux through the CURRENT interface
    G/interstitial_velocity  gel -> fluid   v_f (I16)
    G/displacement           gel -> fluid   u_s on the interface: the fluid's mesh motion

so that the fluid's Robin condition holds in the same weak form as the
monolithic reference's I13 on the current interface.
"""

from __future__ import annotations

import typing

import coupling as cp
from gelcell.geometry import DeviceBoundaries

__all__ = ["coupling_data", "extensive_data", "FLUID_TO_GEL", "GEL_TO_FLUID", "GEL_TO_MOVING_FLUID", "EXTENSIVE"]


FLUID_TO_GEL = ("traction", "velocity")


GEL_TO_FLUID = ("gel_traction", "mixture_velocity", "interstitial_velocity")


#: gel -> fluid with finite kinematics (see the module docstring)
GEL_TO_MOVING_FLUID = ("gel_traction", "normal_flux", "interstitial_velocity", "displacement")


#: data that are consistent nodal integrals (a flux, forces), not nodal values of a field
EXTENSIVE = ("normal_flux", "force", "gel_force")


def extensive_data(names: typing.Iterable[str]) -> list[str]:
    """The names among ``names`` (``"Gamma1/normal_flux"``, ...) of data that are nodal integrals."""
    return [n for n in names if n.rsplit("/", 1)[-1] in EXTENSIVE]


def coupling_data(boundaries: DeviceBoundaries, gamma2: str = "dirichlet", kinematics: str = "small",
                  dim: int = 2) -> list[cp.Data]:
    """The coupling data of a device (see the module docstring); vectors of ``dim`` (2 or 3) components,
    the dimension of the device's meshes."""
    if dim not in (2, 3):
        raise ValueError(f"coupling_data: dim must be 2 or 3 (the meshes' dimension), got {dim!r}")
    data = []
    to_fluid = GEL_TO_MOVING_FLUID if kinematics == "finite" else GEL_TO_FLUID
    for g in boundaries.fluid_interfaces:
        data += [cp.Data(f"{g}/{k}", mesh=g, dim=dim, writer="fluid", readers=("gel",)) for k in FLUID_TO_GEL]
        data += [cp.Data(f"{g}/{k}", mesh=g, dim=dim, writer="gel", readers=("fluid",)) for k in to_fluid]
    for g in boundaries.cell_interfaces:
        data += [cp.Data(f"{g}/displacement", mesh=g, dim=dim, writer="gel", readers=("cell",)),
                 cp.Data(f"{g}/force", mesh=g, dim=dim, writer="cell", readers=("gel",))]
        if gamma2 == "robin":
            data.append(cp.Data(f"{g}/gel_force", mesh=g, dim=dim, writer="gel", readers=("cell",)))
        elif gamma2 == "schur":
            data.append(cp.Data(f"{g}/cell_displacement", mesh=g, dim=dim, writer="cell", readers=("gel",)))
    return data
