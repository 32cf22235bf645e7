#!/usr/bin/env bash
# The Blender LTS test environments (docs/design.md §6): one virtual environment per LTS `bpy`, each with
# requirements.txt's exact pins except bpy, the LTS bpy, and this project (editable), so the Blender-side tests
# run against the Blender Python API studios pin.
#
#   tools/lts_envs.sh          build (or update) every environment; prints one "NAME DIR" line each
#   tools/lts_envs.sh 42       only bpy 4.2
#
# Where: $LTS_VENV_DIR/.venv-bpy42 and .venv-bpy45 (default: the repository root). Idempotent: a stamp of the
# pins' hash skips pip when nothing changed. Each environment is about 4.5 GB (torch, open3d, bpy).
set -euo pipefail
cd "$(dirname "$0")/.."

# The LTS lines and the exact bpy of each (the newest patch on the package index when pinned).
declare -A BPY=([42]=4.2.23 [45]=4.5.15)

PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for c in python3.11 python3; do
    if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PY="$c"; break
    fi
  done
fi
if [ -z "$PY" ]; then
  echo "lts_envs: Python 3.11 is required (every bpy wheel is built for it); set PYTHON=/path/to/python3.11" >&2
  exit 1
fi

dir="${LTS_VENV_DIR:-.}"
names=("$@")
[ ${#names[@]} -gt 0 ] || names=(42 45)
for name in "${names[@]}"; do
  version="${BPY[$name]:-}"
  if [ -z "$version" ]; then
    echo "lts_envs: unknown LTS '$name' (known: ${!BPY[*]})" >&2
    exit 2
  fi
  venv="$dir/.venv-bpy$name"
  pins="$(grep -v '^bpy==' requirements.txt; echo "bpy==$version")"
  stamp="$venv/.requirements-$( (echo "$pins"; cat pyproject.toml) | sha256sum | cut -c1-16)"
  if [ ! -x "$venv/bin/python" ]; then
    "$PY" -m venv "$venv"
  fi
  if [ ! -f "$stamp" ]; then
    # bpy 4.2 and 4.5 were built against numpy 1.x as 5.0.1 was: requirements.txt's numpy 1.26.4 fits all three.
    "$venv/bin/python" -m pip install -q --disable-pip-version-check -r <(echo "$pins")
    "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
    rm -f "$venv"/.requirements-*
    touch "$stamp"
  fi
  echo "bpy$name $venv"
done
