"""The run service's cells and windows: exact cases of the two conventions a grid's axis may follow.

An ascending axis holds ``[k c, (k + 1) c)`` in its cell ``k``; a descending
one (a north-up raster's rows) holds ``((k - 1) c, k c]`` in its cell ``k``.
A tile of side ``s = t c`` holds ``[i s, (i + 1) s)``: its own cells are
those its points fall in, its window the cells that meet the open span of
the tile grown by its buffer.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidar.grid import Grid, cell_of
from lidar.gridrun.kernel import Axis, Frame
from lidar.gridrun.service import _x_by_y
from lidar.gridrun.windows import home_tiles, occupied_box, tile_cells
from pipeline.tiling import Layout

UP, DOWN = Axis(0), Axis(1, down=True)


def test_a_coordinate_on_a_cell_edge_falls_where_its_convention_says():
    # x = 4 m on cells of 2 m: cell 2 ([4, 6)) ascending; cell 2 ((2, 4]) descending, counted from the top
    assert UP.index(np.array([4.0, 5.999, 6.0]), first=0, cell=2.0).tolist() == [2, 2, 3]
    assert DOWN.index(np.array([4.0, 2.001, 2.0]), first=10, cell=2.0).tolist() == [8, 8, 9]  # tops 2, 2, 1


def test_own_cells_and_window_of_a_tile():
    # tile 3 of 10 cells: [30 c, 40 c); a buffer of 2 cells
    assert UP.own(3, 10) == (30, 39) and UP.window(3, 10, 2) == (28, 41)
    assert DOWN.own(3, 10) == (30, 40)  # a point on the tile's lower edge lies in the cell below it (top 30)
    assert DOWN.window(3, 10, 2) == (29, 42)  # cells meeting (28 c, 42 c): tops 29 to 42


def test_labels_to_array_slices_cut_to_the_arrays():
    assert UP.span(first=5, count=10, lo=3, hi=7) == slice(0, 3)  # labels 5..7 of 5..14
    assert UP.span(first=5, count=10, lo=20, hi=30) == slice(10, 10)  # none
    assert DOWN.span(first=14, count=10, lo=3, hi=7) == slice(7, 10)  # tops 7..5 of 14..5
    assert DOWN.span(first=14, count=10, lo=12, hi=20) == slice(0, 3)  # tops 14..12


@pytest.mark.parametrize("axis", [UP, DOWN])
def test_the_tiles_whose_own_cells_meet_the_arrays(axis):
    first, count, tile = (7, 25, 10) if not axis.down else (31, 25, 10)
    labels = set(range(first, first + count)) if not axis.down else set(range(first - count + 1, first + 1))
    found = [
        i for i in axis.tiles(first, count, tile) if labels & set(range(axis.own(i, tile)[0], axis.own(i, tile)[1] + 1))
    ]
    assert found and set(found) == {
        i for i in range(-5, 10) if labels & set(range(axis.own(i, tile)[0], axis.own(i, tile)[1] + 1))
    }


def test_a_north_up_frame_is_the_grid_of_the_box():
    """Frame.covering with a descending row axis is lidar.grid.Grid.covering: same corner, shape and cells."""
    box = (440_000.3, 4_474_000.7, 440_123.9, 4_474_077.2)
    for cell in (1.0, 2.0, 5.0):
        frame = Frame.covering((DOWN, UP), box, cell)
        grid = Grid.covering(*box, cell)
        assert (frame.corner(1), frame.corner(0), frame.shape) == (grid.xmin, grid.ymax, (grid.rows, grid.cols))
        rng = np.random.default_rng(4)
        xyz = np.column_stack((rng.uniform(box[0], box[2], 500), rng.uniform(box[1], box[3], 500), np.zeros(500)))
        xyz[:3, 1] = np.floor(xyz[:3, 1] / cell) * cell  # on cell edges
        row, col = cell_of(xyz, grid)
        np.testing.assert_array_equal(frame.flat(xyz), row * grid.cols + col)


def test_a_frame_cut_keeps_its_cells_labels():
    frame = Frame(2.0, (DOWN, UP), (50, -3), (20, 30))
    cut = frame.cut(slice(4, 9), slice(10, 12))
    assert cut.first == (46, 7) and cut.shape == (5, 2) and cut.corner(0) == 92.0 and cut.corner(1) == 14.0
    xyz = np.array([[15.0, 91.5, 0.0], [14.0, 92.0, 0.0], [13.9, 92.0, 0.0]])  # in, in (top edge), west of it
    assert cut.flat(xyz).tolist() == [0, 0, -1]


def test_home_tiles_are_the_engine_layouts():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(-250, 730, 2000), rng.uniform(80, 910, 2000)
    x[:4], y[:4] = 0.0, 100.0  # on tile edges
    layout = Layout.of((x.min(), y.min(), x.max(), y.max()), 100.0, 0.0)
    where = layout.locate(x, y)
    tiles = {(t.row + layout.r0, t.col + layout.c0): t.index for t in layout.tiles}
    seen = 0
    for key, points in home_tiles(x, y, 100.0):
        assert (where[points] == tiles[key]).all()
        seen += len(points)
    assert seen == len(x)


def test_tiles_in_whole_cells_and_the_occupied_box():
    assert tile_cells(500.0, 146.0, 1.0) == (500, 146) and tile_cells(500.0, 146.5, 1.0) == (500, 147)
    assert tile_cells(500.0, 146.0, 3.0) is None and tile_cells(None, 146.0, 1.0) is None
    occupied = np.zeros((6, 8), bool)
    occupied[2, 3] = occupied[4, 6] = True
    assert occupied_box(occupied) == (slice(2, 5), slice(3, 7)) and occupied_box(occupied & False) is None


def test_grids_are_said_x_by_y_whichever_axis_their_arrays_run_first():
    """Ground's rows-first arrays and water's x-first ones of one 512 m x 384 m survey are both '512 x 384'
    in the log."""
    box = (0.0, 0.0, 511.5, 383.5)
    rows_first = Frame.covering((Axis(1), Axis(0)), box, 1.0)
    x_first = Frame.covering((Axis(0), Axis(1)), box, 1.0)
    assert rows_first.shape == (384, 512) and x_first.shape == (512, 384)
    assert _x_by_y(rows_first) == _x_by_y(x_first) == (512, 384)
