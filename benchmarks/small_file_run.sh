#!/bin/sh
# One cold `pipeline run` (the LAS job's defaults, the report included) of a small file with the code
# of TREE, into a fresh output and cache under SCRATCH; run it for two trees in turn to pair them.
#
#     sh benchmarks/small_file_run.sh TREE SCRATCH [sparse|dense]
#
# sparse (default): the 1,065 points of ../shared/data/real/pdal/1.2-with-color.las (EPSG:2992, 27 m apart,
#                   a 1.45 M-cell grid);
# dense:            1,002 points cut from data_samples/las/sample.laz, the 25.3 m square 200 m east and
#                   north of its south-west corner (1.6 points/m², as a project's tile).
set -eu
tree=$(cd "$1" && pwd)
scratch=$2
kind=${3:-sparse}
here=$(cd "$(dirname "$0")/.." && pwd)
rm -rf "$scratch" && mkdir -p "$scratch"
tile="${scratch%/}.dense.laz"  # cut once, beside SCRATCH, outside the timed runs
if [ "$kind" = dense ] && [ ! -f "$tile" ]; then
  "$here/.venv/bin/python" - "$here/data_samples/las/sample.laz" "$tile" <<'PY'
import sys
import laspy
src = laspy.read(sys.argv[1])
x0, y0 = src.header.mins[0] + 200.0, src.header.mins[1] + 200.0
keep = (src.x >= x0) & (src.x < x0 + 25.3) & (src.y >= y0) & (src.y < y0 + 25.3)
out = laspy.LasData(src.header)
out.points = src.points[keep]
out.write(sys.argv[2])
PY
fi
if [ "$kind" = dense ]; then
  input="{format: las, paths: [$tile]}"
else
  input="{format: las, paths: [$here/../shared/data/real/pdal/1.2-with-color.las], crs: \"EPSG:2992\"}"
fi
cat > "$scratch/small.yaml" <<YAML
input: $input
output: out
cache: cache
YAML
cd "$scratch"
PYTHONPATH=$tree exec "$here/.venv/bin/python" -c 'import sys; from pipeline.cli import main; sys.exit(main(sys.argv[1:]))' \
    run small.yaml -q
