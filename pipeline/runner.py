"""Plan and run the stage graph.

Planning happens entirely before any stage runs: every stage's parameters are
validated (by the configuration model), the enabled stages are ordered from
their declared inputs, and every input must be produced by an enabled stage
(or passed on by a disabled one).  Then each stage runs, or is taken from the
cache when its key matches a complete entry.  Products are copied from the
cache into the output folder atomically, and ``run.json`` records what
happened.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import platform
import shutil
import signal
import stat
import time
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from pipeline import __version__, interrupt
from pipeline.cache import (
    UMASK,
    Cache,
    Entry,
    NotRegularFile,
    TileCache,
    atomic_write_text,
    cache_root,
    exclusive_lock,
    file_kind,
    folder_failure,
    hash_path,
    hash_regular_file,
    hash_value,
    identity,
    path_size,
)
from pipeline.errors import (
    FULL,
    UNWRITABLE,
    ConfigError,
    EnvironmentFailure,
    InputDataError,
    PipelineError,
    PlanError,
)
from pipeline.executor import LocalExecutor, WorkerLost, capped_workers, make_executor, release_freed_memory
from pipeline.interrupt import Interrupted
from pipeline.log import LOGGER_NAME, RunLog, StageWarnings, hosting, stage_logger
from pipeline.replan import PlannedStage, tile_notes
from pipeline.stage import Plugin, Stage, StageContext, StageIO, get_dotted

MANIFEST = "run.json"
#: The run's log, beside its products (every line of INFO and above, whatever the console showed).
RUN_LOG = "run.log"
PRODUCTS_LOCK = ".products.lock"
#: Metrics key in which a stage lists the artifacts it made but that hold nothing worth publishing
#: (an empty map): they stay in the cache entry, are not copied to the output folder, and an older
#: copy there is removed like any product no longer made (listed in ``run.json``'s ``removed_products``).
UNPUBLISHED = "unpublished"
#: Metrics key in which a stage lists the checks its outputs failed (an acceptance's failed rows), one
#: sentence each: ``pipeline run`` logs them as warnings and, with ``--strict``, exits 5 (cached stages too).
FAILED_CHECKS = "failed_checks"
#: Metrics key in which the engine keeps a stage's WARNING and ERROR log lines of its run (cached with
#: its metrics, so a report shows every warning of the run, the cached stages' too).
LOG_WARNINGS = "log_warnings"


def _inside(folder: Path, name: str) -> Path:
    """``folder / name``, refusing a name that would leave *folder*.

    The last part of the name is not resolved: a product replaced by a
    symbolic link is replaced by publishing (the link, never its target).
    """
    path = folder / name
    if path.name in ("", ".", "..") or not _place(path).is_relative_to(folder.resolve()):
        lexical = ".." not in Path(name).parts and not Path(name).is_absolute()
        via = " (a symbolic link in it points elsewhere)" if lexical else ""
        raise PlanError(f"the product name '{name}' would be written outside the output folder {folder}{via}.")
    return path


def _place(path: Path) -> Path:
    """Where *path* is, its folders resolved but not its last part (which may be a link)."""
    return path.parent.resolve() / path.name


def _remove_leftovers(folders: Iterable[Path]) -> None:
    """Remove temporary copies (``.NAME.*.tmp``) left in *folders* by killed runs.

    Called with the products lock held, so no live run is writing them.
    """
    for folder in folders:
        for tmp in folder.glob(".*.tmp") if folder.is_dir() else ():
            if tmp.is_dir() and not tmp.is_symlink():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)


@dataclass
class Step:
    """One stage of a plan with its parameters and artifacts."""

    stage: Stage
    params: BaseModel
    io: StageIO
    enabled: bool
    order: int
    note: str = ""

    @property
    def name(self) -> str:
        return self.stage.name


@dataclass
class Plan:
    """The ordered enabled steps and how every artifact is resolved."""

    steps: list[Step]
    skipped: list[Step]
    producer: dict[str, Step]
    aliases: dict[str, str]

    def resolve(self, artifact: str) -> str:
        """The artifact that actually stands for *artifact* (through disabled stages)."""
        seen = set()
        while artifact not in self.producer and artifact in self.aliases and artifact not in seen:
            seen.add(artifact)
            artifact = self.aliases[artifact]
        return artifact


def build_plan(config: BaseModel, plugin: Plugin, until: str | None = None, force: Iterable[str] = ()) -> Plan:
    """Order the enabled stages and check that every input has a producer.

    Raises
    ------
    ConfigError
        For an unknown stage name in ``until`` or ``force``.
    PlanError
        When two enabled stages write the same artifact, a stage's input is
        produced by no enabled stage, or the graph has a cycle.
    """
    names = [s.name for s in plugin.stages]
    for name in ([until] if until else []) + list(force):
        if name not in names:
            raise ConfigError(f"unknown stage '{name}'; stages are: {', '.join(names)}.")
    active, skipped = _steps(config, plugin)
    plan = Plan([], skipped, _producers(active), {})
    plan.aliases = {out: src for step in skipped for out, src in step.stage.passthrough.items()}
    # Dependencies by producer; an input nobody produces is an error only for
    # a stage that will run (so --until can run a prefix of an unfinished graph).
    missing = {s.name: [a for a in s.io.inputs if plan.resolve(a) not in plan.producer] for s in active}
    deps = {
        s.name: {plan.producer[plan.resolve(a)].name for a in s.io.inputs if a not in missing[s.name]} for s in active
    }
    keep = _needed_until(until, deps, {s.name for s in active})
    for step in active:
        if step.name in keep and missing[step.name]:
            _refuse_missing(step, missing[step.name][0], skipped)
    ordered = _topological(active, deps)
    for step in ordered:
        if step.name not in keep:
            step.note = f"after --until {until}"
            skipped.append(step)
    plan.steps = [s for s in ordered if s.name in keep]
    for name in force:
        if name not in {s.name for s in plan.steps}:
            raise ConfigError(f"--force {name}: that stage does not run in this plan.")
    return plan


def _steps(config: BaseModel, plugin: Plugin) -> tuple[list[Step], list[Step]]:
    """Every stage of *plugin* as a step: (enabled, skipped with the reason)."""
    active: list[Step] = []
    skipped: list[Step] = []
    for order, cls in enumerate(plugin.stages):
        stage = cls()
        params = get_dotted(config, cls.params_path())
        enabled = stage.is_enabled(params, config)
        step = Step(stage, params, stage.declare(params, config), enabled, order)
        if enabled:
            active.append(step)
        else:
            step.note = "disabled" if getattr(params, "enabled", True) is False else "not applicable"
            skipped.append(step)
    return active, skipped


def _producers(active: list[Step]) -> dict[str, Step]:
    """Artifact -> the one enabled step that writes it."""
    producer: dict[str, Step] = {}
    for step in active:
        for artifact in step.io.outputs:
            if artifact in producer:
                raise PlanError(
                    f"stages '{producer[artifact].name}' and '{step.name}' both write '{artifact}'; disable one."
                )
            producer[artifact] = step
    return producer


def _needed_until(until: str | None, deps: dict[str, set[str]], active: set[str]) -> set[str]:
    """The stages a run ``--until`` *until* needs (every active stage without it)."""
    if not until:
        return set(active)
    if until not in active:
        raise ConfigError(f"--until {until}: that stage is disabled in this configuration.")
    keep = {until}
    frontier = [until]
    while frontier:
        for dep in deps[frontier.pop()]:
            if dep not in keep:
                keep.add(dep)
                frontier.append(dep)
    return keep


def _refuse_missing(step: Step, artifact: str, skipped: list[Step]) -> None:
    """Raise the PlanError for *step*'s input *artifact* that no enabled stage produces."""
    could = [s.name for s in skipped if artifact in s.io.outputs]
    hint = (
        f" (enable '{could[0]}' or disable '{step.name}')"
        if could
        else "; no stage of this version writes it from this input: run the stages before it with --until"
    )
    raise PlanError(f"stage '{step.name}' needs '{artifact}', which no enabled stage produces{hint}.")


