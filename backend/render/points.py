"""Coloured points into one camera: cull early, project, z-buffer deterministically (nearest wins).

Conventions (docs/design.md §3): OpenCV camera, our K (pixel (u, v) covers [u, u+1) x [v, v+1)); a point lands in the
pixel that contains its projection. Inputs are *camera-relative*: positions are given relative to a scene origin
chosen near the cameras (float32 then keeps millimetres 1e5 m from the world origin), and ``world_to_camera`` is
expressed for that origin — see ``relative_camera``.

Determinism: the z-buffer key is (depth bits << 32 | point index) reduced with ``amin``; positive float32 bit
patterns order like the floats, so the nearest point wins and ties go to the lower index, identically on CPU
and CUDA, whatever the thread schedule.

Two implementations of one contract (the float32 operations and their order: ``points_cpu``'s docstring): the torch
path here (the reference, and what runs on CUDA) and a numba z-buffer for CPU tensors (``points_cpu``, one
projection per point, no sort, no index tensors; 3-5x faster on 2 cores). Tests demand identical winners, depths
and colours from both.
"""

from __future__ import annotations

import numpy as np
import torch

from scpainter_blender.core.geometry.visibility import relative_camera  # noqa: F401 (the renderer's name for it)


def _depth_keys(z: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    bits = z.to(torch.float32).contiguous().view(torch.int32).to(torch.int64)
    return (bits << 32) | index.to(torch.int64)


def render_points(xyz: torch.Tensor, rgb: torch.Tensor, K, world_to_camera, width: int, height: int,
                  near: float = 0.05, radius_px: int = 0, fast: bool = True):
    """Z-buffer points (N, 3) float32 with colours (N, 3) into a ``height`` x ``width`` image.

    Returns (rgb (H, W, 3) float32, zeros where empty, depth (H, W) float32 +inf where empty, index (H, W) int64 of
    the winning point, -1 where empty), on ``xyz``'s device. ``radius_px`` > 0 splats each point over a (2r+1)^2
    square, nearest still winning. Points at or behind ``near`` (metres, >= 0), outside the image, or with
    non-finite values are culled first. ``fast=False`` runs the torch reference on CPU tensors too.
    """
    if xyz.shape[0] >= 2 ** 31:
        raise ValueError(f"{xyz.shape[0]} points: the z-buffer key holds a 31-bit point index")
    if fast and xyz.device.type == "cpu":
        from . import points_cpu

        return points_cpu.render_points(xyz, rgb, K, world_to_camera, width, height, near=near, radius_px=radius_px)
    return render_points_torch(xyz, rgb, K, world_to_camera, width, height, near=near, radius_px=radius_px)


def render_points_torch(xyz: torch.Tensor, rgb: torch.Tensor, K, world_to_camera, width: int, height: int,
                        near: float = 0.05, radius_px: int = 0):
    """The reference z-buffer in torch (any device): ``render_points``' arguments and outputs."""
    dev = xyz.device
    w2c = torch.as_tensor(np.asarray(world_to_camera, np.float64), dtype=torch.float32, device=dev)
    Kt = torch.as_tensor(np.asarray(K, np.float64), dtype=torch.float32, device=dev)
    X, Y, Z = xyz.to(torch.float32).unbind(1)
    # written out rather than a matmul (whose summation order and fused multiply-adds are the BLAS's choice): the
    # contract the numba path reproduces bit for bit (points_cpu); equal to MKL's sgemm on the CPUs measured
    x, y, z = (((X * w2c[j, 0] + Y * w2c[j, 1]) + Z * w2c[j, 2]) + w2c[j, 3] for j in range(3))
    # every test in one mask and one gather (the hot path: millions of points per frame); NaN fails every test
    u = Kt[0, 0] * x / z + Kt[0, 1] * y / z + Kt[0, 2]
    v = Kt[1, 1] * y / z + Kt[1, 2]
    r = int(radius_px)
    valid = (z > near) & (z < float("inf")) & (u >= -r) & (u < width + r) & (v >= -r) & (v < height + r)
    idx = torch.nonzero(valid).squeeze(1)
    z, cu, cv = z[idx], torch.floor(u[idx]).to(torch.int64), torch.floor(v[idx]).to(torch.int64)
    if r > 0:
        offs = torch.arange(-r, r + 1, device=dev)
        du, dv = torch.meshgrid(offs, offs, indexing="xy")
        cu = (cu[:, None] + du.reshape(1, -1)).reshape(-1)
        cv = (cv[:, None] + dv.reshape(1, -1)).reshape(-1)
        n = du.numel()
        idx, z = idx.repeat_interleave(n), z.repeat_interleave(n)
        ok = (cu >= 0) & (cu < width) & (cv >= 0) & (cv < height)
        idx, z, cu, cv = idx[ok], z[ok], cu[ok], cv[ok]
    pix = cv * width + cu
    best = torch.full((height * width,), torch.iinfo(torch.int64).max, dtype=torch.int64, device=dev)
    best.scatter_reduce_(0, pix, _depth_keys(z, idx), reduce="amin")
    hit = best != torch.iinfo(torch.int64).max
    winner = torch.where(hit, best & 0xFFFFFFFF, torch.full_like(best, -1))
    depth = torch.full((height * width,), float("inf"), device=dev)
    depth[hit] = (best[hit] >> 32).to(torch.int32).view(torch.float32)
    image = torch.zeros((height * width, 3), device=dev)
    image[hit] = rgb[winner[hit]].to(torch.float32)
    return image.reshape(height, width, 3), depth.reshape(height, width), winner.reshape(height, width)
