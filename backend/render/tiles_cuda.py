"""CUDA compositing kernel for ``tiles.rasterize``: Triton, one program per tile, Gaussians in batches.

Each program holds its tile's pixels as one vector (P = TILE² lanes) and walks the tile's depth-sorted list
(``tiles.kernel_inputs``: one column per entry, fields in rows, so a batch is one coalesced load per field) BATCH
entries at a time: a batch's α for every pixel is a [P, BATCH] block, the transmittance inside it a cumulative
product along the batch, and the colour, asset mask, depth and per-asset weights are reductions of that block.
The per-pixel rules are ``gaussians.rasterize``' (float32 here):

* α = min(0.99, o·exp(power)), used where the pixel lies in the Gaussian's pixel box, power ≤ 0, α ≥ 1/255 and
  the Gaussian is in front of the pixel's point (depth order: once behind, every later one is too).
* The stop "before the Gaussian that would take the transmittance below 1e-4" without a sequential loop: ``virt``
  is the product of (1 − α) over every used Gaussian, stops ignored. It is non-increasing, so a Gaussian is
  composited exactly when ``virt`` after it is still ≥ 1e-4 (the first failure fails because the transmittance
  before it equals ``virt`` there; every later one fails because ``virt`` only falls). The transmittance proper,
  ``trans``, is ``virt`` after the last composited Gaussian.
* Weights α·T_before = α·(virt after)/(1 − α) (1 − α ≥ 0.01: one rounding), so no exclusive scan is needed.

A program leaves its loop when no pixel of the tile is live: inside the image, ``virt`` ≥ 1e-4, and in front of
its point at the next batch's first depth (one reduction per batch, not per Gaussian).

The instance: one asset: the sum of the weights per pixel against ``trans``; more: a [P, A_PAD] block of
per-asset weights (A_PAD a power of two ≥ 16 and ≥ the number of assets, a compile-time constant), each batch
adding ``w @ onehot(asset)`` (an exact float32 dot: input_precision "ieee"), the instance the first column of the
largest weight (the lower id on ties) where it exceeds ``trans``. ``tiles.rasterize`` sends frames with more than
``tiles.MAX_ASSETS_CUDA`` assets to the torch reference instead.

Compilation: TILE, BATCH and A_PAD are the only compile-time constants and the integer arguments are not
specialised on their values (``do_not_specialize``; the row stride is a multiple of 32), so a render compiles
once per tile size and asset case, not per frame. Imported only on CUDA machines (and by the interpreter test):
importing Triton is not free and the CPU path does not need it.
"""

from __future__ import annotations

import torch
import triton
import triton.language as tl

from .gaussians import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN
from . import tiles
from .tiles import F32_ROWS, STRIDE_ALIGN

# kernel_inputs' rows, as the compile-time constants a kernel may read
_MX, _MY, _CA, _CB, _CC, _OPACITY, _DEPTH, _RED, _GREEN, _BLUE, _ASSET, _BOX_X, _BOX_Y = (tl.constexpr(v) for v in (
    tiles.MX, tiles.MY, tiles.CA, tiles.CB, tiles.CC, tiles.OPACITY, tiles.DEPTH, tiles.RED, tiles.GREEN, tiles.BLUE,
    tiles.ASSET, tiles.BOX_X, tiles.BOX_Y))


