#!/usr/bin/env bash
# Screenshot of a report.html with headless Chromium (Debian package "chromium": apt-get install -y chromium),
# as kept in docs/:   PYTHON=.venv/bin/python bash scripts/screenshot_report.sh out/flight-ldmrs/report.html \
#                        docs/report_flight.png [window height, default 10000 px: taller than the page]
# The page is self-contained, so Chromium runs offline (no network, no sync, no updates).
set -euo pipefail
page="$(realpath "${1:-out/flight-ldmrs/report.html}")"
png="${2:-docs/report_flight.png}"
height="${3:-10000}"
command -v chromium >/dev/null || { echo "needs chromium: apt-get install -y chromium" >&2; exit 2; }
profile="$(mktemp -d)"
trap 'rm -rf "$profile"' EXIT
chromium --headless --no-sandbox --disable-gpu --disable-background-networking --disable-component-update \
  --disable-sync --no-first-run --user-data-dir="$profile" --window-size=1300,"$height" --hide-scrollbars \
  --screenshot="$png" "file://$page" 2>/dev/null
# crop the blank below the page and store 256 dithered colours (a third of the size; needs Pillow,
# which matplotlib brings: PYTHON=.venv/bin/python)
"${PYTHON:-python3}" - "$png" <<'PY' 2>/dev/null || echo "(not cropped: no Pillow)" >&2
import sys
import numpy as np
from PIL import Image
path = sys.argv[1]
im = Image.open(path).convert("RGB")
rows = np.flatnonzero((np.asarray(im) < 250).any(axis=(1, 2)))
im = im.crop((0, 0, im.size[0], min(im.size[1], int(rows.max()) + 40)))
im.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.FLOYDSTEINBERG).save(path, optimize=True)
PY
echo "$png"
