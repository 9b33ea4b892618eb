#!/usr/bin/env bash
# Create the virtual environment and install vslam.
#   scripts/bootstrap.sh PYTHON VENV [EXTRAS] [DEBIAN_PACKAGES...]
# EXTRAS is a comma list of pyproject extras (e.g. "test,dense,viz,ray"). Debian packages are
# installed with apt-get when missing (root only; otherwise a clear message says what to install).
set -euo pipefail
PYTHON="${1:-python3}"
VENV="${2:-.venv}"
EXTRAS="${3:-}"
shift $(( $# < 3 ? $# : 3 ))
DEBS=("$@")

if ! command -v "$PYTHON" >/dev/null 2>&1; then
  echo "error: $PYTHON not found; install Python >= 3.11 first" >&2; exit 1
fi
if ! "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  echo "error: vslam needs Python >= 3.11 (found $("$PYTHON" --version 2>&1))" >&2; exit 1
fi

missing=()
for pkg in "${DEBS[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
"$PYTHON" -m venv --help >/dev/null 2>&1 || missing+=(python3-venv)
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing Debian packages: ${missing[*]}"
    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null \
      || { echo "error: could not install Debian packages: ${missing[*]}" >&2; exit 1; }
  else
    echo "error: missing system packages: ${missing[*]} (Debian: sudo apt-get install ${missing[*]})" >&2; exit 1
  fi
fi

[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
spec="."
[ -n "$EXTRAS" ] && spec=".[${EXTRAS}]"
constraints=()
[ -f constraints.txt ] && constraints=(-c constraints.txt)  # the exact versions vslam is tested with
"$VENV/bin/python" -m pip install -q "${constraints[@]}" -e "$spec"
# rerun's CLI asks about telemetry on first use; answer it once, non-interactively.
if [ -x "$VENV/bin/rerun" ]; then "$VENV/bin/rerun" analytics disable >/dev/null 2>&1 </dev/null || true; fi
echo "vslam installed in $VENV${EXTRAS:+ with extras $EXTRAS}"