def _topological(active: list[Step], deps: dict[str, set[str]]) -> list[Step]:
    """Kahn's algorithm, ties broken by the plugin's natural order."""
    ordered: list[Step] = []
    done: set[str] = set()
    while len(ordered) < len(active):
        ready = [s for s in active if s.name not in done and deps[s.name] <= done]
        if not ready:
            cycle = sorted({s.name for s in active} - done)
            raise PlanError(f"the stages {', '.join(cycle)} depend on each other in a cycle.")
        nxt = min(ready, key=lambda s: s.order)
        ordered.append(nxt)
        done.add(nxt.name)
    return ordered


def check_writable(folder: Path, what: str) -> None:
    """Create *folder* if needed and prove it takes a file.

    A full or read-only disk, or missing permissions, raise EnvironmentFailure
    (exit 4); a path that cannot be a folder (a file in the way), ConfigError.

    The probe is created with ``O_EXCL | O_NOFOLLOW``: a symbolic link
    planted under its name is removed (the link only), never written through.
    """
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        if probe.is_symlink() or probe.exists():
            probe.unlink()  # ours by name (a killed run of this pid, or a planted link)
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        os.close(fd)
        probe.unlink()
    except OSError as exc:
        if exc.errno in FULL | UNWRITABLE:
            raise EnvironmentFailure(folder_failure(what, folder, exc)) from None
        raise ConfigError(f"the {what} folder {folder} is not writable ({exc.strerror or exc}).") from None


