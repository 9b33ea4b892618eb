#!/usr/bin/env bash
# Create the virtual environment and install vslam with its test extras.
# Installs the few Debian packages the optional extras need when run as root.
set -euo pipefail
PYTHON="${1:-python3}"
VENV="${2:-.venv}"

if ! command -v "$PYTHON" >/dev/null 2>&1; then
  echo "error: $PYTHON not found; install Python >= 3.11 first" >&2; exit 1
fi
if ! "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  echo "error: vslam needs Python >= 3.11 (found $("$PYTHON" --version))" >&2; exit 1
fi
if ! "$PYTHON" -m venv --help >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get update -qq && apt-get install -y -qq python3-venv
  else
    echo "error: the Python venv module is missing (Debian: apt-get install python3-venv)" >&2; exit 1
  fi
fi
# Debian libraries that OpenCV/Open3D wheels load at import time.
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  missing=""
  for lib in libgl1 libgomp1 libusb-1.0-0; do
    dpkg -s "$lib" >/dev/null 2>&1 || missing="$missing $lib"
  done
  if [ -n "$missing" ]; then
    echo "installing Debian packages:$missing"
    (apt-get update -qq && apt-get install -y -qq $missing) || echo "warning: could not install$missing" >&2
  fi
fi
"$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e ".[test]"
echo "vslam installed in $VENV"
