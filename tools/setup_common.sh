# Steps shared by tools/setup.sh (.venv, the Blender side) and tools/setup_backend.sh (.venv-backend, the backend
# alone): sourced, from the repository root.

# open3d links libusb-1.0 (Debian package libusb-1.0-0).
ensure_libusb() {
  if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
      echo "setup: installing libusb-1.0-0 for open3d" >&2
      (apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libusb-1.0-0 >/dev/null; }) \
        || echo "setup: could not install libusb-1.0-0; open3d may fail to import" >&2
    else
      echo "setup: open3d needs libusb-1.0; run: sudo apt-get install -y libusb-1.0-0" >&2
    fi
  fi
}

# Test-only: PlayCanvas' splat-transform (the real SPZ / SOG / glTF splat writer the tests read back), from the npm
# registry with the machine's Node; never used by the product. Without Node the tests that need it skip, saying so.
ensure_splat_transform() {
  if command -v npm >/dev/null 2>&1; then
    local st_stamp
    st_stamp="tools/splat_transform/node_modules/.lock-$(sha256sum tools/splat_transform/package-lock.json | cut -c1-16)"
    if [ ! -f "$st_stamp" ]; then
      (cd tools/splat_transform && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error >/dev/null) \
        && touch "$st_stamp" \
        || echo "setup: npm ci in tools/splat_transform failed; the splat-transform tests will skip" >&2
    fi
  else
    echo "setup: no npm; the tests that read splat-transform's files will skip" >&2
  fi
}

# The interpreter a virtual environment is made with: $PYTHON, else the first of python3.X (for each VERSION given,
# in order) and python3 whose version is one of them; exits naming WHO and WHY otherwise.
find_python() {  # find_python WHO WHY VERSION...
  local who="$1" why="$2" c v w
  shift 2
  if [ -n "${PYTHON:-}" ]; then echo "$PYTHON"; return; fi
  for c in "${@/#/python}" python3; do
    command -v "$c" >/dev/null 2>&1 || continue
    v="$("$c" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)" || continue  # a pyenv shim
    for w in "$@"; do
      if [ "$v" = "$w" ]; then echo "$c"; return; fi
    done
  done
  echo "$who: Python $* is required ($why); set PYTHON=/path/to/python" >&2
  exit 1
}

# VENV with the exact pins of PINS (a file), the test-only packages of requirements-nodeps.txt without their
# dependencies (they declare ones that must not be installed) and those of requirements-isolated.txt in VENV/isolated,
# outside site-packages (importing them there would break other packages) — each file says why —, and this project
# installed editable (the `scpainter-backend` command), made with $PY when missing. Idempotent: a stamp of the pin
# files' and pyproject.toml's hash skips pip when nothing changed.
install_venv() {  # install_venv VENV PINS
  local venv="$1" pins="$2" stamp
  stamp="$venv/.requirements-$(cat "$pins" requirements-nodeps.txt requirements-isolated.txt pyproject.toml \
    | sha256sum | cut -c1-16)"
  if [ ! -x "$venv/bin/python" ]; then
    "$PY" -m venv "$venv"
  fi
  if [ ! -f "$stamp" ] || [ ! -x "$venv/bin/scpainter-backend" ]; then
    "$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$pins"
    "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps -r requirements-nodeps.txt
    rm -rf "$venv/isolated"
    "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --target "$venv/isolated" \
      -r requirements-isolated.txt
    # the project itself, without dependencies (they are the pins above)
    "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
    rm -f "$venv"/.requirements-*
    touch "$stamp"
  fi
}
