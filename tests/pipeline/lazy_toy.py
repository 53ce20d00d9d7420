"""The toy plugin (:mod:`tests.pipeline.toy`) as a :class:`~pipeline.discovery.LazyPlugin`, with one command.

Importing this module imports neither the toy stages nor pydantic.
"""

from __future__ import annotations

import argparse

from pipeline.discovery import LazyCommand, LazyPlugin


def _load():
    # lazy: the plugin's stages load on first use, not by pipeline --help (test_discovery.py checks it)
    from tests.pipeline.toy import plugin as toy

    return toy


def echo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("words", nargs="*", help="words to print")


def echo(args: argparse.Namespace) -> int:
    print("echo:", " ".join(args.words))
    return 0


ECHO = LazyCommand("echo", "print the words", "tests.pipeline.lazy_toy:echo_arguments", "tests.pipeline.lazy_toy:echo")
plugin = LazyPlugin(name="toy", commands=[ECHO], load=_load)
wrong_name = LazyPlugin(name="not-toy", commands=[], load=_load)
