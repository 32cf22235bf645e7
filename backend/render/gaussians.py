"""Gaussian splats into one camera: EWA projection and front-to-back compositing, written plainly in torch.

Conventions (docs/design.md §3, §4.3; the rules of the INRIA rasterizer and gsplat):

* Inputs are camera-relative like ``points.render_points``: means relative to a scene origin, world_to_camera
  for that origin; quaternions (w, x, y, z) any length (normalised here; zero, NaN or inf rows are dropped),
  scales are standard deviations in metres, opacities in [0, 1], SH (N, K, 3) coefficient-major.
* Σ = R S Sᵀ Rᵀ in world, W Σ Wᵀ in camera, Σ₂ = J W Σ Wᵀ Jᵀ + 0.3 I in pixels, with J the perspective Jacobian at
  the mean whose x/z, y/z are clamped to ±1.3·tan(fov/2) first (so Gaussians far off-screen stay bounded).
* Pixel centres are at (u + 0.5, v + 0.5); a Gaussian reaches pixels within 3 σ (``cutoff``) of its mean along
  Σ₂'s major axis.
* Per pixel, in depth order (ties by index): α = min(0.99, o · exp(-½ dᵀ Σ₂⁻¹ d)) (``ALPHA_MAX``); skipped
  below 1/255 (``ALPHA_MIN``); stop before the Gaussian that would drop the transmittance below 1e-4
  (``TRANSMITTANCE_MIN``). Only Gaussians in front of the pixel's nearest point are composited: the point is the
  opaque background behind them. The asset mask M_a = 1 − the transmittance left = Σ α·transmittance.
* Colour = max(0.5 + SH(dir), 0), dir = normalise(mean - camera centre) (``core.sh``, the formula the numpy side
  uses too).

Names: ``alpha`` is always one Gaussian's α at one pixel, ``transmittance`` (``trans``) the product of (1 − α) in
front, ``asset_mask`` the accumulated 1 − transmittance per pixel; ``w2c`` is the world_to_camera matrix.

The rasterizer builds every (Gaussian, pixel) pair within the cutoff, sorts pairs by (pixel, depth) once, and
composites with segmented cumulative products: no per-Gaussian or per-pixel Python loops.
"""

from __future__ import annotations

import numpy as np
import torch

from scpainter_blender.core import sh as core_sh

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4
BLUR = 0.3
CUTOFF = 3.0


