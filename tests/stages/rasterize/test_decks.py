"""The DTM under a bridge deck: interpolated across the deck from the terrain either side (USGS LBS)."""

from __future__ import annotations

import laspy
import numpy as np

from stages.rasterize.decks import across_decks, deck_footprint
from stages.rasterize.params import RasterizeParams
from stages.rasterize.tile_rasters import has_decks, reach


def test_a_deck_strip_takes_the_plane_of_the_terrain_either_side():
    rows, cols = np.mgrid[0:60, 0:40].astype(float)
    plane = 100.0 + 0.3 * cols - 0.05 * rows  # tilted across the deck and along it
    dtm = plane.copy()
    deck = np.zeros(dtm.shape, bool)
    deck[10:50, 18:24] = True  # a deck along the rows, 6 cells wide
    dtm[deck] = 130.0  # what a TIN joining the approaches might leave
    dtm[30, 17] = np.nan  # a cell beside it with no value: the next one out is used
    out = across_decks(dtm, deck, max_cells=20)
    assert np.allclose(out[deck], plane[deck], atol=1e-9)
    assert np.array_equal(out[~deck], dtm[~deck], equal_nan=True)  # nothing off the deck changes


def test_a_deck_across_the_grid_diagonal_is_interpolated_across_it():
    rows, cols = np.mgrid[0:80, 0:80].astype(float)
    plane = 10.0 + 0.2 * (rows - cols)  # rises across a deck laid along the diagonal
    deck = np.abs(rows - cols) <= 3
    deck &= (rows > 10) & (rows < 70)
    dtm = np.where(deck, 50.0, plane)
    out = across_decks(dtm, deck, max_cells=20)
    # the straight line between the first cells off the deck: the plane, to within one cell's rounding
    assert np.max(np.abs(out[deck] - plane[deck])) < 0.2 * 1.5


def test_the_footprint_closes_the_gaps_between_deck_points():
    count = np.zeros((20, 20), int)
    count[5:15:2, 5:12:2] = 1  # points every other cell
    feet = deck_footprint(count)
    assert feet[5:14, 5:12].all()  # closed between them
    assert feet[4, 4] and not feet[2, 2]  # one cell around, no more


def test_cells_near_a_decks_ends_take_the_terrain_beside_it_not_the_approaches():
    """The river's banks either side at 0 m, the approaches beyond the deck's ends 10 m up (LBS: lateral terrain)."""
    dtm = np.zeros((60, 40))
    dtm[:10], dtm[50:] = 10.0, 10.0  # the ground beyond both ends, the deck's level
    deck = np.zeros(dtm.shape, bool)
    deck[10:50, 18:24] = True
    dtm[deck] = 7.0  # a TIN from the approaches down to the banks
    out = across_decks(dtm, deck, max_cells=20)
    assert np.array_equal(out[deck], np.zeros(int(deck.sum())))  # corners included: no crossing cuts them


def test_a_tile_with_the_margin_gives_the_whole_grids_cells():
    """Two decks, one diagonal, cut by a tile's window: the core's cells as in the whole grid."""
    rng = np.random.default_rng(4)
    rows, cols = np.mgrid[0:120, 0:120].astype(float)
    dtm = 50.0 + 0.1 * cols + rng.normal(0, 0.05, rows.shape)
    count = np.zeros(dtm.shape, int)
    count[20:100, 30:37] = rng.integers(0, 2, (80, 7))  # sparse deck points: gaps to close
    diagonal = (np.abs(rows - cols - 10) <= 3) & (rows > 40) & (rows < 110)
    count[diagonal] = 1
    m = 25
    whole = across_decks(dtm, deck_footprint(count), m)
    r0, r1, c0, c1 = 50, 80, 31, 70  # the core
    # the footprint made on the tile's points with their buffer (wider: a closing reaches 4 cells), cut to the margin
    b = m + 5
    feet = deck_footprint(count[r0 - b : r1 + b, c0 - b : c1 + b])[5:-5, 5:-5]
    tile = across_decks(dtm[r0 - m : r1 + m, c0 - m : c1 + m], feet, m)
    assert np.array_equal(tile[m:-m, m:-m], whole[r0:r1, c0:c1])
    assert not np.array_equal(whole[r0:r1, c0:c1], dtm[r0:r1, c0:c1])  # the core holds deck cells


def _las(path, classes, compress=False, point_format=6):
    las = laspy.LasData(laspy.LasHeader(point_format=point_format, version="1.4" if point_format >= 6 else "1.2"))
    n = len(classes)
    las.x, las.y, las.z = np.arange(n, dtype=float), np.zeros(n), np.zeros(n)
    las.classification = np.asarray(classes, np.uint8)
    las.write(str(path), do_compress=compress)
    return path


def test_the_deck_margin_is_kept_only_where_there_are_deck_points(tmp_path):
    assert has_decks(_las(tmp_path / "deck.las", [2] * 2500 + [17] + [2] * 10), chunk=1000)  # in the last chunk
    assert not has_decks(_las(tmp_path / "none.las", [2, 6, 9, 1, 20]))
    assert has_decks(_las(tmp_path / "none.laz", [2, 6], compress=True))  # compressed: cannot tell, keep it
    # LAS 1.2 point format 3: the class in the five low bits of a byte it shares with three flags
    las12 = _las(tmp_path / "f3.las", [2, 17, 1], point_format=3)
    assert has_decks(las12) and not has_decks(_las(tmp_path / "f3_none.las", [2, 1, 9, 31], point_format=3))
    p = RasterizeParams(nodata_distance=10.0, resolution=0.5)
    assert reach(p, decks=True) - reach(p, decks=False) == p.max_deck_width == 40.0
