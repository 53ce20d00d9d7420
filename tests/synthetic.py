"""A small synthetic, already georeferenced LiDAR scene with known truth.

Used for the shipped sample ``data_samples/las/sample.laz`` and for tests and
benchmarks that need the true terrain.  Not the flight simulator
(:mod:`commands.simulate`): points are drawn uniformly over the area, as
if from a perfectly georeferenced survey.  In metres from the area's
south-west corner:

- terrain: a regional slope of 4 %, rolling hills (8 m amplitude) and a
  mound; all slopes below 25 degrees;
- buildings: flat-roofed boxes and a gabled house, eaves 6-15 m above the
  highest ground under them, roofs level;
- trees: crowns 3-7 m in radius, 8-18 m high; a pulse in a crown gives one
  to three returns, the last of which reaches the ground 60 % of the time;
- a coast (:func:`make_coast` only): the east third is sea, 20 m or more
  below the cliff top, returning an echo to one pulse in five.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import date

import laspy
import numpy as np
import pyproj
import rasterio

from lidar.grid import Grid
from lidar.rasters import write_cog

#: Where the sample sits: ETRS89 / UTM zone 30N, near Madrid (the seeds' area).
SAMPLE_CRS = "EPSG:25830"
SAMPLE_ORIGIN = (440_000.0, 4_474_000.0)

# (x0, y0, x1, y1, eave height, ridge height); ridge == eave means a flat roof.
BUILDINGS = [
    (60.0, 60.0, 100.0, 90.0, 9.0, 9.0),
    (200.0, 250.0, 225.0, 290.0, 6.0, 11.0),
    (330.0, 60.0, 360.0, 80.0, 15.0, 15.0),
    (420.0, 280.0, 450.0, 300.0, 7.0, 7.0),
]


def terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """True bare-earth height (m, ellipsoidal) at local coordinates x, y (m)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    return (
        650.0
        + 0.04 * x
        + 8.0 * np.sin(2 * np.pi * x / 300.0) * np.cos(2 * np.pi * y / 250.0)
        + 5.0 * np.exp(-((x - 350.0) ** 2 + (y - 200.0) ** 2) / (2 * 40.0**2))
    )


