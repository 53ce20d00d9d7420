"""The run service's one grid, called as the stages call it: a helper of the grid stages' tests."""

from __future__ import annotations

from pathlib import Path

from lidar.gridrun.kernel import GridKernel
from lidar.gridrun.service import Workers, on_one_grid


def one_grid(
    kernel: GridKernel, src: Path, dst: Path, cap: int, tiles: tuple[int, int] | None = None, **workers
) -> dict | None:
    """:func:`~lidar.gridrun.service.on_one_grid`'s counts by name, its grid's shape and windows; None when it did not fit.

    *workers*: :class:`~lidar.gridrun.service.Workers`' fields (executor, workdir, threads, chunk_size).
    """
    done = on_one_grid(Path(src), Path(dst), kernel, cap, tiles, Workers(**workers))
    if done is None:
        return None
    shape = tuple(done.grid.shape) if done.grid is not None else (0, 0)
    return {**dict(zip(kernel.counts, done.counts, strict=False)), "grid": shape, "windows": done.windows}
