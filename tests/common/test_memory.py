"""The memory a run may still take: the machine's, the control group's and the address-space limit's least."""

from __future__ import annotations

import resource

from dtm.common import memory


def test_free_memory_is_the_least_of_the_limits(monkeypatch):
    monkeypatch.setattr(memory, "_mem_available", lambda: 8_000_000_000)
    monkeypatch.setattr(memory, "_cgroup_room", lambda: None)
    monkeypatch.setattr(memory, "_address_room", lambda: 3_000_000_000)
    assert memory.free_memory() == 3_000_000_000
    monkeypatch.setattr(memory, "_address_room", lambda: None)
    assert memory.free_memory() == 8_000_000_000


def test_mem_available_is_read_from_meminfo(tmp_path, monkeypatch):
    info = tmp_path / "meminfo"
    info.write_text("MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:    9570312 kB\n")
    monkeypatch.setattr(memory, "MEMINFO", info)
    assert memory._mem_available() == 9_570_312 * 1024
    assert memory.gigabytes(9_800_000_000) == "9.8 GB" and memory.gigabytes(17_000_000_000) == "17 GB"
    assert memory.gigabytes(19_296_120) == "19 MB"


def test_an_address_space_limit_counts(monkeypatch):
    monkeypatch.setattr(resource, "getrlimit", lambda _: (4 * 2**30, resource.RLIM_INFINITY))
    assert 0 < memory._address_room() < 4 * 2**30