def _disk_failure(exc: OSError, side: str, folder: Path) -> str | None:
    """The sentence for a full or unwritable disk met writing on the *side* ("cache", "output") in *folder*.

    The sentence names *folder* itself (a stage's workspace inside it is
    gone by the time it is read).  None when *exc* is neither, or when a
    permission error concerns no file or one outside *folder* (an input
    that cannot be read is not the machine's failure).
    """
    if exc.errno not in FULL | UNWRITABLE:
        return None
    where = Path(os.path.realpath(exc.filename)) if isinstance(exc.filename, (str, os.PathLike)) else None
    inside = where is not None and where.is_relative_to(os.path.realpath(folder))
    if exc.errno in FULL and where is not None and not inside:
        return (
            f"the disk holding {where.parent} is full ({exc.strerror}); free space, then run again: "
            "complete stages are reused."
        )
    if exc.errno in UNWRITABLE and not inside:
        return None
    return folder_failure(side, folder, exc)


@contextlib.contextmanager
def _machine_failures(side: str, folder: Path, stage: str | None = None):
    """Turn a full or unwritable disk on the *side* in *folder* into one sentence (exit 4).

    With *stage*, the sentence (and any :class:`EnvironmentFailure` that does
    not name a stage) starts with "stage 'NAME': ".
    """
    prefix = f"stage '{stage}': " if stage else ""
    try:
        yield
    except EnvironmentFailure as exc:
        if not prefix or str(exc).startswith("stage '"):
            raise
        raise EnvironmentFailure(f"{prefix}{exc}") from None
    except OSError as exc:
        sentence = _disk_failure(exc, side, folder)
        if sentence is None:
            raise
        raise EnvironmentFailure(f"{prefix}{sentence}") from None


def _stage_key(
    step: Step, config: BaseModel, input_hashes: dict[str, str], files: dict[str, str], upstream: dict | None
) -> str:
    params = step.params.model_dump(mode="json", exclude={"enabled"}) if step.params is not None else None
    material = {
        "stage": step.name,
        "version": step.stage.version,
        "params": params,
        "config": {k: _dump(get_dotted(config, k)) for k in step.stage.config_keys},
        "inputs": input_hashes,
        "files": files,
    }
    if upstream is not None:
        material["metrics"] = upstream
    return hash_value(material)


def _dump(value: Any) -> Any:
    return value.model_dump(mode="json") if isinstance(value, BaseModel) else value


def run(
    config: BaseModel,
    plugin: Plugin,
    *,
    config_path: Path | None = None,
    until: str | None = None,
    force: Iterable[str] = (),
    dry_run: bool = False,
) -> dict[str, Any]:
    """Run (or, with ``dry_run``, only plan) a validated configuration.

    Returns
    -------
    dict
        The manifest, also written to ``<output>/run.json`` unless dry-running.
        In a dry run each stage's ``status`` is ``cached``, ``run`` or
        ``run (upstream)`` (its key depends on outputs not yet computed).
    """
    log = logging.getLogger(LOGGER_NAME)
    plan = build_plan(config, plugin, until, set(force))
    cache = Cache(cache_root(config), log)
    output = Path(config.output)
    _check_before_running(plan, config, output, cache, config_path, dry_run)
    if dry_run:
        return _run(plan, plugin, config, cache, output, config_path, set(force), dry_run, log)
    with RunLog() as lines:
        try:
            return _run(plan, plugin, config, cache, output, config_path, set(force), dry_run, log)
        finally:
            _write_run_log(output, lines.text(), log)


def _write_run_log(output: Path, text: str, log: logging.Logger) -> None:
    """``run.log`` beside the products: the run's log at INFO and above, written at once (atomically)."""
    try:
        atomic_write_text(output / RUN_LOG, text)
    except OSError as exc:  # a full disk: the products and run.json are what matter
        log.error("cannot write %s (%s)", output / RUN_LOG, exc.strerror or exc)


