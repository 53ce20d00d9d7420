"""``pipeline evaluate ground|classes|dtm``: measure accuracy against reference data.

    pipeline evaluate dtm DTM.tif (--truth TRUTH.tif | --checkpoints CP.csv)
                              [--land-cover-column NAME] [--vegetated VALUE ...] [--json]
    pipeline evaluate ground REF.laz [--config RUN.yaml] [--crs EPSG:nnnn]
                                     [--algorithm NAME] [--param k=v ...]
                                     [--no-denoise] [--compare csf] [--write OUT.laz]
                                     [--no-dtm-check] [--dtm-cell 1] [--dtm-max-edge 20] [--json]
    pipeline evaluate classes REF.laz [--config RUN.yaml] [--crs EPSG:nnnn] [--json]

``dtm``: RMSEz, mean error, NVA and VVA (stages.accuracy), with ``--truth``
also the cells far off.  ``ground``: the engine itself runs ``parse`` to
``classify_objects`` on the labelled file (class 2 = reference ground) with
the stage defaults or ``--config``'s settings, once per algorithm; prints
Type I, Type II, total error and kappa, then the DTM check
(:func:`commands.evaluate.scores.dtm_check`).  ``classes``: the same
run once, to the last classification stage; recall and precision per ASPRS
class, overall accuracy, Cohen's kappa and the ground's Type I and II.
How and why: docs/GROUND.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import laspy
import numpy as np
import yaml
from pydantic import ValidationError
from rasterio.errors import RasterioError

from commands.evaluate.arguments import DTM_CELL, DTM_MAX_EDGE
from commands.evaluate.scores import class_scores, dtm_check, score
from lidar import glossary
from lidar.checkpoints import checkpoint_errors, read_checkpoints
from lidar.clouds import cloud_info
from lidar.crs import check_crs_setting
from lidar.las_guard import las_parse_errors, open_las
from pipeline import runner
from pipeline.config import describe_validation_error, load_yaml
from pipeline.discovery import load_plugin
from pipeline.errors import ConfigError, InputDataError
from pipeline.log import LOGGER_NAME
from pipeline.stage import config_model
from stages.accuracy.vertical import truth_accuracy, truth_on_dtm_cells, vertical_accuracy
from stages.classify_ground.filters import GROUND_FILTERS
from stages.classify_ground.params import ClassifyGroundParams

#: The stages that classify points, last first, and their clouds: ``evaluate`` scores the last one enabled.
CLASSIFICATIONS = (("classify_objects", "points_objects"), ("classify_ground", "points_classified"))


def last_classification(settings) -> tuple[str, str]:
    """The last classification stage the run's *settings* enable, and the name of its cloud."""
    for name, output in CLASSIFICATIONS:
        if getattr(getattr(settings.stages, name), "enabled", True):
            return name, output
    return CLASSIFICATIONS[-1]


def _algorithm(name: str, params: list[str]):
    """The ground algorithm *name* with the ``--param`` values; an unknown name is a usage error naming the known ones."""
    if name not in GROUND_FILTERS:
        raise ConfigError(f"--algorithm {name}: {GROUND_FILTERS.unknown(name)}.")
    values: dict = {"name": name}
    for text in params:
        key, sep, raw = text.partition("=")
        if not sep or not key:
            raise ConfigError(f"--param {text}: expected name=value.")
        values[key.strip()] = yaml.safe_load(raw)
    try:
        return GROUND_FILTERS[name].params.model_validate(values)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ConfigError(f"--param {where}: {err['msg']}.") from None


def reference_classes(path: Path) -> np.ndarray:
    """The class of each point of a labelled LAS/LAZ, read in chunks.

    Raises
    ------
    InputDataError
        When the file cannot be read.
    """

    parts = []
    with open_las(Path(path)) as reader:
        try:
            for chunk in reader.chunk_iterator(1_000_000):
                parts.append(np.asarray(chunk.classification, dtype=np.uint8))
        except las_parse_errors() as exc:
            raise InputDataError(f"{path}: unreadable after point {sum(map(len, parts))} ({exc}).") from None
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.uint8)


