"""YAML configuration: safe loading with line numbers, overrides, validation.

The configuration file is parsed with PyYAML's *safe* loader only.  While it is
read, the line of every key is recorded, so that a validation error can name
the file, the line and the dotted key ("flight.yaml, line 12:
stages.rasterize.resolution: ...").  Values given on the command line with
``--set dotted.key=value`` are merged on top and named as such in errors.

Relative paths in a configuration are resolved against the folder of the
configuration file, never against the current working directory.
"""

from __future__ import annotations

import difflib
import glob
import os
import stat
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
)

from pipeline.cache import file_kind
from pipeline.errors import ConfigError
from pipeline.executor import usable_cores
from pipeline.registry import RegistryField

Location = tuple[str | int, ...]


class StrictModel(BaseModel):
    """Base of every configuration model: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid", validate_default=True)


def _resolve_path(value: Path, info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    path = Path(os.path.expanduser(str(value)))
    if not path.is_absolute() and base is not None:
        path = Path(base) / path
    return Path(os.path.abspath(path))


def _must_be_file(value: Path) -> Path:
    try:
        mode = value.stat().st_mode
    except FileNotFoundError:
        raise ValueError(f"file not found: {value}") from None
    except OSError as exc:
        raise ValueError(f"cannot read {value} ({exc.strerror or exc})") from None
    if not stat.S_ISREG(mode):
        raise ValueError(f"{value} is {file_kind(mode)}, not a regular file")
    return value


#: A path relative to the configuration file's folder.
RelPath = Annotated[Path, AfterValidator(_resolve_path)]
#: A path to an existing file, relative to the configuration file's folder.
InputFile = Annotated[Path, AfterValidator(_resolve_path), AfterValidator(_must_be_file)]


def _has_suffix(path: Path, suffixes: tuple[str, ...]) -> bool:
    name = path.name.lower()
    return any(name.endswith(s) for s in suffixes)


def expand_input_path(value: Path, info: ValidationInfo, suffixes: tuple[str, ...]) -> list[Path]:
    """The files one entry of a file list names: itself, a folder's files, or a glob pattern's, sorted.

    *value* is resolved against the configuration file's folder.  An
    existing file is itself (whatever its name); a folder gives the regular
    files directly inside it whose names end with one of *suffixes*
    (case-insensitive; subfolders are not searched); otherwise a name with
    ``*``, ``?`` or ``[`` is a glob pattern (Python's :mod:`glob`, ``**``
    matching any depth of folders) giving the regular files it matches with
    those suffixes.  Folders and patterns give their files sorted by path.
    Nothing found is a ValueError naming the entry and the way out.
    """
    path = _resolve_path(value, info)
    shown = " or ".join(suffixes)
    if path.is_dir():
        found = sorted((p for p in path.iterdir() if p.is_file() and _has_suffix(p, suffixes)), key=str)
        if not found:
            raise ValueError(
                f"the folder {path} holds no {shown} file directly inside it (subfolders are not searched); "
                f"give a pattern such as {Path(str(value)) / '**' / ('*' + suffixes[-1])} to search them, "
                "or the files themselves"
            )
        return found
    if not path.exists() and glob.has_magic(str(value)):
        matched = (Path(p) for p in glob.glob(str(path), recursive=True))
        found = sorted((p for p in matched if p.is_file() and _has_suffix(p, suffixes)), key=str)
        if not found:
            base = (info.context or {}).get("base_dir")
            where = f" (relative to {base})" if base is not None and not Path(str(value)).is_absolute() else ""
            raise ValueError(
                f"the pattern {value}{where} matches no {shown} file; correct the pattern or list the files"
            )
        return found
    return [_must_be_file(path)]


def _flatten(value: list[list[Path]]) -> list[Path]:
    return [path for paths in value for path in paths]


def input_files(suffixes: tuple[str, ...]) -> Any:
    """A list of input files given as files, folders or glob patterns (:func:`expand_input_path`).

    *suffixes* (lower case, e.g. ``(".csv", ".csv.gz")``) are the file names a
    folder or a pattern picks.  Validated, the list holds every file in the
    order of its entries, each folder's or pattern's files sorted by path;
    an error names the entry (``key.N``) and its line.
    """

    def expand(value: Path, info: ValidationInfo) -> list[Path]:
        return expand_input_path(value, info, suffixes)

    return Annotated[list[Annotated[Path, AfterValidator(expand)]], AfterValidator(_flatten)]


class ExecutorConfig(StrictModel):
    """Where tiled work runs: this machine's processes or a Dask cluster."""

    kind: Literal["local", "dask"] = Field(
        "local", description="local: worker processes on this machine; dask: a Dask distributed cluster"
    )
    workers: int = Field(
        default_factory=lambda: usable_cores(),
        ge=1,
        description="tiles processed at a time (local processes, or the workers of a local Dask cluster); "
        "never more processes than the CPU cores this run may use (os.sched_getaffinity) nor than there are "
        "tasks: a larger number is lowered, and the log says so; default: the usable CPU cores",
    )
    address: str | None = Field(
        None,
        description="Dask scheduler address, e.g. tcp://host:8786 (workers must see the cache folder at the same "
        "path); none = a local Dask cluster of `workers` processes",
    )
    connect_timeout_s: float = Field(
        10.0,
        gt=0,
        le=3600,
        allow_inf_nan=False,
        description="seconds to wait for the Dask scheduler at `address` to answer; then the run stops "
        "(exit 4) instead of waiting for ever; default 10",
    )
    no_workers_timeout_s: float = Field(
        300.0,
        gt=0,
        le=86_400,
        allow_inf_nan=False,
        description="seconds a Dask cluster may have no worker while tasks wait; then the run cancels them and "
        "stops (exit 4) instead of waiting for ever; a worker lost meanwhile is logged; default 300",
    )
    in_process_below: int = Field(
        100_000,
        ge=0,
        description="local executor: a stage whose tiled work weighs less than this (its points, for this "
        "pipeline's stages) runs its tiles one after the other in the run's own process, without starting "
        "workers (about 1 s, more than such work takes); the products are the same; 0: always use the workers",
    )


#: Smallest tile side (metres): smaller tiles cost more in buffers than they save.
MIN_TILE_SIZE = 10.0
#: Largest tile buffer (metres).
MAX_TILE_BUFFER = 10_000.0


class TilingConfig(StrictModel):
    """How stages that work tile by tile cut the survey.

    Tiles are squares of ``size`` aligned on multiples of ``size``; each task
    gets its tile plus a buffer and keeps only the tile.  Lengths are in the
    unit the stages measure their extent in (metres for this pipeline's
    stages, whatever the CRS).
    """

    enabled: bool = Field(True, description="cut large surveys into tiles; false: every stage sees the whole survey")
    size: float = Field(
        500.0,
        ge=MIN_TILE_SIZE,
        allow_inf_nan=False,
        description=f"tile side (metres, at least {MIN_TILE_SIZE:g}); memory per worker grows with size**2 x "
        "point density",
    )
    buffer: float | None = Field(
        None,
        ge=0,
        le=MAX_TILE_BUFFER,
        allow_inf_nan=False,
        description="buffer around each tile (metres, at most "
        f"{MAX_TILE_BUFFER:g}); none = each stage's own, the reach of its algorithm, "
        "which makes tiled results identical to untiled ones",
    )


# --------------------------------------------------------------------------
# YAML with line numbers


#: Largest configuration file read (bytes): a configuration is a page of text.
MAX_CONFIG_BYTES = 1 << 20
#: Deepest nesting of mappings and lists in a configuration.
MAX_DEPTH = 64
#: Most values a configuration may hold once its aliases are expanded.
MAX_VALUES = 100_000


def load_yaml(path: Path) -> tuple[Any, dict[Location, int]]:
    """Read a YAML file safely: the document and the 1-based line of every key and list item.

    Lines are keyed by location (a tuple of keys and indices).  Refused in one
    sentence (``ConfigError``): a path that is not a regular file (a FIFO, a
    folder, a device), an unreadable or invalid file, a repeated key, more
    than :data:`MAX_CONFIG_BYTES`, nesting deeper than :data:`MAX_DEPTH`, an
    alias that refers to itself, or aliases expanding to more than
    :data:`MAX_VALUES` values (a "billion laughs" file is refused after a
    few hundred bytes, not expanded).
    """
    path = Path(path)
    text = _read_config_text(path)
    try:
        data, node = _compose(text, path)
        data = {} if node is None else data
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, max(exc.position, 0)) + 1
        raise ConfigError(
            f"{path}, line {line}: not valid YAML (character #x{exc.character:04x} is not allowed)."
        ) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}{where}: not valid YAML ({exc.problem or exc.context}).") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc}).") from None
    lines: dict[Location, int] = {}
    if node is not None:
        _record_lines(node, (), lines, path)
    return data, lines


