#!/usr/bin/env bash
# Create .venv-backend: the backend alone, as a GPU machine's Python runs it (numpy 2, current OpenCV, no bpy), with
# the exact pins of requirements-backend.txt and this project installed (editable: `scpainter-backend`), and the
# system library open3d needs. `make test-backend-only` runs tests/core and tests/backend in it.
# Idempotent: a stamp of requirements-backend.txt's hash skips the pip step when nothing changed.
# VENV=DIR builds it elsewhere; PYTHON=/path/to/python chooses the interpreter (3.11 or 3.12: the pins' wheels).
set -euo pipefail
cd "$(dirname "$0")/.."

VENV="${VENV:-.venv-backend}"
source tools/setup_common.sh
PY="$(find_python setup_backend "requirements-backend.txt's wheels" 3.11 3.12)"
ensure_libusb
install_venv "$VENV" requirements-backend.txt

ensure_splat_transform
