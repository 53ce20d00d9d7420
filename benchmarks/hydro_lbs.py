"""Hydro-flattening at the USGS Lidar Base Specification's sizes: a simulated survey with ``scene.water: lbs``.

The main sample's scene (160 m x 150 m) holds a river 12 m wide; the LBS
flattens rivers of 100 ft (30.5 m) or more and ponds of 2 acres (8,094 m²)
or more.  This script simulates a survey whose scene has both (a river
31 m wide falling 0.3 % eastwards with its bridge, a round lake of
8,495 m²; docs/SIMULATOR.md, ``scene.water``), runs the LAS job on it, and
prints what issue 34 asks of the flight sample, on these bodies:

- the DTM against the true terrain by the truth's land cover (cells where
  the truth's relief is under 2 m), beside the perfect DTM (the truth
  at the DTM's cells, :func:`benchmarks.flight_truth.perfect_dtm`'s way);
- the water bodies of ``water.gpkg`` (area, flattened, lake or river);
- ``breaklines.gpkg`` against the true shores (``truth/breaklines.gpkg``);
- the acceptance's hydro-flattening and bridge rows.

The simulator does not import the pipeline's stages.  Run from the
repository root (about 2 minutes on 2 cores)::

    python benchmarks/hydro_lbs.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyogrio.raw

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.flight_truth import breakline_offsets, by_cover_table  # noqa: E402
from stages.accuracy.vertical import land_cover_on_dtm_cells, truth_on_dtm_cells  # noqa: E402

#: The survey: the RIEGL system of the flight_lmsq sample, three lines at 250 m over a 420 m scene.
SURVEY = """\
seed: 20261204
formats: [las]
origin: {lat: 40.4168, lon: -3.7038, h: 650.0}
start_utc: "2026-06-22T09:30:00Z"
leap_seconds: 18
scanner: {preset: q140, scan_rate_hz: 40}
navigation: {preset: pos-av-410, gnss_rate_hz: 20, ins_rate_hz: 50}
flight: {altitude_m: 250, speed_ms: 40, lines: 3, sidelap: 0.35, line_length_m: 420, cross_line: false,
         lead_in_m: 30}
scene: {water: lbs}
checkpoints: 30
truth_resolution: %(resolution)s
"""

#: The job: configs/las.yaml's stages with the truth to score against.
JOB = """\
name: hydro-lbs
input: {format: las, paths: [%(sim)s/las/points.laz]}
crs: auto-utm
output: %(out)s
cache: %(cache)s
executor: {kind: local, workers: 2}
stages:
  rasterize: {resolution: 0.5}
  accuracy:
    checkpoints: %(sim)s/checkpoints.csv
    truth_dtm: %(sim)s/truth/terrain.tif
    truth_land_cover: %(sim)s/truth/land_cover.tif
  export_las: {compress: true}
"""


def simulate(folder: Path, resolution: float) -> Path:
    """The survey simulated into *folder* with truth rasters of *resolution* m; the folder."""
    config = folder.with_suffix(".yaml")
    config.write_text(SURVEY % {"resolution": resolution})
    pipeline = str(Path(sys.executable).parent / "pipeline")
    subprocess.run([pipeline, "simulate", str(config), "--out", str(folder)], check=True, capture_output=True)
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        sim = simulate(work / "sim", 1.0)
        fine = simulate(work / "fine", 0.5)  # the truth at the DTM's cells (0.5 m): the perfect DTM
        job = work / "job.yaml"
        job.write_text(JOB % {"sim": sim, "out": work / "out", "cache": work / "cache"})
        pipeline = str(Path(sys.executable).parent / "pipeline")
        run = subprocess.run([pipeline, "run", str(job), "-q"], capture_output=True, text=True)
        if run.returncode:
            print(run.stderr, file=sys.stderr)
            return run.returncode
        report(work / "out", sim / "truth", fine / "truth")
    return 0


def report(out: Path, truth_dir: Path, fine_dir: Path) -> None:
    """Print the figures of the run in *out* against the truth in *truth_dir* (and *fine_dir*'s, at its cells)."""
    dtm, truth = truth_on_dtm_cells(out / "dtm.tif", truth_dir / "terrain.tif")
    _, perfect = truth_on_dtm_cells(out / "dtm.tif", fine_dir / "terrain.tif")
    perfect = np.where(np.isfinite(dtm), perfect, np.nan)
    land_cover = land_cover_on_dtm_cells(out / "dtm.tif", truth_dir / "land_cover.tif")
    print(by_cover_table(dtm, perfect, truth, land_cover))
    print()
    meta, _, _, values = pyogrio.raw.read(str(out / "water.gpkg"))
    fields = dict(zip(meta["fields"], values, strict=True))
    print("| water body | area m² | flattened | level m | spread m |")
    print("|---|---|---|---|---|")
    for i in range(len(fields["level"])):
        print(
            f"| {i + 1} | {fields['area_m2'][i]:,.0f} | {bool(fields['flattened'][i])} | {fields['level'][i]:.3f} "
            f"| {fields['spread_m'][i]:.3f} |"
        )
    print()
    print(breakline_offsets(out / "breaklines.gpkg", truth_dir / "breaklines.gpkg"))
    checks = json.loads((out / "qc" / "acceptance.json").read_text())["checks"]
    rows = [c for c in checks if c.get("measure") in ("unflat_water", "rising_rivers", "decks_in_dem")]
    print("; ".join(f"{c['measure']} {c['measured']} ({c['status']})" for c in rows))


if __name__ == "__main__":
    raise SystemExit(main())
