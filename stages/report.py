"""Stage ``report``: ``report.html``, one self-contained QC page for a person.

Everything is inside the file (images as base64 PNG, CSS inline), so it opens
offline, can be mailed, and is archived with the products.  Content:
counters of every stage (points read, noise, ground), the DTM as colour
relief over hillshade, point density, the flight strips' coverage, class
statistics, strip adjustment (when it ran), and vertical accuracy against
check points (when configured).
"""

from __future__ import annotations

import base64
import html
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import Field

from pipeline import __version__
from pipeline.stage import Stage, StageParams
from stages.io import png_bytes

ASPRS_NAMES = {
    0: "created, never classified",
    1: "unclassified",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low noise",
    9: "water",
    17: "bridge deck",
    18: "high noise",
}
# Colour ramps: (position 0-1, RGB).
TERRAIN = [
    (0.0, (38, 115, 77)),
    (0.3, (134, 179, 89)),
    (0.55, (230, 217, 140)),
    (0.8, (166, 120, 77)),
    (1.0, (245, 245, 245)),
]
VIRIDIS = [
    (0.0, (68, 1, 84)),
    (0.25, (59, 82, 139)),
    (0.5, (33, 145, 140)),
    (0.75, (94, 201, 98)),
    (1.0, (253, 231, 37)),
]
STRIP_COLOURS = np.array(
    [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ],
    dtype=np.float64,
)


class ReportParams(StageParams):
    max_image_size: int = Field(1200, ge=100, description="largest side of the embedded images, pixels")


def colour_ramp(values: np.ndarray, ramp, lo: float, hi: float) -> np.ndarray:
    """Map values to RGB along a ramp; NaN -> white."""
    t = np.clip((values - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
    pos = np.array([p for p, _ in ramp])
    out = np.empty(values.shape + (3,))
    for channel in range(3):
        out[..., channel] = np.interp(t, pos, [c[channel] for _, c in ramp])
    out[~np.isfinite(values)] = 255.0
    return out


def _thin(array: np.ndarray, max_size: int) -> np.ndarray:
    step = max(1, int(np.ceil(max(array.shape[:2]) / max_size)))
    return array[::step, ::step]


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'


def _table(rows: list[tuple[str, object]]) -> str:
    body = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(_fmt(v))}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:,.3f}".rstrip("0").rstrip(".") if abs(value) < 1e6 else f"{value:,.0f}"
    if isinstance(value, int):
        return f"{value:,}"
    return "—" if value is None else str(value)


def relief_image(dtm: np.ndarray, resolution: float, max_size: int) -> tuple[bytes, float, float]:
    """Colour relief blended with hillshade, as PNG; and the elevation range."""
    from stages.grid.terrain import hillshade

    dem = _thin(dtm, max_size)
    res = resolution * dtm.shape[0] / dem.shape[0]
    valid = np.isfinite(dem)
    lo, hi = (float(np.nanmin(dem)), float(np.nanmax(dem))) if valid.any() else (0.0, 1.0)
    colour = colour_ramp(dem, TERRAIN, lo, hi)
    shade = np.nan_to_num(hillshade(np.where(valid, dem, lo), res), nan=180.0)[..., None] / 255.0
    rgb = np.where(valid[..., None], colour * (0.35 + 0.65 * shade), 255.0)
    return png_bytes(rgb.round()), lo, hi


@dataclass
class CloudSummary:
    """What the report shows of the classified points, gathered chunk by chunk."""

    units: object
    strip_grid: np.ndarray  # point_source_id of the last point seen in each DTM cell (-1: none)
    strips: np.ndarray  # every point_source_id met, ascending
    class_counts: np.ndarray  # points per ASPRS class (256 bins)
    points: int


def summarise_cloud(path, *, origin: tuple[float, float], resolution: float, shape: tuple[int, int]) -> CloudSummary:
    """Strip coverage and class counts of a LAS file, read in chunks (memory does not grow with the survey)."""
    import laspy

    from stages.io import cloud_crs
    from stages.units import Units

    rows, cols = shape
    x0, y1 = origin
    strip_grid = np.full((rows, cols), -1, dtype=np.int64)
    seen: set[int] = set()
    counts = np.zeros(256, dtype=np.int64)
    n = 0
    with laspy.open(str(path)) as reader:
        crs = cloud_crs(reader)
        for chunk in reader.chunk_iterator(1_000_000):
            x, y = np.asarray(chunk.x), np.asarray(chunk.y)
            c = np.clip(((x - x0) / resolution).astype(int), 0, cols - 1)
            r = np.clip(((y1 - y) / resolution).astype(int), 0, rows - 1)
            sid = np.asarray(chunk.point_source_id).astype(np.int64)
            strip_grid[r, c] = sid  # in file order: the last point seen wins
            seen.update(int(v) for v in np.unique(sid))
            counts += np.bincount(np.asarray(chunk.classification), minlength=256)
            n += len(chunk)
    return CloudSummary(Units.of(crs), strip_grid, np.array(sorted(seen), dtype=np.int64), counts, n)