def sh_colors(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """max(0.5 + Σ_k Y_k(dir) c_k, 0) for unit directions (N, 3) and coefficients (N, K, 3), K in 1, 4, 9, 16;
    Y_k from ``core.sh.basis`` (the numpy side's formula, evaluated on tensors)."""
    terms = core_sh.basis(dirs[:, 0:1], dirs[:, 1:2], dirs[:, 2:3], core_sh.degree_of(sh.shape[1]))
    out = terms[0] * sh[:, 0]
    for k in range(1, len(terms)):
        out = out + terms[k] * sh[:, k]
    return torch.clamp(out + 0.5, min=0.0)


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def covariance_factors(quats, scales):
    """M = R(q) S with Σ = M Mᵀ, (N, 3, 3), and a mask of usable rows (non-zero, finite quaternion and scales)."""
    qn = torch.linalg.norm(quats, dim=1)
    ok = (qn > 1e-12) & torch.isfinite(quats).all(1) & torch.isfinite(scales).all(1)
    q = torch.where(ok[:, None], quats / qn.clamp_min(1e-12)[:, None], torch.zeros_like(quats))
    return quat_to_rotmat(q) * scales.abs()[:, None, :], ok


def project(means, quats, scales, opacities, sh, K, world_to_camera, width, height, near=0.05, cutoff=CUTOFF):
    """EWA projection of the visible Gaussians given quaternions and scales (see project_factors)."""
    factors, ok = covariance_factors(quats, scales)
    return project_factors(means, factors, opacities, sh, K, world_to_camera, width, height, near, valid=ok,
                           cutoff=cutoff)


def project_factors(means, factors, opacities, sh, K, world_to_camera, width, height, near=0.05, valid=None,
                    cutoff=CUTOFF):
    """EWA projection of Gaussians with covariance Σ = M Mᵀ (``factors`` M, (N, 3, 3), world axes: an asset's
    affine object_to_world A gives M = A R S). Returns a dict of per-Gaussian screen quantities (M rows) and the
    original indices ``index``; Gaussians behind ``near``, with bad values, or entirely off-screen are gone.
    ``cutoff``: each Gaussian reaches pixels within that many σ (major axis) of its mean; beyond
    sqrt(2 ln 255) ≈ 3.33 σ nothing changes, since α < 1/255 there is skipped anyway."""
    dev, dt = means.device, means.dtype
    w2c = torch.as_tensor(np.asarray(world_to_camera, np.float64), dtype=dt, device=dev)
    Kt = torch.as_tensor(np.asarray(K, np.float64), dtype=dt, device=dev)
    fx, fy, cx, cy = Kt[0, 0], Kt[1, 1], Kt[0, 2], Kt[1, 2]
    finite = (torch.isfinite(means).all(1) & torch.isfinite(factors).all(2).all(1)
              & torch.isfinite(opacities) & torch.isfinite(sh).all(2).all(1))
    if valid is not None:
        finite &= valid
    cam = means @ w2c[:3, :3].T + w2c[:3, 3]
    keep = finite & (cam[:, 2] > near) & (opacities >= ALPHA_MIN)
    index = torch.nonzero(keep).squeeze(1)
    cam = cam[index]
    M = w2c[:3, :3] @ factors[index]                            # W M (W: the rotation of world_to_camera)
    cov = M @ M.transpose(1, 2)                                 # W Σ Wᵀ
    tz = cam[:, 2]
    lim_x = 1.3 * 0.5 * width / fx
    lim_y = 1.3 * 0.5 * height / fy
    tx = torch.clamp(cam[:, 0] / tz, -lim_x, lim_x) * tz
    ty = torch.clamp(cam[:, 1] / tz, -lim_y, lim_y) * tz
    J = torch.zeros((len(index), 2, 3), dtype=dt, device=dev)
    J[:, 0, 0], J[:, 0, 2] = fx / tz, -fx * tx / tz ** 2
    J[:, 1, 1], J[:, 1, 2] = fy / tz, -fy * ty / tz ** 2
    cov2 = J @ cov @ J.transpose(1, 2)
    a, b, c = cov2[:, 0, 0] + BLUR, cov2[:, 0, 1], cov2[:, 1, 1] + BLUR
    det = a * c - b * b
    conic = torch.stack([c / det, -b / det, a / det], 1)
    mid = 0.5 * (a + c)
    lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.0))
    radius = torch.ceil(cutoff * torch.sqrt(lam))
    mean2 = torch.stack([fx * cam[:, 0] / tz + Kt[0, 1] * cam[:, 1] / tz + cx, fy * cam[:, 1] / tz + cy], 1)
    on = (mean2[:, 0] + radius > 0) & (mean2[:, 0] - radius < width) & (mean2[:, 1] + radius > 0) & \
        (mean2[:, 1] - radius < height) & (det > 0) & torch.isfinite(radius)
    index = index[on]
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    dirs = means[index] - centre
    dirs = dirs / torch.linalg.norm(dirs, dim=1, keepdim=True).clamp_min(1e-12)
    return {"index": index, "mean2d": mean2[on], "conic": conic[on], "radius": radius[on], "depth": tz[on],
            "opacity": opacities[index], "color": sh_colors(sh[index], dirs)}


def pixel_boxes(proj, width, height) -> torch.Tensor:
    """(G, 4) int64 x0, x1, y0, y1: the inclusive pixel range of each Gaussian's cutoff square, clipped to the
    image. Pixel (x, y) gets a pair with Gaussian g exactly when x0 <= x <= x1 and y0 <= y <= y1."""
    m2, r = proj["mean2d"], proj["radius"]
    return torch.stack([torch.clamp(torch.floor(m2[:, 0] - r), 0, width - 1),
                        torch.clamp(torch.floor(m2[:, 0] + r), 0, width - 1),
                        torch.clamp(torch.floor(m2[:, 1] - r), 0, height - 1),
                        torch.clamp(torch.floor(m2[:, 1] + r), 0, height - 1)], 1).to(torch.int64)


def depth_rank(proj) -> torch.Tensor:
    """(G,) int64: each projected Gaussian's position in front-to-back order, ties by original index."""
    G = len(proj["depth"])
    rank = torch.empty(G, dtype=torch.int64, device=proj["depth"].device)
    order = torch.sort(proj["index"], stable=True).indices
    order = order[torch.sort(proj["depth"][order], stable=True).indices]
    rank[order] = torch.arange(G, device=rank.device)
    return rank


