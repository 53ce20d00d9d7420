"""The main job's DTM against the simulator's truth, beside a perfect DTM scored the same way (issue 16).

``accuracy`` compares ``configs/flight.yaml``'s ``dtm.tif`` with the
sample's ``truth/terrain.tif`` (1 m cells) resampled bilinearly onto the
DTM's cells.  This script asks what that comparison can show:

- **ours**: the job's DTM, exactly as ``accuracy`` scores it;
- **perfect**: the simulator's true terrain computed at the centre of each
  DTM cell (the sample regenerated with ``truth_resolution`` set to the
  DTM's cell, same seed, in a temporary folder), on the DTM's cells that
  have a value, scored against the same 1 m truth.  It is the DTM no
  classification or interpolation can beat: what it misses is the 1 m
  truth raster's own blur across the river's banks, which the scene
  draws as vertical walls 5 to 14 m high.

Each is split into where the cells more than 1 m off lie: the bridge deck
(land cover 17), cells where the truth's relief within the 3 x 3 DTM cells
around is 2 m or more (the banks, walls and terrace), building footprints,
and the rest (with how much of it lies within 10 m of the grid's edge);
then both split as ``accuracy`` splits them (``by_relief``): where the
truth varies by under 2 m over the 3 x 3 cells around a cell, and where
it does not.

Run from the repository root after ``pipeline run configs/flight.yaml``::

    python benchmarks/flight_truth.py [--out out/flight-ldmrs]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyogrio.raw
import rasterio
import shapely

from lidar.water_bodies import breakline_points
from stages.accuracy.vertical import (
    TRUTH_STEEP_M,
    land_cover_on_dtm_cells,
    truth_accuracy,
    truth_on_dtm_cells,
    truth_relief,
)

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "data_samples" / "flight_ldmrs" / "truth"


def perfect_dtm(dtm: np.ndarray, dtm_path: Path, workdir: Path) -> np.ndarray:
    """The true terrain at the centres of the DTM's cells (NaN where *dtm*, read from *dtm_path*, has none).

    The fine truth's cells are the DTM's, so ``accuracy``'s own bilinear resampling onto them returns its
    values unchanged.
    """
    with rasterio.open(dtm_path) as src:
        resolution, transform = src.res[0], src.transform
    command = [
        str(Path(sys.executable).parent / "pipeline"),
        "simulate",
        str(ROOT / "configs" / "simulate.yaml"),
        "--only",
        "flight_ldmrs",
        "--out",
        str(workdir),
        "--set",
        f"surveys.flight_ldmrs.truth_resolution={resolution}",
    ]
    subprocess.run(command, check=True, capture_output=True)
    fine = workdir / "flight_ldmrs" / "truth" / "terrain.tif"
    with rasterio.open(fine) as src:  # the fine truth's cells must be the DTM's (same size, whole-cell offset)
        offset = np.array([(src.transform.c - transform.c), (src.transform.f - transform.f)]) / resolution
        if src.res[0] != resolution or not np.allclose(offset, np.round(offset), atol=1e-6):
            raise SystemExit(f"{fine}: its cells are not the DTM's ({src.transform} against {transform})")
    _, values = truth_on_dtm_cells(dtm_path, fine)
    return np.where(np.isfinite(dtm), values, np.nan)


def where_off(dtm: np.ndarray, truth: np.ndarray, land_cover: np.ndarray, cell: float) -> dict:
    """Cells more than 1 m off, split by where they lie (counts, and per cent of the cells compared)."""
    error = dtm - truth
    compared = np.isfinite(error)
    off = compared & (np.abs(error) > 1.0)
    with np.errstate(invalid="ignore"):
        steep = truth_relief(truth) >= TRUTH_STEEP_M
    rows, cols = np.indices(truth.shape)
    edge = np.minimum.reduce([rows, cols, truth.shape[0] - 1 - rows, truth.shape[1] - 1 - cols])
    parts = {
        "bridge deck": land_cover == 17,
        "relief >= 2 m": steep,
        "building footprints": land_cover == 6,
    }
    left = np.ones(truth.shape, dtype=bool)
    out = {"cells": int(compared.sum()), "off_1m": int(off.sum())}
    for name, mask in parts.items():
        mask = mask & left
        left &= ~mask
        out[name] = int((off & mask).sum())
    out["elsewhere"] = int((off & left).sum())
    out["near the edge"] = int((off & left & (edge * cell < 10.0)).sum())
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "flight-ldmrs", help="the job's output folder")
    args = parser.parse_args(argv)
    dtm_path = args.out / "dtm.tif"
    if not dtm_path.is_file():
        print(f"{dtm_path}: not found; run `pipeline run configs/flight.yaml` first", file=sys.stderr)
        return 2

    dtm, truth = truth_on_dtm_cells(dtm_path, SAMPLE / "terrain.tif")
    land_cover = land_cover_on_dtm_cells(dtm_path, SAMPLE / "land_cover.tif")
    with tempfile.TemporaryDirectory() as tmp:
        perfect = perfect_dtm(dtm, dtm_path, Path(tmp))

    with rasterio.open(dtm_path) as src:
        cell = src.res[0]
    print("| DTM | cells | > 1 m off | bridge deck | relief >= 2 m | buildings | elsewhere (of it near the edge) |")
    print("|---|---|---|---|---|---|---|")
    for name, grid in (("ours", dtm), ("perfect", perfect)):
        r = where_off(grid, truth, land_cover, cell)
        share = 100.0 * r["off_1m"] / r["cells"]
        print(
            f"| {name} | {r['cells']:,} | {r['off_1m']:,} ({share:.2f} %) | {r['bridge deck']:,} | "
            f"{r['relief >= 2 m']:,} | {r['building footprints']:,} | {r['elsewhere']:,} "
            f"({r['near the edge']:,}) |"
        )
    print()
    print("| DTM | truth relief < 2 m: cells, > 1 m off | truth relief >= 2 m: cells, > 1 m off |")
    print("|---|---|---|")
    for name, grid in (("ours", dtm), ("perfect", perfect)):
        flat, steep = (truth_accuracy(grid, truth)["by_relief"][k] for k in ("under_2m", "2m_or_more"))
        print(
            f"| {name} | {flat['n']:,}, {100 * flat['off_1m']:.2f} % | {steep['n']:,}, {100 * steep['off_1m']:.2f} % |"
        )
    print()
    print(by_cover_table(dtm, perfect, truth, land_cover))
    if (args.out / "breaklines.gpkg").is_file():
        print()
        print(breakline_offsets(args.out / "breaklines.gpkg", SAMPLE / "breaklines.gpkg"))
    return 0


def breakline_offsets(ours: Path, truth: Path) -> str:
    """One line: how far our breaklines' vertices lie from the truth's shores, across (m) and in height (m).

    Across: each vertex's (ours densified to 0.5 m) distance to the nearest true shore; in height:
    its z minus the true shore's z at the same easting (the simulated river
    runs east-west), over the vertices within 2 m of a true shore.
    """

    def lines(path: Path) -> list[np.ndarray]:
        out = []
        for wkb in pyogrio.raw.read(str(path))[2]:
            g = shapely.from_wkb(bytes(wkb))
            out += [np.asarray(p.coords) for p in getattr(g, "geoms", [g])]
        return out

    shores = lines(truth)
    xyz = breakline_points(lines(ours), 0.5)  # a vertex every 0.5 m, as the truth's
    d = np.stack([shapely.distance(shapely.LineString(t[:, :2]), shapely.points(xyz[:, :2])) for t in shores])
    nearest, across = np.argmin(d, axis=0), d.min(axis=0)
    dz = -xyz[:, 2]
    for k, shore in enumerate(shores):  # the true shore's z at each vertex's easting, shore by shore
        on = nearest == k
        dz[on] += np.interp(xyz[on, 0], *_by_x(shore))
    close = across < 2.0
    return (
        f"Breaklines (a vertex every 0.5 m): {len(xyz):,} vertices; across from the true shore median {np.median(across):.2f} m, "
        f"95th percentile {np.percentile(across, 95):.2f} m, max {across.max():.2f} m; height above the true "
        f"shore (the {close.sum():,} within 2 m) median {-np.median(dz[close]):+.3f} m, "
        f"95th percentile of |dz| {np.percentile(np.abs(dz[close]), 95):.3f} m."
    )


def _by_x(line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(line[:, 0])
    return line[order, 0], line[order, 2]


#: The truth's land cover codes (truth/land_cover.tif) the cover table shows.
COVERS = {2: "open ground", 5: "under trees", 6: "building footprint", 9: "water", 17: "bridge deck"}


def by_cover_table(dtm: np.ndarray, perfect: np.ndarray, truth: np.ndarray, land_cover: np.ndarray) -> str:
    """Markdown: RMS against the truth by land cover, on the cells where the truth is not steep (issue 34's
    targets: bridge deck within 0.3 m, water within 0.15 m and flat), ours beside the perfect DTM; and the
    spread (standard deviation) of each DTM's values over the water cells, which hydro-flattening makes 0
    per water body."""
    level = truth_relief(truth) < TRUTH_STEEP_M
    lines = [
        "| land cover (truth relief < 2 m) | cells | ours RMS m | perfect RMS m | ours / perfect |",
        "|---|---|---|---|---|",
    ]
    for code, name in COVERS.items():
        cells = level & (land_cover == code) & np.isfinite(dtm) & np.isfinite(perfect) & np.isfinite(truth)
        if not cells.any():
            continue
        ours = float(np.sqrt(np.mean((dtm[cells] - truth[cells]) ** 2)))
        best = float(np.sqrt(np.mean((perfect[cells] - truth[cells]) ** 2)))
        lines.append(
            f"| {code} {name} | {int(cells.sum()):,} | {ours:.3f} | {best:.3f} | {ours / max(best, 1e-9):.1f} |"
        )
    water = level & (land_cover == 9) & np.isfinite(dtm) & np.isfinite(perfect)
    if water.any():
        lines.append("")
        lines.append(
            f"Water cells' spread (std of the DTM over them): ours {np.std(dtm[water]):.3f} m, "
            f"perfect {np.std(perfect[water]):.3f} m, truth {np.std(truth[water]):.3f} m."
        )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
