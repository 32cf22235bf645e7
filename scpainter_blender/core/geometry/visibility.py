"""What a camera cannot see: conservative tests that a box of points, or an asset's Gaussians, reach no pixel.

The renderer (``backend.render.frames``) leaves out what these rule out, and the render's per-frame keys
(``core.frame_keys``) leave out of a frame's key the assets that frame cannot see, so the tests live here, numpy
only: Blender (which has no torch) computes the same keys as the backend, bit for bit, to know a frame is up to
date without starting it.

Conventions: K is ours (docs/design.md §3: pixel centres at + 0.5, skew allowed); ``world_to_camera`` 4x4 OpenCV
(x right, y down, z forward) relative to the same origin as the boxes (the renderer's scene origin, the first
output camera: ``relative_camera``); float64 throughout. Both tests only ever answer "unseen" when it is certain
(non-finite or overflowing values answer "maybe seen").

The Gaussian projection's screen extent constants (``BLUR``, ``EXTEND_MAX``) live here because the skip test
must use the renderer's own: ``backend.render.gaussians`` imports them.
"""

from __future__ import annotations

import numpy as np

#: The EWA low-pass added to every projected 2D covariance (px², gsplat's and INRIA's 0.3).
BLUR = 0.3
#: gsplat's cap on a Gaussian's screen extent in σ of its 2D covariance (just above sqrt(2 ln 255) = 3.329).
EXTEND_MAX = 3.33
#: The Gaussian pass's near plane (metres, camera z; the projection culls means at or before it).
GAUSSIAN_NEAR = 0.05
#: The points' near plane (``backend.render.points.render_points``' default, which the renderer uses).
POINTS_NEAR = 0.05

_BITS = (np.arange(8)[:, None] >> np.arange(3)) & 1                    # corner i takes hi on axis k when bit k is set
_EDGES = np.array([(i, i | 1 << k) for i in range(8) for k in range(3) if not i >> k & 1])  # (12, 2) corner pairs


def relative_camera(world_to_camera: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """world_to_camera (4x4, float64) for positions expressed relative to ``origin`` (world metres)."""
    w2c = np.array(world_to_camera, dtype=np.float64, copy=True)
    w2c[:3, 3] = w2c[:3, 3] + w2c[:3, :3] @ np.asarray(origin, np.float64)
    return w2c


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(..., 8, 3) float64 corners of boxes with low, high corners ``lo``, ``hi`` (..., 3)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return np.where(_BITS == 1, hi[..., None, :], lo[..., None, :])


def clip_near(corners: np.ndarray, near: float) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of each convex hull of 8 camera-space corners (B, 8, 3) (a box or its affine image: corner i's
    neighbours differ in one bit) cut by z >= near: (B, 20, 3) candidates and (B, 20) which are vertices — the
    corners in front and the points where the 12 edges cross the plane. A linear-fractional function of x/z, y/z
    takes its extremes over the cut solid at these vertices."""
    z = corners[..., 2]
    a, b = corners[:, _EDGES[:, 0]], corners[:, _EDGES[:, 1]]
    za, zb = a[..., 2], b[..., 2]
    cross = (za < near) != (zb < near)
    t = np.where(cross, (near - za) / np.where(cross, zb - za, 1.0), 0.0)
    return np.concatenate([corners, a + t[..., None] * (b - a)], 1), np.concatenate([z >= near, cross], 1)


def off_image(V: np.ndarray, ok: np.ndarray, K: np.ndarray, reach: float | np.ndarray, width: int,
              height: int) -> np.ndarray:
    """(B,) bool: for each solid (vertices V (B, n, 3) where ``ok``, z > 0), every pixel u ± reach, v ± reach of
    its points misses [0, width) x [0, height) on one side, with a margin for rounding. u, v with our K (skew
    included); a solid with no vertex (wholly behind the near plane) is off the image too."""
    K = np.asarray(K, np.float64)
    z = np.where(ok, V[..., 2], 1.0)
    u = (K[0, 0] * V[..., 0] + K[0, 1] * V[..., 1]) / z + K[0, 2]
    v = K[1, 1] * V[..., 1] / z + K[1, 2]
    out = ~ok.any(1)
    for w, limit in ((u, width), (v, height)):
        lo, hi = np.where(ok, w, np.inf).min(1), np.where(ok, w, -np.inf).max(1)
        margin = 0.5 + 1e-4 * np.maximum(np.abs(lo), np.abs(hi))  # float32 rounding of large coordinates
        out |= (lo - reach >= limit + margin) | (hi + reach <= -margin)
    return out


def points_unseen(boxes: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int,
                  radius_px: int = 0, near: float = POINTS_NEAR) -> np.ndarray:
    """(B,) bool, for boxes (B, 2, 3) (low, high corner, scene-origin-relative metres): True when no point inside
    the box can land in the image of the camera (K; ``world_to_camera`` 4x4 relative to the same origin): every
    point of the box is at or behind ``near`` or projects (± ``radius_px`` splat) outside the image.
    ``render_points`` culls exactly these (in float32), so leaving them out changes nothing; the test keeps a
    margin for that rounding. One vectorised pass for all boxes (a frame tests every source frame)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 2, 3)
    w2c = np.asarray(world_to_camera, np.float64)
    with np.errstate(all="ignore"):  # huge poses overflow to inf: such a box is never left out (below)
        corners = box_corners(boxes[:, 0], boxes[:, 1]) @ w2c[:3, :3].T + w2c[:3, 3]
        scale = 1.0 + np.abs(corners).max()
        V, ok = clip_near(corners, near - 1e-5 * scale)
        unseen = off_image(V, ok, K, float(radius_px), width, height)
    return unseen & np.isfinite(corners).all((1, 2))  # when unsure, project: the z-buffer culls what is not there


