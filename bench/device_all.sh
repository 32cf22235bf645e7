#!/bin/bash
# Every GPU part of the project's measurements in one run on the device machine (one H100 or H200; Python 3.12,
# torch + CUDA, no network), each part under its own `timeout` and all of them within one budget (8 minutes with the
# install), writing one JSON per part and a summary into $OUT:
#
#   generate     bench/generate.py: our pipeline against stock diffusers, full SVD architecture   generate_full_cuda.json
#   render       bench/render.py: the renderer's speed, error and choice, gsplat side by side     render_cuda.json
#   train        bench/train_throughput.py: training samples/s and peak memory                     train_full_cuda.json
#   gpu_tests    pytest -m gpu (the CUDA kernels against the float64 references)                   gpu_tests.json
#   (all)        which parts ran, their exit status, seconds and JSON                              summary.json
#
#   bash bench/device_all.sh                # on the device machine; the wheels of bench/device_wheels.txt in .whl/
#   bash bench/device_all.sh --dry-run      # here, on the CPU: every part at its smoke size, the same JSON files
#                                           # (each part's limit x4, a 30-minute budget: a shared CPU is slow)
#   bash bench/device_all.sh [--dry-run] --print   # each part's command line, one per line (nothing run)
#
# The device tool's call: carry [".whl"], command `bash bench/device_all.sh`, timeout_s 600. Wheels first:
# `bash bench/fetch_wheels.sh` here. gsplat (benchmark-only) compiles its CUDA code on first use (~2 min): that
# build runs in the background from the start, while generation runs, and render waits for it.
# Environment: OUT (default /tmp/device_all), PYTHON (default python3; the dry run's .venv/bin/python),
# DEVICE_ALL_PARTS (the parts to run, default all, in the order above), DEVICE_ALL_BUDGET_S (default 470: what is left
# of it caps each part's timeout), <PART>_TIMEOUT_S (one part's own limit, e.g. GENERATE_TIMEOUT_S=200), GPU_TESTS
# (the test paths of gpu_tests, default: every test file that marks a test gpu).
set -u -o pipefail
cd "$(dirname "$0")/.."
mode=gpu print=0
for a in "$@"; do
  case $a in
    --dry-run) mode=dry ;;
    --print) print=1 ;;
    *) echo "usage: bash bench/device_all.sh [--dry-run] [--print]" >&2; exit 2 ;;
  esac
done
export PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/device_all}
if [ "$mode" = dry ] && [ -x .venv/bin/python ]; then PY=${PYTHON:-.venv/bin/python}; else PY=${PYTHON:-python3}; fi
PARTS=${DEVICE_ALL_PARTS:-generate render train gpu_tests}
tmp=${TMPDIR:-/tmp}
# the test files that hold gpu-marked tests (collecting only them: the other test modules may import what the
# device machine lacks)
gpu_tests=${GPU_TESTS:-$(grep -rl --include='test_*.py' -e 'mark\.gpu' tests | sort | tr '\n' ' ')}
budget=${DEVICE_ALL_BUDGET_S:-470}
# the dry run's smoke sizes on a shared 2-core CPU: its own, laxer limits (what it checks is that every part runs)
dry_factor=1
if [ "$mode" = dry ]; then dry_factor=4; budget=${DEVICE_ALL_BUDGET_S:-1800}; fi

# One part's command line (the array CMD) and its own time limit (LIMIT). Its JSON: the .json files it wrote in $OUT.
# The GPU lines are each bench's current command for the figures of docs (README "Speed"); --dry-run runs the
# same benches at their smoke size on the CPU.
part() {
  case $1 in
    generate)
      LIMIT=${GENERATE_TIMEOUT_S:-170}
      if [ "$mode" = gpu ]; then CMD=("$PY" bench/generate.py --size full --device cuda --frames 14 --sections compare speed decode
                                      --steps-sweep 12 --speed-rows default euler-12 euler-16-reuse-2 reuse-2
                                      guidance-sigma-max-30 dpmpp2m-12 --out "$OUT")
      else CMD=("$PY" bench/generate.py --smoke --device cpu --out "$OUT"); fi ;;
    render)
      LIMIT=${RENDER_TIMEOUT_S:-130}
      if [ "$mode" = gpu ]; then CMD=("$PY" bench/render.py --devices cuda --sections speed accuracy choice --out "$OUT")
      else CMD=("$PY" bench/render.py --smoke --devices cpu --out "$OUT"); fi ;;
    train)
      LIMIT=${TRAIN_TIMEOUT_S:-100}
      if [ "$mode" = gpu ]; then CMD=("$PY" bench/train_throughput.py --size full --device cuda --resolutions 1024x576
                                      --batches 1 2 --checkpointing on --settings before after --steps 3 --out "$OUT")
      else CMD=("$PY" bench/train_throughput.py --smoke --device cpu --out "$OUT"); fi ;;
    gpu_tests)
      LIMIT=${GPU_TESTS_TIMEOUT_S:-60}
      # shellcheck disable=SC2206  (the paths split on spaces)
      CMD=("$PY" -m pytest -m gpu -q -p no:cacheprovider --junitxml="$tmp/gpu_tests.xml" $gpu_tests) ;;
    *) echo "device_all.sh: no part named $1 (parts: generate render train gpu_tests)" >&2; return 1 ;;
  esac
}

if [ "$print" = 1 ]; then
  for name in $PARTS; do part "$name" || exit 2; printf '%s\t%s\n' "$name" "${CMD[*]}"; done
  exit 0
