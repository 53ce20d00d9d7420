"""``pipeline info FILE... [--json]``: what a LAS/LAZ file holds, before running anything.

Like ``pdal info --summary`` or LAStools' ``lasinfo``: the header (LAS
version, point format, point count, bounds, scale and offset, system and
software, GPS time type), the CRS and its units, the VLRs and EVLRs, and,
from one pass over the points (in chunks), the bounds of the points
themselves, the return numbers, the classes and the GPS time range.

A file that cannot be read is one sentence on stderr, exit 3; the other
files are still summarised.  A file that does not exist is a usage error
(exit 2).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipeline.errors import EXIT_INPUT, ConfigError, InputDataError


def _fmt(values) -> str:
    return ", ".join(f"{v:.10g}" for v in values)


def text(s: dict) -> str:
    """The summary of one file as lines for a person."""
    crs = s["crs"]
    if crs["name"] is None:
        crs_line = crs["error"]
    else:
        crs_line = f"{crs['name']}" + (f" (EPSG:{crs['epsg']})" if crs.get("epsg") else "") + f"; {crs['units']}"
    if s["crs_fits"] is False:
        crs_line += f"; does not fit the coordinates: {s['crs_problem']}"
    elif s["crs_fits"] is True:
        crs_line += "; fits the coordinates"
    lines = [
        f"{s['file']}",
        f"  LAS {s['version']}, point format {s['point_format']}, {s['points']:,} points "
        f"({s['points_read']:,} read), {s['bytes']:,} bytes",
        f"  system {s['system_identifier'] or '-'}; software {s['generating_software'] or '-'}; "
        f"created {s['creation_date'] or '-'}",
        f"  CRS: {crs_line}",
    ]
    if s["bounds"]:
        lines.append(f"  bounds (points): min {_fmt(s['bounds']['min'])}; max {_fmt(s['bounds']['max'])}")
    lines.append(f"  bounds (header): min {_fmt(s['bounds_header']['min'])}; max {_fmt(s['bounds_header']['max'])}")
    if s.get("outside_header_bounds"):
        lines.append(f"  warning: {_strays(s)}")
    lines.append(f"  scale {_fmt(s['scale'])}; offset {_fmt(s['offset'])}")
    if s["gps_time"] is None:
        lines.append("  GPS time: none in this point format")
    else:
        g = s["gps_time"]
        span = f"{g['min']:.6f} to {g['max']:.6f}" if g["min"] is not None else "no finite value"
        bad = f"; {g['not_finite']:,} not finite" if g["not_finite"] else ""
        lines.append(f"  GPS time: {s['gps_time_type']}, {span}{bad}")
    rn = ", ".join(f"{k}: {v:,}" for k, v in s["returns"]["return_number"].items()) or "-"
    nr = ", ".join(f"{k}: {v:,}" for k, v in s["returns"]["number_of_returns"].items()) or "-"
    lines.append(f"  return number {rn}; number of returns {nr}")
    cls = ", ".join(f"{k} {v['name']}: {v['points']:,}" for k, v in s["classes"].items()) or "-"
    lines.append(f"  classes: {cls}")
    lines.append(f"  dimensions: {', '.join(s['dimensions'])}")
    for kind in ("vlrs", "evlrs"):
        for v in s[kind]:
            lines.append(f"  {kind[:-1].upper()} {v['user_id']} {v['record_id']}: {v['description']}")
    return "\n".join(lines)


def _strays(s: dict) -> str:
    """The warning for points outside the header's bounds (as the run's)."""
    return (
        f"{s['outside_header_bounds']:,} points lie outside the header's bounds (damaged records or strays): "
        "a run leaves them out."
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", type=Path, nargs="+", metavar="FILE", help="LAS/LAZ files")
    parser.add_argument("--json", action="store_true", help="print a JSON list, one object per file")


def run(args: argparse.Namespace) -> int:
    from lidar.las_summary import summary  # lazy: NumPy and laspy, not for pipeline --help (start-up time)

    for path in args.files:
        if path.is_dir():
            raise ConfigError(f"{path}: a folder; give its LAS/LAZ files (pipeline info {path}/*.laz).")
        if not path.is_file():
            raise ConfigError(f"{path}: file not found.")
    found, failed = [], 0
    for path in args.files:
        try:
            found.append(summary(path))
            if found[-1].get("outside_header_bounds"):
                print(f"pipeline: warning: {path}: {_strays(found[-1])}", file=sys.stderr)
        except InputDataError as exc:
            print(f"pipeline: error: {exc}", file=sys.stderr)
            failed += 1
    if args.json:
        print(json.dumps(found, indent=2))
    else:
        print("\n\n".join(text(s) for s in found))
    return EXIT_INPUT if failed else 0
