#!/usr/bin/env bash
# Create .venv (Python 3.11) with the pinned requirements and this project installed (editable: the
# `scpainter-backend` command), and the system library open3d needs.
# Idempotent: a stamp of requirements.txt's hash skips the pip step when nothing changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for c in python3.11 python3; do
    if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PY="$c"; break
    fi
  done
fi
if [ -z "$PY" ]; then
  echo "setup: Python 3.11 is required (the bpy 5.0.1 wheel is built for it); set PYTHON=/path/to/python3.11" >&2
  exit 1
fi

# open3d links libusb-1.0 (Debian package libusb-1.0-0).
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing libusb-1.0-0 for open3d" >&2
    (apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libusb-1.0-0 >/dev/null; }) \
      || echo "setup: could not install libusb-1.0-0; open3d may fail to import" >&2
  else
    echo "setup: open3d needs libusb-1.0; run: sudo apt-get install -y libusb-1.0-0" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=".venv/.requirements-$(cat requirements.txt pyproject.toml | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ] || [ ! -x .venv/bin/scpainter-backend ]; then
  .venv/bin/python -m pip install -q --disable-pip-version-check -r requirements.txt
  # the project itself, editable, without dependencies (they are the pins above): the `scpainter-backend` command
  .venv/bin/python -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
  rm -f .venv/.requirements-*
  touch "$stamp"
fi

# Test-only: PlayCanvas' splat-transform (the real SPZ / SOG / glTF splat writer the tests read back), from the npm
# registry with the machine's Node; never used by the product. Without Node the tests that need it skip, saying so.
if command -v npm >/dev/null 2>&1; then
  st_stamp="tools/splat_transform/node_modules/.lock-$(sha256sum tools/splat_transform/package-lock.json | cut -c1-16)"
  if [ ! -f "$st_stamp" ]; then
    (cd tools/splat_transform && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error >/dev/null) \
      && touch "$st_stamp" \
      || echo "setup: npm ci in tools/splat_transform failed; the splat-transform tests will skip" >&2
  fi
else
  echo "setup: no npm; the tests that read splat-transform's files will skip" >&2
fi
