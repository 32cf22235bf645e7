"""The Triton kernel on the CPU: compiled for Hopper without a GPU (PTX, then the wheel's ptxas), and its logic
through Triton's interpreter (TRITON_INTERPRET=1): ``tiles.rasterize``'s
CUDA path after the choice (``tiles.composite_triton``: torch binning, ``kernel_inputs``, the batched kernel) against
the float64 torch pair rasterizer on float64 projections, as ``frames.render_frame`` projects: colour, asset mask,
depth and the instance.

Cases: tiles of 4, 8, 16 and 32 pixels (each its own batch size, ``tiles_cuda.launch_config``); one, three and five
assets (the plain sum and the per-asset ``tl.dot`` block); a wall of points in front of half the image; images
that are not a multiple of the tile; lists longer than a batch (hundreds of faint Gaussians on one tile, every
pixel live to the end) with equal depths (ties by index); early termination (an opaque layer in front of
hundreds more: the loop must leave, and what it left must not matter); empty tiles and an empty projection;
Gaussians behind the camera, the camera inside a huge one, degenerate (zero-scale, edge-on) ones.

Triton is a test-only dependency kept out of the environment's site-packages (``requirements-isolated.txt``,
installed by tools/setup.sh into ``<venv>/isolated``, where only this test's process looks), so the suite runs the
kernel's logic on every CPU machine; CUDA machines ship Triton with torch. A subprocess, because the interpreter is
chosen when Triton is first imported. Small scenes: the interpreter runs each program's batches as numpy.
"""

import importlib.util
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
#: Where the isolated test-only packages are (as tests/backend/export/test_coco.py finds torchvision).
ISOLATED = os.environ.get("SCPAINTER_ISOLATED_PACKAGES") or os.path.join(sys.prefix, "isolated")

