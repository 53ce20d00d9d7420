"""The memory this run may still take, for checking a parameter's cost before the work starts.

:func:`free_memory` is the least of what the machine has free
(``MemAvailable``), what the process's control group still allows (a batch
scheduler's limit) and what its address-space limit (``ulimit -v``) leaves.
"""

from __future__ import annotations

import resource
from pathlib import Path

#: Where Linux says how much memory can be had without swapping.
MEMINFO = Path("/proc/meminfo")


def free_memory() -> int:
    """Bytes this process may still allocate: the least of the machine's, its control group's and its limit's."""
    limits = [_mem_available(), _cgroup_room(), _address_room()]
    known = [v for v in limits if v is not None]
    return max(0, min(known)) if known else _psutil_available()


def _mem_available() -> int | None:
    """``MemAvailable`` of /proc/meminfo, in bytes (None off Linux)."""
    try:
        for line in MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    """What the control group (v2) of this process still allows, in bytes (None: no limit)."""
    try:
        rel = Path("/proc/self/cgroup").read_text().strip().splitlines()[0].split(":", 2)[2]
        folder = Path("/sys/fs/cgroup") / rel.lstrip("/")
        limit = (folder / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int((folder / "memory.current").read_text().strip())
    except (OSError, ValueError, IndexError):
        return None


def _address_room() -> int | None:
    """What ``ulimit -v`` leaves of this process's address space, in bytes (None: no limit)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        size = int(Path("/proc/self/statm").read_text().split()[0]) * resource.getpagesize()
    except (OSError, ValueError, IndexError):
        size = 0
    return soft - size


def _psutil_available() -> int:
    """The machine's available memory as psutil sees it (systems without /proc)."""
    import psutil

    return int(psutil.virtual_memory().available)


def gigabytes(n: float) -> str:
    """*n* bytes for a message: ``17 GB``, ``9.8 GB``, ``190 MB``."""
    g = n / 1e9
    if g >= 10:
        return f"{g:,.0f} GB"
    return f"{g:.1f} GB" if g >= 1 else f"{n / 1e6:,.0f} MB"
