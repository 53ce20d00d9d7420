"""``pipeline evaluate ground|dtm``: measure accuracy against reference data.

    pipeline evaluate dtm DTM.tif (--truth TRUTH.tif | --checkpoints CP.csv)
                              [--land-cover-column NAME] [--vegetated VALUE ...] [--json]

prints RMSEz, mean error, NVA at 95 % and VVA (stages.accuracy).

``pipeline evaluate ground``: score a ground classification against reference labels.

    pipeline evaluate ground REF.laz [--algorithm NAME] [--param k=v ...]
                                     [--no-denoise] [--compare csf] [--write OUT.laz]

The reference file's class 2 is reference ground; every other class is an
object.  The file is classified exactly as the pipeline does it (``denoise``
with its defaults, then ``classify_ground``); noise counts as non-ground.
Prints Type I, Type II, total error and Cohen's kappa (per cent) for each
algorithm run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml
from pydantic import ValidationError

from pipeline.errors import ConfigError, InputDataError
from pipeline.stage import Command
from stages import glossary
from stages.classify import ALGORITHMS, ClassifyGroundParams, classify
from stages.denoise import DenoiseParams, noise_classes


def _algorithm(name: str, params: list[str]):
    values: dict = {"name": name}
    for text in params:
        key, sep, raw = text.partition("=")
        if not sep or not key:
            raise ConfigError(f"--param {text}: expected name=value.")
        values[key.strip()] = yaml.safe_load(raw)
    try:
        return ALGORITHMS[name].model_validate(values)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ConfigError(f"--param {where}: {err['msg']}.") from None


def evaluate_ground(
    path: Path, algorithms: list, *, denoise: bool = True
) -> tuple[list[dict], dict[str, np.ndarray], object]:
    """Classify a labelled file with each algorithm; return scores and classes."""
    import laspy

    from stages.ground.metrics import score
    from stages.io import xyz

    try:
        las = laspy.read(str(path))
    except (laspy.LaspyException, OSError, ValueError) as exc:
        raise InputDataError(f"{path}: not a readable LAS/LAZ file ({exc}).") from None
    reference = np.asarray(las.classification) == glossary.GROUND
    if not reference.any():
        raise InputDataError(f"{path}: no point has class 2, so there is no reference ground to compare with.")
    points = xyz(las)
    start = np.zeros(len(points), dtype=np.uint8)  # labels are hidden from the filters
    if denoise:
        start = noise_classes(points, DenoiseParams())
    rows, classes = [], {}
    for algorithm in algorithms:
        params = ClassifyGroundParams(algorithm=algorithm)
        t0 = time.perf_counter()
        cls = classify(points, start, las.return_number, las.number_of_returns, las.withheld, params)
        seconds = time.perf_counter() - t0
        s = score(reference, cls == glossary.GROUND)
        rows.append({"algorithm": algorithm.name, "params": algorithm.model_dump(), "seconds": seconds, **s.as_dict()})
        classes[algorithm.name] = cls
    return rows, classes, las


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("ground", help="ground classification against a labelled LAS/LAZ (class 2 = ground)")
    p.add_argument("reference", type=Path, help="labelled LAS/LAZ file")
    p.add_argument("--algorithm", choices=sorted(ALGORITHMS), default="smrf", help="ground algorithm (default smrf)")
    p.add_argument(
        "--param", action="append", default=[], metavar="NAME=VALUE", help="algorithm parameter (repeatable)"
    )
    p.add_argument(
        "--compare",
        action="append",
        default=[],
        choices=sorted(ALGORITHMS),
        help="also run this algorithm with its defaults",
    )
    p.add_argument("--no-denoise", action="store_true", help="skip the noise step")
    p.add_argument("--write", type=Path, metavar="OUT.laz", help="save the cloud classified by --algorithm")
    p.add_argument("--json", action="store_true", help="print the scores as JSON")
    _hidden_log_args(p)
    p = sub.add_parser("dtm", help="DTM vertical accuracy against a truth raster or check points")
    p.add_argument("dtm", type=Path, help="DTM GeoTIFF")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--truth", type=Path, help="reference elevation raster (resampled onto the DTM grid)")
    ref.add_argument("--checkpoints", type=Path, help="CSV of check points: x, y, z[, land_cover]")
    p.add_argument("--land-cover-column", default="land_cover", help="land-cover column name (default land_cover)")
    p.add_argument("--vegetated", nargs="+", default=["vegetated"], help="land-cover values counted as vegetated")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    _hidden_log_args(p)


def _hidden_log_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--log-format", choices=["text", "json"], default="text", help=argparse.SUPPRESS)
    p.add_argument("-q", "--quiet", action="count", default=0, help=argparse.SUPPRESS)
    p.add_argument("-v", "--verbose", action="count", default=0, help=argparse.SUPPRESS)


def _run_dtm(args: argparse.Namespace) -> int:
    from rasterio.errors import RasterioError

    from stages.accuracy import checkpoint_errors, compare_with_truth, read_checkpoints, vertical_accuracy

    for path in (args.dtm, args.truth or args.checkpoints):
        if not path.is_file():
            raise ConfigError(f"{path}: file not found.")
    try:
        if args.truth:
            result = vertical_accuracy(compare_with_truth(args.dtm, args.truth).ravel())
        else:
            points, cover = read_checkpoints(args.checkpoints, args.land_cover_column)
            result = vertical_accuracy(checkpoint_errors(args.dtm, points), cover, args.vegetated)
    except RasterioError as exc:
        raise InputDataError(f"{args.dtm} or its reference cannot be read as a raster ({exc}).") from None
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    what = "cells" if args.truth else "check points"
    print(
        f"{args.dtm} against {args.truth or args.checkpoints}: {result['n']:,} {what} ({result['outside']:,} outside or nodata)"
    )
    for label, key in (
        ("RMSEz (m)", "rmse_z"),
        ("mean error (m)", "mean_error"),
        ("NVA 95 % = 1.96 RMSEz (m)", "nva_95"),
        ("VVA 95th percentile (m)", "vva_95"),
    ):
        value = result.get(key)
        print(f"{label:<28} {'—' if value is None else f'{value:.4f}'}")
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.what == "dtm":
        return _run_dtm(args)
    if not args.reference.is_file():
        raise ConfigError(f"{args.reference}: file not found.")
    algorithms = [_algorithm(args.algorithm, args.param)]
    algorithms += [_algorithm(name, []) for name in args.compare if name != args.algorithm or args.param]
    rows, classes, las = evaluate_ground(args.reference, algorithms, denoise=not args.no_denoise)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(
            f"{args.reference}: {rows[0]['n']} points, {rows[0]['ground_as_ground'] + rows[0]['ground_as_object']} reference ground"
        )
        print(f"{'algorithm':<10} {'type I %':>9} {'type II %':>10} {'total %':>8} {'kappa %':>8} {'seconds':>8}")
        for r in rows:
            print(
                f"{r['algorithm']:<10} {100 * r['type_1']:9.2f} {100 * r['type_2']:10.2f} "
                f"{100 * r['total']:8.2f} {100 * r['kappa']:8.2f} {r['seconds']:8.2f}"
            )
    if args.write:
        from stages.io import write_cloud

        las.classification = classes[algorithms[0].name]
        tmp = args.write.with_name(f".{args.write.name}.tmp{args.write.suffix}")
        write_cloud(las, tmp, compress=args.write.suffix.lower() == ".laz")
        tmp.replace(args.write)
        print(f"classified cloud written to {args.write}", file=sys.stderr)
    return 0


EVALUATE = Command(
    name="evaluate", help="measure accuracy against reference data", add_arguments=_add_arguments, run=_run
)
