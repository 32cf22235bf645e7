"""CUDA compositing kernel for ``tiles.rasterize``: Triton, one program per tile, the tile's pixels as one vector.

Each program walks its tile's depth-sorted list one Gaussian at a time (the same per-pixel rules as
``tiles_cpu`` and the torch reference, float32) and leaves the loop when every pixel of the tile is saturated,
hidden by its point, or outside the image. Imported only on CUDA machines: importing Triton is not free and the
CPU path does not need it.

The instance: each pixel's weight per asset is a [TILE * TILE, A_PAD] block (A_PAD a power of two ≥ the number of
assets, a compile-time constant; column c is asset c + 1, read from params column 10), the pixel's instance the
first column of the largest weight (the lower id on ties) where that weight exceeds the transmittance left.
``tiles.rasterize`` sends frames with more than ``tiles.MAX_ASSETS_CUDA`` assets to the torch reference instead.
"""

from __future__ import annotations

import torch
import triton
import triton.language as tl

from .gaussians import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN


@triton.jit
def _composite_kernel(params_ptr, boxes_ptr, tile_start_ptr, bg_ptr, out_c_ptr, out_mask_ptr, out_z_ptr, out_inst_ptr,
                      width, height, tiles_x, TILE: tl.constexpr, A_PAD: tl.constexpr, ALPHA_MAX: tl.constexpr,
                      ALPHA_MIN: tl.constexpr, TRANSMITTANCE_MIN: tl.constexpr):
    t = tl.program_id(0)
    offs = tl.arange(0, TILE * TILE)
    px = (t % tiles_x) * TILE + offs % TILE
    py = (t // tiles_x) * TILE + offs // TILE
    inside = (px < width) & (py < height)
    pix = py * width + px
    zbg = tl.load(bg_ptr + pix, mask=inside, other=0.0)
    fx = (offs % TILE).to(tl.float32) + 0.5  # tile-relative, as the means are
    fy = (offs // TILE).to(tl.float32) + 0.5
    trans = tl.full([TILE * TILE], 1.0, tl.float32)
    r = tl.zeros([TILE * TILE], tl.float32)
    g = tl.zeros([TILE * TILE], tl.float32)
    b = tl.zeros([TILE * TILE], tl.float32)
    z = tl.full([TILE * TILE], float("inf"), tl.float32)
    cols = tl.arange(0, A_PAD)
    w_asset = tl.zeros([TILE * TILE, A_PAD], tl.float32)
    active = inside
    e = tl.load(tile_start_ptr + t)
    last = tl.load(tile_start_ptr + t + 1)
    n_active = tl.sum(active.to(tl.int32), 0)
    while (e < last) & (n_active > 0):
        p = params_ptr + e * 12
        depth = tl.load(p + 6)
        active = active & (depth < zbg)  # depth order: hidden now means hidden for the rest of the list
        x0 = tl.load(boxes_ptr + e * 4)
        x1 = tl.load(boxes_ptr + e * 4 + 1)
        y0 = tl.load(boxes_ptr + e * 4 + 2)
        y1 = tl.load(boxes_ptr + e * 4 + 3)
        dx = fx - tl.load(p)
        dy = fy - tl.load(p + 1)
        power = -0.5 * (tl.load(p + 2) * dx * dx + 2.0 * tl.load(p + 3) * dx * dy + tl.load(p + 4) * dy * dy)
        alpha = tl.minimum(tl.load(p + 5) * tl.exp(power), ALPHA_MAX)
        use = active & (px >= x0) & (px <= x1) & (py >= y0) & (py <= y1) & (power <= 0.0) & (alpha >= ALPHA_MIN)
        trans_next = trans * (1.0 - alpha)
        stop = use & (trans_next < TRANSMITTANCE_MIN)
        active = active & ~stop
        use = use & ~stop
        w = tl.where(use, alpha * trans, 0.0)
        r += w * tl.load(p + 7)
        g += w * tl.load(p + 8)
        b += w * tl.load(p + 9)
        z = tl.where(use & (trans > 0.5) & (trans_next <= 0.5), depth, z)
        asset = tl.load(p + 10).to(tl.int32) - 1
        w_asset += tl.where((cols == asset)[None, :], w[:, None], 0.0)
        trans = tl.where(use, trans_next, trans)
        e += 1
        n_active = tl.sum(active.to(tl.int32), 0)
    tl.store(out_c_ptr + pix * 3, r, mask=inside)
    tl.store(out_c_ptr + pix * 3 + 1, g, mask=inside)
    tl.store(out_c_ptr + pix * 3 + 2, b, mask=inside)
    tl.store(out_mask_ptr + pix, 1.0 - trans, mask=inside)
    tl.store(out_z_ptr + pix, z, mask=inside)
    best_w = tl.max(w_asset, 1)
    best = tl.min(tl.where(w_asset == best_w[:, None], cols[None, :], A_PAD), 1)  # the first maximum
    tl.store(out_inst_ptr + pix, tl.where(best_w > trans, best + 1, 0), mask=inside)


def composite(params, boxes, tile_start, bg, width, height, tiles_x, tile, n_assets=1):
    """Run the kernel on CUDA tensors; returns (color (HW, 3), asset_mask (HW) = 1 - transmittance, depth (HW))
    float32 and instance (HW) int32 for ``n_assets`` assets (ids 1..n_assets in params column 10)."""
    dev = params.device
    out_c = torch.empty((height * width, 3), dtype=torch.float32, device=dev)
    out_mask = torch.empty(height * width, dtype=torch.float32, device=dev)
    out_z = torch.empty(height * width, dtype=torch.float32, device=dev)
    out_inst = torch.empty(height * width, dtype=torch.int32, device=dev)
    n_tiles = len(tile_start) - 1
    a_pad = max(2, 1 << max(0, int(n_assets) - 1).bit_length())  # a power of two >= n_assets (2 at least)
    _composite_kernel[(n_tiles,)](params, boxes, tile_start, bg, out_c, out_mask, out_z, out_inst, width, height,
                                  tiles_x, TILE=tile, A_PAD=a_pad, ALPHA_MAX=ALPHA_MAX, ALPHA_MIN=ALPHA_MIN,
                                  TRANSMITTANCE_MIN=TRANSMITTANCE_MIN, num_warps=4)
    return out_c, out_mask, out_z, out_inst
