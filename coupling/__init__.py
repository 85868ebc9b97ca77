"""Generic partitioned coupling of black-box participants.

``coupling`` knows nothing of Stokes flow, gels or cells: it couples
*participants* (objects with ``solve(inputs) -> outputs`` on named interface
data), maps the data between their interface points, iterates serial
(Gauss–Seidel) or parallel (Jacobi) implicit schemes to convergence with
constant, Aitken, IQN-ILS or IQN-IMVJ acceleration, and records everything.
It depends on numpy and scipy only (mpi4py optional).

Example::

    import coupling as cp

    scheme = cp.build_scheme(config, [fluid, gel], data)
    result = scheme.solve()                  # steady
    result = scheme.run(t_end=1.0, dt=0.1)   # time windows
    traction = scheme.latest("Gamma1/traction")

See ``docs/coupling.md`` for the configuration keys and the algorithms.
"""

from coupling.acceleration import (IQNILS, IQNIMVJ, Acceleration, AccelerationInfo,
                                   AitkenRelaxation, ConstantRelaxation, NoAcceleration,
                                   Preconditioner, build_acceleration, qr_filter)
from coupling.config import (AccelerationConfig, ConvergenceMeasureConfig, CouplingConfig,
                             FilterConfig, PreconditionerConfig, load_config)
from coupling.convergence import (AbsoluteConvergence, ConvergenceMeasure, RelativeConvergence,
                                  ResidualRelativeConvergence, build_measure)
from coupling.errors import CouplingDivergedError, CouplingError, CouplingNotConvergedError
from coupling.extrapolation import lagrange_weights
from coupling.layout import VectorLayout
from coupling.linearization import LinearizedPrior, coupled_jacobian
from coupling.mapping import Mapping, build_mapping, order_along_curve
from coupling.participant import Data, Participant
from coupling.records import (CouplingResult, IterationRecord, RecordedSolve, Recording,
                              WindowRecord)
from coupling.replay import ReplayResult, replay
from coupling.schemes import (CouplingScheme, ParallelExplicitScheme, ParallelImplicitScheme,
                              SerialExplicitScheme, SerialImplicitScheme, build_scheme)

__all__ = [
    "Participant", "Data", "build_scheme", "load_config", "replay",
    "CouplingConfig", "AccelerationConfig", "ConvergenceMeasureConfig", "FilterConfig",
    "PreconditionerConfig",
    "CouplingScheme", "SerialImplicitScheme", "ParallelImplicitScheme", "SerialExplicitScheme",
    "ParallelExplicitScheme",
    "Acceleration", "AccelerationInfo", "NoAcceleration", "ConstantRelaxation", "AitkenRelaxation",
    "IQNILS", "IQNIMVJ", "Preconditioner", "build_acceleration", "qr_filter",
    "ConvergenceMeasure", "AbsoluteConvergence", "RelativeConvergence",
    "ResidualRelativeConvergence", "build_measure",
    "CouplingError", "CouplingDivergedError", "CouplingNotConvergedError",
    "CouplingResult", "IterationRecord", "WindowRecord", "Recording", "RecordedSolve",
    "ReplayResult", "VectorLayout", "LinearizedPrior", "coupled_jacobian", "Mapping", "build_mapping", "order_along_curve", "lagrange_weights",
]
