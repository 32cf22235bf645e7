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

source tools/setup_common.sh
PY="$(find_python lts_envs "every bpy wheel is built for it" 3.11)"

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
  # bpy 4.2 and 4.5 were built against numpy 1.x as 5.0.1 was: requirements.txt's numpy 1.26.4 fits all three.
  pins="$(mktemp)"
  { grep -v '^bpy==' requirements.txt; echo "bpy==$version"; } > "$pins"
  install_venv "$venv" "$pins"
  rm -f "$pins"
  echo "bpy$name $venv"
done