def _roof(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Absolute roof height where a building stands (NaN elsewhere), and a mask.

    Roofs are level: the eaves stand ``eave`` metres above the highest ground
    under the footprint, so a building on a slope is taller on its downhill side.
    """
    height = np.full(x.shape, np.nan)
    for x0, y0, x1, y1, eave, ridge in BUILDINGS:
        inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        gx, gy = np.meshgrid(np.linspace(x0, x1, 21), np.linspace(y0, y1, 21))
        base = float(terrain(gx, gy).max())
        # Gable along x: linear from eave at the long sides to ridge mid-way.
        t = 1.0 - np.abs((y[inside] - (y0 + y1) / 2) / ((y1 - y0) / 2))
        height[inside] = base + eave + (ridge - eave) * t
    return height, ~np.isnan(height)


@dataclass
class Scene:
    """Points of a synthetic survey and their truth."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    true_ground: np.ndarray  # bool: the echo is on the bare earth
    return_number: np.ndarray
    number_of_returns: np.ndarray
    point_source_id: np.ndarray
    gps_time: np.ndarray
    intensity: np.ndarray


def make_scene(
    width: float = 512.0,
    height: float = 384.0,
    density: float = 1.5,
    noise: float = 0.03,
    seed: int = 20111,
    n_trees: int = 60,
) -> Scene:
    """Draw a synthetic survey of *width* × *height* metres from (0, 0).

    *density*: pulses per square metre; *noise*: standard deviation of the
    vertical range noise (m); *seed*: equal seeds give equal scenes;
    *n_trees*: trees, placed away from buildings.

    Returns
    -------
    Scene
        Coordinates in the local frame (add :data:`SAMPLE_ORIGIN` for UTM).
    """
    rng = np.random.default_rng(seed)
    n = int(width * height * density)
    px = rng.uniform(0, width, n)
    py = rng.uniform(0, height, n)
    ground_z = terrain(px, py)
    roof, in_building = _roof(px, py)
    crown_h = _crown_heights(px, py, *_trees(rng, width, height, n_trees))
    in_tree = (crown_h > 0) & ~in_building
    strip = 1 + np.minimum((px / (width / 3.0)).astype(int), 2)
    parts = [_open_returns(px, py, ground_z, roof, in_building, ~in_tree, strip)]
    parts += _tree_returns(rng, px, py, ground_z, crown_h, in_tree, strip)
    return _survey(rng, parts, noise)


#: The coast of :func:`make_coast`: the sea's share of the survey (its east side), the cliff's least
#: height above it (m), the share of pulses over the water that return an echo (water reflects most of
#: the laser away from the scanner), and the waves' standard deviation (m).
COAST = {"sea_share": 1 / 3, "cliff": 20.0, "echoes": 0.2, "waves": 0.05}


def coast_line(width: float) -> float:
    """The x (m) of :func:`make_coast`'s cliff: east of it is sea."""
    return width * (1.0 - COAST["sea_share"])


def sea_level(width: float, height: float) -> float:
    """The sea's height (m) in :func:`make_coast`: ``COAST["cliff"]`` below the lowest ground on the cliff line."""
    return float(terrain(np.full(400, coast_line(width)), np.linspace(0.0, height, 400)).min()) - COAST["cliff"]


def make_coast(width: float = 512.0, height: float = 384.0, density: float = 1.5, seed: int = 20111, **kw) -> Scene:
    """:func:`make_scene` with a coast: the east third of the survey is sea below a cliff (:data:`COAST`).

    Over the sea, the scene's buildings and trees are gone; a pulse returns
    one echo from the water, at :func:`sea_level` plus waves, with the
    probability ``COAST["echoes"]``, and none otherwise.  Sea echoes are not
    ground (``true_ground`` False).  The land is :func:`make_scene`'s.
    """
    scene = make_scene(width=width, height=height, density=density, seed=seed, **kw)
    rng = np.random.default_rng(seed + 2)
    sea = scene.x > coast_line(width)
    last = scene.return_number == scene.number_of_returns  # one echo per pulse
    keep = ~sea | (last & (rng.uniform(size=len(sea)) < COAST["echoes"]))
    z = np.where(sea, sea_level(width, height) + rng.normal(0.0, COAST["waves"], len(sea)), scene.z)
    one = np.ones(len(sea), dtype=np.uint8)
    return Scene(
        x=scene.x[keep],
        y=scene.y[keep],
        z=z[keep],
        true_ground=(scene.true_ground & ~sea)[keep],
        return_number=np.where(sea, one, scene.return_number)[keep],
        number_of_returns=np.where(sea, one, scene.number_of_returns)[keep],
        point_source_id=scene.point_source_id[keep],
        gps_time=scene.gps_time[keep],
        intensity=scene.intensity[keep],
    )


def _trees(
    rng: np.random.Generator, width: float, height: float, n_trees: int
) -> tuple[list[float], list[float], np.ndarray, np.ndarray]:
    """Centres (away from buildings), crown radii and heights of *n_trees* trees."""
    tx, ty = [], []
    while len(tx) < n_trees:
        cx, cy = rng.uniform(10, width - 10), rng.uniform(10, height - 10)
        if not _roof(np.array([cx]), np.array([cy]))[1].any() and not _near_building(cx, cy, 10.0):
            tx.append(cx)
            ty.append(cy)
    tr = rng.uniform(3.0, 7.0, n_trees)
    th = rng.uniform(8.0, 18.0, n_trees)
    return tx, ty, tr, th


def _crown_heights(px: np.ndarray, py: np.ndarray, tx, ty, tr, th) -> np.ndarray:
    """Height above the ground of the highest crown over each pulse (0: no crown)."""
    crown_h = np.zeros(len(px))
    by_x = np.argsort(px, kind="stable")
    sorted_x = px[by_x]
    for cx, cy, r, h in zip(tx, ty, tr, th, strict=True):
        # only the pulses within the crown's x range: O(n log n) overall
        near = by_x[np.searchsorted(sorted_x, cx - r) : np.searchsorted(sorted_x, cx + r, side="right")]
        d2 = ((px[near] - cx) ** 2 + (py[near] - cy) ** 2) / r**2
        inside = near[d2 < 1.0]
        d2 = d2[d2 < 1.0]
        crown_h[inside] = np.maximum(crown_h[inside], h * (0.6 + 0.4 * np.sqrt(1.0 - d2)))
    return crown_h


def _open_returns(px, py, ground_z, roof, in_building, single, strip) -> tuple[np.ndarray, ...]:
    """One return per pulse on open ground and roofs: x, y, z, true ground, return number, returns, strip."""
    z = np.where(in_building[single], roof[single], ground_z[single])
    rn = np.ones(single.sum(), dtype=np.uint8)
    nr = np.ones(single.sum(), dtype=np.uint8)
    return px[single], py[single], z, ~in_building[single], rn, nr, strip[single]


def _tree_returns(rng: np.random.Generator, px, py, ground_z, crown_h, in_tree, strip) -> list[tuple[np.ndarray, ...]]:
    """Pulses in a crown: the canopy return, maybe a mid-crown one, then the ground (60 %) or a low branch."""
    idx = np.flatnonzero(in_tree)
    k = len(idx)
    reaches = rng.uniform(size=k) < 0.6
    has_mid = rng.uniform(size=k) < 0.5
    n_ret = 1 + has_mid.astype(int) + 1
    top = ground_z[idx] + crown_h[idx] - rng.uniform(0, 1.0, k)
    mid = ground_z[idx] + crown_h[idx] * rng.uniform(0.4, 0.8, k)
    low = np.where(reaches, ground_z[idx], ground_z[idx] + crown_h[idx] * rng.uniform(0.15, 0.35, k))
    parts = []
    for order, (zz, present) in enumerate(((top, np.ones(k, bool)), (mid, has_mid), (low, np.ones(k, bool)))):
        sel = present
        truth = reaches[sel] if order == 2 else np.zeros(sel.sum(), dtype=bool)
        number = n_ret[sel] if order == 2 else np.full(sel.sum(), order + 1)
        rn, nr = number.astype(np.uint8), n_ret[sel].astype(np.uint8)
        parts.append((px[idx][sel], py[idx][sel], zz[sel], truth, rn, nr, strip[idx][sel]))
    return parts


def _survey(rng: np.random.Generator, parts: list[tuple[np.ndarray, ...]], noise: float) -> Scene:
    """The returns of *parts* together, with range noise, GPS times and intensities, in time order."""
    xs, ys, zs, truth, rn, nr, src = (list(column) for column in zip(*parts, strict=True))
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    z = np.concatenate(zs) + rng.normal(0.0, noise, len(x))
    source = np.concatenate(src).astype(np.uint16)
    # GPS time: strips flown one after the other, each along y at 60 m/s.
    gps_time = 302_400.0 + (source - 1) * 120.0 + y / 60.0 + rng.uniform(0, 1e-3, len(x))
    order = np.lexsort((np.concatenate(rn), gps_time))
    intensity = np.where(np.concatenate(truth), 300, 180).astype(np.uint16) + rng.integers(0, 40, len(x)).astype(
        np.uint16
    )
    return Scene(
        x=x[order],
        y=y[order],
        z=z[order],
        true_ground=np.concatenate(truth)[order],
        return_number=np.concatenate(rn)[order],
        number_of_returns=np.concatenate(nr)[order],
        point_source_id=source[order],
        gps_time=gps_time[order],
        intensity=intensity[order],
    )


def _near_building(cx: float, cy: float, margin: float) -> bool:
    return any(
        x0 - margin <= cx <= x1 + margin and y0 - margin <= cy <= y1 + margin for x0, y0, x1, y1, _, _ in BUILDINGS
    )


def write_scene_las(
    scene: Scene,
    path,
    *,
    crs: str = SAMPLE_CRS,
    origin=SAMPLE_ORIGIN,
    compress: bool = True,
    created: date | None = None,
    software: str = "tests.synthetic.make_scene",
) -> None:
    """Write a scene as an unclassified LAS 1.4 (format 6) file in *crs*.

    *created* and *software*: the header's creation date (default: today) and generating software.
    """
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([origin[0], origin[1], 0.0])
    header.add_crs(pyproj.CRS.from_user_input(crs))
    header.system_identifier = "dtm-pipeline synthetic"
    header.generating_software = software
    if created is not None:
        header.creation_date = created
    las = laspy.LasData(header)
    las.x = scene.x + origin[0]
    las.y = scene.y + origin[1]
    las.z = scene.z
    las.return_number = scene.return_number
    las.number_of_returns = scene.number_of_returns
    las.point_source_id = scene.point_source_id
    las.gps_time = scene.gps_time
    las.intensity = scene.intensity
    las.classification = np.zeros(len(scene.x), dtype=np.uint8)
    las.write(str(path), do_compress=compress, laz_backend=laspy.LazBackend.Lazrs if compress else None)


def sample_checkpoints(scene_seed: int = 20111, n: int = 60, width: float = 512.0, height: float = 384.0):
    """Check points on the true terrain: two thirds in the open, one third under trees.

    Returns x, y (local metres), z (true terrain) and land cover
    (``open`` or ``vegetated``), as a surveyor's GNSS check points would be.
    Points are kept 15 m from buildings and inside the area by 20 m.
    """
    rng = np.random.default_rng(scene_seed + 1)
    scene = make_scene(seed=scene_seed)
    canopy = ~scene.true_ground & (scene.number_of_returns > 1)
    trees = np.column_stack([scene.x[canopy], scene.y[canopy]])
    xs, ys, cover = [], [], []
    while len(xs) < n:
        x, y = rng.uniform(20, width - 20), rng.uniform(20, height - 20)
        if _near_building(x, y, 15.0):
            continue
        under_tree = bool(np.any(np.hypot(trees[:, 0] - x, trees[:, 1] - y) < 1.0))
        want_tree = len(xs) % 3 == 2
        if want_tree != under_tree:
            if want_tree:  # move onto a random canopy point
                x, y = trees[rng.integers(len(trees))]
                if _near_building(x, y, 15.0):
                    continue
            else:
                continue
        xs.append(float(x))
        ys.append(float(y))
        cover.append("vegetated" if want_tree else "open")
    x, y = np.array(xs), np.array(ys)
    return x, y, terrain(x, y), cover


def write_truth_raster(
    path,
    *,
    resolution: float = 1.0,
    width: float = 512.0,
    height: float = 384.0,
    origin=SAMPLE_ORIGIN,
    crs: str = SAMPLE_CRS,
) -> None:
    """The true bare earth sampled at cell centres, as a COG (for ``evaluate dtm --truth``)."""
    grid = Grid.covering(origin[0], origin[1], origin[0] + width - 1e-6, origin[1] + height - 1e-6, resolution)
    gx, gy = grid.centres()
    write_cog(
        path, terrain(gx - origin[0], gy - origin[1]), transform=grid.transform, crs=pyproj.CRS.from_user_input(crs)
    )


def dtm_at_cell_centres(path, origin=SAMPLE_ORIGIN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A DTM GeoTIFF (north-up) read for comparison with the scene: its heights (NaN at nodata) and its cell
    centres in the scene's local coordinates (m from *origin*)."""
    with rasterio.open(path) as src:
        dtm = src.read(1).astype(np.float64)
        t = src.transform
        dtm[dtm == src.nodata] = np.nan
    rows, cols = np.mgrid[0 : dtm.shape[0], 0 : dtm.shape[1]]
    return dtm, t.c + (cols + 0.5) * t.a - origin[0], t.f + (rows + 0.5) * t.e - origin[1]
