#!/usr/bin/env bash
# Quickstart 2: set up (if needed, with test tools) and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
.venv/bin/ruff check pipeline stages tests benchmarks
.venv/bin/ruff format --check pipeline stages tests benchmarks
.venv/bin/python -m pytest "$@"
