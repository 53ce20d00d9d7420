#!/usr/bin/env bash
# Set up everything the pipeline needs on a fresh Debian machine, idempotently:
#   - the system libraries its Python dependencies load (open3d needs libusb-1.0-0,
#     libGL, libEGL, libX11; the venv needs python3-venv on Debian);
#   - a virtual environment in .venv with the package installed (editable) and,
#     with --test, the test tools and QGIS's Python bindings (python3-qgis, for
#     the system python3: the test of the QGIS project opens it with QGIS).
# As root, missing system packages are installed with apt-get; otherwise the
# script stops with the apt-get command to run.  Re-running is cheap: pip is
# skipped when pyproject.toml has not changed since the last install.
set -euo pipefail
cd "$(dirname "$0")/.."

extras=""
[ "${1:-}" = "--test" ] && extras="[test]"

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
if ! "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
  echo "setup: Python 3.11 or newer is needed (found: $("$PYTHON" --version 2>&1)); install python3.11." >&2
  exit 2
fi

# System libraries: shared object -> Debian package.
declare -A NEEDS=(
  [libusb-1.0.so.0]=libusb-1.0-0
  [libGL.so.1]=libgl1
  [libEGL.so.1]=libegl1
  [libX11.so.6]=libx11-6
  [libgomp.so.1]=libgomp1
)
missing=()
# Read the linker cache once: "ldconfig -p | grep -q" fails under pipefail
# when grep stops reading early (SIGPIPE), which would report a present
# library as missing.
known_libs="$(ldconfig -p 2>/dev/null || true)"
for lib in "${!NEEDS[@]}"; do
  grep -qF "$lib" <<<"$known_libs" || missing+=("${NEEDS[$lib]}")
done
if ! "$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1; then
  missing+=("python3-venv")
fi
# The tests open the QGIS project of a run with QGIS itself: the system Python's bindings
# (Debian's python3-qgis, GPL, used by the tests only; about 35 s to install).
if [ -n "$extras" ] && ! /usr/bin/python3 -c 'import qgis.core' >/dev/null 2>&1; then
  missing+=("python3-qgis")
fi
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing system packages: ${missing[*]}"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "setup: missing system packages: ${missing[*]}; install them with: sudo apt-get install -y ${missing[*]}" >&2
    exit 2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $("$PYTHON" --version)"
  "$PYTHON" -m venv .venv
fi
stamp=".venv/.installed${extras}"
want="$(sha256sum pyproject.toml | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setup: installing the package and its dependencies into .venv (first time: a few minutes)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".${extras}"
  echo "$want" > "$stamp"
fi
.venv/bin/python -c 'import open3d, laspy, lazrs, rasterio, pyproj, pyogrio, contourpy, CSF' 2>/dev/null || {
  echo "setup: the dependencies do not import; run: .venv/bin/python -c 'import open3d, laspy, rasterio'" >&2
  exit 1
}
