"""The ``pipeline`` command line.

Exit codes: 0 success; 2 bad configuration or usage; 3 bad or unusable input
data; 4 the machine failed the run (disk full, a worker killed, a scheduler
not answering); 1 internal error; 130 interrupted by SIGINT (Ctrl-C), 143 by SIGTERM
(:mod:`pipeline.interrupt`).  Errors a user can cause print one sentence and no
traceback; an internal error prints its traceback only with ``-v``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import traceback
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline import __version__, interrupt
from pipeline.discovery import LazyPlugin, load_plugin
from pipeline.errors import (
    EXIT_CHECKS_FAILED,
    EXIT_ENVIRONMENT,
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_USAGE,
    FULL,
    ConfigError,
    PipelineError,
)
from pipeline.interrupt import Interrupted
from pipeline.log import LOGGER_NAME, setup_logging

if TYPE_CHECKING:
    from pipeline.stage import Plugin

# The configuration, the runner and the stages (pydantic, NumPy) are imported by
# the commands that use them: `pipeline --help` builds its parser without them.


class _Parser(argparse.ArgumentParser):
    """argparse that exits 2 with one line (its default is the same code)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def _add_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, help="YAML configuration file")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a configuration value, e.g. stages.rasterize.resolution=0.5 (repeatable)",
    )


def _add_log_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--log-format", choices=["text", "json"], default="text", help="log line format (default text)")
    p.add_argument("-q", "--quiet", action="count", default=0, help="only warnings and errors")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more detail (debug)")


def build_parser(plugin: Plugin | LazyPlugin) -> argparse.ArgumentParser:
    parser = _Parser(prog="pipeline", description="Staged, cached processing from raw logs to products.")
    parser.add_argument("--version", action="version", version=f"pipeline {__version__} ({plugin.name})")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("run", help="run the stages of a configuration, reusing cached results")
    _add_config_args(p)
    p.add_argument("--until", metavar="STAGE", help="stop after this stage (runs only what it needs)")
    p.add_argument("--force", metavar="STAGE", action="append", default=[], help="re-run this stage (repeatable)")
    p.add_argument("--dry-run", action="store_true", help="print the plan and cache hits; run nothing")
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit 5 when the run finished but a check failed (the acceptance), for batch jobs",
    )
    _add_log_args(p)

    p = sub.add_parser("validate", help="check a configuration, its input files and its stage graph")
    _add_config_args(p)
    _add_log_args(p)

    p = sub.add_parser("schema", help="print the JSON Schema of the configuration (for editors)")
    _add_log_args(p)

    for command in plugin.commands:
        p = sub.add_parser(command.name, help=command.help)
        command.add_arguments(p)
        if not any(a.dest == "log_format" for a in p._actions):
            _add_log_args(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    verbose = "-v" in argv or "--verbose" in argv
    try:
        plugin = load_plugin()
        parser = build_parser(plugin)
        args = parser.parse_args(argv)
        setup_logging(args.log_format, -1 if args.quiet else args.verbose)
        if args.command == "run":
            with interrupt.handling():
                return _cmd_run(args, plugin)
        if args.command == "validate":
            return _cmd_validate(args, plugin)
        if args.command == "schema":
            # lazy: pydantic and the stages load when the command runs, not by pipeline --help (start-up time)
            from pipeline.stage import config_model

            print(json.dumps(config_model(plugin).model_json_schema(), indent=2))
            return EXIT_OK
        command = next(c for c in plugin.commands if c.name == args.command)
        return command.run(args)
    except PipelineError as exc:
        print(f"pipeline: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except Interrupted as exc:
        print(
            f"pipeline: interrupted by {exc.name}; run it again to resume (complete stages are reused).",
            file=sys.stderr,
        )
        return exc.exit_code
    except KeyboardInterrupt:
        print("pipeline: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into a reader that stopped early (| head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:
        if exc.errno in FULL:
            where = f" while writing {exc.filename}" if exc.filename else ""
            print(f"pipeline: error: the disk is full{where}; no partial result was kept.", file=sys.stderr)
            return EXIT_ENVIRONMENT
        return _internal_error(exc, verbose)
    except Exception as exc:  # an internal error: a bug, not the user's
        return _internal_error(exc, verbose)


def _internal_error(exc: BaseException, verbose: bool) -> int:
    if verbose:
        traceback.print_exception(exc)
    print(
        f"pipeline: internal error: {type(exc).__name__}: {exc} (run with -v for the traceback; please report it)",
        file=sys.stderr,
    )
    return EXIT_INTERNAL


def _refuse_data_files(path: Path, plugin: Plugin | LazyPlugin) -> None:
    """A data file of the plugin's domain given as the configuration: the plugin's sentence (exit 2)."""
    explain = plugin.not_a_configuration
    said = explain(path) if explain is not None else None
    if said:
        raise ConfigError(f"{path}: {said}")


def _cmd_validate(args: argparse.Namespace, plugin: Plugin | LazyPlugin) -> int:
    # lazy: pydantic and the stages load when the command runs, not by pipeline --help (start-up time)
    from pipeline.config import load_config
    from pipeline.runner import build_plan
    from pipeline.stage import config_model

    _refuse_data_files(args.config, plugin)
    config = load_config(args.config, config_model(plugin), args.overrides)
    plan = build_plan(config, plugin)
    names = " -> ".join(s.name for s in plan.steps)
    print(f"{args.config}: valid; stages: {names}")
    for warning in plugin.configuration_warnings(config) if plugin.configuration_warnings else []:
        print(f"pipeline: warning: {warning}", file=sys.stderr)
    return EXIT_OK


def _cmd_run(args: argparse.Namespace, plugin: Plugin | LazyPlugin) -> int:
    # lazy: pydantic and the stages load when the command runs, not by pipeline --help (start-up time)
    from pipeline.config import load_config
    from pipeline.runner import FAILED_CHECKS, run
    from pipeline.stage import config_model

    _refuse_data_files(args.config, plugin)
    config = load_config(args.config, config_model(plugin), args.overrides)
    manifest = run(
        config, plugin, config_path=args.config.resolve(), until=args.until, force=args.force, dry_run=args.dry_run
    )
    if args.dry_run:
        width = max((len(s["name"]) for s in manifest["stages"]), default=5)
        print(f"{'stage':<{width}}  status          key           tiles")
        for s in manifest["stages"]:
            key = s.get("key", "")[:12]
            print(f"{s['name']:<{width}}  {s['status']:<14}  {key:<12}  {s.get('tiles', '')}".rstrip())
        return EXIT_OK
    log = logging.getLogger(LOGGER_NAME)
    log.info("%s", ", ".join(f"{s['name']} {s['status']}" for s in manifest["stages"]))
    failed = [(s["name"], c) for s in manifest["stages"] for c in (s.get("metrics") or {}).get(FAILED_CHECKS) or []]
    for name, check in failed:
        log.warning("[%s] check failed: %s", name, check)
    if failed and args.strict:
        log.warning("%d check(s) failed: exit %d (--strict)", len(failed), EXIT_CHECKS_FAILED)
        return EXIT_CHECKS_FAILED
    return EXIT_OK