def _run(
    plan: Plan,
    plugin: Plugin,
    config: BaseModel,
    cache: Cache,
    output: Path,
    config_path: Path | None,
    force: set[str],
    dry_run: bool,
    log: logging.Logger,
) -> dict[str, Any]:
    """:func:`run` once planned and checked (*force*: the stages to re-run)."""
    started = time.time()
    state = _Run(plan, config, cache, force, dry_run, _new_manifest(config, plugin, config_path, started))
    manifest, records = state.manifest, state.records
    executor = state.executor = make_executor(config)
    published = False
    try:
        for step in plan.steps:
            records[step.name] = _run_step(step, state)
        for step in plan.skipped:
            records[step.name] = {"name": step.name, "status": step.note or "disabled"}
        manifest["stages"] = [records[s.name] for s in sorted(plan.steps + plan.skipped, key=lambda s: s.order)]
        if dry_run:
            _plan_tiles(plan, plugin, config, output, manifest)
            return manifest
        executor.close()
        _finish(manifest, started)
        with _machine_failures("output", output):
            publish(output, _products(state), manifest, log)
        published = True
        return manifest
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", None) or interrupt.received()
        manifest["status"] = "interrupted"
        manifest["error"] = f"interrupted by {_signal_name(signum)}"
        raise
    except PipelineError as exc:
        manifest["status"] = "failed"
        manifest["error"] = str(exc)
        raise
    except Exception as exc:
        if interrupt.received() is not None:  # a worker's death caused by the same signal, seen first
            manifest["status"] = "interrupted"
            manifest["error"] = f"interrupted by {_signal_name(interrupt.received())}"
            raise Interrupted(interrupt.received()) from None
        manifest["status"] = "failed"
        manifest["error"] = f"internal error: {type(exc).__name__}: {exc}"
        raise
    finally:
        executor.close(abort=True)  # a no-op when closed above; else stops the workers at once
        if not dry_run and not published:
            if not manifest["stages"]:
                manifest["stages"] = list(records.values())
            _finish(manifest, started)
            _record_failure(output, manifest, log)


@dataclass
class _Run:
    """What the steps of one run share: the plan, the cache and what has been computed so far."""

    plan: Plan
    config: BaseModel
    cache: Cache
    force: set[str]
    dry_run: bool
    manifest: dict[str, Any]
    artifacts: dict[str, tuple[Path, str]] = field(default_factory=dict)
    unknown: set[str] = field(default_factory=set)  # dry run: artifacts whose content is not known yet
    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    executor: Any = None


def _check_before_running(
    plan: Plan, config: BaseModel, output: Path, cache: Cache, config_path: Path | None, dry_run: bool
) -> None:
    """Every product lands inside the output folder, no input is a product, both folders take files."""
    for step in plan.steps:
        for file_name in step.io.products.values():
            _inside(output, file_name)
    _check_inputs_are_not_products(plan, config, output, config_path)
    if not dry_run:
        check_writable(output, "output")
        check_writable(cache.root, "cache")


def _new_manifest(config: BaseModel, plugin: Plugin, config_path: Path | None, started: float) -> dict[str, Any]:
    """The manifest of a run that starts now: what runs, with which versions and configuration."""
    return {
        "name": getattr(config, "name", None) or (Path(config_path).stem if config_path else None),
        "tool": plugin.name,
        "version": __version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "libraries": plugin.versions(),
        "config": {
            "path": str(config_path) if config_path else None,
            "sha256": hash_value(config.model_dump(mode="json")),
        },
        "started": _utc(started),
        "status": "running",
        "stages": [],
        "inputs": {},
        "products": {},
    }


def _products(state: _Run) -> dict[str, tuple[Path, str]]:
    """Product file name -> (cached file, SHA-256) of every product the run publishes."""
    return {
        file_name: state.artifacts[artifact]
        for step in state.plan.steps
        for artifact, file_name in step.io.products.items()
        if artifact not in _unpublished(state.records.get(step.name))
    }


def _signal_name(signum: int | None) -> str:
    return signal.Signals(signum).name if signum else "SIGINT"


def _finish(manifest: dict[str, Any], started: float) -> None:
    finished = time.time()
    manifest["finished"] = _utc(finished)
    manifest["seconds"] = round(finished - started, 3)


