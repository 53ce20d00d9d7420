"""``pipeline evaluate ground``: score a ground classification against reference labels.

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
    p.add_argument("--log-format", choices=["text", "json"], default="text", help=argparse.SUPPRESS)
    p.add_argument("-q", "--quiet", action="count", default=0, help=argparse.SUPPRESS)
    p.add_argument("-v", "--verbose", action="count", default=0, help=argparse.SUPPRESS)


def _run(args: argparse.Namespace) -> int:
    if args.what != "ground":  # pragma: no cover - argparse restricts it
        raise ConfigError(f"evaluate {args.what}: not available.")
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
