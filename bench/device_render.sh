#!/bin/bash
# The renderer's GPU checks and figures in one run on the device machine (H100): the CUDA accuracy tests,
# bench/render.py on CUDA with gsplat side by side. gsplat (benchmark-only) comes as a wheel in .whl/ and
# compiles its CUDA code on first use, in the background while the tests run.
set -o pipefail
export PYTHONUNBUFFERED=1 MAX_JOBS=16 TORCH_EXTENSIONS_DIR=/tmp/torch_ext
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
python3 -c "import torch, triton, numpy; print('torch', torch.__version__, 'triton', triton.__version__, 'numpy', numpy.__version__)"
( t=$(date +%s); python3 - > "$OUT/gsplat_build.log" 2>&1 <<'PY'
import torch
from gsplat import rasterization
m = torch.zeros(1, 3, device="cuda"); m[0, 2] = 2
q = torch.tensor([[1.0, 0, 0, 0]], device="cuda"); s = torch.full((1, 3), 0.1, device="cuda")
o = torch.ones(1, device="cuda"); c = torch.ones(1, 3, device="cuda")
K = torch.tensor([[[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]]], device="cuda")
img, a, _ = rasterization(m, q, s, o, c, torch.eye(4, device="cuda")[None], K, 64, 64)
print("gsplat ok", float(a.max()))
PY
echo "gsplat build+first call: $(( $(date +%s) - t )) s" >> "$OUT/gsplat_build.log" ) &
build=$!
python3 -m pytest -q --noconftest -p no:cacheprovider tests/backend/render/test_gaussians.py -k cuda 2>&1 \
  | tail -15 | tee "$OUT/gpu_tests.log"
wait $build; tail -3 "$OUT/gsplat_build.log"
python3 bench/render.py --devices cuda --sections speed accuracy choice --out "$OUT" 2>&1 | tee "$OUT/bench_cuda.log"
