"""The stage contract and the plugin that registers stages.

A stage declares its ``name``, ``version`` (part of the cache key: bump it
when the output changes for the same inputs and parameters) and ``Params``
(read from ``stages.<name>`` or ``config_path``); the artifacts it reads
(``inputs``) and writes (``outputs``), the outputs it publishes
(``products``), what stands in for its outputs when it is disabled
(``passthrough``), other settings that change its result (``config_keys``),
whether it reads earlier stages' metrics (``reads_metrics``), and through
:meth:`Stage.tile_buffer` whether it works tile by tile.  The engine knows
nothing else: it orders stages by their inputs, checks the graph before
anything runs, and calls :meth:`Stage.run` with a :class:`StageContext`.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Generic, TypeVar

from pydantic import BaseModel, Field, create_model

from pipeline.config import ExecutorConfig, RelPath, StrictModel, TilingConfig
from pipeline.log import Progress

#: The parameters' model of a stage (``StageContext[RasterizeParams]``).
P = TypeVar("P", bound=BaseModel)


class StageParams(StrictModel):
    """Base of the parameters of every stage that can be switched off."""

    enabled: bool = Field(
        True, description="run this stage; when false, a filter passes its input on and a product is not made"
    )


@dataclass(frozen=True)
class StageIO:
    """The artifacts a stage reads and writes under a given configuration."""

    inputs: tuple[str, ...] = ()
    outputs: dict[str, str] = field(default_factory=dict)
    products: dict[str, str] = field(default_factory=dict)


@dataclass
class StageContext(Generic[P]):
    """What a stage's ``run`` receives; ``StageContext[MyParams]`` types ``ctx.params``.

    ``params``: the stage's validated parameters; ``config``: the whole
    configuration, for checks and messages (a value that changes the result
    is read with :meth:`setting`); ``inputs``: artifact name -> path to read;
    ``outputs``: artifact name -> path to write, in a private workspace;
    ``executor``: runs tiled work (:func:`pipeline.tiling.run_tiled`);
    ``metrics``: JSON-ready figures for the manifest and the report, cached
    with the outputs; ``upstream_metrics``: the earlier stages' (with
    ``reads_metrics``).
    """

    name: str
    params: P
    config: BaseModel
    inputs: dict[str, Path]
    outputs: dict[str, Path]
    workdir: Path
    workers: int
    log: logging.LoggerAdapter
    executor: Any = None
    metrics: dict[str, Any] = field(default_factory=dict)
    upstream_metrics: dict[str, dict[str, Any]] = field(default_factory=dict)
    config_keys: tuple[str, ...] = ()
    tile_cache: Any = None

    def setting(self, key: str) -> Any:
        """The configuration value at the dotted *key*, which the stage declared in ``config_keys``.

        A stage whose result depends on another block's setting reads it here,
        so that the setting is in the stage's cache key and in the docs;
        reading an undeclared key is a bug of the stage (``KeyError``).
        """
        if not any(key == k or key.startswith(k + ".") for k in self.config_keys):
            raise KeyError(f"stage {self.name} reads '{key}' without declaring it in config_keys")
        return get_dotted(self.config, key)

    def progress(self, total: float, desc: str, unit: str = "it") -> Progress:
        """A progress reporter for *total* units of work."""
        return Progress(total, desc, self.name, unit)


class Stage:
    """Base class of a stage.  Subclasses set the class attributes and ``run``."""

    name: ClassVar[str]
    version: ClassVar[str] = "1"
    Params: ClassVar[Any] = StageParams  # a model, or an Annotated union of models
    config_path: ClassVar[str | None] = None
    inputs: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[dict[str, str]] = {}
    products: ClassVar[dict[str, str]] = {}
    passthrough: ClassVar[dict[str, str]] = {}
    config_keys: ClassVar[tuple[str, ...]] = ()
    reads_metrics: ClassVar[bool] = False
    description: ClassVar[str] = ""

    def __init_subclass__(
        cls, *, name: str | None = None, version: str | None = None, params: Any = None, **kwargs: Any
    ) -> None:
        """``class Rasterize(Stage, name="rasterize", version="5", params=RasterizeParams)``.

        The identity may also be set as class attributes.  The class docstring,
        without its final period, is the ``description`` unless one is set.
        """
        super().__init_subclass__(**kwargs)
        for attr, value in (("name", name), ("version", version), ("Params", params)):
            if value is not None:
                setattr(cls, attr, value)
        if "description" not in cls.__dict__ and cls.__doc__:
            cls.description = " ".join(cls.__doc__.split()).removesuffix(".")

    @classmethod
    def params_path(cls) -> str:
        """Dotted location of this stage's parameters in the configuration."""
        return cls.config_path or f"stages.{cls.name}"

    def is_enabled(self, params: BaseModel, config: BaseModel) -> bool:
        """Whether the stage runs under this configuration."""
        return bool(getattr(params, "enabled", True))

    def declare(self, params: BaseModel, config: BaseModel) -> StageIO:
        """The stage's artifacts under this configuration (default: the class attributes)."""
        return StageIO(tuple(self.inputs), dict(self.outputs), dict(self.products))

    def tile_buffer(self, params: BaseModel) -> float | None:
        """The buffer a per-tile stage needs around each tile; None for a global stage.

        A per-tile stage runs its work through :func:`pipeline.tiling.run_tiled`
        with this buffer (in the unit of the extent it gives, the reach of its
        algorithm); a global stage sees the whole input (and streams it).
        """
        return None

    def spreads_changes(self, params: BaseModel, previous: dict[str, Any]) -> str | None:
        """Why a change in one part of the input may change this stage's output everywhere (None: it does not).

        *previous*: the stage's entry in the last run's ``run.json``.  The
        dry run then counts every tile of the stages after it
        (:mod:`pipeline.replan`).
        """
        return None

    def external_files(self, params: BaseModel, config: BaseModel) -> list[Path]:
        """Files outside the cache that the stage reads (their content enters the key)."""
        return []

    def run(self, ctx: StageContext[Any]) -> None:  # pragma: no cover - interface
        """Do the work: read ``ctx.inputs``, write every path in ``ctx.outputs``."""
        raise NotImplementedError


