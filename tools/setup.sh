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

# shared with tools/setup_backend.sh: libusb for open3d, the test-only splat-transform
source tools/setup_common.sh
ensure_libusb

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

ensure_splat_transform
