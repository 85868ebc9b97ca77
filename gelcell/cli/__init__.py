"""The ``gelcell`` command line: ``main`` parses the options, runs a command and maps failures to exit codes.

Every expected failure ends with one line on stderr and the exit code of
:mod:`gelcell.errors`; ``gelcell --debug`` adds the traceback and the form
compiler's log.
"""

from __future__ import annotations

import logging
import os
import sys
import time
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


#: Seconds a failing rank waits for the other ranks to fail too (an error they all meet, such as a
#: bad option, reaches every rank within milliseconds) before it ends the whole job.
AGREEMENT_TIMEOUT = 5.0


def _everyone_failed(errors: MPI.Comm, timeout: float = AGREEMENT_TIMEOUT) -> bool:
    """Whether every rank of ``errors`` arrived here (all failed) within ``timeout`` seconds.

    ``errors`` is a duplicate of COMM_WORLD used for nothing else, so this non-blocking barrier
    cannot be matched by the collective calls of a rank that did not fail and is still working.
    """
    request = errors.Ibarrier()
    deadline = time.monotonic() + timeout
    while not request.Test():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _end(errors: MPI.Comm | None, code: int, report: typing.Callable[[str], None]) -> int:
    """End a failure on every rank: the exit code of rank 0's failure if every rank failed (rank 0
    reports it), else this rank reports its own and aborts the job (the others would wait forever)."""
    if errors is None or _everyone_failed(errors):
        if errors is not None:
            code = errors.bcast(code, root=0)
            errors.Free()
        if MPI.COMM_WORLD.rank == 0:
            report("")
        return code
    world = MPI.COMM_WORLD
    report(f" (on rank {world.rank} of {world.size} only: aborting the job)")
    world.Abort(code)
    return code                         # not reached


def main(argv: typing.Sequence[str] | None = None) -> int:
    """Run one ``gelcell`` command; the exit code (every failure: one line, see :mod:`gelcell.errors`).

    Under MPI a failure ends every rank: if all ranks fail (within :data:`AGREEMENT_TIMEOUT`),
    rank 0 prints its line; if one rank fails alone, it prints its line and aborts the job.
    """
    world = MPI.COMM_WORLD
    errors = world.Dup() if world.size > 1 else None
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:                 # argparse printed its message (on each rank that failed)
        if exc.code in (0, None) or errors is None:
            if errors is not None:
                errors.Free()
            raise
        raise SystemExit(_end(errors, int(exc.code) if isinstance(exc.code, int) else 2, lambda _: None)) from None
    configure_logging(args.debug)
    if not getattr(args, "command_name", None):
        if errors is not None:
            errors.Free()
        parser.print_help()
        return 2
    failure: BaseException | None = None
    with install_signal_handlers():
        try:
            code = int(COMMANDS[args.command_name](args) or 0)
        except (Exception, KeyboardInterrupt) as exc:      # every failure: one line and its exit code
            failure, code = exc, exit_code(exc)
            trace = traceback.format_exc()
    if failure is None:
        if errors is not None:
            errors.Free()
        return code

    def report(where: str) -> None:
        if args.debug:
            print(trace, file=sys.stderr, end="", flush=True)
        print(f"gelcell {args.command}: error: {message(failure)}{where}", file=sys.stderr, flush=True)

    return _end(errors, code, report)