@dataclass
class Command:
    """An extra sub-command a plugin adds to the ``pipeline`` command line."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


@dataclass
class Plugin:
    """What a domain package gives the engine.

    ``name``: shown in ``--version`` and the manifest; ``stages``: the Stage
    classes in their natural order (ties in the graph's order); ``global_fields``:
    extra top-level configuration keys, name -> (annotation, default), as for
    :func:`pydantic.create_model`; ``commands``: extra sub-commands (:class:`Command`,
    or any object with its attributes, e.g. :class:`pipeline.discovery.LazyCommand`);
    ``versions``: ``{package: version}`` of the libraries that shape results,
    for the manifest; ``changed_areas``: in a dry run after input files
    changed, ``changed_areas(config, changed, previous, output)`` places them
    (a :class:`pipeline.replan.ChangedAreas`, or None when it cannot say) so
    that the dry run says how many tiles each tiled stage will run
    (*changed*: path -> "changed", "new" or "removed" against the last run's
    ``run.json``, *previous*, in the folder *output*); ``not_a_configuration``:
    given the path ``run`` or ``validate`` was asked to read as a configuration,
    one sentence saying what the file is and how to run it when it is one of
    the domain's data files (None otherwise); ``configuration_warnings``: given
    a valid configuration, the sentences ``validate`` prints as warnings (what
    will run but likely not as meant).
    """

    name: str
    stages: list[type[Stage]]
    global_fields: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    commands: list[Any] = field(default_factory=list)
    versions: Callable[[], dict[str, str]] = dict
    changed_areas: Callable[..., Any] | None = None
    not_a_configuration: Callable[[Path], str | None] | None = None
    configuration_warnings: Callable[[Any], list[str]] | None = None

    def stage(self, name: str) -> type[Stage]:
        for stage in self.stages:
            if stage.name == name:
                return stage
        raise KeyError(name)


def config_model(plugin: Plugin) -> type[BaseModel]:
    """Build the configuration model of a plugin's stages.

    The top level has ``name``, ``output``, ``cache``, ``executor``, ``tiling``, the
    plugin's global fields, ``stages`` (one block per stage whose parameters
    live under ``stages.``) and any stage parameters placed elsewhere by
    ``config_path`` (for example ``input``).
    """
    stage_fields: dict[str, Any] = {}
    top_fields: dict[str, Any] = {}
    for stage in plugin.stages:
        path = stage.params_path().split(".")
        has_defaults = _all_defaults(stage.Params)
        desc = f"stage {stage.name}: {stage.description}" if stage.description else f"stage {stage.name}"
        default: Any = (
            Field(default_factory=stage.Params, description=desc) if has_defaults else Field(..., description=desc)
        )
        if path[0] == "stages" and len(path) == 2:
            stage_fields[path[1]] = (stage.Params, default)
        elif len(path) == 1:
            top_fields[path[0]] = (stage.Params, default)
        else:
            raise ValueError(f"stage {stage.name}: config_path must be one key or stages.<key>")
    stages_model = create_model("Stages", __base__=StrictModel, **stage_fields)
    fields: dict[str, Any] = {
        "name": (str | None, Field(None, description="name of the job (default: the config file's name)")),
        "output": (RelPath, Field(..., description="folder for products, relative to the config file")),
        "cache": (
            RelPath | None,
            Field(None, description="cache folder, relative to the config file (default: <output>/.cache)"),
        ),
        "executor": (ExecutorConfig, Field(default_factory=ExecutorConfig, description="where tiled work runs")),
        "tiling": (TilingConfig, Field(default_factory=TilingConfig, description="how large surveys are cut")),
        **plugin.global_fields,
        **top_fields,
        "stages": (stages_model, Field(default_factory=stages_model, description="one block per stage")),
    }
    return create_model("Config", __base__=StrictModel, **fields)


def _all_defaults(params: Any) -> bool:
    """Whether a stage's parameter block may be left out (a union of models never may)."""
    if not (isinstance(params, type) and issubclass(params, BaseModel)):
        return False
    return all(not f.is_required() for f in params.model_fields.values())


def get_dotted(obj: Any, dotted: str) -> Any:
    """``get_dotted(config, "stages.rasterize")`` -> that block (None if absent)."""
    for part in dotted.split("."):
        if obj is None:
            return None
        obj = obj.get(part) if isinstance(obj, dict) else getattr(obj, part, None)
    return obj
