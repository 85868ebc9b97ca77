"""The ``gelcell`` command line: ``main`` parses the options, runs a command and maps failures to exit codes.

Every expected failure ends with one line on stderr and the exit code of
:mod:`gelcell.errors`; ``gelcell --debug`` adds the traceback and the form
compiler's log.
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
import typing

# Started without mpirun, this process is an MPI singleton that talks to nobody, yet Open MPI's
# MPI_Init would probe the high-speed network libraries (psm, psm2, libfabric) and start a
# helper daemon for MPI_Comm_spawn, which gelcell never calls: ob1 and no daemon avoid both.
# Only for this process's MPI_Init (a setting the user made is kept); its children do not inherit them.
# Not under a launcher (mpirun, srun, a PMI server): there the transport is the launcher's choice.
_LAUNCHED = ("OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE", "SLURM_PROCID")
_SINGLETON_MCA = {"OMPI_MCA_pml": "ob1", "OMPI_MCA_ess_singleton_isolated": "1"}
_SINGLETON_MCA = {} if any(k in os.environ for k in _LAUNCHED) else \
    {k: v for k, v in _SINGLETON_MCA.items() if k not in os.environ}
os.environ.update(_SINGLETON_MCA)
from mpi4py import MPI  # noqa: E402

for _key in _SINGLETON_MCA:
    del os.environ[_key]

from gelcell.cli.commands import COMMANDS  # noqa: E402
from gelcell.cli.parser import build_parser  # noqa: E402
from gelcell.errors import exit_code, install_signal_handlers, message  # noqa: E402

__all__ = ["main", "build_parser"]


def configure_logging(debug: bool = False) -> None:
    """Warnings on stderr; debug records (incl. the C compiler lines of FFCx's JIT) only with ``debug``.

    FFCx calls ``logging.basicConfig()`` when imported and the compiler driver
    logs each command at INFO on the root logger; a handler of our own, at
    WARNING unless ``debug``, keeps those lines out of a normal run.
    """
    handler = logging.StreamHandler(sys.stderr)
    handler.setLevel(logging.DEBUG if debug else logging.WARNING)
    logging.basicConfig(handlers=[handler], format="%(levelname)s:%(name)s: %(message)s",
                        level=logging.DEBUG if debug else logging.WARNING, force=True)


def main(argv: typing.Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(args.debug)
    if not getattr(args, "command_name", None):
        parser.print_help()
        return 2
    with install_signal_handlers():
        try:
            return int(COMMANDS[args.command_name](args) or 0)
        except (Exception, KeyboardInterrupt) as exc:      # every failure: one line and its exit code
            if MPI.COMM_WORLD.rank == 0:
                if args.debug:
                    traceback.print_exc()
                print(f"gelcell {args.command}: error: {message(exc)}", file=sys.stderr, flush=True)
            return exit_code(exc)
