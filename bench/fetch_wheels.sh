#!/bin/bash
# The wheels bench/device_all.sh installs on the device machine (which has no network), downloaded here into .whl/
# (git-ignored; carried with `carry: [".whl"]`): bench/device_wheels.txt, each without its dependencies (the list
# names every one the machine lacks), for CPython 3.12 on x86-64 Linux whatever this machine is.
#   bash bench/fetch_wheels.sh [DIR]        # default .whl
set -euo pipefail
cd "$(dirname "$0")/.."
dest=${1:-.whl}
mkdir -p "$dest"
plats=()
for p in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 manylinux1_x86_64; do
  plats+=(--platform "$p")
done
grep -v '^\s*\(#\|$\)' bench/device_wheels.txt | while read -r req; do
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    "${plats[@]}" -d "$dest" "$req"
done
ls -1 "$dest"
du -sh "$dest"
