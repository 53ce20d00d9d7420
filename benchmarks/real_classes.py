"""Classes and DTMs on real labelled projects of other providers, their labels erased before the run.

    python benchmarks/real_classes.py [--at COMMIT] [--only NAME ...] [--json OUT.json] [--workdir DIR]

For each project (:data:`PROJECTS`: every labelled file of
``../shared/data/real`` (IGN, AHN, BC Timber Sales, lidR's and PDAL's) and the
five shared ISPRS samples):

1. every point's class is set to 1 (the provider's labels erased) in a copy;
2. the LAS job runs on the copies with every default but strip adjustment
   (off, so that the points keep their coordinates), the map products,
   accuracy and the report (none changes a class or the DTM);
3. each output point is matched to its input point (by position in the
   file, checked on x, y, z and GPS time; else by those values) and its
   class compared with the provider's, per kind: ground (the provider's 2
   against our 2 and 20), vegetation (3, 4, 5 together), building (6),
   water (9), bridge deck (17).  Points whose provider class is none of
   these are left out of every score (the provider's 1, "unclassified",
   except in the ISPRS samples, where 1 is labelled: not ground);
4. the DTM is compared with a TIN of the provider's ground points (no edge
   limit) at its cell centres, cells within 2 m of a provider water point
   left out: RMS, median (ours - provider) and the share of cells off by
   more than 0.5 m; and, where the provider has bridge decks, the share of
   the DTM cells holding a deck point where the DTM is higher than 1 m
   below the deck's lowest point there.

Per kind: recall, precision and Cohen's kappa (per cent); ground also
Type I, Type II and total error (per cent; the ISPRS filter test's,
Sithole & Vosselman 2004, doi:10.1016/j.isprsjprs.2004.05.004).  Heights
in metres whatever the project's CRS.  ``--at COMMIT`` runs the job from a
worktree of that commit (scored by this tree's code).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import laspy
import numpy as np
import rasterio
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))
from _isolated import tree_at  # noqa: E402

from tests.shared_data import DATA as SHARED  # noqa: E402

#: The provider classes scored, by kind; our classes that count as each kind.
KINDS = {
    "ground": ((2,), (2, 20)),
    "vegetation": ((3, 4, 5), (3, 4, 5)),
    "building": ((6,), (6,)),
    "water": ((9,), (9,)),
    "deck": ((17,), (17,)),
}
SCORED = {c for provider, _ in KINDS.values() for c in provider}


@dataclass(frozen=True)
class Project:
    """Files of one project (relative to ``../shared/data``), the CRS to give them, and whether the provider's
    class 1 is a label (ISPRS: not ground) or the unclassified points it left out."""

    files: tuple[str, ...]
    crs: str | None = None
    ones_labelled: bool = False
    kinds: tuple[str, ...] = field(default=("ground",))


IGN = ("ground", "vegetation", "building", "water", "deck")
PROJECTS: dict[str, Project] = {
    "ign/crop_2": Project(("real/ign/crop_2.laz",), kinds=IGN),
    "ahn/AHN3": Project(("real/ahn/AHN3.laz",), crs="EPSG:28992", kinds=("ground", "building", "water")),
    "ign/pont": Project(("real/ign/pont.laz",), kinds=IGN),
    "ign/bat": Project(("real/ign/bat.laz",), kinds=IGN),
    "ign/crop_1": Project(("real/ign/crop_1.laz",), kinds=IGN),
    "lasR/bcts": Project(tuple(f"real/lasR/bcts_{i}.laz" for i in range(1, 5))),
    "lidR/Topography": Project(("real/lidR/Topography.laz",), kinds=("ground", "water")),
    "pdal/sample_c": Project(("real/pdal/sample_c.las",), crs="EPSG:2994", kinds=("ground", "vegetation", "building")),
    # the other labelled files of ../shared/data/real: provider ground under forest, in feet, over 25 km²
    "lidR/Megaplot": Project(("real/lidR/Megaplot.laz",)),
    "lidR/MixedConifer": Project(("real/lidR/MixedConifer.laz",)),
    "pdal/autzen_trim": Project(("real/pdal/autzen_trim.las",)),
    "pdal/1.2-with-color": Project(("real/pdal/1.2-with-color.las",), crs="EPSG:2992"),
    "pdal/mvk-thin": Project(("real/pdal/mvk-thin.las",), kinds=("ground", "vegetation", "water")),
    **{
        f"isprs/{s}": Project((f"isprs/{s}.laz",), ones_labelled=True)
        for s in ("samp11", "samp31", "samp51", "samp61", "samp71")
    },
}

#: The job: the LAS job's defaults, strip adjustment off; what changes no class and no DTM off.
CONFIG = """input: {{format: las, paths: [{paths}]{crs}}}
output: {out}
cache: {cache}
stages:
  strip_adjust: {{enabled: false}}
  hillshade: {{enabled: false}}
  contours: {{enabled: false}}
  accuracy: {{enabled: false}}
  report: {{enabled: false}}
