"""CPU fast path of ``points.render_points``: a numba z-buffer, the same winners as the torch reference bit for bit.

Contract shared with the torch path (``points``): the projection is float32 arithmetic done in one written order,

    x = ((X·R00 + Y·R01) + Z·R02) + t0     (likewise y, z; R, t = world_to_camera rounded to float32)
    u = ((K00·x)/z + (K01·y)/z) + K02,     v = (K11·y)/z + K12     (K rounded to float32)

each operation rounded to float32 (no fused multiply-add: numba without fastmath does not contract, torch runs one
kernel per operation), the tests ``z > near`` (near rounded to float32, as torch compares a float32 tensor with a
Python float), ``z < inf``, ``-r <= u < W + r``, ``-r <= v < H + r`` (NaN fails each), then pixel (floor u, floor v)
and, for a splat radius r, every pixel of the (2r+1)^2 square around it that is inside the image. Each pixel keeps
the smallest key (float32 bits of z) << 32 | point index: nearest wins, ties go to the lower index.

Parallel and deterministic without atomics: pass 1 (parallel over points) projects every point once into its base
pixel row, column and key; pass 2 (parallel over bands of image rows) has each band scan every point and take the
minimum over the pixels of its own rows, so no two threads write one pixel and the minimum does not depend on the
order or the thread count; pass 3 (parallel over pixels) decodes the keys into depth, winner and colour.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import get_num_threads, njit, prange

_EMPTY = np.iinfo(np.int64).max
_CULLED = np.iinfo(np.int32).min // 2  # a row no band reaches, whatever r is


@njit(parallel=True, cache=True, nogil=True)
def _project(xyz, cam, k, near, width, height, r, row, col, depth):
    """Pass 1. xyz (N, 3) float32; cam (12,) float32 = R row-major then t; k (5,) float32 = K00 K01 K02 K11 K12;
    near float32. Writes row/col (N,) int32 (the base pixel; row = _CULLED when culled) and depth (N,) float32."""
    n = xyz.shape[0]
    lo_u, hi_u = np.float32(-r), np.float32(width + r)
    lo_v, hi_v = np.float32(-r), np.float32(height + r)
    inf = np.float32(np.inf)
    for i in prange(n):
        px, py, pz = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        x = ((px * cam[0] + py * cam[1]) + pz * cam[2]) + cam[9]
        y = ((px * cam[3] + py * cam[4]) + pz * cam[5]) + cam[10]
        z = ((px * cam[6] + py * cam[7]) + pz * cam[8]) + cam[11]
        u = ((k[0] * x) / z + (k[1] * y) / z) + k[2]
        v = (k[3] * y) / z + k[4]
        if z > near and z < inf and u >= lo_u and u < hi_u and v >= lo_v and v < hi_v:
            row[i] = np.int32(np.floor(v))
            col[i] = np.int32(np.floor(u))
            depth[i] = z
        else:
            row[i] = _CULLED
            col[i] = 0
            depth[i] = inf


@njit(parallel=True, cache=True, nogil=True)
def _scatter(row, col, depth_bits, width, height, r, bands, best):
    """Pass 2: best (H*W,) int64 (filled with _EMPTY) = per pixel the minimum key of the points covering it;
    depth_bits (N,) int32 is pass 1's depth seen as its bit pattern.
    Band b owns image rows [b*H//bands, (b+1)*H//bands): the only writer of those pixels."""
    n = row.shape[0]
    for b in prange(bands):
        y0, y1 = b * height // bands, (b + 1) * height // bands
        for i in range(n):
            cv = row[i]
            if cv + r < y0 or cv - r >= y1:
                continue  # culled points (row _CULLED) land here too
            kk = (np.int64(depth_bits[i]) << 32) | np.int64(i)
            cu = col[i]
            for yy in range(max(cv - r, y0), min(cv + r + 1, y1)):
                base = yy * width
                for xx in range(max(cu - r, 0), min(cu + r + 1, width)):
                    if kk < best[base + xx]:
                        best[base + xx] = kk


@njit(parallel=True, cache=True, nogil=True)
def _decode(best, rgb, image, depth_bits, winner):
    """Pass 3: keys into depth (float32 seen as int32 bits; +inf empty), winner (int64, -1 empty), colour (float32,
    0 empty)."""
    inf_bits = np.int32(0x7F800000)
    for p in prange(best.shape[0]):
        kk = best[p]
        if kk == _EMPTY:
            winner[p] = -1
            depth_bits[p] = inf_bits
            image[p, 0] = image[p, 1] = image[p, 2] = 0.0
        else:
            w = kk & 0xFFFFFFFF
            winner[p] = w
            depth_bits[p] = np.int32(kk >> 32)
            for c in range(3):
                image[p, c] = np.float32(rgb[w, c])


def render_points(xyz: torch.Tensor, rgb: torch.Tensor, K, world_to_camera, width: int, height: int,
                  near: float = 0.05, radius_px: int = 0):
    """``points.render_points`` on CPU tensors (same arguments, same outputs, bit for bit)."""
    xyz_np = xyz.detach().to(torch.float32).contiguous().numpy()
    if rgb.dtype not in (torch.float32, torch.float64, torch.uint8):
        rgb = rgb.to(torch.float32)  # exact for the other types a colour comes in (float16, bfloat16, small ints)
    rgb_np = rgb.detach().contiguous().numpy()
    w2c = np.asarray(world_to_camera, np.float64).astype(np.float32)
    Kf = np.asarray(K, np.float64).astype(np.float32)
    cam = np.concatenate([w2c[:3, :3].reshape(-1), w2c[:3, 3]])
    k = np.array([Kf[0, 0], Kf[0, 1], Kf[0, 2], Kf[1, 1], Kf[1, 2]], np.float32)
    n, r = len(xyz_np), int(radius_px)
    row = np.empty(n, np.int32)
    col = np.empty(n, np.int32)
    zs = np.empty(n, np.float32)
    _project(xyz_np, cam, k, np.float32(near), width, height, r, row, col, zs)
    best = np.full(height * width, _EMPTY, np.int64)
    _scatter(row, col, zs.view(np.int32), width, height, r, max(1, min(get_num_threads(), height)), best)
    image = torch.empty((height, width, 3), dtype=torch.float32)
    depth = torch.empty((height, width), dtype=torch.float32)
    winner = torch.empty((height, width), dtype=torch.int64)
    _decode(best, rgb_np, image.numpy().reshape(-1, 3), depth.numpy().reshape(-1).view(np.int32),
            winner.numpy().reshape(-1))
    return image, depth, winner