def reference_ground(path: Path) -> np.ndarray:
    """Whether each point of a labelled LAS/LAZ is reference ground (class 2).

    Raises
    ------
    InputDataError
        When the file cannot be read, or no point has class 2.
    """
    reference = reference_classes(path) == glossary.GROUND
    if not reference.any():
        raise InputDataError(f"{path}: no point has class 2, so there is no reference ground to compare with.")
    return reference


def run_settings(path: Path, *, config: Path | None = None, crs: str | None = None) -> tuple[dict, Path, dict]:
    """The configuration (plain values) that runs *path* as ``pipeline run`` would, its base folder, its key lines.

    Without *config*: every stage's defaults.  With it: that file's settings,
    its input replaced by *path* (which must then be a ``las`` input).
    *crs* sets ``input.crs`` (the CRS of a file whose header has none).
    """

    path = Path(path).resolve()
    data: dict = {}
    base = Path.cwd()
    lines: dict = {}
    if crs is not None:
        try:
            check_crs_setting(crs)
        except ValueError as exc:
            raise ConfigError(f"--crs {crs}: {exc}.") from None
    if config is not None:
        loaded, lines = load_yaml(config)
        if not isinstance(loaded, dict):
            raise ConfigError(f"{config}, line 1: the configuration must be a mapping of keys to values.")
        data, base = loaded, Path(config).resolve().parent
        if (data.get("input") or {}).get("format", "las") != "las":
            raise ConfigError(f"{config}: input.format must be las to evaluate a labelled LAS/LAZ file.")
    data = dict(data)
    data["input"] = {**(data.get("input") or {}), "format": "las", "paths": [str(path)]}
    if crs is not None:
        data["input"]["crs"] = crs
    data.setdefault("stages", {})
    return data, base, lines