SCRIPT = r"""
import json, sys
import numpy as np, torch
from backend.render import gaussians as GS, tiles, tiles_cuda
from tests.backend.render.test_gaussians import random_scene, K, EYE

def camera(W, H):  # test_gaussians' K (64 x 48) scaled to the image: the same view of the same scenes
    return np.diag([W / 64, H / 48, 1.0]) @ K

def project(means, quats, scales, opac, sh, W, H):
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)
    return GS.project(t(means), t(quats), t(scales), t(opac), t(sh), camera(W, H), EYE, W, H, fast=False)

def layered(n_front, n_back, W, H, seed):
    # an opaque layer of wide Gaussians at z 3 in front of faint ones at z 6..8: every pixel saturates early
    rng = np.random.default_rng(seed)
    f = random_scene(n_front, seed)
    b = random_scene(n_back, seed + 1)
    means = np.concatenate([np.c_[rng.uniform(-1.6, 1.6, n_front), rng.uniform(-1.2, 1.2, n_front),
                                  np.full(n_front, 3.0)], np.c_[b[0][:, :2], rng.uniform(6, 8, n_back)]])
    scales = np.concatenate([np.full((n_front, 3), 1.0), b[2]])
    opac = np.concatenate([np.full(n_front, 0.99), b[3]])
    return means, np.concatenate([f[1], b[1]]), scales, opac, np.concatenate([f[4], b[4]])

def crowded(n, W, H, seed):
    # n faint Gaussians whose boxes hold one 16 x 16 corner tile, half of them at one depth (ties by index)
    rng = np.random.default_rng(seed)
    z = np.where(np.arange(n) % 2 == 0, 5.0, rng.uniform(4, 6, n))
    u, v = rng.uniform(2, 14, n), rng.uniform(2, 14, n)  # pixels of the first 16 x 16 tile
    Kc = camera(W, H)
    means = np.c_[(u - Kc[0, 2]) * z / Kc[0, 0], (v - Kc[1, 2]) * z / Kc[1, 1], z]
    quats = rng.normal(size=(n, 4))
    scales = np.full((n, 3), 0.02)
    opac = rng.uniform(0.02, 0.06, n)
    sh = rng.normal(0, 0.4, (n, 4, 3))
    return means, quats, scales, opac, sh

def extreme(W, H, seed):
    # behind the camera, at the near plane, the camera inside a huge one, zero scales, edge-on needles
    m, q, s, o, sh = random_scene(60, seed)
    m[:8, 2] = np.linspace(-3, 0.04, 8)          # behind the camera and inside the near plane: culled
    s[8] = [50.0, 50.0, 50.0]; m[8] = [0.1, 0.0, 1.0]; o[8] = 0.3   # the camera inside it
    s[9] = [1e3, 1e-3, 1e-3]; m[9] = [0.0, 0.2, 20.0]              # a huge needle across the image
    s[10:14, 0] = 0.0                                              # degenerate: zero along one axis
    s[14:18] = [[0.5, 1e-6, 0.5]] * 4                              # edge-on discs
    q[18] = 0.0                                                    # zero quaternion: dropped
    return m, q, s, o, sh

results = []
def check(name, proj, W, H, tile, bg=None, n_assets=1):
    bgt = None if bg is None else torch.as_tensor(bg, dtype=torch.float64)
    stats = {}
    c, mask, z, inst = tiles.composite_triton(proj, W, H, bgt, tile, n_assets, stats)
    rc, rmask, rz, rinst = GS.rasterize(proj, W, H, bgt)
    per_tile = stats["entries"]
    batch = tiles_cuda.launch_config(tile)[0]
    z, inst = z.double().reshape(H, W), inst.reshape(H, W)
    finite = ~torch.isinf(rz)
    results.append({
        "case": name, "tile": tile, "assets": n_assets, "gaussians": len(proj["depth"]),
        "longest_list": int(per_tile.max()) if len(per_tile) else 0, "empty_tiles": int((per_tile == 0).sum()),
        "batch": batch, "batches": int(stats["batches"].sum()),
        "batches_full": int(((per_tile + batch - 1) // batch).sum()),
        "err_color": float((c.double().reshape(H, W, 3) - rc).abs().max()),
        "err_mask": float((mask.double().reshape(H, W) - rmask).abs().max()),
        "max_mask": float(rmask.max()) if rmask.numel() else 0.0,
        "depth_inf_equal": bool(torch.equal(torch.isinf(z), torch.isinf(rz))),
        "err_depth": float((z[finite] - rz[finite]).abs().max()) if bool(finite.any()) else 0.0,
        "instance_diff": int((inst != rinst).sum()), "instances": sorted(torch.unique(rinst).tolist())})

W, H = 32, 24  # small: the interpreter runs every program's batches in numpy
def wall(W, H):
    bg = np.full((H, W), np.inf); bg[:, :W // 2] = 5.0
    return bg
for seed, tile, bg, n_assets in ((0, 16, False, 1), (1, 16, True, 1), (2, 8, False, 3), (3, 8, True, 5),
                                 (4, 4, False, 1), (5, 32, True, 3)):
    w, h = {32: (64, 48), 4: (16, 12)}.get(tile, (W, H))
    proj = project(*random_scene(150, seed), w, h)
    bg = wall(w, h) if bg else None
    if n_assets > 1:  # Gaussians split into assets by their side of the image (overlapping at the borders)
        proj["asset_id"] = 1 + (proj["mean2d"][:, 0] * n_assets / w).clamp(0, n_assets - 1).to(torch.int64)
    check(f"random {seed}", proj, w, h, tile, bg, n_assets)
proj = project(*random_scene(120, 6), 61, 37)
check("61 x 37 image", proj, 61, 37, 16, np.full((37, 61), 7.0))
proj = project(*crowded(300, W, H, 7), W, H)
check("crowded tile", proj, W, H, 16)
check("crowded tile", proj, W, H, 8)
proj = project(*layered(100, 300, W, H, 8), W, H)
check("opaque layer in front", proj, W, H, 16)
proj["asset_id"] = 1 + (torch.arange(len(proj["depth"])) % 2)
check("opaque layer in front", proj, W, H, 8, None, 2)
proj = project(*extreme(W, H, 9), W, H)
check("extreme", proj, W, H, 8, wall(W, H))
check("extreme", proj, W, H, 16)
one = random_scene(3, 10); one[0][:, :2] = [[-1.2, -0.8]] * 3  # three Gaussians in one corner: empty tiles
check("corner only", project(*one, W, H), W, H, 8)
empty = project(*random_scene(5, 11), W, H)
empty = {k: v[:0] for k, v in empty.items()}
check("empty projection", empty, W, H, 8)
json.dump(results, sys.stdout)
"""


