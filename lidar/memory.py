"""The memory this run may still take, for checking a parameter's cost before the work starts.

:func:`free_memory` is the least of what the machine has free
(``MemAvailable``), what the process's control group still allows (a batch
scheduler's limit) and what its address-space limit (``ulimit -v``) leaves.
"""

from __future__ import annotations

import resource
from pathlib import Path

import psutil

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


#: Control group files: (mount, limit, usage, reclaimable cache in memory.stat), for cgroup v2 and v1.
CGROUP_FILES = {
    "v2": ("/sys/fs/cgroup", "memory.max", "memory.current", "inactive_file"),
    "v1": ("/sys/fs/cgroup/memory", "memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"),
}


def _cgroup_room() -> int | None:
    """What the control group of this process still allows, in bytes (None: no limit found).

    Its page cache not in active use is reclaimable, so it counts as room.
    The group's own folder is tried, then the mount's root (inside a
    container the group is often mounted there).
    """
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    rooms = []
    for line in lines:
        _, controllers, rel = (line.split(":", 2) + ["", ""])[:3]
        version = "v2" if controllers == "" else "v1" if "memory" in controllers.split(",") else None
        if version is None:
            continue
        mount, limit, usage, cache = CGROUP_FILES[version]
        for folder in (Path(mount) / rel.lstrip("/"), Path(mount)):
            room = _room(folder, limit, usage, cache)
            if room is not None:
                rooms.append(room)
                break
    return min(rooms) if rooms else None


def _room(folder: Path, limit: str, usage: str, cache: str) -> int | None:
    """Limit minus usage plus reclaimable cache of one control group folder (None: no limit, or not there)."""
    try:
        most = (folder / limit).read_text().strip()
        if most == "max" or int(most) >= 1 << 60:
            return None
        used = int((folder / usage).read_text().strip())
        stat = dict(line.split() for line in (folder / "memory.stat").read_text().splitlines() if line.count(" ") == 1)
        return int(most) - used + int(stat.get(cache, 0))
    except (OSError, ValueError):
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
    return int(psutil.virtual_memory().available)


def gigabytes(n: float) -> str:
    """*n* bytes for a message: ``17 GB``, ``9.8 GB``, ``190 MB``."""
    g = n / 1e9
    if g >= 10:
        return f"{g:,.0f} GB"
    return f"{g:.1f} GB" if g >= 1 else f"{n / 1e6:,.0f} MB"