def evaluate_ground(
    path: Path,
    algorithms: list | None = None,
    *,
    denoise: bool = True,
    config: Path | None = None,
    crs: str | None = None,
    write: Path | None = None,
    dtm: bool = True,
    dtm_cell: float = DTM_CELL,
    dtm_max_edge: float = DTM_MAX_EDGE,
) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Classify a labelled file (class 2 = reference ground) with the run's stages, once per algorithm.

    *algorithms*: ground-algorithm models (default: the configuration's, SMRF
    without *config*, see :func:`run_settings`); *denoise* runs ``denoise``
    first; *crs* is ``input.crs``; *write* saves the first run's
    ``export_las`` product (LAZ when it ends in ``.laz``).  With *dtm*, also
    the DTM check (:func:`commands.evaluate.scores.dtm_check`) on cells
    of *dtm_cell* m where no reference triangle edge exceeds *dtm_max_edge* m.

    Returns
    -------
    rows, classes : list of dict, dict
        Per algorithm: name, parameters, seconds (``denoise``, ``classify_ground``, ``classify_objects``), the scores
        (:class:`~commands.evaluate.scores.GroundScore`) and, with *dtm*, ``dtm_check``;
        algorithm name -> the classes the run gave every point, in file order.
    """

    reference = reference_ground(path)
    if dtm and reference.sum() < 3:
        raise InputDataError(
            f"{path}: {int(reference.sum())} point(s) of class 2: the DTM check needs at least 3 reference ground "
            "points (--no-dtm-check to score the classes only)."
        )
    data, base, lines = run_settings(path, config=config, crs=crs)
    plugin = load_plugin()  # the plugin that registered this command (stages.plugin), found as the CLI finds it
    model = config_model(plugin)
    rows, classes = [], {}
    work = Path(tempfile.mkdtemp(prefix="pipeline-evaluate-"))
    try:
        with _inner_runs_quiet():
            for i, algorithm in enumerate(algorithms or [None]):
                saving = write if i == 0 else None
                stages = _run_stages(data, algorithm, denoise=denoise, write=saving)
                values = {**data, "stages": stages, "output": str(work / "out"), "cache": str(work / "cache")}
                settings = _validated(model, values, base, config or Path(path), lines)
                until = "export_las" if saving is not None else last_classification(settings)[0]
                manifest = _run_until(settings, plugin, until, crs_hint=config is None and crs is None)
                row, cls = _scored_run(manifest, settings, reference, dtm_cell if dtm else None, dtm_max_edge)
                rows.append(row)
                classes[row["algorithm"]] = cls
                if saving is not None:
                    _save_export(work / "out", stages["export_las"]["compress"], saving)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rows, classes


def evaluate_classes(path: Path, *, config: Path | None = None, crs: str | None = None) -> dict:
    """Classify a labelled file with the run's stages up to the last classification; its scores per class.

    The same run as :func:`evaluate_ground` (*config*, *crs* as there), once.
    Returns ``n``, ``seconds`` (the filter stages), ``scores``
    (:class:`~commands.evaluate.scores.ClassScores` as a dict: every
    class present in either labelling) and ``ground`` (Type I and II of
    class 2, :class:`~commands.evaluate.scores.GroundScore`).
    """

    reference = reference_classes(path)
    data, base, lines = run_settings(path, config=config, crs=crs)
    plugin = load_plugin()
    work = Path(tempfile.mkdtemp(prefix="pipeline-evaluate-"))
    try:
        values = {**data, "output": str(work / "out"), "cache": str(work / "cache")}
        settings = _validated(config_model(plugin), values, base, config or Path(path), lines)
        with _inner_runs_quiet():
            last, output = last_classification(settings)
            manifest = _run_until(settings, plugin, last, crs_hint=config is None and crs is None)
        records = {r["name"]: r for r in manifest["stages"]}
        classified = Path(records[last]["outputs"][output]["file"])
        predicted = np.asarray(laspy.read(str(classified)).classification, dtype=np.uint8)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if len(predicted) != len(reference):  # pragma: no cover - parse keeps every point, in order
        raise RuntimeError(f"{len(predicted)} points classified of {len(reference)} read")
    filters = ("denoise", "classify_ground", "classify_objects")
    return {
        "n": int(len(reference)),
        "seconds": sum(records[n].get("seconds") or 0.0 for n in dict.fromkeys(filters) if n in records),
        "scores": class_scores(reference, predicted, glossary.class_name).as_dict(),
        "ground": score(reference == glossary.GROUND, np.isin(predicted, glossary.GROUNDS)).as_dict(),
    }


def _run_classes(args: argparse.Namespace) -> int:
    """``pipeline evaluate classes``: the table per class, accuracy, kappa and the ground's errors."""
    for path, what in ((args.reference, "file"), (args.config, "configuration file")):
        if path is not None and not path.is_file():
            raise ConfigError(f"{path}: {what} not found.")
    result = evaluate_classes(args.reference, config=args.config, crs=args.crs)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    s, g = result["scores"], result["ground"]
    print(f"{args.reference}: {result['n']} points")
    print(f"{'class':<5} {'name':<26} {'reference':>9} {'predicted':>9} {'recall %':>8} {'precision %':>11}")

    def pc(value) -> str:
        return "—" if value is None else f"{100 * value:.2f}"

    for r in s["classes"]:
        print(
            f"{r['code']:<5} {r['name']:<26} {r['reference']:9d} {r['predicted']:9d} "
            f"{pc(r['recall']):>8} {pc(r['precision']):>11}"
        )
    print(f"overall accuracy {pc(s['accuracy'])} %, kappa {pc(s['kappa'])} %")
    print(f"ground (class 2): type I {pc(g['type_1'])} %, type II {pc(g['type_2'])} %, total {pc(g['total'])} %")
    return 0


