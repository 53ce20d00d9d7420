#!/usr/bin/env bash
# Screenshot of a report.html with headless Chromium (Debian package "chromium"),
# as kept in docs/report.png:   bash scripts/screenshot_report.sh out/flight-ldmrs/report.html docs/report.png
set -euo pipefail
page="$(realpath "${1:-out/flight-ldmrs/report.html}")"
png="${2:-docs/report.png}"
command -v chromium >/dev/null || { echo "needs chromium: apt-get install -y chromium" >&2; exit 2; }
profile="$(mktemp -d)"
chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking \
  --disable-component-update --disable-sync --user-data-dir="$profile" --window-size=1300,2600 --hide-scrollbars \
  --screenshot="$png" "file://$page" 2>/dev/null
rm -rf "$profile"
echo "$png"
