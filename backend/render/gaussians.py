"""Gaussian splats into one camera: EWA projection and front-to-back compositing, written plainly in torch.

Conventions (docs/design.md §3, §4.3; the rules of the INRIA rasterizer, with gsplat 1.5.3's screen extent and
Jacobian clamp):

* Inputs are camera-relative like ``points.render_points``: means relative to a scene origin, world_to_camera
  for that origin; quaternions (w, x, y, z) any length (normalised here; zero, NaN or inf rows are dropped),
  scales are standard deviations in metres, opacities in [0, 1], SH (N, K, 3) coefficient-major.
* Σ = R S Sᵀ Rᵀ in world, W Σ Wᵀ in camera, Σ₂ = J W Σ Wᵀ Jᵀ + 0.3 I in pixels, with J the perspective Jacobian at
  the mean whose x/z is clamped to [-(cx/fx + 0.3·tan_x), (W - cx)/fx + 0.3·tan_x], tan_x = 0.5·W/fx (likewise
  y/z with cy, fy, H) first, so Gaussians far off-screen stay bounded (``jacobian_limits``: gsplat's clamp, which
  follows the principal point; with a centred K it is INRIA's ±1.3·tan(fov/2)).
* Screen extent (gsplat 1.5.3, per axis and opacity-aware): extend = min(3.33, sqrt(2 ln(255·o))), radius_x =
  ceil(extend·sqrt(Σ₂_xx)), radius_y = ceil(extend·sqrt(Σ₂_yy)) (``screen_extent``). It is exact, not a cutoff:
  α ≥ 1/255 means dᵀ Σ₂⁻¹ d ≤ 2 ln(255·o), and by Cauchy–Schwarz |d_x| ≤ sqrt(Σ₂_xx)·sqrt(dᵀ Σ₂⁻¹ d) ≤ radius_x
  (likewise y; for o ≤ 1 the 3.33 cap never binds, sqrt(2 ln 255) = 3.329), so every pixel the rules composite
  has its centre inside the box and a render equals the one that tries every Gaussian at every pixel.
* Pixel centres are at (u + 0.5, v + 0.5); ``pixel_boxes`` are the pixels whose centres lie within the extent.
  Gaussians whose box holds no pixel of the image are culled.
* Per pixel, in depth order (ties by index): α = min(0.99, o · exp(-½ dᵀ Σ₂⁻¹ d)) (``ALPHA_MAX``); skipped
  below 1/255 (``ALPHA_MIN``); stop before the Gaussian that would drop the transmittance below 1e-4
  (``TRANSMITTANCE_MIN``). Only Gaussians in front of the pixel's nearest point are composited: the point is the
  opaque background behind them. The asset mask M_a = 1 − the transmittance left = Σ α·transmittance.
* Instance: each Gaussian belongs to an asset (``proj["asset_id"]``, 1-based; ``asset_ids``). Per pixel w_a =
  Σ α·transmittance over the composited Gaussians of asset a and T_rest = the transmittance left; the instance is
  argmax_a w_a (ties to the lower id) where max_a w_a > T_rest, else 0 (one asset: where its M_a > 0.5).
  The 0.99 cap is the INRIA rasterizer's (graphdeco-inria/diff-gaussian-rasterization), the one the TRELLIS and
  Amodal3R assets were trained with; gsplat caps at 0.999. We keep 0.99: the assets' opacities were fitted to it.
* Colour = max(0.5 + SH(dir), 0), dir = normalise(mean - camera centre) (``core.splats.sh``, the formula the numpy side
  uses too).

Names: ``alpha`` is always one Gaussian's α at one pixel, ``transmittance`` (``trans``) the product of (1 − α) in
front, ``asset_mask`` the accumulated 1 − transmittance per pixel; ``w2c`` is the world_to_camera matrix.

Two projections of one contract: ``project_factors_torch`` here (the reference, any device) and a numba kernel for
CPU tensors (``project_cpu``, one pass per Gaussian, no 3x3 batched products or index tensors); tests compare them.
The rasterizer here builds every (Gaussian, pixel) pair inside the boxes, sorts pairs by (pixel, depth) once, and
composites with segmented cumulative products: no per-Gaussian or per-pixel Python loops. It is the reference for
the tile kernels (``tiles``).
"""

