#!/usr/bin/env bash
# Quickstart 1: set up (if needed) and run the main job on the shipped sample:
# the raw LD-MRS + MTi-G helicopter flight (format 3.A) -> DTM, classified points, QC.
#   bash scripts/run_sample.sh           # configs/flight.yaml
#   bash scripts/run_sample.sh --all     # and every other sample config (3.B, 3.C, 3.D)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
configs=(configs/flight.yaml)
if [[ "${1:-}" == "--all" ]]; then
    shift
    configs+=(configs/flight_nmea.yaml configs/flight_sbet.yaml configs/las.yaml)
fi
for config in "${configs[@]}"; do
    .venv/bin/pipeline run "$config" "$@"
done
echo "products in out/flight-ldmrs/: $(ls out/flight-ldmrs | tr '\n' ' ')"