def _check_inputs_are_not_products(plan: Plan, config: BaseModel, output: Path, config_path: Path | None) -> None:
    """Refuse, before anything runs, an input file that publishing would overwrite.

    A product found replaced by a symbolic link is refused when the link
    leads to an input (or a folder holding one), else replaced with a warning.
    """
    names = [name for step in plan.steps for name in step.io.products.values()] + [MANIFEST]
    products = {_place(output / name): name for name in names}
    inputs = [Path(config_path)] if config_path else []
    for step in plan.steps:
        inputs += [Path(p) for p in step.stage.external_files(step.params, config)]
    for place, name in products.items():
        if place.is_symlink():
            _check_product_link(place, name, output, inputs)
    for path in inputs:
        real = path.resolve()
        name = products.get(real) or next(
            (n for p, n in products.items() if real.is_relative_to(p) and p != real), None
        )
        if name is not None:
            raise ConfigError(
                f"the input {path} is in the output folder under the product name '{name}', which a run "
                "replaces: move the input out of the output folder or choose another output."
            )


def _check_product_link(place: Path, name: str, output: Path, inputs: list[Path]) -> None:
    """A product that is a symbolic link: refused if it leads to an input, else a warning (publishing replaces it)."""
    target = place.resolve()
    hit = next((p for p in inputs if p.resolve() == target or p.resolve().is_relative_to(target)), None)
    if hit is not None:
        to = f"the input {hit}" if hit.resolve() == target else f"{os.readlink(place)}, which holds the input {hit}"
        raise ConfigError(
            f"the product '{name}' in the output folder {output} is a symbolic link to {to}: "
            "remove the link (not its target) or choose another output."
        )
    logging.getLogger(LOGGER_NAME).warning(
        "the product '%s' in the output folder %s is a symbolic link to %s; publishing replaces the link, "
        "never its target",
        name,
        output,
        os.readlink(place),
    )


def _plan_tiles(plan: Plan, plugin: Plugin, config: BaseModel, output: Path, manifest: dict[str, Any]) -> None:
    """Dry run: how many tiles each tiled stage will run (:mod:`pipeline.replan`), when input files changed."""
    hook = getattr(plugin, "changed_areas", None)
    previous = _read_manifest(output)
    if hook is None or not previous.get("inputs"):
        return
    now, before = manifest["inputs"], previous["inputs"]
    changed = {p: ("new" if p not in before else "changed") for p, h in now.items() if before.get(p) != h}
    changed.update({p: "removed" for p in before if p not in now})
    if not changed:
        return
    areas = hook(config, changed, previous, output)
    if areas is None:
        return
    records = {s["name"]: s for s in previous.get("stages", [])}
    stages = [
        PlannedStage(
            step.name,
            step.stage.tile_buffer(step.params) is not None,
            step.stage.spreads_changes(step.params, records.get(step.name, {})),
        )
        for step in plan.steps
    ]
    notes = tile_notes(stages, areas, previous)
    for record in manifest["stages"]:
        if record["name"] in notes and record.get("status", "").startswith("run"):
            record["tiles"] = notes[record["name"]]


def _read_manifest(output: Path) -> dict[str, Any]:
    """The output folder's ``run.json`` as it is (an empty dict when absent or unreadable)."""
    path = output / MANIFEST
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
        with os.fdopen(fd, "rb") as fh:
            raw = fh.read(64 << 20)
        value = json.loads(raw)
    except (OSError, ValueError, RecursionError):
        return {}
    return value if isinstance(value, dict) else {}


def _write_manifest(output: Path, manifest: dict[str, Any]) -> None:
    atomic_write_text(output / MANIFEST, json.dumps(manifest, indent=2, default=str))


def _unpublished(record: dict[str, Any] | None) -> set[str]:
    """Outputs a stage said hold nothing to publish (``ctx.metrics[UNPUBLISHED]``): kept in the cache only."""
    names = ((record or {}).get("metrics") or {}).get(UNPUBLISHED) or []
    return {n for n in names if isinstance(n, str)}


def _carry_products(manifest: dict[str, Any], old: dict[str, Any]) -> None:
    """Describe in *manifest* the products already in the folder (those *old* lists)."""
    manifest["products"] = old.get("products", {}) if isinstance(old.get("products"), dict) else {}
    manifest["products_run"] = old.get("products_run", old.get("started"))
    if old.get("status") == "publishing" or old.get("products_incomplete"):
        manifest["products_incomplete"] = True  # a publication was cut short (SIGKILL, power loss)


def _record_failure(output: Path, manifest: dict[str, Any], log: logging.Logger) -> None:
    """Write a failed or interrupted run's manifest, still describing the products that are there.

    Under the folder's lock, as publication is: ``run.json`` never describes
    products another run is replacing.  When even this cannot be written
    (a full disk), the previous ``run.json`` stays: it is still true.
    """
    try:
        with interrupt.deferred(), exclusive_lock(output / PRODUCTS_LOCK):
            _carry_products(manifest, _read_manifest(output))
            _write_manifest(output, manifest)
    except OSError as exc:
        log.error("cannot write %s (%s); the previous one is kept", output / MANIFEST, exc.strerror or exc)
        return
    log.info("run %s in %.2f s; manifest %s", manifest["status"], manifest["seconds"], output / MANIFEST)