fi

mkdir -p "$OUT"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
log=$OUT/device_all.log
: > "$log"
start=$(date +%s)
say() { echo "$*" | tee -a "$log"; }
say "device_all.sh ($mode) $(git rev-parse --short HEAD 2>/dev/null) $(date -u +%FT%TZ)"

if [ "$mode" = gpu ]; then
  if ls .whl/*.whl >/dev/null 2>&1; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
      >>"$log" 2>&1 || say "warning: installing .whl/ failed (see above)"
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
  else
    say "warning: no .whl/ (bash bench/fetch_wheels.sh here, then carry .whl): diffusers, gsplat may be missing"
  fi
  export MAX_JOBS=16 TORCH_EXTENSIONS_DIR=/tmp/torch_ext
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>&1 | tee -a "$log"
  # gsplat's CUDA build (first use) in the background, while generation holds the GPU; render waits for it
  ( timeout 300 "$PY" - >>"$tmp/gsplat_build.log" 2>&1 <<'PY'
import torch
from gsplat import rasterization
m = torch.zeros(1, 3, device="cuda"); m[0, 2] = 2
q = torch.tensor([[1.0, 0, 0, 0]], device="cuda"); s = torch.full((1, 3), 0.1, device="cuda")
o = torch.ones(1, device="cuda"); c = torch.ones(1, 3, device="cuda")
K = torch.tensor([[[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]]], device="cuda")
img, a, _ = rasterization(m, q, s, o, c, torch.eye(4, device="cuda")[None], K, 64, 64)
print("gsplat built", float(a.max()))
PY
  ) &
  gsplat_build=$!
fi
"$PY" -c "import torch, numpy; print('torch', torch.__version__, 'numpy', numpy.__version__, 'cuda', torch.cuda.is_available())" \
  2>&1 | tee -a "$log"

results=()
for name in $PARTS; do
  part "$name" || exit 2
  LIMIT=$(( LIMIT * dry_factor ))
  if [ "$name" = render ] && [ -n "${gsplat_build:-}" ]; then
    wait "$gsplat_build"; gsplat_build=""; tail -3 "$tmp/gsplat_build.log" | tee -a "$log"
  fi
  left=$(( start + budget - $(date +%s) ))
  limit=$(( LIMIT < left ? LIMIT : left ))
  if [ "$limit" -lt 5 ]; then
    say "== $name: skipped, the budget of ${budget} s is spent"
    results+=("$name skipped 0 0 -"); continue
  fi
  say "== $name (limit ${limit} s): ${CMD[*]}"
  t0=$(date +%s)
  touch "$tmp/before_$name"
  timeout --kill-after=10 "$limit" "${CMD[@]}" 2>&1 | tee -a "$log"
  rc=$?
  secs=$(( $(date +%s) - t0 ))
  status=ok
  if [ "$rc" = 124 ] || [ "$rc" = 137 ]; then status=timeout; elif [ "$rc" != 0 ]; then status=failed; fi
  say "== $name: $status (exit $rc, ${secs} s)"
  wrote=$(find "$OUT" -maxdepth 1 -name '*.json' -newer "$tmp/before_$name" -printf '%f,' | sed 's/,$//')
  [ "$name" = gpu_tests ] && wrote=gpu_tests.json
  results+=("$name $status $rc $secs ${wrote:--}")
done

# gpu_tests.json from pytest's JUnit XML; summary.json: every part's status, exit code, seconds and the JSON files
# it wrote
"$PY" - "$OUT" "$tmp/gpu_tests.xml" "$mode" "$(( $(date +%s) - start ))" "${results[@]}" <<'PY' 2>&1 | tee -a "$log"
import json, os, sys, xml.etree.ElementTree as ET
out, xml, mode, total = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
rows = [r.split() for r in sys.argv[5:]]
if os.path.isfile(xml):
    cases = ET.parse(xml).getroot().iter("testcase")
    tests = {"passed": [], "failed": [], "skipped": []}
    for c in cases:
        kind = "failed" if c.find("failure") is not None or c.find("error") is not None else \
            "skipped" if c.find("skipped") is not None else "passed"
        tests[kind].append(f"{c.get('classname')}::{c.get('name')}")
    with open(os.path.join(out, "gpu_tests.json.tmp"), "w") as f:
        json.dump({**{k: len(v) for k, v in tests.items()}, "failed_tests": tests["failed"]}, f, indent=1)
    os.replace(os.path.join(out, "gpu_tests.json.tmp"), os.path.join(out, "gpu_tests.json"))
    os.remove(xml)
parts = {}
for name, status, rc, secs, js in rows:
    written = [j for j in js.split(",") if j != "-" and os.path.isfile(os.path.join(out, j))]
    parts[name] = {"status": status, "exit_code": int(rc), "seconds": int(secs), "json": written}
summary = {"mode": mode, "total_s": total, "parts": parts,
           "ok": all(p["status"] == "ok" and p["json"] for p in parts.values())}
with open(os.path.join(out, "summary.json.tmp"), "w") as f:
    json.dump(summary, f, indent=1)
os.replace(os.path.join(out, "summary.json.tmp"), os.path.join(out, "summary.json"))
print(json.dumps(summary))
PY
[ -n "${gsplat_build:-}" ] && kill "$gsplat_build" 2>/dev/null  # render was not among the parts
say "device_all.sh: $(( $(date +%s) - start )) s in all"
