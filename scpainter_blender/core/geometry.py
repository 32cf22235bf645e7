"""Small geometric fits and tests on point sets, in numpy (Blender's Python has no open3d).

Frames are whatever the caller's points are in (world metres for placement). Planes are (a, b, c, d) with
a x + b y + c z + d = 0 and a unit normal; "up" is +Z.
"""

from __future__ import annotations

import numpy as np


def fit_plane_ransac(points, threshold: float = 0.05, iterations: int = 256, seed: int = 0,
                     up=(0.0, 0.0, 1.0), max_tilt_deg: float = 30.0):
    """The plane with most inliers among candidates within ``max_tilt_deg`` of ``up``, refined by least squares.

    Returns (plane (4,), inlier mask (N,), inlier RMS distance). Seeded: the same points give the same plane.
    Raises ValueError when there are fewer than 3 points or no acceptable plane.
    """
    P = np.asarray(points, np.float64)
    if len(P) < 3:
        raise ValueError(f"need at least 3 points to fit a plane, got {len(P)}")
    origin = P.mean(axis=0)  # relative coordinates: 1e5 m scenes stay exact
    X = P - origin
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    cos_max = np.cos(np.radians(max_tilt_deg))
    rng = np.random.default_rng(seed)
    best, best_count = None, -1
    for _ in range(iterations):
        a, b, c = X[rng.choice(len(X), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        if abs(n @ up) < cos_max:
            continue
        inl = np.abs((X - a) @ n) < threshold
        count = int(inl.sum())
        if count > best_count:
            best, best_count = inl, count
    if best is None or best_count < 3:
        raise ValueError("no plane within the allowed tilt found among the points")
    Q = X[best]
    centre = Q.mean(axis=0)
    n = np.linalg.svd(Q - centre, full_matrices=False)[2][2]
    if n @ up < 0:
        n = -n
    d = -float(n @ (centre + origin))
    rms = float(np.sqrt(np.mean(((Q - centre) @ n) ** 2)))
    inliers = np.abs(P @ n + d) < threshold
    return np.array([*n, d]), inliers, rms


def plane_height(plane, x: float, y: float) -> float:
    """z of the plane above (x, y); the plane must not be vertical."""
    a, b, c, d = plane
    if abs(c) < 1e-9:
        raise ValueError("the plane is vertical: it has no height")
    return -(a * x + b * y + d) / c


def points_in_box(points, box_to_world, size) -> np.ndarray:
    """Mask of points inside an oriented box (rigid box_to_world, full ``size`` along its local axes)."""
    T = np.asarray(box_to_world, np.float64)
    local = (np.asarray(points, np.float64) - T[:3, 3]) @ T[:3, :3]
    return np.all(np.abs(local) <= np.asarray(size, np.float64) / 2, axis=1)


def proportion_deviation(asset_size, target_size) -> np.ndarray:
    """Relative deviation of (length, width, height) once the asset is scaled uniformly to the target's length.

    Sizes are (length, width, height); the paper's stage-1 filter rejects assets whose box proportions deviate
    from the box they should fill by more than a tolerance. Returns (3,): 0 for the length by construction.
    """
    a = np.asarray(asset_size, np.float64)
    t = np.asarray(target_size, np.float64)
    if np.any(a <= 0) or np.any(t <= 0):
        raise ValueError(f"sizes must be positive, got {a.tolist()} and {t.tolist()}")
    scaled = a * (t[0] / a[0])
    return (scaled - t) / t