def publish(output: Path, products: dict[str, tuple[Path, str]], manifest: dict[str, Any], log: logging.Logger) -> None:
    """Publish *products* (name -> cached file and its SHA-256) and ``run.json`` as one step.

    Under the output folder's lock: (1) every product that differs from the
    one in place is copied beside it (``.NAME.*.tmp``); a failure (a full
    disk) removes the copies and leaves the folder as it was; (2)
    ``run.json`` is written as ``"publishing"`` with the new product list;
    (3) with SIGINT and SIGTERM held back, the copies are renamed into place,
    products of the previous publication this run does not make are removed,
    and ``run.json`` is written as ``"ok"``.  A run killed in step 3 leaves
    ``"publishing"``: the next run completes it.
    """
    products = _flatten_nested(products)
    folders = {output} | {(output / name).parent for name in products}
    with exclusive_lock(output / PRODUCTS_LOCK, lambda: log.info("waiting for another run to publish its products")):
        _remove_leftovers(folders)
        old = _read_manifest(output)
        staged: list[tuple[Path, Path]] = []  # (temporary copy, final name)
        try:
            for name, (src, digest) in products.items():
                dst = output / name  # inside the output folder: checked at planning
                if not (_is_real(dst) and path_size(dst) == path_size(src) and hash_path(dst) == digest):
                    staged.append((_stage_copy(src, dst), dst))
            stale = [
                name
                for name in (old.get("products") or {})
                if isinstance(name, str) and name not in products and name != MANIFEST
            ]
            # an old folder product now published file by file: only its files no longer made are stale
            parents = [n for n in stale if any(Path(p).is_relative_to(n) for p in products)]
            stale = [n for n in stale if n not in parents]
            stale += [
                str(f.relative_to(output))
                for n in parents
                if (output / n).is_dir()
                for f in sorted((output / n).rglob("*"))
                if f.is_file() and not f.name.endswith(".tmp") and str(f.relative_to(output)) not in products
            ]
            manifest.update(
                status="publishing",
                products={
                    name: {"sha256": digest, "bytes": path_size(src)} for name, (src, digest) in products.items()
                },
                products_run=manifest["started"],
            )
            if stale:
                manifest["removed_products"] = sorted(stale)
            _write_manifest(output, manifest)
        except BaseException:
            for tmp, _ in staged:
                _remove_path(tmp)
            raise
        with interrupt.deferred():
            for tmp, dst in staged:
                _rename_into_place(tmp, dst)
            for name in stale:
                path = output / name
                if _place(path).is_relative_to(output.resolve()) and (path.is_symlink() or path.exists()):
                    _remove_path(path)
            manifest["status"] = "ok"
            _write_manifest(output, manifest)
    log.info("run ok in %.2f s; manifest %s", manifest["seconds"], output / MANIFEST)


def _flatten_nested(products: dict[str, tuple[Path, str]]) -> dict[str, tuple[Path, str]]:
    """Folder products that another product lies inside (``qc`` and ``qc/trajectory.gpkg``), file by file.

    A folder is published by renaming its copy into place, which would drop
    a product another stage publishes inside it; such a folder's files are
    published one by one instead (``run.json`` then lists each of them).
    """
    nested = {
        outer
        for outer in products
        for inner in products
        if inner != outer and Path(inner).is_relative_to(outer) and Path(products[outer][0]).is_dir()
    }
    if not nested:
        return products
    out = {name: v for name, v in products.items() if name not in nested}
    for outer in sorted(nested):
        src = Path(products[outer][0])
        for f in sorted(src.rglob("*")):
            name = str(Path(outer) / f.relative_to(src))
            if f.is_file() and name not in out:
                out[name] = (f, hash_path(f))
    return out


def _is_real(path: Path) -> bool:
    return path.exists() and not path.is_symlink()


