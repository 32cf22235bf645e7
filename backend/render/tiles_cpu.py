"""CPU compositing kernel for ``tiles.rasterize``: numba, parallel over tiles, one front-to-back loop per pixel.

Rules and names: see ``gaussians`` (module docstring) and ``tiles``. Transmittance and colour are accumulated in
float64 so the 1e-4 stop decision matches the reference's float64 log-space product; outputs are float32.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from .gaussians import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN


@njit(parallel=True, cache=True, nogil=True)
def _composite(params, boxes, tile_start, bg, width, height, tiles_x, tile, out_c, out_mask, out_z):
    n_tiles = len(tile_start) - 1
    for t in prange(n_tiles):
        first, last = tile_start[t], tile_start[t + 1]
        if first == last:
            continue
        tx0, ty0 = (t % tiles_x) * tile, (t // tiles_x) * tile
        for py in range(ty0, min(ty0 + tile, height)):
            for px in range(tx0, min(tx0 + tile, width)):
                pix = py * width + px
                trans, r, g, b, z = 1.0, 0.0, 0.0, 0.0, np.inf
                fx, fy = px - tx0 + 0.5, py - ty0 + 0.5  # tile-relative, as the means are
                zbg = bg[pix]
                for e in range(first, last):
                    if params[e, 6] >= zbg:
                        break  # depth order: this and every later Gaussian are behind the pixel's point
                    if px < boxes[e, 0] or px > boxes[e, 1] or py < boxes[e, 2] or py > boxes[e, 3]:
                        continue
                    dx, dy = fx - params[e, 0], fy - params[e, 1]
                    power = -0.5 * (params[e, 2] * dx * dx + 2.0 * params[e, 3] * dx * dy + params[e, 4] * dy * dy)
                    if power > 0.0:
                        continue
                    alpha = min(ALPHA_MAX, params[e, 5] * math.exp(power))
                    if alpha < ALPHA_MIN:
                        continue
                    trans_next = trans * (1.0 - alpha)
                    if trans_next < TRANSMITTANCE_MIN:
                        break
                    w = alpha * trans
                    r += w * params[e, 7]
                    g += w * params[e, 8]
                    b += w * params[e, 9]
                    if trans > 0.5 and trans_next <= 0.5:
                        z = params[e, 6]
                    trans = trans_next
                out_c[pix, 0], out_c[pix, 1], out_c[pix, 2] = r, g, b
                out_mask[pix] = 1.0 - trans
                out_z[pix] = z


def composite(params, boxes, tile_start, bg, width, height, tiles_x, tile):
    """Run the kernel on CPU tensors (shared memory, no copies); returns (color (HW, 3), asset_mask (HW) = 1 -
    transmittance, depth (HW))."""
    out_c = torch.zeros((height * width, 3), dtype=torch.float32)
    out_mask = torch.zeros(height * width, dtype=torch.float32)
    out_z = torch.full((height * width,), float("inf"), dtype=torch.float32)
    _composite(params.numpy(), boxes.numpy(), tile_start.numpy(), bg.numpy(), width, height, tiles_x, tile,
               out_c.numpy(), out_mask.numpy(), out_z.numpy())
    return out_c, out_mask, out_z
