#!/usr/bin/env bash
# Quickstart 1: set up (if needed) and run the main job on the shipped sample.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/pipeline run configs/las.yaml "$@"
echo "products in out/sample-las/: $(ls out/sample-las | tr '\n' ' ')"
