"""The memory a run may still take: the machine's, the control group's and the address-space limit's least."""

from __future__ import annotations

import resource
from pathlib import Path as RealPath

from lidar import memory


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


def test_a_control_group_limit_counts_its_reclaimable_cache(tmp_path, monkeypatch):
    group = tmp_path / "sys" / "job"
    group.mkdir(parents=True)
    (tmp_path / "cgroup").write_text("0::/job\n")
    (group / "memory.max").write_text("4000000000\n")
    (group / "memory.current").write_text("1500000000\n")
    (group / "memory.stat").write_text("anon 1000000000\ninactive_file 300000000\nfile 500000000\n")

    _redirect_cgroups(monkeypatch, tmp_path / "cgroup", tmp_path / "sys")
    assert memory._cgroup_room() == 4_000_000_000 - 1_500_000_000 + 300_000_000
    (group / "memory.max").write_text("max\n")
    assert memory._cgroup_room() is None


def test_a_cgroup_v1_limit_counts_too(tmp_path, monkeypatch):
    group = tmp_path / "memory"  # inside a container: the group at the mount's root
    group.mkdir()
    (tmp_path / "cgroup").write_text("9:name=systemd:/\n4:memory:/job/7\n0::/\n")
    (group / "memory.limit_in_bytes").write_text("2000000000\n")
    (group / "memory.usage_in_bytes").write_text("500000000\n")
    (group / "memory.stat").write_text("cache 100\ntotal_inactive_file 100000000\n")

    _redirect_cgroups(monkeypatch, tmp_path / "cgroup", tmp_path)
    assert memory._cgroup_room() == 2_000_000_000 - 500_000_000 + 100_000_000


def _redirect_cgroups(monkeypatch, cgroup_file, sys_root):
    """memory reads /proc/self/cgroup from *cgroup_file* and /sys/fs/cgroup/... under *sys_root*."""

    def fake(path):
        text = str(path)
        if text == "/proc/self/cgroup":
            return RealPath(cgroup_file)
        if text.startswith("/sys/fs/cgroup"):
            return RealPath(str(sys_root) + text[len("/sys/fs/cgroup") :])
        return RealPath(path)

    monkeypatch.setattr(memory, "Path", fake)