def _compose(text: str, source: Path | str, depth: int = 1) -> tuple[Any, yaml.Node | None]:
    """The document of *text* and its node tree, its size and nesting checked before it is built.

    *source* is the file (messages name its line) or an override's label;
    *depth* is the level the document sits at (1: the top of a
    configuration).  Limits break in one sentence (``ConfigError``); YAML
    syntax errors propagate as ``yaml.YAMLError``.
    """
    loader = yaml.SafeLoader(text)  # the reader checks every character here
    try:
        try:
            node = loader.get_single_node()
        except RecursionError:
            raise ConfigError(
                f"{_at(source, loader.get_mark().line + 1)}: the configuration nests mappings or lists more than "
                f"{MAX_DEPTH} levels deep."
            ) from None
        if node is None:
            return None, None
        _check_graph(node, source, depth)
        return loader.construct_document(node), node
    finally:
        loader.dispose()


def _at(source: Path | str, line: int) -> str:
    """Where a problem is: the file and line, or the override (a one-line value)."""
    return f"{source}, line {line}" if isinstance(source, Path) else str(source)


def _read_config_text(path: Path) -> str:
    """The text of a configuration file, read up to :data:`MAX_CONFIG_BYTES`.

    Only a regular file is read: a FIFO (which blocks until someone writes
    to it), a folder or a device (``/dev/zero`` never ends) is refused at
    once, without waiting on it.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))  # a FIFO does not block
    except FileNotFoundError:
        raise ConfigError(f"{path}: configuration file not found.") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration file ({exc.strerror or exc}).") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = file_kind(mode) + (", which would block until something writes to it" if stat.S_ISFIFO(mode) else "")
        raise ConfigError(f"{path}: not a configuration file but {kind}; give the path of a YAML file.")
    with open(fd, "rb") as fh:
        try:
            raw = fh.read(MAX_CONFIG_BYTES + 1)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read the configuration file ({exc.strerror or exc}).") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{path}: not a configuration file (more than {MAX_CONFIG_BYTES // 1024} KiB); "
            "a configuration is a short YAML text."
        )
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise ConfigError(f"{path}, line {line}: not UTF-8 text (byte {exc.start}).") from None


def _check_graph(root: yaml.Node, source: Path | str, depth: int = 1) -> None:
    """Refuse recursive aliases, deep nesting and alias expansion beyond :data:`MAX_VALUES`.

    Each distinct node is visited once (an alias is the same node object
    again), so the check costs the size of the file, not of its expansion.
    *depth* is the level of *root* (an override's value sits below its keys).
    """
    sizes: dict[int, int] = {}  # id(node) -> values it expands to
    open_nodes: set[int] = set()  # on the current path: meeting one again is a recursion
    # An explicit stack of (node, depth, children-done?) instead of recursion.
    stack: list[tuple[yaml.Node, int, bool]] = [(root, depth, False)]
    while stack:
        node, depth, done = stack.pop()
        children = _children(node)
        if done:
            open_nodes.discard(id(node))
            total = 1 + sum(sizes[id(c)] for c in children)
            sizes[id(node)] = total
            if total > MAX_VALUES:
                raise ConfigError(
                    f"{_at(source, node.start_mark.line + 1)}: the aliases here expand to more than "
                    f"{MAX_VALUES:,} values; a configuration this large is refused (write the values out)."
                )
            continue
        if id(node) in sizes:
            continue
        if depth > MAX_DEPTH:
            raise ConfigError(
                f"{_at(source, node.start_mark.line + 1)}: the configuration nests mappings or lists more than "
                f"{MAX_DEPTH} levels deep."
            )
        open_nodes.add(id(node))
        stack.append((node, depth, True))
        for child in children:
            if id(child) in open_nodes:
                raise ConfigError(
                    f"{_at(source, child.start_mark.line + 1)}: an alias refers to a value that contains it "
                    "(a recursive alias); a configuration must be a finite tree."
                )
            if id(child) not in sizes:
                stack.append((child, depth + 1, False))


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _record_lines(node: yaml.Node, loc: Location, lines: dict[Location, int], path: Path) -> None:
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key_node, value_node in node.value:
            key = key_node.value
            if key in seen:
                raise ConfigError(f"{path}, line {key_node.start_mark.line + 1}: key '{key}' is given twice.")
            seen.add(key)
            lines[loc + (key,)] = key_node.start_mark.line + 1
            _record_lines(value_node, loc + (key,), lines, path)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            lines[loc + (index,)] = item.start_mark.line + 1
            _record_lines(item, loc + (index,), lines, path)


# --------------------------------------------------------------------------
# --set overrides


#: Longest part of an override echoed in a message.
MAX_SHOWN = 80


def override_label(text: str) -> str:
    """``--set key=value`` as messages name it, a long value cut short."""
    return f"--set {text if len(text) <= MAX_SHOWN else text[: MAX_SHOWN - 1] + '…'}"


def parse_override(text: str) -> tuple[tuple[str, ...], Any]:
    """Split ``dotted.key=value``; the value is read as a YAML scalar or list.

    The key and the value together nest at most :data:`MAX_DEPTH` levels,
    as in a file, and the value's aliases expand to at most
    :data:`MAX_VALUES` values; text that is not YAML is kept as a string.
    """
    label = override_label(text)
    if "=" not in text:
        raise ConfigError(f"{label}: expected dotted.key=value.")
    key, _, raw = text.partition("=")
    parts = tuple(p for p in key.strip().split("."))
    if not key.strip() or any(not p for p in parts):
        raise ConfigError(f"{label}: the key must be dotted names like stages.rasterize.resolution.")
    if len(parts) >= MAX_DEPTH:
        raise ConfigError(
            f"{label}: the key nests {len(parts)} levels deep; a configuration nests at most {MAX_DEPTH}."
        )
    if not raw.strip():
        return parts, None
    try:
        value, _ = _compose(raw, label, depth=len(parts) + 1)
    except yaml.YAMLError:
        value = raw
    return parts, value


def apply_overrides(data: dict, overrides: list[str]) -> dict[Location, str]:
    """Merge ``--set`` overrides into *data* in place; return their locations."""
    sources: dict[Location, str] = {}
    for text in overrides:
        parts, value = parse_override(text)
        label = override_label(text)
        node = data
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
                # A mapping this override created: an error in it is the override's.
                sources.setdefault(parts[: i + 1], label)
            elif not isinstance(child, dict):
                where = ".".join(parts[: i + 1])
                raise ConfigError(f"{label}: '{where}' is not a mapping, so it has no key '{parts[i + 1]}'.")
            node = child
        node[parts[-1]] = value
        sources[parts] = label
    return sources


# --------------------------------------------------------------------------
# Validation errors in one sentence


def _real_location(data: Any, loc: Location) -> tuple[Location, str | None]:
    """Map a pydantic error location onto keys present in the data.

    Pydantic inserts union tags and validator names into locations; those are
    skipped.  Returns the deepest location present in *data* and, when the last
    element names a key that is absent (a missing key), that key.
    """
    real: list[str | int] = []
    cur = data
    missing: str | None = None
    for i, elem in enumerate(loc):
        if isinstance(cur, dict) and elem in cur:
            real.append(elem)
            cur = cur[elem]
        elif isinstance(cur, list) and isinstance(elem, int) and 0 <= elem < len(cur):
            real.append(elem)
            cur = cur[elem]
        elif i == len(loc) - 1 and isinstance(elem, str) and isinstance(cur, dict):
            missing = elem
    return tuple(real), missing


def model_types(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation may hold (through unions and Annotated)."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        choices = [m for m in typing.get_args(annotation)[1:] if isinstance(m, RegistryField)]
        return choices[0].registry.models() if choices else model_types(typing.get_args(annotation)[0])
    if origin in (Union, types.UnionType):
        found: list[type[BaseModel]] = []
        for arg in typing.get_args(annotation):
            found.extend(model_types(arg))
        return found
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return []


def field_models(field: Any) -> list[type[BaseModel]]:
    """The pydantic models a model's field may hold: those of a registry's algorithms, or of its annotation."""
    choices = [m for m in field.metadata if isinstance(m, RegistryField)]
    return choices[0].registry.models() if choices else model_types(field.annotation)


def _allowed_keys(model: type[BaseModel], loc: Location) -> set[str]:
    """Field names allowed at *loc* (a location of a mapping) under *model*."""
    models = [model]
    for elem in loc:
        if isinstance(elem, int):
            continue
        nxt: list[type[BaseModel]] = []
        for m in models:
            field = m.model_fields.get(elem)
            if field is not None:
                nxt.extend(field_models(field))
        models = nxt
    return {name for m in models for name in m.model_fields}


#: Most problems listed in one error message.
MAX_LISTED = 20


def describe_validation_error(
    exc: ValidationError,
    data: Any,
    source: Path,
    lines: dict[Location, int],
    overrides: dict[Location, str],
    model: type[BaseModel],
) -> str:
    """Turn pydantic's errors into sentences with file, line and key.

    One problem is one sentence; several are one sentence each, on their own
    lines (at most :data:`MAX_LISTED`, then how
    many more there are).
    """
    sentences: list[str] = []
    for err in exc.errors(include_url=False):
        sentence = _describe_one(err, data, source, lines, overrides, model).replace("\n", "\\n")  # one line each
        if sentence not in sentences:
            sentences.append(sentence)
    if len(sentences) == 1:
        return sentences[0]
    shown = sentences[:MAX_LISTED]
    more = len(sentences) - len(shown)
    tail = f"\n  ... and {more} more." if more else ""
    return f"{len(sentences)} problems in the configuration:\n  " + "\n  ".join(shown) + tail


def _describe_one(
    err: Any,
    data: Any,
    source: Path,
    lines: dict[Location, int],
    overrides: dict[Location, str],
    model: type[BaseModel],
) -> str:
    loc, missing = _real_location(data, tuple(err["loc"]))
    key = ".".join(str(p) for p in loc + ((missing,) if missing else ()))
    # The most specific place: the override that set it, else the line of
    # the key, else the line of the nearest parent key.
    # An override of the key or of a parent wins over the file's lines (it replaced what they said).
    where = next((overrides[loc[:n]] for n in range(len(loc), -1, -1) if loc[:n] in overrides), None)
    overridden = where is not None
    if where is None:
        where = next((f"{source}, line {lines[loc[:n]]}" for n in range(len(loc), -1, -1) if loc[:n] in lines), None)
    if where is None:
        where = f"{source}, line 1"
    etype = err["type"]
    msg = str(err["msg"])
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if etype == "extra_forbidden":
        allowed = sorted(_allowed_keys(model, loc[:-1]))
        close = difflib.get_close_matches(str(loc[-1]), allowed, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        msg = f"unknown key{hint}; allowed here: {', '.join(allowed)}"
    elif etype == "missing":
        msg = "required key is missing"
    elif etype in ("model_type", "dict_type") and err.get("input") is None:
        msg = "an empty block; give it keys (docs/CONFIG.md lists them) or remove the line"
    elif "input" in err and etype != "value_error" and not isinstance(err["input"], (dict, list)):
        msg = f"{msg} (got {err['input']!r})"
    if overridden and msg.startswith("file not found"):
        msg += f" (relative paths are read from the configuration's folder, {Path(source).parent.resolve()})"
    return f"{where}: {key or '<top level>'}: {msg}."


def load_config(path: Path, model: type[BaseModel], overrides: list[str] | None = None) -> BaseModel:
    """Read a YAML configuration, merge the ``--set`` overrides (``dotted.key=value``), validate it.

    *model* is the configuration model (:func:`pipeline.stage.config_model`).
    Every problem is one sentence naming the file, line and key (``ConfigError``).
    """
    path = Path(path)
    data, lines = load_yaml(path)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}, line 1: the configuration must be a mapping of keys to values.")
    sources = apply_overrides(data, list(overrides or []))
    try:
        return model.model_validate(data, context={"base_dir": path.parent.resolve()})
    except ValidationError as exc:
        raise ConfigError(describe_validation_error(exc, data, path, lines, sources, model)) from None
