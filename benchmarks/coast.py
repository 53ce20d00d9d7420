"""The simulated coast: is the sea kept out of the ground, and is the land's DTM on the land?

    python benchmarks/coast.py [--at COMMIT] [--density 1.5] [--workdir DIR] [--json OUT.json]

The scene is :func:`tests.synthetic.make_coast`: the sample scene with its
east third turned to sea, 20 m or more below a cliff, returning an echo to
one pulse in five (waves of 5 cm).  No shared project has a sea, and the
kept-back coastal one showed the failure this checks: the sea taken as the
ground, the land above the cliff as objects.

The LAS job runs with every default but strip adjustment (off, so that the
points keep their coordinates), the map products, accuracy and the report,
as ``real_classes.py`` runs it.  Reported:

- the sea's points by the class they got, and the share of them in the
  ground (2 or 20): the issue's bar is none;
- the DTM against the true terrain over the land (cells whose centre is
  more than 2 m west of the cliff): median, RMS and the share of cells off
  by more than 0.5 m; the bar is a median within 0.5 m;
- the DTM over the sea against the sea's level (median).

``--at COMMIT`` runs the job from a worktree of that commit (scored by this
tree's code).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _isolated import tree_at  # noqa: E402
from real_classes import CONFIG  # noqa: E402

from tests.synthetic import (  # noqa: E402
    SAMPLE_ORIGIN,
    coast_line,
    dtm_at_cell_centres,
    make_coast,
    sea_level,
    terrain,
    write_scene_las,
)

WIDTH, HEIGHT = 512.0, 384.0


def run(work: Path, tree: Path, env: dict[str, str], density: float) -> Path:
    """The coast written as LAZ and the job run on it: its output folder."""
    laz = work / "coast.laz"
    if not laz.exists():
        write_scene_las(make_coast(width=WIDTH, height=HEIGHT, density=density), laz)
    out, cache = work / "out", work / "cache"
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(cache, ignore_errors=True)
    config = work / "job.yaml"
    config.write_text(CONFIG.format(paths=str(laz), crs="", out=out, cache=cache))
    proc = subprocess.run(
        [sys.executable, "-m", "pipeline", "run", str(config), "-q"], cwd=tree, env=env, capture_output=True, text=True
    )
    if proc.returncode != 0:
        raise SystemExit(f"the job failed (exit {proc.returncode}): {proc.stderr.strip()[-1500:]}")
    shutil.rmtree(cache, ignore_errors=True)
    return out


def scores(out: Path) -> dict:
    """The figures of the module's docstring for the job's output *out*."""
    cliff, sea_z = coast_line(WIDTH), sea_level(WIDTH, HEIGHT)
    las = laspy.read(str(out / "points.laz"))
    x = np.asarray(las.x) - SAMPLE_ORIGIN[0]
    cls = np.asarray(las.classification)
    sea = x > cliff
    classes, counts = np.unique(cls[sea], return_counts=True)
    dtm, cx, cy = dtm_at_cell_centres(out / "dtm.tif")
    land = (cx < cliff - 2.0) & np.isfinite(dtm)
    e = dtm[land] - terrain(cx[land], cy[land])
    water = (cx > cliff + 2.0) & np.isfinite(dtm)
    return {
        "sea_points": int(sea.sum()),
        "sea_classes": {int(c): int(n) for c, n in zip(classes, counts, strict=True)},
        "sea_in_ground_pct": 100.0 * float(np.isin(cls[sea], (2, 20)).mean()),
        "land_median_m": float(np.median(e)),
        "land_rms_m": float(np.sqrt(np.mean(e**2))),
        "land_over_05_pct": 100.0 * float((np.abs(e) > 0.5).mean()),
        "sea_dtm_median_m": float(np.median(dtm[water] - sea_z)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--at", metavar="COMMIT", help="run the job from a worktree of this commit")
    parser.add_argument("--density", type=float, default=1.5, help="pulses per m² (default 1.5, the sample's)")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/coast_bench"))
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args(argv)
    work = args.workdir / f"{args.density:g}"
    work.mkdir(parents=True, exist_ok=True)
    tree, env = tree_at(args.at, args.workdir)
    s = scores(run(work, tree, env, args.density))
    print(f"at {args.at or 'this tree'}, {args.density:g} pulses/m²")
    print(
        "| sea points | their classes | sea in the ground % | land DTM median m | RMS m | > 0.5 m % | sea DTM − sea level m |"
    )
    print("|---|---|---|---|---|---|---|")
    classes = ", ".join(f"{c}: {n:,}" for c, n in s["sea_classes"].items())
    print(
        f"| {s['sea_points']:,} | {classes} | {s['sea_in_ground_pct']:.1f} | {s['land_median_m']:+.3f} "
        f"| {s['land_rms_m']:.3f} | {s['land_over_05_pct']:.1f} | {s['sea_dtm_median_m']:+.3f} |"
    )
    if args.json:
        args.json.write_text(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
