"""The truth beside the points: the bare earth and its land cover on a grid of the output CRS, and check points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj
import shapely
from rasterio.transform import from_origin
from scipy.ndimage import binary_closing, binary_dilation, binary_erosion

from commands.simulate import scene as sc
from commands.simulate.forward import Earth
from lidar.rasters import NODATA, write_cog
from lidar.vectors import write_gpkg


def ground_height(
    world: sc.Scene, frame: Earth, crs: pyproj.CRS, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Height in the output CRS where the vertical through (x, y) meets the bare earth, and the local (e, n)."""
    from_crs = pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True)
    h = np.full(len(x), frame.h0)
    for _ in range(5):
        ex, ey, ez = from_crs.transform(x, y, h)
        local = frame.from_ecef(np.column_stack((ex, ey, ez)))
        g = world.sample(world.ground, local[:, 0], local[:, 1])
        h = h - (local[:, 2] - np.nan_to_num(g))
    return np.where(np.isfinite(g), h, np.nan), local


def write_checkpoints(
    path: Path,
    world: sc.Scene,
    frame: Earth,
    crs: pyproj.CRS,
    ground_xy: np.ndarray,
    n: int,
    rng: np.random.Generator,
) -> None:
    """GNSS-style check points on the true terrain, spread over the survey: two thirds in the open, one third under trees.

    Where the flown lines recorded ground echoes (*ground_xy*, local east and
    north: so the DTM covers them), at least 5 m from buildings, water, the
    bridge, breaklines and slopes over 20 %, as a surveyor would place them;
    each as far as it can be from those placed before, so that they sample
    every part of the survey and every land cover, the ground beside the
    channel included.
    """
    rows = _checkpoint_places(world, ground_xy, n, rng)
    local = np.array([[r[0], r[1], 0.0] for r in rows]).reshape(-1, 3)
    ecef = frame.to_ecef(local)
    x, y, _ = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True).transform(
        ecef[:, 0], ecef[:, 1], ecef[:, 2]
    )
    z, _ = ground_height(world, frame, crs, np.asarray(x), np.asarray(y))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(f"# true terrain of the simulated survey; {crs.to_string()}, ellipsoidal heights, metres\n")
        fh.write("id,x,y,z,land_cover\n")
        for i, (xi, yi, zi, r) in enumerate(zip(x, y, z, rows, strict=True), 1):
            fh.write(f"CP{i:03d},{xi:.3f},{yi:.3f},{zi:.3f},{r[2]}\n")


#: Check points stay this far (m) inside the area the lines' ground echoes cover.
COVERAGE_MARGIN_M = 3.0


def _checkpoint_places(
    world: sc.Scene, ground_xy: np.ndarray, n: int, rng: np.random.Generator
) -> list[tuple[float, float, str]]:
    """(e, n, land cover) of *n* check points, every third under trees, spread by farthest-point sampling.

    The candidates are the scene's cells with the lines' ground echoes
    around them (gaps of a few metres between scan lines closed,
    ``COVERAGE_MARGIN_M`` inside the edge), 5 m clear of structures and steep
    ground; the first point is drawn at random, each next one is the
    candidate of the wanted land cover farthest from every point placed so
    far, jittered inside its cell.
    """
    shape = world.cls.shape
    gy, gx = np.gradient(world.ground, world.cell)
    steep = np.hypot(gx, gy) > 0.2  # breaklines and steep slopes: no check point within 5 m (ASPRS practice)
    structures = binary_dilation((world.cls != sc.GROUND) | steep, iterations=int(5 / world.cell))
    trees = world.canopy > world.solid + 0.5
    hit = np.zeros(shape, dtype=bool)
    col = np.floor((ground_xy[:, 0] - world.e0) / world.cell).astype(np.int64)
    row = np.floor((ground_xy[:, 1] - world.n0) / world.cell).astype(np.int64)
    inside = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    hit[row[inside], col[inside]] = True
    gap = max(1, int(round(3.0 / world.cell)))
    covered = binary_erosion(
        binary_closing(hit, iterations=gap), iterations=max(1, int(round(COVERAGE_MARGIN_M / world.cell)))
    )
    iy, ix = np.nonzero(covered & ~structures)
    e = world.e0 + (ix + 0.5) * world.cell
    nn = world.n0 + (iy + 0.5) * world.cell
    tree = trees[iy, ix]
    rows: list[tuple[float, float, str]] = []
    far = np.full(len(e), np.inf)  # each candidate's distance to the nearest point placed
    for k in range(n):
        want_tree = k % 3 == 2
        pool = np.flatnonzero(tree == want_tree)
        if not len(pool):
            continue
        pick = int(rng.choice(pool)) if not rows else int(pool[np.argmax(far[pool])])
        pe = e[pick] + rng.uniform(-0.5, 0.5) * world.cell
        pn = nn[pick] + rng.uniform(-0.5, 0.5) * world.cell
        rows.append((pe, pn, "vegetated" if want_tree else "open"))
        far = np.minimum(far, np.hypot(e - pe, nn - pn))
    return rows


