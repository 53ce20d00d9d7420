"""The simulator's world: a 2.5-D scene on a fine grid in a local ENU frame, and ray casting into it.

The scene is defined by rasters (cell ``cell`` metres, bilinear between
cell centres) in the local east-north-up frame of :class:`~commands.simulate.forward.Earth`
(PROJ's topocentric frame), an exact rigid transform of ECEF: rays are
straight lines there, so casting them is exact geometry.

- ``ground``: the bare earth (the water surface over water bodies: the
  truth DTM is hydro-flattened, as delivered DTMs are);
- ``solid``: ground plus buildings and the bridge deck;
- ``canopy``: solid plus tree crowns (what a first echo sees);
- ``cls``: LAS class of the solid surface (2 ground, 6 building, 9 water,
  17 bridge deck); vegetation (5) where canopy is above solid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GROUND, VEGETATION, BUILDING, NOISE, WATER, BRIDGE = 2, 5, 6, 7, 9, 17

#: A step (m) between neighbouring cells of the solid surface that stands for a wall, not a slope (a
#: 30-degree slope rises 0.29 m between 0.5 m cells); an echo on it more than FOOT (m) up is the wall's.
WALL, FOOT = 1.0, 0.1

#: Thickness (m) of the bridge deck: the solid surface draws a deck as a block down to the ground.
DECK = 1.0
CLASS_NAMES = {
    GROUND: "ground",
    VEGETATION: "vegetation",
    BUILDING: "building",
    NOISE: "noise",
    WATER: "water",
    BRIDGE: "bridge",
}


@dataclass
class Scene:
    e0: float  # west edge of the grid (local ENU, m)
    n0: float  # south edge
    cell: float
    ground: np.ndarray  # (ny, nx), row 0 = south
    solid: np.ndarray
    canopy: np.ndarray
    cls: np.ndarray  # uint8
    river: tuple[float, float] | None = None  # the river's centre line (northing) and half width, m (none: none)
    lakes: tuple[tuple[float, float, float, float], ...] = ()  # each lake's centre (e, n), radius and level, m

    def sample(self, grid: np.ndarray, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Bilinear value of a scene raster at local (e, n); NaN outside the grid."""
        ny, nx = grid.shape
        fx = (np.asarray(e) - self.e0) / self.cell - 0.5
        fy = (np.asarray(n) - self.n0) / self.cell - 0.5
        inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
        fx = np.clip(np.nan_to_num(fx), 0, nx - 1.000001)
        fy = np.clip(np.nan_to_num(fy), 0, ny - 1.000001)
        ix, iy = fx.astype(np.int64), fy.astype(np.int64)
        ax, ay = fx - ix, fy - iy
        flat = grid.ravel()
        k = iy * nx + ix
        v = (flat[k] * (1 - ax) + flat[k + 1] * ax) * (1 - ay) + (flat[k + nx] * (1 - ax) + flat[k + nx + 1] * ax) * ay
        return np.where(inside, v, np.nan)

    def class_of_hit(self, e: np.ndarray, n: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Class of an echo of the solid surface at (e, n, z): :meth:`class_at`, except on a wall.

        Between the centres of a low and a high cell the bilinear surface is a
        ramp, which stands for a vertical wall: where the 2 x 2 cells around
        (e, n) differ by more than ``WALL`` m, an echo more than ``FOOT`` m
        above the lowest of them is the high cell's (a building's or a
        deck's side, as a labeller would call it), not the ground's; more
        than ``DECK`` m below a deck it is what lies under the deck.
        """
        cls = self.class_at(e, n)
        ny, nx = self.solid.shape
        fx = np.clip(np.nan_to_num((np.asarray(e) - self.e0) / self.cell - 0.5), 0, nx - 1.000001)
        fy = np.clip(np.nan_to_num((np.asarray(n) - self.n0) / self.cell - 0.5), 0, ny - 1.000001)
        k = fy.astype(np.int64) * nx + fx.astype(np.int64)
        corners = np.stack([k, k + 1, k + nx, k + nx + 1])
        z4 = self.solid.ravel()[corners]
        z, low, top = np.asarray(z), z4.min(axis=0), z4.argmax(axis=0)
        high, c4 = z4.max(axis=0), self.cls.ravel()[corners]
        wall = (high - low > WALL) & (z > low + FOOT)
        # a deck is DECK m thick: below it, open air down to what lies under it (the lowest cell's class)
        under = wall & (c4[top, np.arange(len(k))] == BRIDGE) & (z < high - DECK)
        return np.where(
            under, c4[z4.argmin(axis=0), np.arange(len(k))], np.where(wall, c4[top, np.arange(len(k))], cls)
        )

    def class_at(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Class of the solid surface at (e, n) (nearest cell)."""
        ny, nx = self.cls.shape
        ix = np.clip(np.nan_to_num((np.asarray(e) - self.e0) / self.cell).astype(np.int64), 0, nx - 1)
        iy = np.clip(np.nan_to_num((np.asarray(n) - self.n0) / self.cell).astype(np.int64), 0, ny - 1)
        return self.cls[iy, ix]


def make_scene(
    extent: tuple[float, float, float, float],
    *,
    seed: int = 1,
    cell: float = 0.5,
    terrain: str = "default",
    water: str = "default",
) -> Scene:
    """A scene covering *extent* (e_min, e_max, n_min, n_max, local metres) with every feature the tests need.

    Hills, a 30-degree slope, a 3 m terrace (breakline), a river (water) with
    a bridge over it, flat-roofed and gabled buildings, trees.  Feature
    positions scale with the extent; *seed* moves buildings and trees.
    *terrain* ``"flat"``: bare ground only, level at local height 0 (the
    origin's ellipsoidal height), nothing on it: the geometry in which
    overlapping strips cannot see a horizontal shift.  *water* ``"lbs"``:
    water the USGS Lidar Base Specification hydro-flattens (:data:`LBS_RIVER_WIDTH`,
    :data:`LBS_LAKE_RADIUS`): the river 31 m wide and a round lake of
    8,495 m² north of it; the extent must be at least :data:`LBS_EXTENT` m
    each way.
    """
    rng = np.random.default_rng(seed)
    g = _Lattice.of(extent, cell)
    if terrain == "flat":
        level = np.zeros(g.E.shape)
        flat = np.full(level.shape, GROUND, np.uint8)
        return Scene(g.e_min, g.n_min, cell, level, level.copy(), level.copy(), flat)
    lbs = water == "lbs"
    if lbs and min(g.w, g.h) < LBS_EXTENT:
        raise ValueError(
            f"scene.water: lbs needs a scene of {LBS_EXTENT:g} m each way; this one is {g.w:.0f} x {g.h:.0f} m"
        )
    ground, river, banks, level = _river(g, _terrain(g), wide=lbs)
    lakes, shore = ((), np.zeros(ground.shape, bool))
    if lbs:
        ground, lake, shore, lakes = _lake(g, ground)
        river |= lake
    cls = np.full(ground.shape, GROUND, np.uint8)
    cls[river] = WATER
    solid = ground.copy()
    _add_bridge(g, ground, solid, cls, banks, level)
    # buildings: flat and gabled, away from the water and the slope band
    free = ~banks & ~shore
    _add_buildings(g, rng, ground, solid, cls, free)
    canopy = _canopy(g, rng, ground, solid, cls, free)
    band = river_band(g.n_min, g.h, wide=lbs)
    return Scene(g.e_min, g.n_min, cell, ground, solid, canopy, cls, river=band, lakes=lakes)


@dataclass(frozen=True)
class _Lattice:
    """The cells of a scene: their centres (E, N: local metres) and the extent's corner and size."""

    e_min: float
    e_max: float
    n_min: float
    n_max: float
    cell: float
    E: np.ndarray
    N: np.ndarray

    @property
    def w(self) -> float:
        return self.e_max - self.e_min

    @property
    def h(self) -> float:
        return self.n_max - self.n_min

    @classmethod
    def of(cls, extent: tuple[float, float, float, float], cell: float) -> _Lattice:
        e_min, e_max, n_min, n_max = extent
        nx = int(np.ceil((e_max - e_min) / cell))
        ny = int(np.ceil((n_max - n_min) / cell))
        e = e_min + (np.arange(nx) + 0.5) * cell
        n = n_min + (np.arange(ny) + 0.5) * cell
        E, N = np.meshgrid(e, n)
        return cls(e_min, e_max, n_min, n_max, cell, E, N)

    def window(self, cx: float, cy: float, rx: float, ry: float) -> tuple[slice, slice]:
        """The rows and columns around the box of half-sides *rx*, *ry* centred on (*cx*, *cy*)."""
        ny, nx = self.E.shape
        e_min, n_min, cell = self.e_min, self.n_min, self.cell
        i0, i1 = int(max(0, (cx - rx - e_min) / cell)), int(min(nx, (cx + rx - e_min) / cell + 2))
        j0, j1 = int(max(0, (cy - ry - n_min) / cell)), int(min(ny, (cy + ry - n_min) / cell + 2))
        return slice(j0, j1), slice(i0, i1)


def _terrain(g: _Lattice) -> np.ndarray:
    """The bare earth before the river: hills, rolling relief, a 30-degree slope and a terrace."""
    E, N, e_min, n_min, w = g.E, g.N, g.e_min, g.n_min, g.w
    u = (E - e_min) / w  # 0..1 across the scene
    v = (N - n_min) / g.h
    # smooth hills (amplitude a few metres) on a gentle regional slope
    ground = 4.0 * np.sin(2 * np.pi * u * 1.3 + 0.4) * np.cos(2 * np.pi * v * 0.9) + 0.01 * (E - e_min)
    ground += 3.0 * np.exp(-(((u - 0.75) / 0.12) ** 2 + ((v - 0.7) / 0.15) ** 2))
    # rolling relief of 60-90 m wavelength (slopes up to about 10 degrees): what makes horizontal
    # strip offsets observable, as real terrain does
    ground += 1.5 * np.sin(2 * np.pi * (E - e_min) / 70.0) * np.sin(2 * np.pi * (N - n_min) / 90.0 + 0.7)
    # a steep 30-degree slope rising eastwards over a 12 m band
    band = np.clip((E - (e_min + 0.15 * w)) / 12.0, 0.0, 1.0)
    ground += band * 12.0 * np.tan(np.radians(30.0))
    # a terrace: a 3 m step (breakline) along a north-south line in the west
    ground += np.where(E > e_min + 0.3 * w, 3.0, 0.0) * (v < 0.5)
    return ground


#: The river's water surface falls this much (m per m) eastwards, downstream: 0.3 %, a lowland river's.
RIVER_SLOPE = 0.003


#: ``water: lbs``: the river's width (m), the LBS's smallest hydro-flattened river, 100 ft (30.48 m), and more.
LBS_RIVER_WIDTH = 31.0
#: ``water: lbs``: the lake's radius (m): 8,495 m², the LBS's smallest hydro-flattened pond, 2 acres
#: (8,094 m²), and more.
LBS_LAKE_RADIUS = 52.0
#: ``water: lbs``: the smallest scene (m each way) that holds the river, the lake north of it and their banks.
LBS_EXTENT = 350.0


def river_band(n_min: float, height: float, wide: bool = False) -> tuple[float, float]:
    """The river's centre line (local northing, m) and half its width in a scene from *n_min*, *height* m high
    (*wide*: ``water: lbs``): its shores run east-west at centre - half and centre + half."""
    return n_min + 0.55 * height, LBS_RIVER_WIDTH / 2 if wide else max(6.0, 0.03 * height)


def _river(
    g: _Lattice, ground: np.ndarray, wide: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A river along the east-west direction at 55 % of the height, its water falling eastwards by
    ``RIVER_SLOPE`` (level across): the ground with it, the river's and its banks' cells, the water level
    of each cell's column."""
    h = g.h
    centre, half = river_band(g.n_min, h, wide)
    river = np.abs(g.N - centre) < half
    banks = np.abs(g.N - centre) < half + max(4.0, 0.02 * h)
    level = float(np.percentile(ground[banks], 5)) - 1.0 - RIVER_SLOPE * (g.E - (g.e_min + 0.5 * g.w))
    ground = np.where(banks & ~river, np.minimum(ground, level + 1.5), ground)
    ground = np.where(river, level, ground)
    return ground, river, banks, level


def _lake(g: _Lattice, ground: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
    """A round lake of :data:`LBS_LAKE_RADIUS` at 40 % of the width, 20 m north of the river's banks, level 1 m
    below the 5th percentile of its shore, with banks at most 1.5 m above it within 4 m: the ground with it, the
    lake's and its shore's cells, and the lake (centre e, n, radius, level)."""
    centre, half = river_band(g.n_min, g.h, wide=True)
    e, n = g.e_min + 0.4 * g.w, centre + half + max(4.0, 0.02 * g.h) + 20.0 + LBS_LAKE_RADIUS
    r = np.hypot(g.E - e, g.N - n)
    lake, shore = r < LBS_LAKE_RADIUS, r < LBS_LAKE_RADIUS + 4.0
    level = float(np.percentile(ground[shore & ~lake], 5)) - 1.0
    ground = np.where(shore & ~lake, np.minimum(ground, level + 1.5), ground)
    return np.where(lake, level, ground), lake, shore, ((e, n, LBS_LAKE_RADIUS, level),)


def _add_bridge(
    g: _Lattice, ground: np.ndarray, solid: np.ndarray, cls: np.ndarray, banks: np.ndarray, level: np.ndarray
):
    """A 6 m deck across the river's banks, joining the ground at both ends (in *solid* and *cls*, in place).

    The deck is level across and straight from the ground just south of the
    banks to the ground just north of them (its approaches), and at least
    4 m above the water.
    """
    across = np.abs(g.E - (g.e_min + 0.62 * g.w)) < 3.0
    bridge = banks & across
    if not bridge.any():
        return
    rows = np.flatnonzero(bridge.any(axis=1))
    south, north = max(rows[0] - 1, 0), min(rows[-1] + 1, len(ground) - 1)
    z_s, z_n = float(ground[south][across[south]].mean()), float(ground[north][across[north]].mean())
    along = (g.N[:, :1] - g.N[south, 0]) / max(g.N[north, 0] - g.N[south, 0], g.cell)
    deck = np.maximum(z_s + (z_n - z_s) * along, level + 4.0)
    solid[bridge] = deck[bridge]
    cls[bridge] = BRIDGE


def _add_buildings(
    g: _Lattice, rng: np.random.Generator, ground: np.ndarray, solid: np.ndarray, cls: np.ndarray, free: np.ndarray
) -> None:
    """Flat-roofed and gabled buildings on free, open ground (in *solid*, *cls* and *free*, in place)."""
    w, h = g.w, g.h
    for k in range(max(2, int(w * h / 3000))):
        for _ in range(50):
            cx, cy = (
                rng.uniform(g.e_min + 0.1 * w, g.e_max - 0.1 * w),
                rng.uniform(g.n_min + 0.1 * h, g.n_max - 0.1 * h),
            )
            bw, bh = rng.uniform(8, 20), rng.uniform(8, 16)
            win = g.window(cx, cy, bw / 2 + 4, bh / 2 + 4)
            Ew, Nw = g.E[win], g.N[win]
            box = (np.abs(Ew - cx) < bw / 2) & (np.abs(Nw - cy) < bh / 2)
            if box.any() and np.all(free[win]) and np.all(cls[win] == GROUND):
                break
        else:
            continue
        base = float(ground[win][box].max())
        eaves = base + rng.uniform(4, 9)
        if k % 2:  # gabled: ridge along the longer side
            roof = eaves + rng.uniform(2, 4) * (1 - np.abs(Nw - cy) / (bh / 2))
        else:
            roof = np.full(Ew.shape, eaves)
        solid[win] = np.where(box, roof, solid[win])
        cls[win][box] = BUILDING
        free[win] = False


def _canopy(
    g: _Lattice, rng: np.random.Generator, ground: np.ndarray, solid: np.ndarray, cls: np.ndarray, free: np.ndarray
) -> np.ndarray:
    """The solid surface with trees: half-ellipsoid crowns on open ground."""
    ny, nx = g.E.shape
    w, h = g.w, g.h
    canopy = solid.copy()
    for _ in range(int(w * h / 400)):
        cx, cy = rng.uniform(g.e_min, g.e_max), rng.uniform(g.n_min, g.n_max)
        r, top = rng.uniform(2, 5), rng.uniform(6, 16)
        ix, iy = int((cx - g.e_min) / g.cell), int((cy - g.n_min) / g.cell)
        if not (0 <= ix < nx and 0 <= iy < ny) or cls[iy, ix] != GROUND or not free[iy, ix]:
            continue
        win = g.window(cx, cy, r, r)
        d2 = ((g.E[win] - cx) ** 2 + (g.N[win] - cy) ** 2) / r**2
        crown = ground[iy, ix] + top * np.sqrt(np.clip(1 - d2, 0, None))
        inside = (d2 < 1) & (cls[win] == GROUND)
        canopy[win] = np.where(inside, np.maximum(canopy[win], crown), canopy[win])
    return canopy


def cast(
    scene: Scene, surface: np.ndarray, o: np.ndarray, d: np.ndarray, *, t_min: np.ndarray | float = 0.0
) -> np.ndarray:
    """Distance along each ray (origin ``o``, unit direction ``d``, local ENU) to *surface*; NaN for a miss.

    March in steps of one metre horizontally (and at most 2 m vertically)
    between the heights of the surface's extremes, then bisect the step in
    which the ray goes below the surface to 1e-7 m.  A feature thinner than
    the step that a ray only grazes can be missed; the truth is whatever the
    ray hits, so this never makes the truth inconsistent.
    """
    zmax, zmin = float(np.nanmax(surface)) + 0.1, float(np.nanmin(surface)) - 0.1
    down = -d[:, 2]
    ok = down > 1e-6
    down = np.where(ok, down, 1.0)
    t_lo = np.maximum((o[:, 2] - zmax) / down, t_min)
    t_hi = (o[:, 2] - zmin) / down
    horiz = np.hypot(d[:, 0], d[:, 1])
    step = np.minimum(1.0 / np.maximum(horiz, 1e-9), 2.0 / down)
    result = np.full(len(o), np.nan)

    def g(idx, t):
        p = o[idx] + d[idx] * t[:, None]
        return p[:, 2] - scene.sample(surface, p[:, 0], p[:, 1])

    idx = np.flatnonzero(ok & (t_hi > t_lo))
    a = t_lo[idx]
    ga = g(idx, a)
    alive = np.isfinite(ga)
    hit_now = alive & (ga <= 0)  # starts below: the origin is inside (only with t_min)
    result[idx[hit_now]] = a[hit_now]
    idx, a = idx[alive & ~hit_now], a[alive & ~hit_now]
    lo_list, hi_list, id_list = [], [], []
    while len(idx):
        b = np.minimum(a + step[idx], t_hi[idx])
        gb = g(idx, b)
        crossed = np.isfinite(gb) & (gb <= 0)
        lo_list.append(a[crossed])
        hi_list.append(b[crossed])
        id_list.append(idx[crossed])
        go_on = ~crossed & np.isfinite(gb) & (b < t_hi[idx])
        idx, a = idx[go_on], b[go_on]
    if not id_list:
        return result
    lo, hi, ids = np.concatenate(lo_list), np.concatenate(hi_list), np.concatenate(id_list)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        below = g(ids, mid) <= 0
        hi = np.where(below, mid, hi)
        lo = np.where(below, lo, mid)
        if np.max(hi - lo, initial=0.0) < 1e-7:
            break
    result[ids] = 0.5 * (lo + hi)
    return result
