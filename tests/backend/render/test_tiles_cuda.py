"""The Triton kernel's logic on the CPU, through Triton's interpreter (TRITON_INTERPRET=1): colour, asset mask,
depth and the instance (one, three and five assets, with and without points in front) against the torch reference.

Runs wherever Triton is importable (CUDA machines ship it with torch; the CPU venv does not, so CI skips this
and the gpu-marked tests in test_gaussians run the compiled kernel on a GPU). A subprocess, because the
interpreter is chosen when Triton is first imported.
"""

import importlib.util
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

SCRIPT = r"""
import numpy as np, torch
from backend.render import gaussians as GS, tiles, tiles_cuda
from tests.backend.render.test_gaussians import random_scene, K, EYE
t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)
for seed, bg_wall, n_assets in ((0, False, 1), (1, True, 1), (2, False, 3), (3, True, 5)):
    proj = GS.project(*(t(a) for a in random_scene(150, seed, 1)), K, EYE, 64, 48)
    if n_assets > 1:  # Gaussians split into assets by their side of the image (overlapping at the borders)
        proj["asset_id"] = 1 + (proj["mean2d"][:, 0] * n_assets / 64).clamp(0, n_assets - 1).to(torch.int64)
    bg = torch.full((48, 64), float("inf"))
    if bg_wall:
        bg[:, :32] = 5.0
    bins = tiles.bin_tiles(proj, 64, 48)
    inputs = tiles.kernel_inputs(proj, bins, 64, 48, bg, dtype=torch.float32)  # as on CUDA
    c, mask, z, inst = tiles_cuda.composite(*inputs, 64, 48, bins["tiles_x"], 16, n_assets)
    rc, rmask, rz, rinst = GS.rasterize(proj, 64, 48, bg)
    # the instance: equal but where float32 against float64 may decide a near tie (none on these scenes)
    inst = inst.reshape(48, 64)
    assert set(torch.unique(rinst).tolist()) == set(range(n_assets + 1)), "every asset and the scene win somewhere"
    assert int((inst != rinst).sum()) == 0, ("instance", int((inst != rinst).sum()))
    assert float(rmask.max()) > 0.5
    assert float((c.reshape(48, 64, 3) - rc).abs().max()) <= 1e-5, "colour"
    assert float((mask.reshape(48, 64) - rmask).abs().max()) <= 1e-5, "asset mask"
    z, rz = z.reshape(48, 64), rz
    assert torch.equal(torch.isinf(z), torch.isinf(rz)) and torch.allclose(z[~torch.isinf(z)], rz[~torch.isinf(rz)])
print("ok")
"""


@pytest.mark.skipif(importlib.util.find_spec("triton") is None, reason="Triton is not installed")
def test_triton_kernel_matches_reference_in_interpreter():
    env = dict(os.environ, TRITON_INTERPRET="1", PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0 and "ok" in proc.stdout, proc.stderr[-3000:]
