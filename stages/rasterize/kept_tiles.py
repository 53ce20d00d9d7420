"""The rasters of a tile kept for later runs (:class:`pipeline.tiling.TileMemo`).

A tile's windows depend on its points, the stage's parameters and where its
cells lie: the survey grid's anchor and the tile's rows and columns in it.
A survey that grows to the west or north moves the anchor, and every tile
is made again; one that changes inside, or grows to the east or south,
makes again only the tiles whose points changed.
"""

from __future__ import annotations

import hashlib
from dataclasses import astuple
from pathlib import Path

import numpy as np

from lidar.tile_points import column_digests, keep_file
from pipeline.tiling import TileMemo
from stages.rasterize.tile_rasters import RasterTask, tile_windows


def _key(task: RasterTask) -> dict:
    core, wide, _ = tile_windows(task.grid, task.window, task.buffer)
    inside = task.inside(core)  # the outline where this tile's cells are: what it cuts here
    inside = np.packbits(inside) if inside is not None else np.zeros(0, np.uint8)
    return {
        "outline": hashlib.sha256(inside.tobytes()).hexdigest(),
        "kind": "rasters",
        "params": task.params,
        "core": astuple(core),
        "wide": astuple(wide),
        "vertical": task.vertical,
        "outputs": list(task.outputs),
        "water": [task.water_digest, list(task.water_units)] if task.water is not None else None,
        "columns": column_digests(Path(task.source)),
    }


def _save(task: RasterTask, result: dict, folder: Path) -> dict:
    for name in task.outputs:
        keep_file(Path(task.result) / f"{name}.npy", folder / f"{name}.npy")
    return result


def _load(task: RasterTask, folder: Path, kept: dict) -> dict:
    out = Path(task.result)
    out.mkdir(parents=True, exist_ok=True)
    for name in task.outputs:
        keep_file(folder / f"{name}.npy", out / f"{name}.npy")
    return {**kept, "tile": task.tile}


#: A tile's rasters kept for later runs: a tile whose points did not change is not gridded again.
MEMO = TileMemo(_key, _save, _load)
