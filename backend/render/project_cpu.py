"""CPU fast path of ``gaussians.project_factors``: one numba pass per Gaussian, the same rules as the torch reference.

The torch reference (``gaussians.project_factors_torch``) spends most of its time outside arithmetic: index
tensors, batched 3x3 products with their temporaries, a dozen masked copies. Here one parallel loop reads each
Gaussian once and writes its screen quantities (or nothing), then one compaction keeps the visible rows.

Rules (``gaussians``' module docstring; each line below is that docstring's line, written per Gaussian):

* culled: a non-finite mean, factor, opacity or SH coefficient, ``valid`` False, camera z <= ``near``, o < 1/255;
* T = J W M (2 x 3), Σ₂ = T Tᵀ + 0.3 I: the same Σ₂ = J W M Mᵀ Wᵀ Jᵀ + 0.3 I as the reference, summed in another
  order (float64 throughout, whatever the input dtype: differences are rounding, ~1e-16 relative);
* J at the mean with x/z, y/z clamped to ``gaussians.jacobian_limits``; mean2d = (fx x + skew y)/z + cx, fy y/z + cy;
* conic = Σ₂⁻¹, radius = ceil(``screen_extent``(o) · sqrt(Σ₂_xx)), likewise y; culled when det Σ₂ <= 0, a value is
  not finite, or no pixel centre of the image lies inside the extent (``gaussians.centre_range``).

Colours are evaluated for the kept rows by ``gaussians.sh_colors`` (the one SH formula, shared with numpy) at the
view directions the kernel writes (normalise(mean - camera centre), as the reference), in float64.
Outputs are tensors of the input's dtype, rows in ascending original index as the reference returns them.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from .gaussians import ALPHA_MIN, BLUR, EXTEND_MAX, jacobian_limits, sh_colors

# columns of the per-Gaussian scratch rows written by _project
_MX, _MY, _CA, _CB, _CC, _RX, _RY, _DEPTH, _DIR, _NCOL = 0, 1, 2, 3, 4, 5, 6, 7, 8, 11


@njit(parallel=True, cache=True, nogil=True)
def _project(means, factors, opacities, sh, valid, w2c, centre, k, lims, width, height, near, out, keep):
    """means (N, 3), factors (N, 3, 3), opacities (N,), sh (N, S) float64; valid (N,) bool; w2c (3, 4); centre (3,)
    the camera centre; k = (fx, skew, cx, fy, cy); lims = jacobian_limits. Writes out (N, _NCOL) and keep (N,)."""
    n = means.shape[0]
    x_neg, x_pos, y_neg, y_pos = lims[0], lims[1], lims[2], lims[3]
    fx, skew, cx, fy, cy = k[0], k[1], k[2], k[3], k[4]
    for i in prange(n):
        keep[i] = False
        ok = valid[i] and math.isfinite(opacities[i])
        for j in range(3):
            ok = ok and math.isfinite(means[i, j])
            for c in range(3):
                ok = ok and math.isfinite(factors[i, j, c])
        for j in range(sh.shape[1]):
            ok = ok and math.isfinite(sh[i, j])
        o = opacities[i]
        if not ok or not o >= ALPHA_MIN:
            continue
        mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
        x = w2c[0, 0] * mx + w2c[0, 1] * my + w2c[0, 2] * mz + w2c[0, 3]
        y = w2c[1, 0] * mx + w2c[1, 1] * my + w2c[1, 2] * mz + w2c[1, 3]
        z = w2c[2, 0] * mx + w2c[2, 1] * my + w2c[2, 2] * mz + w2c[2, 3]
        if not z > near:
            continue
        tx = min(max(x / z, -x_neg), x_pos) * z
        ty = min(max(y / z, -y_neg), y_pos) * z
        j00, j02 = fx / z, -fx * tx / (z * z)
        j11, j12 = fy / z, -fy * ty / (z * z)
        a, b, c = 0.0, 0.0, 0.0
        for col in range(3):
            # column col of W M, then of T = J W M
            w0 = w2c[0, 0] * factors[i, 0, col] + w2c[0, 1] * factors[i, 1, col] + w2c[0, 2] * factors[i, 2, col]
            w1 = w2c[1, 0] * factors[i, 0, col] + w2c[1, 1] * factors[i, 1, col] + w2c[1, 2] * factors[i, 2, col]
            w2 = w2c[2, 0] * factors[i, 0, col] + w2c[2, 1] * factors[i, 1, col] + w2c[2, 2] * factors[i, 2, col]
            t0 = j00 * w0 + j02 * w2
            t1 = j11 * w1 + j12 * w2
            a += t0 * t0
            b += t0 * t1
            c += t1 * t1
        a += BLUR
        c += BLUR
        det = a * c - b * b
        if not det > 0.0:
            continue
        extend = min(math.sqrt(2.0 * max(math.log(o / ALPHA_MIN), 0.0)), EXTEND_MAX)
        rx = np.ceil(extend * math.sqrt(a))  # np.ceil: a float, inf and NaN stay
        ry = np.ceil(extend * math.sqrt(c))
        u = fx * x / z + skew * y / z + cx
        v = fy * y / z + cy
        # some pixel centre of the image inside the extent (gaussians.centre_range; NaN fails every test)
        x0, x1 = np.ceil(u - rx - 0.5), np.floor(u + rx - 0.5)
        y0, y1 = np.ceil(v - ry - 0.5), np.floor(v + ry - 0.5)
        if not (x0 <= x1 and x0 <= width - 1 and x1 >= 0 and y0 <= y1 and y0 <= height - 1 and y1 >= 0):
            continue
        ca, cb, cc = c / det, -b / det, a / det
        if not (math.isfinite(rx) and math.isfinite(ry) and math.isfinite(ca) and math.isfinite(cb)
                and math.isfinite(cc)):
            continue
        out[i, _MX], out[i, _MY] = u, v
        out[i, _CA], out[i, _CB], out[i, _CC] = ca, cb, cc
        out[i, _RX], out[i, _RY] = rx, ry
        out[i, _DEPTH] = z
        # the view direction for the colour: normalise(mean - camera centre)
        d0, d1, d2 = mx - centre[0], my - centre[1], mz - centre[2]
        norm = max(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), 1e-12)
        out[i, _DIR], out[i, _DIR + 1], out[i, _DIR + 2] = d0 / norm, d1 / norm, d2 / norm
        keep[i] = True


def project_factors(means, factors, opacities, sh, K, world_to_camera, width, height, near=0.05, valid=None):
    """``gaussians.project_factors`` for CPU tensors (its arguments and outputs)."""
    dt = means.dtype
    f64 = lambda x: np.ascontiguousarray(x.detach().to(torch.float64).numpy())  # noqa: E731  (no copy if float64)
    n = means.shape[0]
    w2c = np.ascontiguousarray(np.asarray(world_to_camera, np.float64)[:3, :4])
    Kn = np.asarray(K, np.float64)
    k = np.array([Kn[0, 0], Kn[0, 1], Kn[0, 2], Kn[1, 1], Kn[1, 2]])
    lims = np.array(jacobian_limits(Kn, width, height), np.float64)
    ok = np.ones(n, bool) if valid is None else np.ascontiguousarray(valid.numpy(), dtype=bool)
    out = np.empty((n, _NCOL), np.float64)
    keep = np.empty(n, bool)
    opac64, sh64 = f64(opacities).reshape(n), f64(sh).reshape(n, sh.shape[1] * sh.shape[2])
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    _project(f64(means).reshape(n, 3), f64(factors).reshape(n, 3, 3), opac64, sh64, ok, w2c, centre, k, lims,
             int(width), int(height), float(near), out, keep)
    index, mean2d, conic, radius, depth, dirs, opac, sh_kept = _compact(out, keep, opac64, sh64)
    t = lambda a: torch.from_numpy(a).to(dt)  # noqa: E731  (no copy for float64)
    color = sh_colors(torch.from_numpy(sh_kept.reshape(len(index), sh.shape[1], 3)), torch.from_numpy(dirs))
    return {"index": torch.from_numpy(index), "mean2d": t(mean2d), "conic": t(conic), "radius": t(radius),
            "depth": t(depth), "opacity": t(opac), "color": color.to(dt)}


@njit(cache=True, nogil=True)
def _compact(out, keep, opacities, sh):
    """The kept rows, in ascending index, as separate contiguous arrays (one sequential pass)."""
    n = keep.shape[0]
    g = 0
    for i in range(n):
        g += keep[i]
    index = np.empty(g, np.int64)
    mean2d, conic, radius = np.empty((g, 2)), np.empty((g, 3)), np.empty((g, 2))
    depth, dirs, opac = np.empty(g), np.empty((g, 3)), np.empty(g)
    sh_kept = np.empty((g, sh.shape[1]))
    r = 0
    for i in range(n):
        if keep[i]:
            index[r] = i
            mean2d[r, 0], mean2d[r, 1] = out[i, _MX], out[i, _MY]
            conic[r, 0], conic[r, 1], conic[r, 2] = out[i, _CA], out[i, _CB], out[i, _CC]
            radius[r, 0], radius[r, 1] = out[i, _RX], out[i, _RY]
            depth[r] = out[i, _DEPTH]
            dirs[r, 0], dirs[r, 1], dirs[r, 2] = out[i, _DIR], out[i, _DIR + 1], out[i, _DIR + 2]
            opac[r] = opacities[i]
            sh_kept[r, :] = sh[i, :]
            r += 1
    return index, mean2d, conic, radius, depth, dirs, opac, sh_kept
