#!/usr/bin/env bash
# Create .venv (Python 3.11) with the pinned requirements and this project installed (editable: the
# `scpainter-backend` command), and the system library open3d needs.
# Idempotent: a stamp of requirements.txt's hash skips the pip step when nothing changed.
set -euo pipefail
cd "$(dirname "$0")/.."

# shared with tools/setup_backend.sh and tools/lts_envs.sh: the interpreter, libusb for open3d, the venv, the
# test-only splat-transform
source tools/setup_common.sh
PY="$(find_python setup "the bpy 5.0.1 wheel is built for it" 3.11)"
ensure_libusb
install_venv .venv requirements.txt

ensure_splat_transform