def rasterize(proj, width, height, background_depth=None, max_pairs=200_000_000):
    """Front-to-back compositing of projected Gaussians (see the module rules).

    ``background_depth`` (H, W): the nearest point per pixel (+inf where none); Gaussians at or behind it are
    hidden. Returns (color (H, W, 3) premultiplied, asset_mask (H, W) = M_a = 1 - transmittance, depth (H, W):
    where the accumulated opacity first reaches 0.5, +inf elsewhere).
    """
    dev = proj["mean2d"].device
    dt = proj["mean2d"].dtype
    color = torch.zeros((height * width, 3), dtype=dt, device=dev)
    asset_mask = torch.zeros(height * width, dtype=dt, device=dev)
    zmed = torch.full((height * width,), float("inf"), dtype=dt, device=dev)
    G = len(proj["depth"])
    if G == 0:
        return color.reshape(height, width, 3), asset_mask.reshape(height, width), zmed.reshape(height, width)
    m2 = proj["mean2d"]
    x0, x1, y0, y1 = pixel_boxes(proj, width, height).unbind(1)
    w, h = x1 - x0 + 1, y1 - y0 + 1
    counts = w * h
    total = int(counts.sum())
    if total > max_pairs:
        raise MemoryError(f"{total:,} Gaussian-pixel pairs exceed the limit of {max_pairs:,}: render in tiles")
    g = torch.repeat_interleave(torch.arange(G, device=dev), counts)
    start = torch.cumsum(counts, 0) - counts
    k = torch.arange(total, device=dev) - start[g]
    px = x0[g] + k % w[g]
    py = y0[g] + k // w[g]
    d = torch.stack([px.to(dt) + 0.5 - m2[g, 0], py.to(dt) + 0.5 - m2[g, 1]], 1)
    con = proj["conic"][g]
    power = -0.5 * (con[:, 0] * d[:, 0] ** 2 + 2 * con[:, 1] * d[:, 0] * d[:, 1] + con[:, 2] * d[:, 1] ** 2)
    alpha = torch.clamp(proj["opacity"][g] * torch.exp(power), max=ALPHA_MAX)
    pix = py * width + px
    ok = (alpha >= ALPHA_MIN) & (power <= 0)
    if background_depth is not None:
        ok &= proj["depth"][g] < background_depth.reshape(-1)[pix]
    g, pix, alpha = g[ok], pix[ok], alpha[ok]
    # depth order within each pixel; ties by the Gaussian's original index (rank = position in a stable sort)
    order = torch.argsort(pix * G + depth_rank(proj)[g])
    g, pix, alpha = g[order], pix[order], alpha[order]
    # segmented exclusive cumulative product of (1 - α) per pixel (the transmittance), in log space. The running
    # sum spans every pair of the image, so it is kept in float64: in float32 subtracting a segment's base loses
    # ~1e-4 of the transmittance.
    log1m = torch.log1p(-alpha).to(torch.float64)
    csum = torch.cumsum(log1m, 0)
    seg_start = torch.ones_like(pix, dtype=torch.bool)
    seg_start[1:] = pix[1:] != pix[:-1]
    first = torch.nonzero(seg_start).squeeze(1)
    seg_id = torch.cumsum(seg_start.to(torch.int64), 0) - 1
    base = (csum - log1m)[first][seg_id]               # log transmittance before the segment's first pair
    log_trans_after = csum - base
    trans_before = torch.exp(log_trans_after - log1m).to(dt)
    keep = torch.exp(log_trans_after) >= TRANSMITTANCE_MIN  # monotone: every pair after the first failure goes too
    log_trans_after = log_trans_after.to(dt)
    wgt = torch.where(keep, alpha * trans_before, torch.zeros_like(alpha))
    color.index_add_(0, pix, wgt[:, None] * proj["color"][g])
    asset_mask.index_add_(0, pix, wgt)                  # Σ α·transmittance = 1 - the transmittance left
    acc_after = 1.0 - torch.exp(log_trans_after)
    cross = keep & (acc_after >= 0.5) & ((acc_after - wgt) < 0.5)
    zmed.index_put_((pix[cross],), proj["depth"][g[cross]])
    return color.reshape(height, width, 3), asset_mask.reshape(height, width), zmed.reshape(height, width)


def fov_limits(K, width, height):
    """The 1.3·tan(fov/2) clamps used by project(), for tests and documentation."""
    return 1.3 * 0.5 * width / K[0][0], 1.3 * 0.5 * height / K[1][1]

