#!/usr/bin/env bash
# Create .venv-backend: the backend alone, as a GPU machine's Python runs it (numpy 2, current OpenCV, no bpy), with
# the exact pins of requirements-backend.txt and this project installed (editable: `scpainter-backend`), and the
# system library open3d needs. `make test-backend-only` runs tests/core and tests/backend in it.
# Idempotent: a stamp of requirements-backend.txt's hash skips the pip step when nothing changed.
# VENV=DIR builds it elsewhere; PYTHON=/path/to/python chooses the interpreter (3.11 or 3.12: the pins' wheels).
set -euo pipefail
cd "$(dirname "$0")/.."

VENV="${VENV:-.venv-backend}"
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for c in python3.11 python3.12 python3; do
    if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys; sys.exit(sys.version_info[:2] not in ((3, 11), (3, 12)))'; then
      PY="$c"; break
    fi
  done
fi
if [ -z "$PY" ]; then
  echo "setup_backend: Python 3.11 or 3.12 is required (requirements-backend.txt's wheels); set PYTHON=/path/to/python" >&2
  exit 1
fi

source tools/setup_common.sh
ensure_libusb

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.requirements-$(cat requirements-backend.txt pyproject.toml | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ] || [ ! -x "$VENV/bin/scpainter-backend" ]; then
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements-backend.txt
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
  rm -f "$VENV"/.requirements-*
  touch "$stamp"
fi

ensure_splat_transform