def asset_bounds(means: np.ndarray, quats: np.ndarray, scales: np.ndarray) -> tuple[np.ndarray | None, float]:
    """(bounds, max_sigma) of an asset's Gaussians as the renderer draws them (file coordinates): bounds (2, 3)
    float64, the low and high corner of the means of the rows it draws (non-zero, finite quaternion, finite
    scales, finite mean), and the largest σ (|scale|, file units, + 1e-6 relative for the rotation's rounding:
    the factor R S has singular values |scales|). (None, inf) when no row is drawable. ``means``, ``quats``,
    ``scales``: (N, 3), (N, 4), (N, 3) as ``core.splats.gaussians.decode`` gives them."""
    m = np.asarray(means, np.float64)
    q = np.asarray(quats, np.float64)
    sc = np.abs(np.asarray(scales, np.float64))
    with np.errstate(all="ignore"):
        finite = (np.isfinite(q).all(1) & (np.linalg.norm(q, axis=1) > 1e-12) & np.isfinite(sc).all(1)
                  & np.isfinite(m).all(1))
    if not finite.any():  # rows with non-finite values are culled by the projection; they bound nothing
        return None, float("inf")
    m, sc = m[finite], sc[finite]
    return np.stack([m.min(0), m.max(0)]), float(sc.max()) * (1.0 + 1e-6)


def asset_unseen(bounds: np.ndarray | None, max_sigma: float, object_to_world: np.ndarray, origin: np.ndarray,
                 K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int,
                 near: float = GAUSSIAN_NEAR) -> bool:
    """True when none of an asset's Gaussians can reach a pixel of the camera (``world_to_camera`` relative to
    ``origin``), so the projection would cull every one of them. ``bounds``, ``max_sigma``: ``asset_bounds`` of its
    Gaussians (bounds None: nothing drawable, always unseen); ``object_to_world`` 4x4 (file → world metres) at
    that frame.

    Why not the 3D box ± 3.33 σ against the frustum: the renderer's footprint is the linearised (EWA) one,
    J Σ Jᵀ + 0.3 px² at the mean, which reaches further towards the image centre than the true projection of
    the ellipsoid for a Gaussian elongated in depth, and the 0.3 px² blur reaches beyond it. So the test bounds
    what the projection computes. With A = object_to_world, the means lie in the hull of the 8 corners of
    A·``bounds``, cut at z ≥ near (V, in camera axes); every σ is at most s = ‖A‖₂·``max_sigma``. For a mean at
    (x, y, z) the projection keeps it only if its screen box (mean ± r) meets the image, where

        r ≤ ⌈E·√(λ_max(J Σ Jᵀ) + 0.3)⌉ ≤ E·√(s²·‖J‖_F² + 0.3) + 1,
        ‖J‖_F² = (fx² (1 + t_x²) + fy² (1 + t_y²)) / z²  (+ a skew term),

    E = ``EXTEND_MAX`` and t the clamped x/z, y/z, |t| ≤ max over V of |x/z| (clamping towards 0) — or the
    clamp's own limit when the principal point lies outside the image. z ≥ min over V of z. The mean's pixel
    lies within the range of u, v over V (linear-fractional: extremes at vertices). If that range ± the bound
    on r misses the image, every Gaussian is culled."""
    if bounds is None:
        return True  # nothing finite to draw
    with np.errstate(all="ignore"):  # huge transforms overflow to inf: then the pass runs (never skipped unsure)
        return _asset_unseen(bounds, max_sigma, object_to_world, origin, K, world_to_camera, width, height, near)


def _asset_unseen(bounds, max_sigma, object_to_world, origin, K, world_to_camera, width, height, near) -> bool:
    A = np.array(object_to_world, np.float64)
    A[:3, 3] -= np.asarray(origin, np.float64)
    w2c = np.asarray(world_to_camera, np.float64)
    corners = box_corners(bounds[0], bounds[1]) @ A[:3, :3].T + A[:3, 3]
    corners = (corners @ w2c[:3, :3].T + w2c[:3, 3])[None]
    if not np.isfinite(corners).all():
        return False
    V, ok = clip_near(corners, near - 1e-9 * (1.0 + np.abs(corners).max()))
    if not ok.any():
        return True  # every mean is at or behind the near plane
    V = V[0][ok[0]]
    K = np.asarray(K, np.float64)
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    # numpy scalars, not Python floats: an overflow gives inf (and no skip), not an OverflowError
    z_min = V[:, 2].min()
    tx = np.abs(V[:, 0] / V[:, 2]).max()
    ty = np.abs(V[:, 1] / V[:, 2]).max()
    if not 0.0 <= cx <= width:  # a clamp interval that may not contain 0: bound |t| by its limits too
        tx = max(tx, 1.3 * (abs(cx) + width) / fx)
    if not 0.0 <= cy <= height:
        ty = max(ty, 1.3 * (abs(cy) + height) / fy)
    s = np.linalg.norm(A[:3, :3], 2) * np.float64(max_sigma)
    J2 = ((fx + abs(skew)) ** 2 * (1.0 + (tx + ty) ** 2) + fy ** 2 * (1.0 + ty ** 2)) / z_min ** 2
    reach = EXTEND_MAX * np.sqrt(s * s * J2 + BLUR) + 1.0
    if not np.isfinite(reach):
        return False
    return bool(off_image(V[None], np.ones((1, len(V)), bool), K, reach, width, height)[0])
