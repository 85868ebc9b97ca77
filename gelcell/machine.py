"""What this machine offers a run: its memory, and the share of it a run (or gmsh) may take."""

from __future__ import annotations

import os

__all__ = ["MEMORY_SHARE", "machine_memory"]

#: Refuse meshes whose estimated memory exceeds this share of the machine's memory; gmsh, in its
#: child process (gelcell.geometry.files.child), may use this share of it.
MEMORY_SHARE = 0.8


def machine_memory() -> int:
    """Physical memory of this machine in bytes (or of the cgroup it runs in, if smaller)."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, int(text))
    return total