"""


def erased(src: Path, dst: Path) -> None:
    """A copy of the LAS/LAZ *src* with every point's class set to 1."""
    las = laspy.read(str(src))
    las.classification = np.ones(len(las.points), dtype=np.uint8)
    las.write(str(dst))


def run_job(project: Project, work: Path, tree: Path, env: dict[str, str]) -> tuple[Path, float]:
    """The job on the erased copies of *project*'s files; its output folder and seconds."""
    copies = []
    for f in project.files:
        copy = work / "erased" / Path(f).name
        copy.parent.mkdir(parents=True, exist_ok=True)
        if not copy.exists():
            erased(SHARED / f, copy)
        copies.append(copy)
    out, cache = work / "out", work / "cache"
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(cache, ignore_errors=True)
    crs = f", crs: '{project.crs}'" if project.crs else ""
    config = work / "job.yaml"
    config.write_text(CONFIG.format(paths=", ".join(str(c) for c in copies), crs=crs, out=out, cache=cache))
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "pipeline", "run", str(config), "-q"], cwd=tree, env=env, capture_output=True, text=True
    )
    if proc.returncode != 0:
        raise SystemExit(f"{work.name}: the job failed (exit {proc.returncode}): {proc.stderr.strip()[-1500:]}")
    shutil.rmtree(cache, ignore_errors=True)
    return out, time.perf_counter() - t0


def _columns(las: laspy.LasData) -> dict[str, np.ndarray]:
    return {
        "x": np.asarray(las.x),
        "y": np.asarray(las.y),
        "z": np.asarray(las.z),
        "t": np.asarray(las.gps_time) if "gps_time" in las.point_format.dimension_names else np.zeros(len(las.points)),
        "cls": np.asarray(las.classification, dtype=np.uint8),
    }


def matched(inputs: dict[str, np.ndarray], output: dict[str, np.ndarray]) -> tuple[np.ndarray, float]:
    """Our class for each input point (255: no output point matched it), and the share matched.

    By position first (the job keeps every point in file order); where x, y,
    z or GPS time differ there, by those values (to the millimetre).
    """
    n = len(inputs["x"])
    ours = np.full(n, 255, dtype=np.uint8)
    if len(output["x"]) == n:
        same = np.ones(n, dtype=bool)
        for k in ("x", "y", "z"):
            same &= np.abs(output[k] - inputs[k]) < 5e-4
        same &= output["t"] == inputs["t"]
        ours[same] = output["cls"][same]
        if same.all():
            return ours, 1.0

    def keys(c: dict[str, np.ndarray]) -> list[tuple]:
        mm = [np.round(c[k] * 1000).astype(np.int64).tolist() for k in ("x", "y", "z")]
        return list(zip(*mm, c["t"].tolist(), strict=True))

    table = dict(zip(keys(output), output["cls"].tolist(), strict=True))
    left = np.flatnonzero(ours == 255)
    for i, key in zip(left, keys({k: v[left] for k, v in inputs.items()}), strict=True):
        ours[i] = table.get(key, 255)
    return ours, float(np.mean(ours != 255))