def build_report(
    *,
    name: str,
    metrics: dict,
    dtm: np.ndarray,
    density: np.ndarray,
    resolution: float,
    cloud: CloudSummary,
    max_size: int,
) -> str:
    """The report page as an HTML string."""
    parse = metrics.get("parse", {})
    noise = metrics.get("denoise", {})
    ground = metrics.get("classify_ground", {})
    grid = metrics.get("rasterize", {})
    accuracy = metrics.get("accuracy")
    adjust = metrics.get("strip_adjust")
    units = cloud.units
    relief, lo, hi = relief_image(dtm * units.vertical, resolution * units.horizontal, max_size)
    dens = _thin(density, max_size)
    dmax = float(np.nanpercentile(dens, 99)) if np.isfinite(dens).any() else 1.0
    density_png = png_bytes(colour_ramp(dens, VIRIDIS, 0.0, max(dmax, 1.0)).round())
    # Strip coverage: the strip of the last point seen in each cell.
    rows, cols = dtm.shape
    unique = cloud.strips
    has = cloud.strip_grid >= 0
    strip_grid = np.full((rows, cols), -1)
    strip_grid[has] = np.searchsorted(unique, cloud.strip_grid[has])
    strip_rgb = np.full((rows, cols, 3), 255.0)
    has = strip_grid >= 0
    strip_rgb[has] = STRIP_COLOURS[strip_grid[has] % len(STRIP_COLOURS)]
    strip_png = png_bytes(_thin(strip_rgb, max_size).round())
    legend = "".join(
        f'<span class="sw" style="background:rgb{tuple(int(v) for v in STRIP_COLOURS[i % len(STRIP_COLOURS)])}"></span>{int(s)} '
        for i, s in enumerate(unique)
    )
    classes = np.flatnonzero(cloud.class_counts)
    class_rows = "".join(
        f"<tr><td>{int(k)}</td><td>{html.escape(ASPRS_NAMES.get(int(k), 'other'))}</td><td>{int(n):,}</td><td>{100 * n / max(cloud.points, 1):.2f} %</td></tr>"
        for k, n in zip(classes, cloud.class_counts[classes], strict=True)
    )
    geo = metrics.get("georeference")
    summary = [
        ("points read", parse.get("points_read") or (geo or {}).get("points")),
        ("input files", len(parse.get("points_per_file", {})) or None),
        ("CRS", parse.get("crs") or (geo or {}).get("crs")),
        (
            "flight strips (point_source_id)",
            ", ".join(str(s) for s in parse.get("strips", []) or (geo or {}).get("strips", {})) or None,
        ),
        (
            "low noise (7) / high noise (18)",
            f"{noise.get('low_noise', 0):,} / {noise.get('high_noise', 0):,}" if noise else None,
        ),
        ("ground points", ground.get("ground")),
        ("ground fraction", ground.get("ground_fraction")),
        ("ground algorithm", (ground.get("algorithm") or {}).get("name")),
        (
            "DTM grid",
            f"{grid.get('cols')} × {grid.get('rows')} cells at {grid.get('resolution')} m ({grid.get('method')})"
            if grid
            else None,
        ),
        ("units of the products", grid.get("units")),
        (
            "DTM nodata cells",
            f"{grid.get('nodata_cells', 0):,} ({100 * grid.get('nodata_fraction', 0):.2f} %)" if grid else None,
        ),
        ("DTM elevation range", f"{lo:,.2f} – {hi:,.2f} m"),
        ("mean density", f"{grid.get('density_mean')} points per cell" if grid else None),
    ]
    if geo:
        counters = [
            (k.replace("_", " "), v) for k, v in parse.items() if isinstance(v, (int, float)) and k != "gps_week"
        ]
        geo_rows = [
            ("pulses", geo.get("pulses")),
            ("points written", geo.get("points")),
            ("dropped: flown in turns", geo.get("dropped_in_turns")),
            ("dropped: no trajectory (outside it or in a gap)", geo.get("rejected_no_trajectory")),
            ("points per strip", ", ".join(f"{k}: {v:,}" for k, v in geo.get("strips", {}).items())),
            ("frame / CRS", f"{geo.get('frame')} / {geo.get('crs')}"),
            ("attitude convention", geo.get("attitude_convention")),
            ("map transform (largest difference from PROJ, m)",
             f"{geo.get('map_transform')} ({geo.get('map_transform_max_error_m', 0):.1e})" if geo.get("map_transform") else None),
            ("ltp vs exact, largest horizontal / vertical difference (m)",
             f"{geo.get('ltp_vs_exact_max_horizontal_m', 0):.3f} / {geo.get('ltp_vs_exact_max_vertical_m', 0):.3f} "
             f"over {geo.get('ltp_vs_exact_extent_m', 0):,.0f} m (geometry predicts "
             f"{geo.get('ltp_predicted_max_horizontal_m', 0):.3f} / {geo.get('ltp_predicted_max_vertical_m', 0):.3f})"),
        ]  # fmt: skip
        raw_html = (
            f"<h3>Read and skipped (qc/debug.txt)</h3>{_table(counters)}<h3>Georeferencing</h3>{_table(geo_rows)}"
        )
    else:
        raw_html = "<p>Georeferenced input (LAS/LAZ): no raw flight to report on.</p>"
    if adjust:
        adjust_html = _table([(k, v) for k, v in adjust.items() if not isinstance(v, (dict, list))])
    else:
        adjust_html = "<p>Strip adjustment did not run for this survey: discrepancies between strips were not measured or corrected.</p>"
    if accuracy:
        acc_rows = [
            ("check points used", accuracy.get("n")),
            ("RMSEz (m)", accuracy.get("rmse_z")),
            ("mean error (m)", accuracy.get("mean_error")),
            ("NVA at 95 % = 1.96 × RMSEz (m)", accuracy.get("nva_95")),
            ("VVA, 95th percentile (m)", accuracy.get("vva_95")),
            ("outside the DTM", accuracy.get("outside")),
        ]
        accuracy_html = _table(acc_rows)
    else:
        accuracy_html = (
            "<p>No check points were configured (<code>stages.accuracy.checkpoints</code>), so no accuracy figures.</p>"
        )
    made = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>QC report — {html.escape(name)}</title>