def _stage_copy(src: Path, dst: Path) -> Path:
    """Copy *src* beside *dst* under a temporary name; an error names *dst*, the product."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.parent / f".{dst.name}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        if Path(src).is_dir():
            shutil.copytree(src, tmp)
        else:
            with open(src, "rb") as fin:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666 & ~UMASK)
                with os.fdopen(fd, "wb") as fout:
                    shutil.copyfileobj(fin, fout, 1 << 20)
                    fout.flush()
                    os.fsync(fout.fileno())
    except OSError as exc:
        _remove_path(tmp)
        raise OSError(exc.errno, exc.strerror, str(dst)) from None
    except BaseException:
        _remove_path(tmp)
        raise
    return tmp


def _rename_into_place(tmp: Path, dst: Path) -> None:
    if dst.is_symlink() and tmp.is_dir():
        dst.unlink()  # a folder cannot be renamed over a link; the link goes, never its target
    if dst.is_dir() and not dst.is_symlink():
        aside = dst.parent / f".{dst.name}.{uuid.uuid4().hex[:8]}.old.tmp"
        os.replace(dst, aside)
        os.replace(tmp, dst)
        shutil.rmtree(aside, ignore_errors=True)
    else:
        os.replace(tmp, dst)  # replaces a file or a link (never what a link points to)


def _remove_path(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _run_step(step: Step, state: _Run) -> dict[str, Any]:
    """Run one step, or take it from the cache; its record for the manifest."""
    slog = stage_logger(step.name, f"{state.plan.steps.index(step) + 1} of {len(state.plan.steps)}")
    resolved = {name: state.plan.resolve(name) for name in step.io.inputs}
    record: dict[str, Any] = {"name": step.name, "version": step.stage.version}
    buffer = step.stage.tile_buffer(step.params)
    record["tiled"] = buffer is not None
    if buffer is not None:
        record["tile_buffer"] = buffer
    if any(r in state.unknown for r in resolved.values()):
        return _upstream_unknown(step, state, record)
    files, watched = _external_hashes(step, state.config)
    state.manifest["inputs"].update(files)
    input_hashes = {name: state.artifacts[r][1] for name, r in resolved.items()}
    upstream = None
    if step.stage.reads_metrics:
        if any("metrics" not in r for r in state.records.values()):  # dry run: not known yet
            return _upstream_unknown(step, state, record)
        upstream = {name: r["metrics"] for name, r in state.records.items()}
    key = _stage_key(step, state.config, input_hashes, files, upstream)
    record.update(key=key, inputs=input_hashes)
    if state.dry_run:
        return _dry_run_record(step, state, key, record)
    # One run at a time computes an entry; a concurrent run of the same
    # configuration waits here and then finds the entry complete.
    cache = state.cache
    with (
        _machine_failures("cache", cache.root, step.name),
        cache.lock(step.name, key, lambda: slog.info("another run is computing this stage; waiting for it")),
    ):
        entry = None if step.name in state.force else cache.lookup(step.name, key)
        if entry is not None:
            cache.sweep(step.name, key)
            slog.info("cache hit (key %s; stage %s)", key[:12], slog.extra["step"])
            for line in (entry.meta.get("metrics") or {}).get(LOG_WARNINGS) or []:
                slog.warning("%s (cached result)", line)  # what the result warned of when it was made still holds
            record.update(status="cached", seconds=0.0, ran_seconds=entry.meta.get("seconds"))
        else:
            inputs = {n: state.artifacts[r][0] for n, r in resolved.items()}
            replace = step.name in state.force
            entry = _execute(
                step, state.config, cache, key, inputs, input_hashes, slog, upstream, state.executor, replace, watched
            )
            record.update(status="ran", seconds=entry.meta["seconds"])
    _remember(entry, step, state.artifacts)
    record["outputs"] = {
        a: {"file": str(entry.output_path(a)), "sha256": o["sha256"], "bytes": o["bytes"]}
        for a, o in entry.meta["outputs"].items()
    }
    record["metrics"] = entry.meta.get("metrics", {})
    return record


def _upstream_unknown(step: Step, state: _Run, record: dict[str, Any]) -> dict[str, Any]:
    """Dry run: the step's key depends on outputs not computed yet."""
    state.unknown.update(step.io.outputs)
    record["status"] = "run (upstream)"
    return record


