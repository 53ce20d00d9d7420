"""``pipeline init FOLDER``: a configuration for one's own folder of LAS/LAZ files.

It reads the headers of the ``.las``/``.laz`` files directly in FOLDER and
writes a configuration of the LAS job (``FOLDER/dtm-pipeline.yaml``, or
``--config FILE``) named after the folder, its products and cache next to
the configuration (``dtm-out/``, ``.dtm-cache/``), with no check points.
What it cannot know it does not guess: a header without a CRS, or a CRS
that names no vertical CRS, is a commented key to fill in, and the command
says so.  An existing configuration is kept unless ``--force``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from pipeline.errors import ConfigError, InputDataError

#: The configuration's file name in FOLDER when ``--config`` is not given.
DEFAULT_NAME = "dtm-pipeline.yaml"
#: The products' and the cache's folders, next to the configuration.
OUTPUT, CACHE = "dtm-out", ".dtm-cache"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", type=Path, metavar="FOLDER", help="folder of LAS/LAZ files (directly inside)")
    parser.add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help=f"the configuration to write (default: FOLDER/{DEFAULT_NAME}); products go next to it, in {OUTPUT}/",
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing configuration")


def las_files(folder: Path) -> list[Path]:
    """The ``.las``/``.laz`` files directly in *folder*, sorted (as ``input.paths`` reads a folder)."""
    from stages.parse.params import LAS_SUFFIXES  # lazy: pydantic, not for pipeline --help (start-up time)

    return sorted(p for p in folder.iterdir() if p.is_file() and p.name.lower().endswith(LAS_SUFFIXES))


def run(args: argparse.Namespace) -> int:
    folder = args.folder
    if not folder.is_dir():
        raise ConfigError(f"{folder}: not a folder; give the folder that holds the LAS/LAZ files.")
    files = las_files(folder)
    if not files:
        raise ConfigError(f"{folder}: no .las or .laz file directly inside (files in subfolders are not read).")
    config = args.config or folder / DEFAULT_NAME
    if config.exists() and not args.force:
        raise ConfigError(f"{config}: exists; keep it, or write over it with --force.")
    survey = _survey(files)
    text = configuration(folder, config, survey)
    tmp = config.with_name(f".{config.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, config)  # never half a configuration
    print(f"wrote {config}: {len(files)} LAS/LAZ files, {survey['points']:,} points, CRS {survey['crs_said']}")
    for note in survey["notes"]:
        print(f"pipeline: warning: {note}")
    print(f"run it: pipeline run {config}   (products in {config.parent / OUTPUT})")
    return 0


def _survey(files: list[Path]) -> dict:
    """What the headers say: points, the CRSs, the files without one, and the notes for the user."""
    from lidar.crs import UNKNOWN, heights_of  # lazy: pyproj and laspy, not for pipeline --help
    from stages.parse.las_index import read_headers

    index = read_headers(files)  # InputDataError (exit 3) names an unreadable file
    crss, missing = {}, []
    for path in files:
        try:
            crs, _ = index.file_crs(path, None)
            crss[crs.to_wkt()] = crs
        except InputDataError:
            missing.append(path.name)
    points = sum(int(index.header(p).point_count) for p in files)
    notes = []
    if missing:
        notes.append(
            f"{len(missing)} file(s) name no CRS ({', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''}): "
            "set input.crs in the configuration to the CRS of their coordinates before running."
        )
    if len(crss) > 1:
        notes.append(f"the files are in {len(crss)} CRSs; they are brought into the first one's (crs: auto-utm).")
    first = next(iter(crss.values()), None)
    heights = heights_of(first, georeferenced=False)
    if first is not None and heights.kind == UNKNOWN:
        notes.append(heights.warning.replace("input.override_crs", "input.override_crs in the configuration"))
    said = (
        "none in the headers"
        if first is None
        else f"{first.name}" + (f" (EPSG:{first.to_epsg()})" if first.to_epsg() else "")
    )
    return {"points": points, "crs_said": said, "missing": missing, "heights": heights, "first": first, "notes": notes}


def configuration(folder: Path, config: Path, survey: dict) -> str:
    """The YAML text of the configuration for *folder*'s files, written at *config*."""
    here = os.path.relpath(folder.resolve(), config.parent.resolve())
    crs_line = (
        "  # crs: EPSG:XXXX                   # REQUIRED: some headers name no CRS (pipeline validate says which)\n"
        if survey["missing"]
        else ""
    )
    first = survey["first"]
    vertical = ""
    if first is not None and survey["heights"].kind == "unknown":
        code = first.to_epsg()
        example = f"EPSG:{code}+<vertical EPSG code>" if code else "<horizontal>+<vertical EPSG codes>"
        vertical = f"  # override_crs: {example}   # states the heights' vertical datum: the headers name none\n"
    made = time.strftime("%Y-%m-%d", time.gmtime())
    return (
        f"# Written by `pipeline init` on {made} for the LAS/LAZ files in {folder.resolve()}.\n"
        "#   pipeline validate THIS-FILE, then pipeline run THIS-FILE\n"
        "# Every path is relative to this file.  Every key and its default: docs/CONFIG.md.\n"
        f"name: {json.dumps(folder.resolve().name or 'survey')}\n"
        "input:\n"
        "  format: las\n"
        f"  paths: [{json.dumps(here)}]               # the .las/.laz files directly in the folder\n"
        f"{crs_line}{vertical}"
        "crs: auto-utm                          # keeps the files' projected CRS\n"
        f"output: {OUTPUT}                        # the products, next to this file\n"
        f"cache: {CACHE}                        # cached intermediates (delete freely)\n"
        "stages:\n"
        "  # accuracy: {checkpoints: checkpoints.csv}   # surveyed check points x, y, z, land_cover: RMSEz, NVA, VVA\n"
        "  export_las: {compress: true}\n"
        "  report: {enabled: true}\n"
    )
