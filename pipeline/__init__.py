"""A small, domain-free engine for staged, cached, configurable data pipelines.

The engine knows stages only through their declared contract
(:class:`pipeline.stage.Stage`); a plugin (the ``stages`` package) registers
them through the ``pipeline.plugins`` entry point.
"""

__version__ = "0.1.0"
