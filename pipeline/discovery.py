"""Finding the plugin that supplies the stages.

The plugin is named by the environment variable ``PIPELINE_PLUGIN``
(``module:attribute``) when set, else by the one entry point of the group
``pipeline.plugins`` of the installed packages.

A plugin may be a :class:`~pipeline.stage.Plugin`, a callable returning one,
or a :class:`LazyPlugin`: its name and commands, with its stages loaded on
first use.  The command line builds its parser from the name and the
commands alone, so that ``pipeline --help`` imports no stage (nor the
libraries the stages use); ``run``, ``validate`` and ``schema`` load them.
This module imports nothing heavy for the same reason.
"""

from __future__ import annotations

import argparse
import importlib
import os
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any

from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Callable

    from pipeline.stage import Plugin

ENTRY_POINT_GROUP = "pipeline.plugins"


def _resolve(spec: str) -> Any:
    """The object named by ``module:attribute``."""
    module_name, _, attr = spec.partition(":")
    return getattr(importlib.import_module(module_name), attr)


@dataclass(frozen=True)
class LazyCommand:
    """A sub-command whose code is imported only when the parser or the command needs it.

    Parameters
    ----------
    name, help
        The sub-command's name and its one line in ``pipeline --help``.
    arguments
        ``module:function`` adding the sub-command's arguments to its parser;
        its module should import little, as every ``pipeline`` call builds
        the whole parser.
    run
        ``module:function`` running the command with the parsed arguments,
        returning the exit code.
    """

    name: str
    help: str
    arguments: str
    run_with: str

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Add the sub-command's arguments to *parser* (imports the ``arguments`` module)."""
        _resolve(self.arguments)(parser)

    def run(self, args: argparse.Namespace) -> int:
        """Run the command (imports the ``run_with`` module)."""
        return _resolve(self.run_with)(args)


@dataclass
class LazyPlugin:
    """A plugin known by its name and commands, its stages loaded on first use.

    ``load`` builds the :class:`~pipeline.stage.Plugin` (importing the stages);
    it is called once, when an attribute other than ``name`` and ``commands``
    is read (``stages``, ``global_fields``, ``versions``, ``stage``), and its
    name must be this one's.
    """

    name: str
    commands: list[Any]
    load: Callable[[], Plugin]
    _loaded: Plugin | None = field(default=None, init=False, repr=False)

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__") or attr == "_loaded":
            raise AttributeError(attr)
        if self._loaded is None:
            loaded = self.load()
            if loaded.name != self.name:
                raise ValueError(f"plugin {self.name}: its loader built plugin {loaded.name}")
            self._loaded = loaded
        return getattr(self._loaded, attr)


def _instance(obj: Any) -> Any:
    """The plugin an entry point names: the object itself, or what a factory returns."""
    return obj() if callable(obj) else obj  # a Plugin or a LazyPlugin is not callable


def load_plugin() -> Plugin | LazyPlugin:
    """The plugin that supplies the stages and commands (an empty one when none is installed)."""
    spec = os.environ.get("PIPELINE_PLUGIN")
    if spec:
        module_name, _, attr = spec.partition(":")
        try:
            obj = getattr(importlib.import_module(module_name), attr or "plugin")
        except (ImportError, AttributeError) as exc:
            raise ConfigError(f"PIPELINE_PLUGIN={spec}: cannot load it ({exc}).") from None
        return _instance(obj)
    found = list(entry_points(group=ENTRY_POINT_GROUP))
    if not found:
        from pipeline.stage import Plugin  # lazy: pydantic, not for pipeline --help (start-up time)

        return Plugin(name="pipeline", stages=[])
    if len(found) > 1:
        names = ", ".join(ep.value for ep in found)
        raise ConfigError(f"several plugins are installed ({names}); choose one with PIPELINE_PLUGIN.")
    return _instance(found[0].load())
