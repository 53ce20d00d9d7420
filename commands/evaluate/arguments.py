"""The arguments of ``pipeline evaluate`` (imported by every ``pipeline`` call to build the parser).

It imports only :mod:`argparse` and :mod:`pathlib`: the command's code
(:mod:`commands.evaluate.command`) loads NumPy, pydantic and the stages
when the command runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

#: The DTM check's cell (m) and longest reference triangle edge (m) unless said otherwise.
DTM_CELL = 1.0
DTM_MAX_EDGE = 20.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="what", required=True)
    _ground_args(sub.add_parser("ground", help="ground classification against a labelled LAS/LAZ (class 2 = ground)"))
    p = sub.add_parser("classes", help="every class against a labelled LAS/LAZ: recall, precision, kappa")
    p.add_argument("reference", type=Path, help="labelled LAS/LAZ file (ASPRS classes)")
    _run_args(p)
    p.add_argument("--json", action="store_true", help="print the scores as JSON")
    _hidden_log_args(p)
    _dtm_args(sub.add_parser("dtm", help="DTM vertical accuracy against a truth raster or check points"))


def _ground_args(p: argparse.ArgumentParser) -> None:
    """``evaluate ground``: the run, the algorithms and the DTM check."""
    p.add_argument("reference", type=Path, help="labelled LAS/LAZ file")
    _run_args(p)
    p.add_argument(
        "--algorithm",
        metavar="NAME",
        help="ground algorithm: one registered for stages.classify_ground.algorithm (docs/CONFIG.md lists them; "
        "default: the configuration's, or the stage's default without --config)",
    )
    p.add_argument(
        "--param", action="append", default=[], metavar="NAME=VALUE", help="algorithm parameter (repeatable)"
    )
    p.add_argument(
        "--compare",
        action="append",
        default=[],
        metavar="NAME",
        help="also run this ground algorithm with its defaults (repeatable)",
    )
    p.add_argument("--no-denoise", action="store_true", help="skip the noise step")
    p.add_argument(
        "--write",
        type=Path,
        metavar="OUT.laz",
        help="save the cloud classified by --algorithm (as export_las writes it)",
    )
    p.add_argument(
        "--dtm-check",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also compare the TIN DTM of each run's ground with the TIN DTM of the reference ground (default: on)",
    )
    p.add_argument(
        "--dtm-cell",
        type=float,
        default=DTM_CELL,
        metavar="METRES",
        help=f"cell of the DTM check (default {DTM_CELL:g} m)",
    )
    p.add_argument(
        "--dtm-max-edge",
        type=float,
        default=DTM_MAX_EDGE,
        metavar="METRES",
        help="DTM check: leave out cells inside a reference triangle with a longer edge "
        f"(default {DTM_MAX_EDGE:g} m; inf: none)",
    )
    p.add_argument("--json", action="store_true", help="print the scores as JSON")
    _hidden_log_args(p)


def _dtm_args(p: argparse.ArgumentParser) -> None:
    """``evaluate dtm``: the DTM and its reference."""
    p.add_argument("dtm", type=Path, help="DTM GeoTIFF")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--truth", type=Path, help="reference elevation raster (resampled onto the DTM grid)")
    ref.add_argument("--checkpoints", type=Path, help="CSV of check points: x, y, z[, land_cover]")
    p.add_argument("--land-cover-column", default="land_cover", help="land-cover column name (default land_cover)")
    p.add_argument("--vegetated", nargs="+", default=["vegetated"], help="land-cover values counted as vegetated")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    _hidden_log_args(p)


def _run_args(p: argparse.ArgumentParser) -> None:
    """``--config`` and ``--crs``: the run that classifies the reference file."""
    p.add_argument(
        "--config",
        type=Path,
        metavar="RUN.yaml",
        help="use this run configuration's settings (its input replaced by the reference file); default: "
        "every stage's defaults",
    )
    p.add_argument("--crs", metavar="CRS", help="input.crs: the CRS of a file whose header has none, e.g. EPSG:2992")


def _hidden_log_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--log-format", choices=["text", "json"], default="text", help=argparse.SUPPRESS)
    p.add_argument("-q", "--quiet", action="count", default=0, help=argparse.SUPPRESS)
    p.add_argument("-v", "--verbose", action="count", default=0, help=argparse.SUPPRESS)