def _kappa(truth: np.ndarray, pred: np.ndarray) -> float | None:
    n = len(truth)
    if not n:
        return None
    po = np.mean(truth == pred)
    pt, pp = truth.mean(), pred.mean()
    pe = pt * pp + (1 - pt) * (1 - pp)
    return float((po - pe) / (1 - pe)) if pe < 1 else None


def _pct(v: float | None) -> float | None:
    return None if v is None else round(100.0 * v, 2)


def kind_scores(provider: np.ndarray, ours: np.ndarray, scored: np.ndarray, kinds: tuple[str, ...]) -> dict:
    """Recall, precision and kappa (per cent) of each kind over the *scored* points; ground's Type I, II, total."""
    out = {}
    p, o = provider[scored], ours[scored]
    for kind in kinds:
        theirs, mine = KINDS[kind]
        truth, pred = np.isin(p, theirs), np.isin(o, mine)
        tp = int((truth & pred).sum())
        row = {
            "reference": int(truth.sum()),
            "found": int(pred.sum()),
            "recall": _pct(tp / truth.sum()) if truth.any() else None,
            "precision": _pct(tp / pred.sum()) if pred.any() else None,
            "kappa": _pct(_kappa(truth, pred)) if truth.any() else None,
        }
        if kind == "ground":
            objects = ~truth
            row["type_1"] = _pct((truth & ~pred).sum() / truth.sum()) if truth.any() else None
            row["type_2"] = _pct((objects & pred).sum() / objects.sum()) if objects.any() else None
            row["total"] = _pct((truth != pred).mean())
        out[kind] = row
    return out


def dtm_scores(dtm: Path, provider: dict[str, np.ndarray], metres: float) -> dict:
    """Our DTM against a TIN of the provider's ground at its cell centres (metres); and the deck in the DTM."""
    with rasterio.open(dtm) as src:
        z = src.read(1).astype(np.float64)
        t = src.transform
        if src.nodata is not None:
            z[z == src.nodata] = np.nan
    rows, cols = np.nonzero(np.isfinite(z))
    cx, cy = t.c + (cols + 0.5) * t.a, t.f + (rows + 0.5) * t.e
    ground = provider["cls"] == 2
    xy = np.column_stack((provider["x"], provider["y"]))
    tin = LinearNDInterpolator(xy[ground], provider["z"][ground])
    reference = tin(cx, cy)
    water = provider["cls"] == 9
    if water.any():
        near, _ = cKDTree(xy[water]).query(np.column_stack((cx, cy)), distance_upper_bound=2.0 / metres)
        reference[np.isfinite(near)] = np.nan
    d = (z[rows, cols] - reference) * metres
    d = d[np.isfinite(d)]
    out = {
        "cells": int(d.size),
        "rms_m": round(float(np.sqrt(np.mean(d**2))), 3) if d.size else None,
        "median_m": round(float(np.median(d)), 3) if d.size else None,
        "off_0_5_pct": round(100.0 * float(np.mean(np.abs(d) > 0.5)), 1) if d.size else None,
    }
    deck = provider["cls"] == 17
    if deck.any():
        c = np.floor((provider["x"][deck] - t.c) / t.a).astype(np.int64)
        r = np.floor((provider["y"][deck] - t.f) / t.e).astype(np.int64)
        inside = (r >= 0) & (r < z.shape[0]) & (c >= 0) & (c < z.shape[1])
        k = r[inside] * z.shape[1] + c[inside]
        lowest = np.full(z.size, np.inf)
        np.minimum.at(lowest, k, provider["z"][deck][inside])
        cells = np.flatnonzero(np.isfinite(lowest))
        under = z.ravel()[cells]
        high = np.isfinite(under) & (under > lowest[cells] - 1.0 / metres)
        out["deck_cells"] = int(len(cells))
        out["deck_in_dtm_pct"] = round(100.0 * float(high.mean()), 1) if len(cells) else None
    return out