def test_triton_kernel_matches_reference_in_interpreter():
    path = [p for p in (ISOLATED, os.environ.get("PYTHONPATH")) if p]
    assert os.path.isdir(os.path.join(ISOLATED, "triton")) or importlib.util.find_spec("triton"), \
        f"Triton is neither in {ISOLATED} nor importable: run tools/setup.sh (requirements-isolated.txt)"
    env = dict(os.environ, TRITON_INTERPRET="1", PYTHONPATH=os.pathsep.join([ROOT, *path]))
    proc = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = json.loads(proc.stdout)
    assert len(rows) == 15
    for r in rows:
        assert r["err_color"] <= 2e-5 and r["err_mask"] <= 2e-5, r  # float32 kernel, float64 reference
        assert r["depth_inf_equal"] and r["err_depth"] <= 1e-5, r
        assert r["instance_diff"] == 0, r
    by = {(r["case"], r["tile"]): r for r in rows}
    # the scenes hold what they are for
    for seed, tile, n_assets in ((0, 16, 1), (2, 8, 3), (3, 8, 5), (5, 32, 3)):
        r = by[f"random {seed}", tile]
        assert r["instances"] == list(range(n_assets + 1)) and r["max_mask"] > 0.5, r
    for tile in (8, 16):  # lists of several batches, every pixel live to the end (faint: no saturation)
        r = by["crowded tile", tile]
        assert r["longest_list"] >= 2 * r["batch"] and 0.3 < r["max_mask"] < 0.999, r
        assert r["batches"] == r["batches_full"], r  # nothing saturates: every batch of every list
    for tile in (8, 16):  # saturation in the first batches of lists much longer than them
        r = by["opaque layer in front", tile]
        assert r["longest_list"] > 3 * r["batch"] and r["max_mask"] > 0.9998, r
        assert r["batches"] < r["batches_full"] / 2, r  # the programs left their loops early
    assert by["corner only", 8]["empty_tiles"] >= 8 and by["corner only", 8]["gaussians"] == 3
    assert by["empty projection", 8]["gaussians"] == 0 and by["empty projection", 8]["max_mask"] == 0.0
    assert by["extreme", 8]["max_mask"] > 0.2 and by["extreme", 16]["gaussians"] < 60 - 8


COMPILE = r"""
import json, os, re, subprocess, sys
import triton
from triton.backends.compiler import GPUTarget
from triton.compiler import ASTSource
from backend.render import gaussians as GS, raster_choice, tiles_cuda

kernel = tiles_cuda._composite_kernel
signature = {name: ("*fp32" if name.endswith("_ptr") else "i32") for name in kernel.arg_names}
signature.update(tile_start_ptr="*i64", out_inst_ptr="*i32", out_batches_ptr="*i32")
ptxas = os.path.join(os.path.dirname(triton.__file__), "backends", "nvidia", "bin", "ptxas")
out = []
tile = raster_choice.TILE_CUDA
batch, warps = tiles_cuda.launch_config(tile)
for n_assets in (1, 3):
    consts = {"TILE": tile, "BATCH": batch, "A_PAD": tiles_cuda.a_pad(n_assets), "ALPHA_MAX": GS.ALPHA_MAX,
              "ALPHA_MIN": GS.ALPHA_MIN, "TRANSMITTANCE_MIN": GS.TRANSMITTANCE_MIN}
    signature.update({k: "constexpr" for k in consts})
    src = ASTSource(fn=kernel, signature=dict(signature),
                    constexprs={(kernel.arg_names.index(k),): v for k, v in consts.items()})
    compiled = triton.compile(src, target=GPUTarget("cuda", 90, 32), options={"num_warps": warps})
    path = os.path.join(sys.argv[1], f"kernel_{n_assets}.ptx")
    with open(path, "w") as f:
        f.write(compiled.asm["ptx"])
    info = subprocess.run([ptxas, "-arch=sm_90a", "-v", path, "-o", os.devnull], capture_output=True, text=True)
    regs = re.search(r"Used (\d+) registers", info.stderr)
    spills = re.search(r"(\d+) bytes spill stores", info.stderr)
    out.append({"assets": n_assets, "rc": info.returncode, "registers": int(regs.group(1)) if regs else None,
                "spill_stores": int(spills.group(1)) if spills else None, "stderr": info.stderr[-500:]})
json.dump(out, sys.stdout)
"""


def test_triton_kernel_compiles_for_hopper(tmp_path):
    """The kernel as a GPU runs it, not interpreted: Triton compiles it to PTX for sm_90 (H100/H200) without a GPU,
    and the wheel's ptxas assembles it; catches what the interpreter lets through (types in the loop, lowering of
    the scan and the dot) before a device run. The single-asset kernel at the CUDA tile size keeps its registers
    without spilling (ptxas -v; 161 registers with Triton 3.6.0)."""
    path = [p for p in (ISOLATED, os.environ.get("PYTHONPATH")) if p]
    assert os.path.isdir(os.path.join(ISOLATED, "triton")) or importlib.util.find_spec("triton"), \
        f"Triton is neither in {ISOLATED} nor importable: run tools/setup.sh (requirements-isolated.txt)"
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    env.update(PYTHONPATH=os.pathsep.join([ROOT, *path]), TRITON_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-c", COMPILE, str(tmp_path)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    single, three = json.loads(proc.stdout)
    assert single["rc"] == 0 and three["rc"] == 0, (single, three)
    assert single["registers"] <= 168 and single["spill_stores"] == 0, single  # 3 programs of 4 warps per SM
    assert three["registers"] <= 255, three
