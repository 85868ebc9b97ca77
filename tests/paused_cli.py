"""Run the CLI in a subprocess that waits at a chosen point, so a test can signal it there.

Reading the progress lines and signalling when one appears is a race: a fast run can
finish before the signal arrives.  Here the child pauses inside the patched method
(printing ``PAUSED``) until the signal interrupts it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

__all__ = ["paused_gelcell", "signal_when_paused"]


def paused_gelcell(args: list[str], target: str = "gelcell.coupled.participants.GelParticipant.solve",
                   call: int = 2) -> subprocess.Popen:
    """``gelcell *args`` whose ``call``-th call of ``target`` (module.Class.method) waits for a signal."""
    module, cls, method = target.rsplit(".", 2)
    script = textwrap.dedent(f"""
        import signal, sys, time
        # a child of a background job starts with SIGINT ignored; gmsh restores that state when
        # it finalizes, so set Python's handler before anything imports gmsh
        signal.signal(signal.SIGINT, signal.default_int_handler)
        import {module} as target_module
        from gelcell.cli import main
        original = getattr(target_module.{cls}, {method!r})
        calls = [0]
        def paused(*a, **kw):
            calls[0] += 1
            if calls[0] == {call}:
                print("PAUSED", flush=True)
                time.sleep(120)          # the signal interrupts this
            return original(*a, **kw)
        setattr(target_module.{cls}, {method!r}, paused)
        sys.exit(main({list(args)!r}))
    """)
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)


def signal_when_paused(proc: subprocess.Popen, signum: int, timeout: float = 600) -> tuple[str, str]:
    """Send ``signum`` once the child printed PAUSED; return its (stdout, stderr)."""
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.strip() == "PAUSED":
            proc.send_signal(signum)
            break
    out, err = proc.communicate(timeout=timeout)
    return "".join(seen) + out, err
