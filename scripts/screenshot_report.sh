#!/usr/bin/env bash
# Screenshot of a report.html with headless Chromium (Debian package "chromium": apt-get install -y chromium),
# as kept in docs/:   bash scripts/screenshot_report.sh out/flight-ldmrs/report.html docs/report_flight.png [height]
# The page is self-contained, so Chromium runs offline (no network, no sync, no updates).
set -euo pipefail
page="$(realpath "${1:-out/flight-ldmrs/report.html}")"
png="${2:-docs/report_flight.png}"
height="${3:-7000}"
command -v chromium >/dev/null || { echo "needs chromium: apt-get install -y chromium" >&2; exit 2; }
profile="$(mktemp -d)"
trap 'rm -rf "$profile"' EXIT
chromium --headless --no-sandbox --disable-gpu --disable-background-networking --disable-component-update \
  --disable-sync --no-first-run --user-data-dir="$profile" --window-size=1300,"$height" --hide-scrollbars \
  --screenshot="$png" "file://$page" 2>/dev/null
echo "$png"