<style>
body{{font-family:system-ui,sans-serif;margin:2em auto;max-width:1300px;color:#222;padding:0 1em}}
h1{{margin-bottom:0}} .sub{{color:#666;margin-top:.2em}}
section{{margin:1.5em 0}} table{{border-collapse:collapse}} th,td{{padding:.25em .8em;border-bottom:1px solid #ddd;text-align:left}}
th{{font-weight:600;color:#444}} .maps{{display:flex;flex-wrap:wrap;gap:1.5em}} figure{{margin:0}}
img{{max-width:100%;border:1px solid #ccc;image-rendering:pixelated}} figcaption{{color:#555;font-size:.9em}}
.sw{{display:inline-block;width:1em;height:1em;margin:0 .3em 0 .8em;vertical-align:middle}}
</style></head><body>
<h1>QC report: {html.escape(name)}</h1>
<p class="sub">dtm-pipeline {__version__} · made {made}</p>
<section id="summary"><h2>Summary</h2>{_table(summary)}</section>
<section id="maps"><h2>Maps</h2><div class="maps">
<figure>{_img(relief, "DTM colour relief over hillshade")}<figcaption>DTM, colour relief over hillshade: {lo:,.1f} m (green) to {hi:,.1f} m (white); nodata white.</figcaption></figure>
<figure>{_img(density_png, "point density")}<figcaption>Points per cell (noise excluded): 0 (purple) to {dmax:,.0f} (yellow, 99th percentile).</figcaption></figure>
<figure>{_img(strip_png, "flight strip coverage")}<figcaption>Flight strips (point_source_id):{legend}</figcaption></figure>
</div></section>
<section id="classes"><h2>Classification</h2><table><tr><th>class</th><th>name</th><th>points</th><th>share</th></tr>{class_rows}</table></section>
<section id="raw"><h2>Raw flight</h2>{raw_html}</section>
<section id="strips"><h2>Strip adjustment</h2>{adjust_html}</section>
<section id="accuracy"><h2>Vertical accuracy</h2>{accuracy_html}</section>
</body></html>
"""


class Report(Stage):
    name = "report"
    version = "3"  # 3: points read in chunks; 2: units of the products
    Params = ReportParams
    description = "self-contained QC page (report.html)"
    inputs = ("dtm", "density", "points_classified")
    outputs: ClassVar = {"report": "report.html"}
    products: ClassVar = {"report": "report.html"}
    reads_metrics = True

    def run(self, ctx) -> None:
        from stages.io import read_raster

        dtm, _, _, resolution = read_raster(ctx.inputs["dtm"])
        density, _, _, _ = read_raster(ctx.inputs["density"])
        grid = ctx.upstream_metrics.get("rasterize", {})
        cloud = summarise_cloud(
            ctx.inputs["points_classified"], origin=tuple(grid["origin"]), resolution=resolution, shape=dtm.shape
        )
        page = build_report(
            name=ctx.config.name or "survey",
            metrics=ctx.upstream_metrics,
            dtm=dtm,
            density=density,
            resolution=resolution,
            cloud=cloud,
            max_size=ctx.params.max_image_size,
        )
        ctx.outputs["report"].write_text(page, encoding="utf-8")
        ctx.metrics.update(bytes=len(page), images=page.count("<img"))