from __future__ import annotations

import numpy as np
import torch

from scpainter_blender.core.geometry.visibility import BLUR, EXTEND_MAX  # the skip test's constants too
from scpainter_blender.core.splats import sh as core_sh
from scpainter_blender.core.splats.gaussians import ALPHA_MIN  # the input check's cut too

ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4


def sh_colors(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """max(0.5 + Σ_k Y_k(dir) c_k, 0) for unit directions (N, 3) and coefficients (N, K, 3), K in 1, 4, 9, 16;
    Y_k from ``core.splats.sh.basis`` (the numpy side's formula, evaluated on tensors)."""
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


def covariance_factors(quats: torch.Tensor, scales: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """M = R(q) S with Σ = M Mᵀ, (N, 3, 3), and a mask of usable rows (non-zero, finite quaternion and scales)."""
    qn = torch.linalg.norm(quats, dim=1)
    ok = (qn > 1e-12) & torch.isfinite(quats).all(1) & torch.isfinite(scales).all(1)
    q = torch.where(ok[:, None], quats / qn.clamp_min(1e-12)[:, None], torch.zeros_like(quats))
    return quat_to_rotmat(q) * scales.abs()[:, None, :], ok


def jacobian_limits(K: np.ndarray, width: int, height: int) -> tuple[float, float, float, float]:
    """gsplat's clamp of the Jacobian's x/z and y/z: (x_neg, x_pos, y_neg, y_pos), x/z is clamped to
    [-x_neg, x_pos] and y/z to [-y_neg, y_pos]. The view's tangent range extended by 0.3·tan(half fov) on each side,
    following the principal point: x_pos = (W - cx)/fx + 0.3·tan_x, x_neg = cx/fx + 0.3·tan_x, tan_x = 0.5·W/fx
    (likewise y with cy, fy, H). With cx = W/2 both are INRIA's 1.3·tan(fov_x/2)."""
    fx, fy, cx, cy = float(K[0][0]), float(K[1][1]), float(K[0][2]), float(K[1][2])
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    return (cx / fx + 0.3 * tan_x, (width - cx) / fx + 0.3 * tan_x,
            cy / fy + 0.3 * tan_y, (height - cy) / fy + 0.3 * tan_y)


def screen_extent(opacities: torch.Tensor) -> torch.Tensor:
    """extend = min(3.33, sqrt(2 ln(255·o))) per Gaussian (gsplat 1.5.3): how many σ along each screen axis a
    Gaussian of opacity o reaches with α ≥ 1/255 (0 at o = 1/255; rows with o < 1/255 are culled before)."""
    return torch.sqrt(2.0 * torch.log(opacities / ALPHA_MIN).clamp_min(0.0)).clamp_max(EXTEND_MAX)


def centre_range(m: torch.Tensor, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The pixels u whose centres u + 0.5 lie in [m - r, m + r], as floats (lo, hi), not clipped; lo > hi when
    none does. Written once for the torch and numba paths (``project_cpu`` repeats the same two operations)."""
    return torch.ceil(m - r - 0.5), torch.floor(m + r - 0.5)


def project(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor, sh: torch.Tensor,
            K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int, near: float = 0.05,
            fast: bool = True) -> dict:
    """EWA projection of the visible Gaussians given quaternions and scales (see project_factors)."""
    factors, ok = covariance_factors(quats, scales)
    return project_factors(means, factors, opacities, sh, K, world_to_camera, width, height, near, valid=ok,
                           fast=fast)


def project_factors(means: torch.Tensor, factors: torch.Tensor, opacities: torch.Tensor, sh: torch.Tensor,
                    K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int, near: float = 0.05,
                    valid: torch.Tensor | None = None, fast: bool = True) -> dict:
    """EWA projection of Gaussians with covariance Σ = M Mᵀ (``factors`` M, (N, 3, 3), world axes: an asset's
    affine object_to_world A gives M = A R S). Returns a dict of per-Gaussian screen quantities (G rows, in
    ascending original index), each a tensor of ``means``' dtype and device: ``index`` (G,) int64 the original
    rows, ``mean2d`` (G, 2) pixels, ``conic`` (G, 3) = Σ₂⁻¹ as (xx, xy, yy), ``radius`` (G, 2) the extent in pixels
    along x and y (``screen_extent``), ``depth`` (G,) camera z in metres, ``opacity`` (G,), ``color`` (G, 3).
    Gaussians behind ``near``, with opacity below 1/255, with bad values, or whose extent holds no pixel centre of
    the image are gone. CPU tensors go through the numba kernel (``project_cpu``) unless ``fast`` is False; the
    torch code (``project_factors_torch``) is the reference and runs on every other device."""
    if fast and means.device.type == "cpu":
        from . import project_cpu

        return project_cpu.project_factors(means, factors, opacities, sh, K, world_to_camera, width, height,
                                           near=near, valid=valid)
    return project_factors_torch(means, factors, opacities, sh, K, world_to_camera, width, height, near=near,
                                 valid=valid)


def project_factors_torch(means: torch.Tensor, factors: torch.Tensor, opacities: torch.Tensor, sh: torch.Tensor,
                          K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int, near: float = 0.05,
                          valid: torch.Tensor | None = None) -> dict:
    """The reference projection in torch (any device): ``project_factors``' arguments and outputs."""
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
    x_neg, x_pos, y_neg, y_pos = jacobian_limits(K, width, height)
    tx = torch.clamp(cam[:, 0] / tz, -x_neg, x_pos) * tz
    ty = torch.clamp(cam[:, 1] / tz, -y_neg, y_pos) * tz
    J = torch.zeros((len(index), 2, 3), dtype=dt, device=dev)
    J[:, 0, 0], J[:, 0, 2] = fx / tz, -fx * tx / tz ** 2
    J[:, 1, 1], J[:, 1, 2] = fy / tz, -fy * ty / tz ** 2
    cov2 = J @ cov @ J.transpose(1, 2)
    a, b, c = cov2[:, 0, 0] + BLUR, cov2[:, 0, 1], cov2[:, 1, 1] + BLUR
    det = a * c - b * b
    conic = torch.stack([c / det, -b / det, a / det], 1)
    extend = screen_extent(opacities[index])
    radius = torch.stack([torch.ceil(extend * torch.sqrt(a)), torch.ceil(extend * torch.sqrt(c))], 1)
    mean2 = torch.stack([fx * cam[:, 0] / tz + Kt[0, 1] * cam[:, 1] / tz + cx, fy * cam[:, 1] / tz + cy], 1)
    # on screen: some pixel centre of the image inside the extent (gsplat's test m + r > 0, m - r < W, per axis,
    # on pixel centres); NaN fails every comparison
    x0, x1 = centre_range(mean2[:, 0], radius[:, 0])
    y0, y1 = centre_range(mean2[:, 1], radius[:, 1])
    on = ((x0 <= x1) & (x0 <= width - 1) & (x1 >= 0) & (y0 <= y1) & (y0 <= height - 1) & (y1 >= 0)
          & (det > 0) & torch.isfinite(radius).all(1) & torch.isfinite(conic).all(1))
    on = torch.nonzero(on).squeeze(1)  # one host sync here (the boolean masks below would each sync again)
    index = index[on]
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    dirs = means[index] - centre
    dirs = dirs / torch.linalg.norm(dirs, dim=1, keepdim=True).clamp_min(1e-12)
    return {"index": index, "mean2d": mean2[on], "conic": conic[on], "radius": radius[on], "depth": tz[on],
            "opacity": opacities[index], "color": sh_colors(sh[index], dirs)}


def pixel_boxes(proj: dict, width: int, height: int) -> torch.Tensor:
    """(G, 4) int64 x0, x1, y0, y1: the inclusive range of the pixels whose centres lie inside each Gaussian's
    extent (``radius`` along x and y), clipped to the image. Pixel (x, y) gets a pair with Gaussian g exactly when
    x0 <= x <= x1 and y0 <= y <= y1; the projection keeps only Gaussians whose box is not empty."""
    m2, r = proj["mean2d"], proj["radius"]
    x0, x1 = centre_range(m2[:, 0], r[:, 0])
    y0, y1 = centre_range(m2[:, 1], r[:, 1])
    return torch.stack([torch.clamp(x0, 0, width - 1), torch.clamp(x1, 0, width - 1),
                        torch.clamp(y0, 0, height - 1), torch.clamp(y1, 0, height - 1)], 1).to(torch.int64)


def depth_order(proj: dict) -> torch.Tensor:
    """(G,) int64: the projected Gaussians' rows front to back, ties by original index (then by row)."""
    order = torch.sort(proj["index"], stable=True).indices
    return order[torch.sort(proj["depth"][order], stable=True).indices]


def depth_rank(proj: dict) -> torch.Tensor:
    """(G,) int64: each projected Gaussian's position in front-to-back order (``depth_order``'s inverse)."""
    order = depth_order(proj)
    rank = torch.empty(len(order), dtype=torch.int64, device=order.device)
    rank[order] = torch.arange(len(order), device=rank.device)
    return rank


def asset_ids(proj: dict) -> torch.Tensor:
    """(G,) int64: each projected Gaussian's asset id (``proj["asset_id"]``, 1-based; every Gaussian is asset 1
    when the projection carries none)."""
    if "asset_id" in proj:
        return proj["asset_id"].to(torch.int64)
    return torch.ones(len(proj["depth"]), dtype=torch.int64, device=proj["depth"].device)


def rasterize(proj: dict, width: int, height: int, background_depth: torch.Tensor | None = None,
              max_pairs: int = 200_000_000) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Front-to-back compositing of projected Gaussians (see the module rules).

    ``background_depth`` (H, W): the nearest point per pixel (+inf where none); Gaussians at or behind it are
    hidden. Returns (color (H, W, 3) premultiplied, asset_mask (H, W) = M_a = 1 - transmittance, depth (H, W):
    where the accumulated opacity first reaches 0.5, +inf elsewhere, instance (H, W) int32).

    Instance (``asset_ids``: ``proj["asset_id"]``, 1-based, else every Gaussian is asset 1): per pixel
    w_a = Σ α·transmittance over the composited Gaussians of asset a (the weights of colour and M_a, the same
    stop rules) and T_rest = the transmittance left (what the point behind, or nothing, receives); instance =
    argmax_a w_a, ties to the lower id, where max_a w_a > T_rest, else 0. Here T_rest = 1 - Σ_a w_a in float64.
    """
    dev = proj["mean2d"].device
    dt = proj["mean2d"].dtype
    color = torch.zeros((height * width, 3), dtype=dt, device=dev)
    asset_mask = torch.zeros(height * width, dtype=dt, device=dev)
    zmed = torch.full((height * width,), float("inf"), dtype=dt, device=dev)
    instance = torch.zeros(height * width, dtype=torch.int32, device=dev)
    G = len(proj["depth"])
    if G == 0:
        return (color.reshape(height, width, 3), asset_mask.reshape(height, width), zmed.reshape(height, width),
                instance.reshape(height, width))
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
    # per (pixel, asset) weights in float64, then the argmax (torch.argmax returns the first maximum: the lower id)
    aid = asset_ids(proj)
    n_assets = int(aid.max())
    w_asset = torch.zeros((height * width, n_assets), dtype=torch.float64, device=dev)
    w_asset.view(-1).index_add_(0, pix * n_assets + aid[g] - 1, wgt.to(torch.float64))
    best = torch.argmax(w_asset, 1)
    best_w = w_asset.gather(1, best[:, None])[:, 0]
    t_rest = 1.0 - w_asset.sum(1)
    instance = torch.where(best_w > t_rest, best + 1, 0).to(torch.int32)
    return (color.reshape(height, width, 3), asset_mask.reshape(height, width), zmed.reshape(height, width),
            instance.reshape(height, width))