def launch_config(tile: int) -> tuple[int, int]:
    """(BATCH, num_warps) for a tile size: about 16 values of each [TILE², BATCH] temporary per thread (a dozen
    such temporaries live in the loop body; more would spill registers), BATCH between 16 (``tl.dot``'s minimum,
    for the per-asset weights) and 64, 4 to 16 warps: tiles of 8 → (32, 4), 16 → (16, 8). From the register
    budget (ptxas -v for sm_90a, Triton 3.6.0: tile 8 / batch 32 / 4 warps 161 registers, three programs per SM;
    16 / 16 / 8 158; no spills; batch 64 spills 116 B at tile 8 and 736 B at 16; with several assets 255 registers
    and ≤ 104 B spilled; tested: ``test_tiles_cuda``), not timed on a GPU yet: bench/render.py's speed row on CUDA
    times the kernel for other batch sizes (``kernel_sweep``) so a device run can retune it."""
    pixels = tile * tile
    batch = max(16, min(64, 2048 // pixels))
    return batch, max(4, min(16, pixels * batch // 512))


@triton.jit(do_not_specialize=["stride", "width", "height", "tiles_x"])
def _composite_kernel(params_ptr, tile_start_ptr, bg_ptr, out_c_ptr, out_mask_ptr, out_z_ptr, out_inst_ptr,
                      out_batches_ptr, stride, width, height, tiles_x, TILE: tl.constexpr, BATCH: tl.constexpr,
                      A_PAD: tl.constexpr, ALPHA_MAX: tl.constexpr, ALPHA_MIN: tl.constexpr,
                      TRANSMITTANCE_MIN: tl.constexpr):
    t = tl.program_id(0)
    offs = tl.arange(0, TILE * TILE)
    lx = offs % TILE  # tile-relative, as the means are
    ly = offs // TILE
    ox = (t % tiles_x) * TILE
    oy = (t // tiles_x) * TILE
    px = ox + lx
    py = oy + ly
    inside = (px < width) & (py < height)
    pix = py * width + px
    zbg = tl.load(bg_ptr + pix, mask=inside, other=float("-inf"))  # outside the image: everything is "behind"
    fx = lx.to(tl.float32) + 0.5
    fy = ly.to(tl.float32) + 0.5
    trans = tl.full([TILE * TILE], 1.0, tl.float32)
    virt = tl.full([TILE * TILE], 1.0, tl.float32)
    r = tl.zeros([TILE * TILE], tl.float32)
    g = tl.zeros([TILE * TILE], tl.float32)
    b = tl.zeros([TILE * TILE], tl.float32)
    w_sum = tl.zeros([TILE * TILE], tl.float32)
    z = tl.full([TILE * TILE], float("inf"), tl.float32)
    cols = tl.arange(0, A_PAD)
    w_asset = tl.zeros([TILE * TILE, A_PAD], tl.float32)
    lanes = tl.arange(0, BATCH)
    e = tl.load(tile_start_ptr + t)
    last = tl.load(tile_start_ptr + t + 1)
    first_depth = tl.load(params_ptr + _DEPTH * stride + e, mask=e < last, other=float("inf"))
    n_live = tl.sum((inside & (first_depth < zbg)).to(tl.int32), 0)
    batches = tl.full([], 0, tl.int32)
    while (e < last) & (n_live > 0):
        idx = e + lanes
        valid = idx < last
        mx = tl.load(params_ptr + _MX * stride + idx, mask=valid, other=0.0)
        my = tl.load(params_ptr + _MY * stride + idx, mask=valid, other=0.0)
        ca = tl.load(params_ptr + _CA * stride + idx, mask=valid, other=0.0)
        cb = tl.load(params_ptr + _CB * stride + idx, mask=valid, other=0.0)
        cc = tl.load(params_ptr + _CC * stride + idx, mask=valid, other=0.0)
        opac = tl.load(params_ptr + _OPACITY * stride + idx, mask=valid, other=0.0)
        depth = tl.load(params_ptr + _DEPTH * stride + idx, mask=valid, other=float("inf"))
        # the box's bits (past the list: 0, a one-pixel box, but opacity 0 there: α < 1/255, never used)
        box_x = tl.load(params_ptr + _BOX_X * stride + idx, mask=valid, other=0.0).to(tl.int32, bitcast=True)
        box_y = tl.load(params_ptr + _BOX_Y * stride + idx, mask=valid, other=0.0).to(tl.int32, bitcast=True)
        x0 = (box_x & 0xFFFF) - ox  # relative to the tile: the loop keeps only lx, ly per pixel live
        x1 = (box_x >> 16) - ox
        y0 = (box_y & 0xFFFF) - oy
        y1 = (box_y >> 16) - oy
        dx = fx[:, None] - mx[None, :]
        dy = fy[:, None] - my[None, :]
        power = -0.5 * (ca[None, :] * dx * dx + 2.0 * cb[None, :] * dx * dy + cc[None, :] * dy * dy)
        alpha = tl.minimum(opac[None, :] * tl.exp(power), ALPHA_MAX)
        use = ((lx[:, None] >= x0[None, :]) & (lx[:, None] <= x1[None, :]) & (ly[:, None] >= y0[None, :])
               & (ly[:, None] <= y1[None, :]) & (power <= 0.0) & (alpha >= ALPHA_MIN)
               & (depth[None, :] < zbg[:, None]))
        a = tl.where(use, alpha, 0.0)
        one_minus = 1.0 - a
        after = virt[:, None] * tl.cumprod(one_minus, axis=1)  # virt after each entry of the batch
        keep = use & (after >= TRANSMITTANCE_MIN)
        before = after / one_minus
        w = tl.where(keep, a * before, 0.0)
        r += tl.sum(w * tl.load(params_ptr + _RED * stride + idx, mask=valid, other=0.0)[None, :], 1)
        g += tl.sum(w * tl.load(params_ptr + _GREEN * stride + idx, mask=valid, other=0.0)[None, :], 1)
        b += tl.sum(w * tl.load(params_ptr + _BLUE * stride + idx, mask=valid, other=0.0)[None, :], 1)
        cross = keep & (before > 0.5) & (after <= 0.5)  # the accumulated opacity reaches 0.5 here (once a pixel)
        z = tl.minimum(z, tl.min(tl.where(cross, depth[None, :], float("inf")), 1))
        if A_PAD == 1:
            w_sum += tl.sum(w, 1)
        else:
            asset = tl.load(params_ptr + _ASSET * stride + idx, mask=valid, other=0.0).to(tl.int32) - 1
            onehot = (asset[:, None] == cols[None, :]).to(tl.float32)
            w_asset += tl.dot(w, onehot, input_precision="ieee")
        trans = tl.minimum(trans, tl.min(tl.where(keep, after, 1.0), 1))
        virt = tl.min(after, 1)  # non-increasing along the batch: its last value
        e += BATCH
        batches += 1
        next_depth = tl.load(params_ptr + _DEPTH * stride + e, mask=e < last, other=float("inf"))
        n_live = tl.sum((inside & (virt >= TRANSMITTANCE_MIN) & (next_depth < zbg)).to(tl.int32), 0)
    tl.store(out_batches_ptr + t, batches)
    tl.store(out_c_ptr + pix * 3, r, mask=inside)
    tl.store(out_c_ptr + pix * 3 + 1, g, mask=inside)
    tl.store(out_c_ptr + pix * 3 + 2, b, mask=inside)
    tl.store(out_mask_ptr + pix, 1.0 - trans, mask=inside)
    tl.store(out_z_ptr + pix, z, mask=inside)
    if A_PAD == 1:
        tl.store(out_inst_ptr + pix, tl.where(w_sum > trans, 1, 0), mask=inside)
    else:
        best_w = tl.max(w_asset, 1)
        best = tl.min(tl.where(w_asset == best_w[:, None], cols[None, :], A_PAD), 1)  # the first maximum
        tl.store(out_inst_ptr + pix, tl.where(best_w > trans, best + 1, 0), mask=inside)


def a_pad(n_assets: int) -> int:
    """The per-asset block's width: 1 for one asset (a plain sum), else a power of two ≥ n_assets and ≥ 16."""
    return 1 if n_assets <= 1 else max(16, 1 << (int(n_assets) - 1).bit_length())


def composite(params: torch.Tensor, tile_start: torch.Tensor, bg: torch.Tensor, width: int,
              height: int, tiles_x: int, tile: int, n_assets: int = 1,
              batches: torch.Tensor | None = None, batch: int | None = None,
              num_warps: int | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Run the kernel on ``tiles.kernel_inputs``' arrays (params (F32_ROWS, S) float32, S a multiple of
    ``STRIDE_ALIGN``; tile_start (tiles + 1,) int64; bg (HW,) float32); returns (color (HW, 3), asset_mask (HW) =
    1 - transmittance, depth (HW)) float32 and instance (HW) int32 for ``n_assets`` assets (ids 1..n_assets in params row ``ASSET``).
    ``batches`` (tiles,) int32, if given, receives how many batches each tile's program composited before it
    left its loop (the work done: tests check the early exit with it, the bench reports it). ``batch`` (a power
    of two ≥ 16) and ``num_warps`` override ``launch_config`` (the bench's sweep)."""
    dev = params.device
    assert params.shape[0] == F32_ROWS and params.dtype == torch.float32 and params.shape[1] % STRIDE_ALIGN == 0
    out_c = torch.empty((height * width, 3), dtype=torch.float32, device=dev)
    out_mask = torch.empty(height * width, dtype=torch.float32, device=dev)
    out_z = torch.empty(height * width, dtype=torch.float32, device=dev)
    out_inst = torch.empty(height * width, dtype=torch.int32, device=dev)
    n_tiles = len(tile_start) - 1
    if batches is None:
        batches = torch.empty(n_tiles, dtype=torch.int32, device=dev)
    default_batch, default_warps = launch_config(tile)
    batch, warps = batch or default_batch, num_warps or default_warps
    _composite_kernel[(n_tiles,)](params, tile_start, bg, out_c, out_mask, out_z, out_inst, batches,
                                  params.shape[1],
                                  width, height, tiles_x, TILE=tile, BATCH=batch, A_PAD=a_pad(n_assets),
                                  ALPHA_MAX=ALPHA_MAX, ALPHA_MIN=ALPHA_MIN, TRANSMITTANCE_MIN=TRANSMITTANCE_MIN,
                                  num_warps=warps)
    return out_c, out_mask, out_z, out_inst