@contextmanager
def _inner_runs_quiet() -> Iterator[None]:
    """The inner runs' progress is not this command's output: INFO is raised to WARNING while they run."""

    log = logging.getLogger(LOGGER_NAME)
    level = log.level
    if log.level <= logging.INFO:
        log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        log.setLevel(level)


def _run_stages(data: dict, algorithm, *, denoise: bool, write: Path | None) -> dict:
    """The stages' settings of one run: ``denoise`` on or off, the algorithm, ``export_las`` on to *write*."""
    stages = {key: dict(value or {}) for key, value in data["stages"].items()}
    stages.setdefault("denoise", {})["enabled"] = denoise
    if algorithm is not None:
        stages.setdefault("classify_ground", {})["algorithm"] = algorithm.model_dump(mode="json")
    if write is not None:
        stages["export_las"] = {**stages.get("export_las", {}), "enabled": True}
        stages["export_las"]["compress"] = Path(write).suffix.lower() == ".laz"
    return stages


def _validated(model, values: dict, base: Path, where: Path, lines: dict):
    """The run's settings, or a ConfigError naming the key (and its line in *where*)."""

    try:
        return model.model_validate(values, context={"base_dir": base})
    except ValidationError as exc:
        raise ConfigError(describe_validation_error(exc, values, where, lines, {}, model)) from None


def _run_until(settings, plugin, until: str, *, crs_hint: bool) -> dict:
    """Run the engine's stages up to *until*; its manifest.  *crs_hint*: point to --crs when the CRS is missing."""
    try:
        return runner.run(settings, plugin, until=until)
    except InputDataError as exc:
        if crs_hint and "input.crs" in str(exc):
            raise InputDataError(f"{str(exc).rstrip('.')} (for evaluate ground: --crs).") from None
        raise


def _scored_run(
    manifest: dict, settings, reference: np.ndarray, cell: float | None, max_edge: float
) -> tuple[dict, np.ndarray]:
    """The row of one run (algorithm, parameters, seconds, scores; the DTM check unless *cell* is None), its classes."""

    records = {r["name"]: r for r in manifest["stages"]}
    last, output = last_classification(settings)
    classified = Path(records[last]["outputs"][output]["file"])
    las = laspy.read(str(classified))
    cls = np.asarray(las.classification, dtype=np.uint8)
    if len(cls) != len(reference):  # pragma: no cover - parse keeps every point, in order
        raise RuntimeError(f"{len(cls)} points classified of {len(reference)} read")
    used = settings.stages.classify_ground.algorithm
    seconds = sum(
        records[n].get("seconds") or 0.0 for n in ("denoise", "classify_ground", "classify_objects") if n in records
    )
    s = score(reference, np.isin(cls, glossary.GROUNDS))
    row = {"algorithm": used.name, "params": used.model_dump(), "seconds": seconds, **s.as_dict()}
    if cell is not None:
        xyz = cloud_info(classified).units.to_metres(np.column_stack((las.x, las.y, las.z)))
        row["dtm_check"] = dtm_check(
            xyz,
            reference,
            np.isin(cls, glossary.GROUNDS),
            cell=cell,
            max_edge=max_edge,
            rasterize=settings.stages.rasterize,
        ).as_dict()
    return row, cls


def _save_export(out: Path, compress: bool, write: Path) -> None:
    """Copy the run's ``points.laz`` (or ``.las``) to *write*, through a temporary name."""

    name = "points.laz" if compress else "points.las"
    tmp = Path(write).with_name(f".{Path(write).name}.tmp")
    shutil.copyfile(out / name, tmp)
    tmp.replace(write)


