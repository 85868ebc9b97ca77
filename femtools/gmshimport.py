"""The one way gelcell imports gmsh: lazily, and without losing the SIGINT handler.

gmsh 4.8's module sets SIGINT to the default action when first imported
(``oldsig = signal.signal(SIGINT, SIG_DFL)``) and puts ``oldsig`` back in
``gmsh.finalize()``.  gmsh is imported only where a model is built or read
(its import loads libgmsh), long after the CLI installed its handlers, so
both the import (while it loads libgmsh, 0.2-0.6 s) and a later
``finalize`` would drop the CLI's Ctrl-C handling.  This module imports
nothing heavy, so light modules can use it.
"""

from __future__ import annotations

import contextlib
import signal
import sys

__all__ = ["import_gmsh", "gmsh_session"]


def import_gmsh():
    """The gmsh module, with the SIGINT handler in place now kept through the import and the next finalize.

    Call it right before ``gmsh.initialize()`` (it is cheap once gmsh is loaded).  During the
    first import gmsh's ``signal.signal(SIGINT, SIG_DFL)`` is not carried out: the import then
    loads libgmsh (0.2-0.6 s), and a Ctrl-C in that time would otherwise kill the process by the
    default action, with no error line and no exit 130.
    """
    handler = signal.getsignal(signal.SIGINT)
    if "gmsh" not in sys.modules and handler is not None:
        real = signal.signal

        def keep_sigint(signum, action):
            if signum == signal.SIGINT:
                return handler            # what gmsh keeps as ``oldsig``; the handler stays
            return real(signum, action)
        signal.signal = keep_sigint
        try:
            import gmsh
        finally:
            signal.signal = real
    import gmsh
    if handler is not None:          # None: a handler not installed from Python, nothing to keep
        if signal.getsignal(signal.SIGINT) is not handler:
            signal.signal(signal.SIGINT, handler)
        gmsh.oldsig = handler
    return gmsh


@contextlib.contextmanager
def gmsh_session():
    """``with gmsh_session() as gmsh:`` a quiet gmsh session (no config files, no terminal output),
    finalized on leaving, whatever happens inside."""
    gmsh = import_gmsh()
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        yield gmsh
    finally:
        gmsh.finalize()