def write_truth_terrain(
    folder: Path,
    world: sc.Scene,
    frame: Earth,
    crs: pyproj.CRS,
    extent: tuple[float, float, float, float],
    resolution: float,
) -> None:
    """The bare earth on a grid of the output CRS, and what covers it, on the same cells.

    ``terrain.tif``: for each cell centre, the height where the vertical meets
    the ground.  ``land_cover.tif`` (uint8, ASPRS class codes, 0 = outside the
    scene): the class of the solid surface there (2 ground, 6 building,
    9 water, 17 bridge deck), 5 where tree crowns stand more than 0.5 m above
    it (the rule the check points' "vegetated" follows).
    """
    e_min, e_max, n_min, n_max = extent
    corners = np.array([[e_min, n_min, 0.0], [e_max, n_min, 0.0], [e_min, n_max, 0.0], [e_max, n_max, 0.0]])
    to_crs = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True)
    ec = frame.to_ecef(corners)
    cx, cy, _ = to_crs.transform(ec[:, 0], ec[:, 1], ec[:, 2])
    x0 = np.ceil(min(cx) / resolution) * resolution
    y1 = np.floor(max(cy) / resolution) * resolution
    nx = int((np.floor(max(cx) / resolution) * resolution - x0) / resolution)
    ny = int((y1 - np.ceil(min(cy) / resolution) * resolution) / resolution)
    xs = x0 + (np.arange(nx) + 0.5) * resolution
    ys = y1 - (np.arange(ny) + 0.5) * resolution
    X, Y = np.meshgrid(xs, ys)
    h, local = ground_height(world, frame, crs, X.ravel(), Y.ravel())
    z = np.where(np.isfinite(h), h, NODATA).reshape(ny, nx)
    transform = from_origin(x0, y1, resolution, resolution)
    write_cog(folder / "terrain.tif", z.astype(np.float32), transform=transform, crs=crs)
    e, n = local[:, 0], local[:, 1]
    cover = world.class_at(e, n).astype(np.uint8)
    trees = world.sample(world.canopy, e, n) > world.sample(world.solid, e, n) + 0.5
    cover = np.where(trees, sc.VEGETATION, cover)
    cover = np.where(np.isfinite(h), cover, 0).reshape(ny, nx).astype(np.uint8)
    write_cog(folder / "land_cover.tif", cover, transform=transform, crs=crs, nodata=0, dtype="uint8", unit=None)


def write_truth_breaklines(
    folder: Path, world: sc.Scene, frame: Earth, crs: pyproj.CRS, extent: tuple[float, float, float, float]
) -> None:
    """The water's true shores as 3-D breaklines: ``breaklines.gpkg`` (GeoPackage 1.2, layer ``breaklines``).

    LineString Z, field ``shore``: the river's south and north shores
    (``world.river``, east-west along the scene, a vertex every 0.5 m at
    the water's height there, falling eastwards, under the bridge too),
    and each lake's (``world.lakes``: a closed circle at its level, a
    vertex every 0.5 m), in the output CRS.
    """
    e_min, e_max, _, _ = extent
    to_crs = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True)
    shores: list[tuple[str, np.ndarray]] = []
    if world.river is not None:
        centre, half = world.river
        e = np.arange(e_min + 0.25, e_max, 0.5)
        level = world.sample(world.ground, e, np.full(len(e), centre))  # the water, level across the river
        for name, n in (("river south", centre - half), ("river north", centre + half)):
            shores.append((name, np.column_stack((e, np.full(len(e), n), level))[np.isfinite(level)]))
    for i, (e0, n0, radius, level) in enumerate(world.lakes, start=1):
        a = np.linspace(0.0, 2 * np.pi, int(np.ceil(2 * np.pi * radius / 0.5)) + 1)
        shores.append(
            (f"lake {i}", np.column_stack((e0 + radius * np.cos(a), n0 + radius * np.sin(a), np.full(len(a), level))))
        )
    lines = []
    for _, enu in shores:
        ec = frame.to_ecef(enu)
        x, y, h = to_crs.transform(ec[:, 0], ec[:, 1], ec[:, 2])
        lines.append(shapely.to_wkb(shapely.LineString(np.column_stack((x, y, h))), output_dimension=3))
    fields = {"shore": np.array([name for name, _ in shores], dtype=object)}
    write_gpkg(folder / "breaklines.gpkg", lines, fields, crs=crs, layer="breaklines", geometry_type="LineString Z")