def _run_dtm(args: argparse.Namespace) -> int:

    for path in (args.dtm, args.truth or args.checkpoints):
        if not path.is_file():
            raise ConfigError(f"{path}: file not found.")
    try:
        if args.truth:
            dtm, truth = truth_on_dtm_cells(args.dtm, args.truth)
            result = vertical_accuracy((dtm - truth).ravel())
            result["truth"] = {"file": args.truth.name, "resampling": "bilinear", **truth_accuracy(dtm, truth)}
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
    if args.truth:
        t = result["truth"]
        for label, key, scale in (
            ("cells > 1 m off (%)", "off_1m", 100.0),
            ("cells > 5 m off (%)", "off_5m", 100.0),
            ("largest above truth (m)", "max_above", 1.0),
            ("largest below truth (m)", "max_below", 1.0),
        ):
            value = t.get(key)
            print(f"{label:<28} {'—' if value is None else f'{scale * value:.4f}'}")
        for label, part in (("truth relief < 2 m", "under_2m"), ("truth relief >= 2 m", "2m_or_more")):
            v = t["by_relief"][part]
            share = "—" if v["off_1m"] is None else f"{100.0 * v['off_1m']:.4f}"
            print(f"{label:<28} {share} % of {v['n']:,} cells > 1 m off")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.what == "dtm":
        return _run_dtm(args)
    if args.what == "classes":
        return _run_classes(args)
    if not args.reference.is_file():
        raise ConfigError(f"{args.reference}: file not found.")
    if args.config is not None and not args.config.is_file():
        raise ConfigError(f"{args.config}: configuration file not found.")
    if args.param and args.algorithm is None and args.config is not None:
        raise ConfigError("--param needs --algorithm with --config (which algorithm the parameters are for).")
    if not np.isfinite(args.dtm_cell) or args.dtm_cell <= 0:
        raise ConfigError(f"--dtm-cell {args.dtm_cell:g}: must be a positive number of metres.")
    if not args.dtm_max_edge > 0:  # inf: no limit
        raise ConfigError(f"--dtm-max-edge {args.dtm_max_edge:g}: must be a positive number of metres (or inf).")
    first = None  # None: the configuration's algorithm
    if args.algorithm is not None or (args.param and args.config is None):
        first = _algorithm(args.algorithm or ClassifyGroundParams().algorithm.name, args.param)
    algorithms = [first]
    algorithms += [_algorithm(n, []) for n in args.compare if first is None or n != first.name or args.param]
    rows, _ = evaluate_ground(
        args.reference,
        algorithms,
        denoise=not args.no_denoise,
        config=args.config,
        crs=args.crs,
        write=args.write,
        dtm=args.dtm_check,
        dtm_cell=args.dtm_cell,
        dtm_max_edge=args.dtm_max_edge,
    )
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
        if args.dtm_check:
            _print_dtm_check(rows)
    if args.write:
        print(f"classified cloud written to {args.write}", file=sys.stderr)
    return 0


def _print_dtm_check(rows: list[dict]) -> None:
    """The DTM check's table (figures in metres and per cent of the cells compared)."""
    first = rows[0]["dtm_check"]
    print()
    print(
        f"DTM check: TIN of the ground on {first['cell']:g} m cells minus TIN of the reference ground, "
        f"where no reference triangle edge exceeds {first['max_edge']:g} m "
        f"({first['sparse_cells']:,} of {first['reference_cells']:,} reference cells left out as too sparse)"
    )
    print(
        f"{'algorithm':<10} {'cells':>8} {'RMS m':>7} {'mean m':>7} {'>0.5 up %':>9} {'>2 up %':>8} "
        f"{'>0.5 dn %':>9} {'max up m':>8} {'empty':>6}"
    )

    def cell(value, scale: float = 1.0, width: int = 7) -> str:
        return f"{'—':>{width}}" if value is None else f"{scale * value:{width}.2f}"

    for r in rows:
        c = r["dtm_check"]
        print(
            f"{r['algorithm']:<10} {c['n']:8d} {cell(c['rms'])} {cell(c['mean'])} {cell(c['above_0_5'], 100, 9)} "
            f"{cell(c['above_2'], 100, 8)} {cell(c['below_0_5'], 100, 9)} {cell(c['max_above'], 1, 8)} "
            f"{c['missing_cells']:6d}"
        )
