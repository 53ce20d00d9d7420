"""Water (class 9) found by ``classify_water`` against a reference: real data and the simulated flight (issue 34).

- ``lidR/Topography.laz`` (real ALS, 73,403 points, 3,897 provider water
  points): every class is reset to 1 (nothing of the provider's labels
  reaches the run), the run's own stages with their defaults classify it up
  to ``classify_water``, and its class 9 is scored against the provider's:
  Type I (provider water missed), Type II (other points taken as water),
  kappa (per cent).
- ``--flight``: ``configs/simulate.yaml``'s ``flight_ldmrs`` simulated into a
  temporary folder and ``configs/flight.yaml`` run on it; each point's true
  class is its echo's in ``truth/points.laz`` (matched by GPS time, channel,
  return and scan angle): recall and precision of class 9, and the same on
  the true water echoes within 0.3 m of the water level (the truth classes
  the echoes on the river's vertical banks by their plan position); and the
  hydro-flattened DTM against the true terrain on the water and open
  ground cells (``accuracy.json``'s figures by land cover).

Run from the repository root::

    python benchmarks/water_real.py [--flight] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.cli import main as pipeline_main  # noqa: E402
from tests.shared_data import DATA as SHARED  # noqa: E402

TOPOGRAPHY = SHARED / "real" / "lidR" / "Topography.laz"


def scores(found: np.ndarray, truth: np.ndarray) -> dict:
    """Type I, Type II, kappa (per cent), recall and precision of the mask *found* against *truth*."""
    tp, fp = int((found & truth).sum()), int((found & ~truth).sum())
    fn, tn = int((~found & truth).sum()), int((~found & ~truth).sum())
    n = tp + fp + fn + tn
    agree = (tp + tn) / n
    chance = ((tp + fp) * (tp + fn) + (fn + tn) * (fp + tn)) / n**2
    return {
        "points": n,
        "reference_water": tp + fn,
        "found_water": tp + fp,
        "type_1": round(100.0 * fn / max(tp + fn, 1), 2),
        "type_2": round(100.0 * fp / max(fp + tn, 1), 3),
        "kappa": round(100.0 * (agree - chance) / (1.0 - chance), 1),
        "recall": round(100.0 * tp / max(tp + fn, 1), 2),
        "precision": round(100.0 * tp / max(tp + fp, 1), 2),
    }


def _run(config: Path, out: Path, until: str) -> dict:
    """``pipeline run`` of *config* up to *until*; the run's stage entries by name."""
    args = ["run", str(config), "-q", "--until", until, "--set", f"output={out}", "--set", f"cache={out / 'cache'}"]
    if pipeline_main(args) != 0:
        raise RuntimeError(f"the run of {config} failed")
    return {s["name"]: s for s in json.loads((out / "run.json").read_text())["stages"]}


def _water_classes(stages: dict) -> np.ndarray:
    return np.asarray(laspy.read(stages["classify_water"]["outputs"]["points_water"]["file"]).classification)


def topography(work: Path) -> dict:
    """Scores of ``classify_water`` (defaults) on Topography.laz against the provider's class 9."""
    las = laspy.read(str(TOPOGRAPHY))
    truth = np.asarray(las.classification) == 9
    las.classification = np.ones(len(truth), dtype=np.uint8)  # nothing of the provider's labels goes in
    las.write(str(work / "topography.laz"))
    (work / "topography.yaml").write_text(
        "name: topography\ninput: {format: las, paths: [topography.laz]}\noutput: out\ncache: cache\n"
        "executor: {kind: local, workers: 1}\n"
    )
    classes = _water_classes(_run(work / "topography.yaml", work / "topography", "classify_water"))
    return {"file": "real/lidR/Topography.laz", **scores(classes == 9, truth)}


def _truth_of(points, truth) -> tuple[np.ndarray, np.ndarray]:
    """The true class and height of each of *points*' echoes in the simulator's *truth* (both laspy records)."""

    def key(las):
        return np.rec.fromarrays(
            [
                np.asarray(las.gps_time),
                np.asarray(las.scanner_channel, dtype=np.int16),
                np.asarray(las.return_number, dtype=np.int16),
                np.asarray(las.scan_angle, dtype=np.int32),
            ]
        )

    ours, theirs = key(points), key(truth)
    order = np.argsort(theirs, order=("f0", "f1", "f2", "f3"))
    at = np.clip(np.searchsorted(theirs[order], ours), 0, len(order) - 1)
    if not np.all(theirs[order][at] == ours):
        raise RuntimeError("an echo of the run is not in the simulator's truth")
    return np.asarray(truth.classification)[order][at], np.asarray(truth.z)[order][at]


def flight(work: Path) -> dict:
    """Recall and precision of class 9 on configs/flight.yaml's simulated survey against the echoes' true classes."""
    if pipeline_main(
        ["simulate", str(ROOT / "configs" / "simulate.yaml"), "--only", "flight_ldmrs", "--out", str(work)]
    ):
        raise RuntimeError("the simulation failed")
    text = (ROOT / "configs" / "flight.yaml").read_text()
    text = text.replace("../data_samples/flight_ldmrs", str(work / "flight_ldmrs"))
    (work / "flight.yaml").write_text(text)
    stages = _run(work / "flight.yaml", work / "flight", "accuracy")
    cover = json.loads((work / "flight" / "accuracy.json").read_text())["truth"]["by_land_cover"]
    points = laspy.read(stages["classify_water"]["outputs"]["points_water"]["file"])
    cls, z = _truth_of(points, laspy.read(str(work / "flight_ldmrs" / "truth" / "points.laz")))
    found, truth = np.asarray(points.classification) == 9, cls == 9
    level = float(np.median(z[truth]))
    on_level = truth & (np.abs(z - level) <= 0.3)
    return {
        "file": "configs/flight.yaml (simulated)",
        **scores(found, truth),
        "reference_on_level": int(on_level.sum()),
        "recall_on_level": round(100.0 * (found & on_level).sum() / max(on_level.sum(), 1), 2),
        "dtm_water_rms_m": round(cover["9"]["rmse"], 3),
        "dtm_water_mean_m": round(cover["9"]["mean"], 3),
        "dtm_ground_rms_m": round(cover["2"]["rmse"], 3),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flight", action="store_true", help="also the simulated flight (about 30 s)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="water-") as tmp:
        rows = [topography(Path(tmp))]
        if args.flight:
            rows.append(flight(Path(tmp)))
    print(
        f"{'survey':<34} {'points':>8} {'ref 9':>6} {'found 9':>7} {'T I %':>6} {'T II %':>7} {'kappa':>6} "
        f"{'recall':>7} {'prec.':>7}"
    )
    for r in rows:
        print(
            f"{r['file']:<34} {r['points']:>8,} {r['reference_water']:>6,} {r['found_water']:>7,} {r['type_1']:>6.2f} "
            f"{r['type_2']:>7.3f} {r['kappa']:>6.1f} {r['recall']:>7.2f} {r['precision']:>7.2f}"
        )
        if "recall_on_level" in r:
            print(
                f"  true water echoes within 0.3 m of the level: {r['reference_on_level']:,}, recall {r['recall_on_level']:.2f} %"
            )
            print(
                f"  DTM - truth: water cells RMS {r['dtm_water_rms_m']:.3f} m (mean {r['dtm_water_mean_m']:+.3f} m), "
                f"open ground RMS {r['dtm_ground_rms_m']:.3f} m"
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