def _external_hashes(step: Step, config: BaseModel) -> tuple[dict[str, str], dict[str, tuple[str, tuple]]]:
    """SHA-256 of every file outside the cache the step reads, and what each was when hashed.

    Returns ``{path: sha256}`` and ``{path: (sha256, identity)}`` for
    :func:`_check_unchanged`.  A missing input, or one that is not a regular
    file (a FIFO, a folder, a device: never opened), is a ConfigError; one
    that cannot be read, an InputDataError.
    """
    files, watched = {}, {}
    for path in step.stage.external_files(step.params, config):
        try:
            mode = os.stat(path).st_mode
            if not stat.S_ISREG(mode):
                raise NotRegularFile(0, file_kind(mode), str(path))
            digest, seen = hash_regular_file(Path(path))
        except FileNotFoundError:
            raise ConfigError(f"stage '{step.name}': input file not found: {path}.") from None
        except NotRegularFile as exc:
            raise ConfigError(
                f"stage '{step.name}': the input {path} is {exc.strerror}, not a regular file; "
                "name the file itself in the configuration."
            ) from None
        except PermissionError as exc:
            raise InputDataError(
                f"stage '{step.name}': the input {path} cannot be read ({exc.strerror}); "
                "make it readable and run again."
            ) from None
        files[str(path)] = digest
        watched[str(path)] = (digest, seen)
    return files, watched


def _check_unchanged(stage: str, watched: dict[str, tuple[str, tuple]]) -> None:
    """Refuse the result of a stage whose input file changed while it ran (its key would lie).

    A file with another identity (size, times, inode) is hashed again; only
    other bytes than those hashed for the key are refused.
    """
    for path, (digest, seen) in watched.items():
        try:
            if identity(os.stat(path)) == seen or hash_regular_file(Path(path))[0] == digest:
                continue
        except OSError:
            pass  # gone, or not a regular file any more
        raise InputDataError(
            f"stage '{stage}': the input {path} changed while the run read it; nothing was cached: "
            "run again once it is no longer being written."
        )


def _dry_run_record(step: Step, state: _Run, key: str, record: dict[str, Any]) -> dict[str, Any]:
    """Dry run: whether the step would be taken from the cache or run."""
    entry = None if step.name in state.force else state.cache.lookup(step.name, key)
    if entry is None:
        state.unknown.update(step.io.outputs)
        record["status"] = "run"
    else:
        _remember(entry, step, state.artifacts)
        record["status"] = "cached"
        record["metrics"] = entry.meta.get("metrics", {})
    return record


def _remember(entry: Entry, step: Step, artifacts: dict[str, tuple[Path, str]]) -> None:
    for artifact in step.io.outputs:
        artifacts[artifact] = (entry.output_path(artifact), entry.output_hash(artifact))


def _execute(
    step: Step,
    config: BaseModel,
    cache: Cache,
    key: str,
    inputs: dict[str, Path],
    input_hashes: dict[str, str],
    slog: logging.LoggerAdapter,
    upstream: dict[str, dict[str, Any]] | None = None,
    executor: Any = None,
    replace: bool = False,
    watched: dict[str, tuple[str, tuple]] | None = None,
) -> Entry:
    workspace = cache.new_workspace(step.name, key)
    try:  # from here on, any failure or interruption removes the workspace
        ctx = StageContext(
            name=step.name,
            params=step.params,
            config=config,
            inputs=inputs,
            outputs={a: workspace / f for a, f in step.io.outputs.items()},
            workdir=workspace,
            workers=capped_workers(getattr(getattr(config, "executor", None), "workers", 1)),
            log=slog,
            executor=executor if executor is not None else LocalExecutor(1),
            upstream_metrics=upstream or {},
            config_keys=tuple(step.stage.config_keys),
            tile_cache=TileCache(cache.root, step.name, _stage_key(step, config, {}, {}, None), not replace, slog),
        )
        slog.info("running (stage %s)", slog.extra.get("step", "?"))
        t0 = time.perf_counter()
        with StageWarnings(step.name) as warned, hosting(step.name):
            step.stage.run(ctx)
        if warned.lines:
            ctx.metrics[LOG_WARNINGS] = warned.lines
        _check_unchanged(step.name, watched or {})
        seconds = round(time.perf_counter() - t0, 3)
        meta = {
            "stage": step.name,
            "version": step.stage.version,
            "params": step.params.model_dump(mode="json") if step.params is not None else None,
            "inputs": input_hashes,
            "outputs": dict(step.io.outputs),
            "metrics": ctx.metrics,
            "seconds": seconds,
        }
        known = {Path(inputs[n]): input_hashes[n] for n in inputs if n in input_hashes}
        entry = cache.commit(step.name, key, workspace, meta, replace=replace, known=known)
    except BaseException as exc:
        if isinstance(exc, WorkerLost):
            exc.stage = step.name  # the sentence names the stage
        if executor is not None:  # its workers may still be writing tile parts into the workspace: stop them first
            executor.close(abort=True)
        Cache.discard(workspace)
        raise
    slog.info("done in %.2f s", seconds)
    release_freed_memory()  # what the stage freed, not held into the next ones
    return entry


def _utc(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))