def score(name: str, project: Project, work: Path, tree: Path, env: dict[str, str]) -> dict:
    out, seconds = run_job(project, work, tree, env)
    provider = [_columns(laspy.read(str(SHARED / f))) for f in project.files]
    inputs = {k: np.concatenate([p[k] for p in provider]) for k in provider[0]}
    output = _columns(laspy.read(str(out / "points.laz")))
    ours, share = matched(inputs, output)
    labels = inputs["cls"]
    scored = np.isin(labels, list(SCORED)) | ((labels == 1) & project.ones_labelled)
    scored &= ours != 255
    with laspy.open(str(out / "points.laz")) as reader:
        crs = reader.header.parse_crs()
    metres = crs.axis_info[-1].unit_conversion_factor if crs is not None and crs.axis_info else 1.0
    row = {
        "project": name,
        "points": int(len(labels)),
        "matched_pct": round(100.0 * share, 2),
        "scored": int(scored.sum()),
        "seconds": round(seconds, 1),
        **kind_scores(labels, ours, scored, project.kinds),
        "dtm": dtm_scores(out / "dtm.tif", inputs, metres),
    }
    return row


def _cell(v, fmt: str = "{:.1f}") -> str:
    return "–" if v is None else fmt.format(v)


def table(rows: list[dict]) -> str:
    """The rows as Markdown: per project, each kind's R / P / kappa, ground's Type I / II / total, the DTM."""
    lines = [
        "| project | points | ground R / P / κ | type I / II / total | vegetation R / P | building R / P | water R / P "
        "| deck R / P | DTM RMS m | median m | > 0.5 m % | deck in DTM % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        g = r["ground"]

        def rp(kind: str, r: dict = r) -> str:
            k = r.get(kind)
            return "–" if not k or not k["reference"] else f"{_cell(k['recall'])} / {_cell(k['precision'])}"

        d = r["dtm"]
        lines.append(
            f"| {r['project']} | {r['points']:,} | {_cell(g['recall'])} / {_cell(g['precision'])} / {_cell(g['kappa'])} "
            f"| {_cell(g['type_1'], '{:.2f}')} / {_cell(g['type_2'], '{:.2f}')} / {_cell(g['total'], '{:.2f}')} "
            f"| {rp('vegetation')} | {rp('building')} | {rp('water')} | {rp('deck')} "
            f"| {_cell(d['rms_m'], '{:.3f}')} | {_cell(d['median_m'], '{:+.3f}')} | {_cell(d['off_0_5_pct'])} "
            f"| {_cell(d.get('deck_in_dtm_pct'))} |"
        )
    isprs = [r["ground"]["total"] for r in rows if r["project"].startswith("isprs/")]
    if isprs:
        lines.append(f"\nISPRS samples: mean total error {np.mean(isprs):.2f} % over {len(isprs)}.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--at", metavar="COMMIT", help="run the job from a worktree of this commit")
    ap.add_argument("--only", nargs="+", choices=list(PROJECTS), help="these projects only")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON")
    ap.add_argument("--workdir", type=Path, help="keep the runs here (default: a temporary folder)")
    args = ap.parse_args(argv)
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="real-classes-"))
    tree, env = tree_at(args.at, workdir)
    rows = []
    for name in args.only or list(PROJECTS):
        work = workdir / name.replace("/", "_")
        work.mkdir(parents=True, exist_ok=True)
        rows.append(score(name, PROJECTS[name], work, tree, env))
        print(f"{name}: done in {rows[-1]['seconds']} s", file=sys.stderr, flush=True)
    print(f"at {args.at or 'this tree'}")
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    if args.workdir is None:
        shutil.rmtree(workdir, ignore_errors=True)
    if args.at is not None:
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, capture_output=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
