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

This namespace holds the ``__all__`` of every module; the toy problems with
known answers stay in their own module, :mod:`coupling.toys`.  See
``docs/coupling.md`` for the configuration keys and the algorithms.
"""

from coupling.acceleration import (IQNILS, IQNIMVJ, Acceleration, AccelerationInfo,
                                   AitkenRelaxation, ConstantRelaxation, NoAcceleration,
                                   Preconditioner, build_acceleration, qr_filter,
                                   relaxation_prior_diagonal)
from coupling.coarse_surrogate import CoarseSurrogate
from coupling.config import (ACCELERATION_OPTIONS, ACCELERATIONS, FILTERS, JACOBIAN_PRIORS, MEASURES,
                             ACCEPTED_VALUES, ON_MAX_ITERATIONS, PRECONDITIONERS, SCHEMES, STATE_RELOADS,
                             AccelerationConfig, ConvergenceMeasureConfig, CouplingConfig,
                             FilterConfig, PreconditionerConfig, load_config)
from coupling.convergence import (MEASURE_ALIASES, MEASURE_FORMULAS, AbsoluteConvergence, ConvergenceMeasure,
                                  MeasureValue,
                                  RelativeConvergence, ResidualRelativeConvergence, build_measure,
                                  measure_type)
from coupling.distributed import (DISTRIBUTION_FORMS, Distribution, GroupParticipant, ParticipantGroupError,
                                  group_sizes, parse_distribution)
from coupling.errors import CouplingDivergedError, CouplingError, CouplingNotConvergedError
from coupling.extrapolation import lagrange_weights
from coupling.layout import VectorLayout
from coupling.linearization import LinearizedPrior, coupled_jacobian, operator_key
from coupling.mapping import Mapping, build_mapping, order_along_curve, polyline_interpolation_matrix
from coupling.parallel import SerialComm, default_comm, gather_rows, scatter_rows
from coupling.participant import CURVE_ORDERS, CURVES, MAPPINGS, Data, Participant, uses_advance
from coupling.records import (CouplingResult, IterationRecord, RecordedSolve, Recording,
                              WindowRecord, format_progress, write_records)
from coupling.replay import ReplayResult, replay
from coupling.schemes import (CouplingScheme, ParallelExplicitScheme, ParallelImplicitScheme,
                              SerialExplicitScheme, SerialImplicitScheme, build_scheme)
from coupling.serialization import decode_text, encode_text, load_npz, save_npz, to_jsonable, write_bytes
from coupling.surface_mapping import (SURFACE_MAPPINGS, surface_interpolation_matrix, surface_mapping_matrix,
                                      surface_mass_matrix)

__all__ = [
    # participants, data and schemes
    "Participant", "uses_advance", "Data", "MAPPINGS", "CURVES", "CURVE_ORDERS",
    "build_scheme", "CouplingScheme", "SerialImplicitScheme", "ParallelImplicitScheme",
    "SerialExplicitScheme", "ParallelExplicitScheme",
    # configuration
    "load_config", "CouplingConfig", "AccelerationConfig", "ConvergenceMeasureConfig", "FilterConfig",
    "PreconditionerConfig", "SCHEMES", "STATE_RELOADS", "ACCEPTED_VALUES", "ACCELERATIONS", "FILTERS",
    "PRECONDITIONERS", "MEASURES", "ON_MAX_ITERATIONS", "JACOBIAN_PRIORS", "ACCELERATION_OPTIONS",
    # acceleration, convergence, extrapolation
    "Acceleration", "AccelerationInfo", "NoAcceleration", "ConstantRelaxation", "AitkenRelaxation",
    "IQNILS", "IQNIMVJ", "Preconditioner", "build_acceleration", "qr_filter", "relaxation_prior_diagonal",
    "LinearizedPrior", "coupled_jacobian", "operator_key", "CoarseSurrogate", "VectorLayout",
    "ConvergenceMeasure", "AbsoluteConvergence", "RelativeConvergence", "ResidualRelativeConvergence",
    "MeasureValue", "build_measure", "measure_type", "MEASURE_ALIASES", "MEASURE_FORMULAS",
    "lagrange_weights",
    # mapping and MPI
    "Mapping", "build_mapping", "order_along_curve", "polyline_interpolation_matrix",
    "SURFACE_MAPPINGS", "surface_interpolation_matrix", "surface_mapping_matrix", "surface_mass_matrix",
    "SerialComm", "default_comm", "gather_rows", "scatter_rows",
    "Distribution", "GroupParticipant", "ParticipantGroupError", "parse_distribution", "group_sizes",
    "DISTRIBUTION_FORMS",
    # errors, records, replay, files
    "CouplingError", "CouplingDivergedError", "CouplingNotConvergedError",
    "CouplingResult", "IterationRecord", "WindowRecord", "Recording", "RecordedSolve",
    "format_progress", "write_records", "replay", "ReplayResult",
    "save_npz", "load_npz", "to_jsonable", "write_bytes", "encode_text", "decode_text",
]
