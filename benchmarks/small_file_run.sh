#!/bin/sh
# One cold `pipeline run` of a 1,065-point real file (the LAS job's defaults) with the code of TREE,
# into a fresh output and cache under SCRATCH; run it for two trees in turn to pair them.
#
#     sh benchmarks/small_file_run.sh TREE SCRATCH
set -eu
tree=$(cd "$1" && pwd)
scratch=$2
here=$(cd "$(dirname "$0")/.." && pwd)
rm -rf "$scratch" && mkdir -p "$scratch"
cat > "$scratch/small.yaml" <<YAML
input: {format: las, paths: [$here/../shared/data/real/pdal/1.2-with-color.las], crs: "EPSG:2992"}
output: out
cache: cache
YAML
cd "$scratch"
PYTHONPATH=$tree exec "$here/.venv/bin/python" -c 'import sys; from pipeline.cli import main; sys.exit(main(sys.argv[1:]))' \
    run small.yaml -q
