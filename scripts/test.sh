#!/usr/bin/env bash
# Quickstart 2: set up (if needed, with test tools) and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
.venv/bin/ruff check pipeline stages lidar commands tests benchmarks scripts data_samples
.venv/bin/ruff format --check pipeline stages lidar commands tests benchmarks scripts data_samples
# One test process per core (pytest-xdist); each test file runs whole on one
# of them, so a module's fixtures are built once, longest files first (tests/conftest.py,
# LONGEST_FIRST); the 15 slowest tests are listed.
.venv/bin/python -m pytest -n auto --dist loadfile --no-loadscope-reorder --durations=15 "$@"
