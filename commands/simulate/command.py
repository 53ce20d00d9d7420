"""``pipeline simulate CONFIG [--out DIR] [--set key=value ...]``: write a simulated survey with its truth.

The configuration (``configs/simulate.yaml`` for the shipped samples) is
validated like a pipeline configuration: unknown keys and wrong types are
errors with the file's line.  ``--out`` replaces ``output``; ``--set``
overrides any key.  Prints one line per file written and the fault counts.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipeline.errors import ConfigError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, help="simulation configuration (YAML)")
    p.add_argument("--out", type=Path, help="folder to write (default: the config's output; with surveys, DIR/<name>)")
    p.add_argument("--only", action="append", default=[], metavar="NAME", help="only this survey (repeatable)")
    overrides = "override a configuration key (repeatable)"
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help=overrides)


def run(args: argparse.Namespace) -> int:
    # lazy: pydantic, NumPy and SciPy, loaded when the command runs, not by pipeline --help (start-up time)
    from commands.simulate.settings import SimConfigError, SimulateConfig, SimulateFile
    from commands.simulate.simulator import simulate
    from pipeline.config import load_config, load_yaml

    if not args.config.is_file():
        raise ConfigError(f"{args.config}: file not found.")
    overrides = list(args.overrides)
    data, _ = load_yaml(args.config)
    several = isinstance(data, dict) and "surveys" in data
    if several:
        names = list(data["surveys"] or {})
        unknown = [n for n in args.only if n not in names]
        if unknown:
            raise ConfigError(f"{args.config}: no survey named '{unknown[0]}' (surveys: {', '.join(names)}).")
        if args.out is not None:
            overrides += [f"surveys.{n}.output={(args.out / n).resolve()}" for n in names]
        surveys = load_config(args.config, SimulateFile, overrides).surveys
    else:
        if args.out is not None:
            overrides.append(f"output={args.out.resolve()}")
        surveys = {"survey": load_config(args.config, SimulateConfig, overrides)}
    for name, cfg in surveys.items():
        if args.only and name not in args.only:
            continue
        try:
            result = simulate(cfg)
        except SimConfigError as exc:  # combinations the model cannot check alone (scanner vs format, counts)
            raise ConfigError(f"{args.config}: {name if several else 'survey'}: {exc}.") from None
        for path in result.files.values():
            print(f"wrote {result.output / path}", file=sys.stderr)
        counts = {k: v for k, v in result.faults.items() if k in ("pulses", "echoes", "ldmrs_mtig", "lmsq")}
        print(f"{name}: {json.dumps(counts)}", file=sys.stderr)
    return 0
