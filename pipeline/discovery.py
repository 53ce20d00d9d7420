"""Finding the plugin that supplies the stages.

The plugin is named by the environment variable ``PIPELINE_PLUGIN``
(``module:attribute``) when set, else by the one entry point of the group
``pipeline.plugins`` of the installed packages.
"""

from __future__ import annotations

import importlib
import os
from importlib.metadata import entry_points

from pipeline.errors import ConfigError
from pipeline.stage import Plugin

ENTRY_POINT_GROUP = "pipeline.plugins"


def load_plugin() -> Plugin:
    spec = os.environ.get("PIPELINE_PLUGIN")
    if spec:
        module_name, _, attr = spec.partition(":")
        try:
            obj = getattr(importlib.import_module(module_name), attr or "plugin")
        except (ImportError, AttributeError) as exc:
            raise ConfigError(f"PIPELINE_PLUGIN={spec}: cannot load it ({exc}).") from None
        return obj() if callable(obj) and not isinstance(obj, Plugin) else obj
    found = list(entry_points(group=ENTRY_POINT_GROUP))
    if not found:
        return Plugin(name="pipeline", stages=[])
    if len(found) > 1:
        names = ", ".join(ep.value for ep in found)
        raise ConfigError(f"several plugins are installed ({names}); choose one with PIPELINE_PLUGIN.")
    obj = found[0].load()
    return obj() if callable(obj) and not isinstance(obj, Plugin) else obj
