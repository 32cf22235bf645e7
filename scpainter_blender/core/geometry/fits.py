"""Small geometric fits and tests on point sets, in numpy (it runs in Blender's own Python).

Frames are whatever the caller's points are in (world metres for placement, VGGT's world for the camera-height
scale). Planes are (a, b, c, d) with a x + b y + c z + d = 0 and a unit normal.

The one RANSAC plane fit (``fit_plane_ransac``) serves both the ground under a placed asset and the road plane
that gives a VGGT reconstruction its metric scale from a known camera height (``fit_ground_plane``). Its
contract: seeded (the same points, threshold and seed give the same plane, bit for bit, on one machine), only
hypotheses within ``max_tilt_deg`` of ``up`` are scored, the winner has the most points closer than
``threshold`` (strictly, in the points' units: open3d's ``segment_plane`` rule) and is refined by least squares
on its inliers, rows with NaN/inf are left out, and coordinates far from the origin (1e5 m) stay exact because
everything is computed relative to the points' centroid. Numpy only (1.x and 2.x).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import cameras

if TYPE_CHECKING:
    from collections.abc import Sequence

#: Triples drawn (and their planes computed) at once; each is then scored on its own.
_BATCH = 32

#: Probability that the best plane was sampled at least once before RANSAC stops early (open3d's default).
RANSAC_CONFIDENCE = 0.99999999


class PlaneFitError(ValueError):
    """No plane: ``reason`` is ``"too_few"`` (fewer usable points than needed), ``"degenerate"`` (every triple
    drawn was collinear or coincident: the points span no plane), ``"tilt"`` (no plane within the allowed tilt of
    ``up`` among the points), ``"up"`` (the cameras share no up axis) or ``"weak"`` (the best plane holds too
    small a share of the points to be the ground). Callers that know the file turn it into an ``InputError``."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def _finite_rows(points) -> tuple:
    """(float64 (N, 3) array, mask of the rows with finite coordinates); ValueError for another shape."""
    P = np.asarray(points, dtype=np.float64)
    if P.size == 0:
        P = P.reshape(0, 3)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got shape {P.shape}")
    return P, np.all(np.isfinite(P), axis=1)


def _sample_triples(rng, n: int, count: int) -> tuple:
    """``count`` triples of distinct indices below ``n`` (n >= 3), uniformly: i, then j != i, then k != i, j."""
    i = rng.integers(0, n, count)
    j = rng.integers(0, n - 1, count)
    j += j >= i
    k = rng.integers(0, n - 2, count)
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    k += k >= lo
    k += k >= hi
    return i, j, k


def _least_squares_plane(Q: np.ndarray, up: np.ndarray) -> tuple:
    """(unit normal oriented with ``up``, centroid) of the total-least-squares plane through ``Q`` (M >= 3, 3)."""
    centre = Q.mean(axis=0)
    n = np.linalg.svd(Q - centre, full_matrices=False)[2][2]
    if n @ up < 0:
        n = -n
    return n, centre


def fit_plane_ransac(points: np.ndarray, threshold: float = 0.05, iterations: int = 256, seed: int = 0,
                     up: Sequence[float] = (0.0, 0.0, 1.0), max_tilt_deg: float = 30.0,
                     confidence: float = RANSAC_CONFIDENCE) -> tuple[np.ndarray, np.ndarray, float]:
    """The plane with most inliers among hypotheses within ``max_tilt_deg`` of ``up``, refined by least squares.

    ``points`` (N, 3), any units and frame; rows with NaN/inf are left out. ``threshold``: a point is an inlier
    when its distance to the plane is below it (strictly, same units). RANSAC draws triples of distinct points
    with ``numpy.random.default_rng(seed)``, skips collinear triples and planes tilted more than ``max_tilt_deg``
    from ``up``, counts inliers, and stops after ``iterations`` triples or once the best plane's inlier fraction
    w makes a better one unlikely (1 - w³)^k < 1 - ``confidence``. The winner is refitted by least squares on its
    inliers, and again on the refined plane's inliers while they change (at most 3 passes).

    Returns (plane (4,) with the normal oriented along ``up``, inlier mask (N,) over the rows given (False for
    non-finite rows), inlier RMS distance to the returned plane). Seeded: the same points give the same plane.
    Raises ``PlaneFitError`` (a ValueError; ``reason`` "too_few": fewer than 3 finite points, "degenerate": only
    collinear triples, "tilt": no hypothesis within the tilt); ValueError for a non-(N, 3) array, a non-positive
    threshold or a zero ``up``.
    """
    P, finite = _finite_rows(points)
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a positive distance, got {threshold}")
    up = np.asarray(up, np.float64)
    if up.shape != (3,) or not np.all(np.isfinite(up)) or np.linalg.norm(up) == 0:
        raise ValueError(f"up must be a non-zero 3-vector, got {up}")
    up = up / np.linalg.norm(up)
    X = P[finite]
    N = len(X)
    if N < 3:
        dropped = len(P) - N
        raise PlaneFitError("too_few", f"need at least 3 points to fit a plane, got {N}"
                                       + (f" ({dropped} rows with NaN/inf left out)" if dropped else ""))
    origin = X.mean(axis=0)  # relative coordinates: 1e5 m scenes stay exact
    X = X - origin
    x, y, z = (np.ascontiguousarray(X[:, c]) for c in range(3))
    dist, term, near = np.empty(N), np.empty(N), np.empty(N, bool)  # scoring buffers, reused per hypothesis
    cos_max = np.cos(np.radians(max_tilt_deg))
    rng = np.random.default_rng(seed)
    log_miss = np.log(max(1.0 - confidence, 1e-300))
    best_n, best_offset, best_count, spans_plane = None, 0.0, 0, False
    needed, drawn = int(iterations), 0
    while drawn < min(needed, iterations):
        count = min(_BATCH, iterations - drawn)
        i, j, k = _sample_triples(rng, N, count)
        drawn += count
        a = X[i]
        u, v = X[j] - a, X[k] - a
        n = np.cross(u, v)
        norm = np.linalg.norm(n, axis=1)
        # collinear (or coincident) triples: the sine of the angle at ``a`` is ~0, whatever the scene's units
        ok = norm > 1e-9 * np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1)
        n = n[ok] / norm[ok, None]
        a = a[ok]
        spans_plane |= bool(ok.any())
        ok = np.abs(n[:, 0] * up[0] + n[:, 1] * up[1] + n[:, 2] * up[2]) >= cos_max
        n, a = n[ok], a[ok]
        offset = n[:, 0] * a[:, 0] + n[:, 1] * a[:, 1] + n[:, 2] * a[:, 2]
        for h in range(len(n)):  # elementwise (no BLAS): the counts, hence the plane, do not depend on threads
            np.multiply(x, n[h, 0], out=dist)
            np.subtract(dist, offset[h], out=dist)
            np.multiply(y, n[h, 1], out=term)
            np.add(dist, term, out=dist)
            np.multiply(z, n[h, 2], out=term)
            np.add(dist, term, out=dist)
            np.abs(dist, out=dist)
            np.less(dist, threshold, out=near)
            c = int(np.count_nonzero(near))
            if c > best_count:  # ties: the first drawn
                best_n, best_offset, best_count = n[h], float(offset[h]), c
                w = c / N
                miss = np.log1p(-w ** 3) if w < 1.0 else -np.inf
                needed = int(np.ceil(log_miss / miss)) if miss < 0 else iterations
    if not spans_plane:
        raise PlaneFitError("degenerate", f"the {N} points are collinear or coincident (in {drawn} triples "
                                          "drawn): they span no plane")
    if best_n is None:
        raise PlaneFitError("tilt", f"no plane within the allowed tilt ({max_tilt_deg:g}°) of up "
                                    f"{np.round(up, 3).tolist()} found among the {N} points")
    inl = np.abs(X @ best_n - best_offset) < threshold
    for _ in range(3):
        n, centre = _least_squares_plane(X[inl], up)
        new = np.abs((X - centre) @ n) < threshold
        if np.count_nonzero(new) < 3 or np.array_equal(new, inl):
            break
        inl = new
    # the least-squares plane's RMS over the set it was fitted to is below the threshold, so ``inl`` is never empty
    dist = (X - centre) @ n
    inl = np.abs(dist) < threshold
    rms = float(np.sqrt(np.mean(dist[inl] ** 2)))
    d = -float(n @ (centre + origin))
    mask = np.zeros(len(P), bool)
    mask[np.flatnonzero(finite)[inl]] = True
    return np.array([*n, d]), mask, rms


def plane_tilt_deg(plane: np.ndarray, up: Sequence[float] = (0.0, 0.0, 1.0)) -> float:
    """Angle in degrees between the plane's normal and the ``up`` axis (0 = level; sign of the normal ignored)."""
    n = np.asarray(plane, np.float64)[:3]
    up = np.asarray(up, np.float64)
    c = abs(float(n @ up)) / (np.linalg.norm(n) * np.linalg.norm(up))
    return float(np.degrees(np.arccos(min(1.0, c))))


@dataclass
class GroundPlane:
    """A road plane under a set of cameras, in the cameras' world and units.

    ``plane`` (4,): unit normal pointing towards the cameras (the median camera is on the positive side);
    ``inliers`` (N,) bool over the candidate points given; ``inlier_rms`` and ``threshold`` in the world's units;
    ``tilt_deg`` from the cameras' mean up axis; ``candidates`` the finite points fitted; ``nonfinite`` the rows
    with NaN/inf left out.
    """

    plane: np.ndarray
    inliers: np.ndarray
    inlier_rms: float
    tilt_deg: float
    threshold: float
    candidates: int
    nonfinite: int

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


#: Fewer candidate points than this cannot tell the road from clutter.
MIN_GROUND_POINTS = 100

#: A "road" holding a smaller share of the candidate points is a chance alignment of clutter, not the ground
#: (the street fixture's road holds 97 %).
MIN_GROUND_INLIER_FRACTION = 0.05


def cameras_up(world_to_camera: np.ndarray) -> np.ndarray:
    """The cameras' mean "up" (the mean of their OpenCV -y axes) in world coordinates, unit (3,).

    ``world_to_camera`` (S, 4, 4) or (S, 3, 4), finite. Raises ``PlaneFitError("up")`` when the axes cancel out.
    """
    T = cameras.as_matrix4(world_to_camera, "world_to_camera").reshape(-1, 4, 4)
    up = -T[:, 1, :3].mean(axis=0)
    norm = np.linalg.norm(up)
    if not norm >= 1e-9:
        raise PlaneFitError("up", "the cameras' up axes cancel out (they point every way): no common up direction")
    return up / norm


def fit_ground_plane(points: np.ndarray, world_to_camera: np.ndarray, *, max_tilt_deg: float = 30.0,
                     threshold_fraction: float = 0.01, iterations: int = 2000, seed: int = 0,
                     min_points: int = MIN_GROUND_POINTS,
                     min_inlier_fraction: float = MIN_GROUND_INLIER_FRACTION) -> GroundPlane:
    """The road under forward-looking cameras: the largest plane among ``points`` within ``max_tilt_deg`` of up.

    ``points`` (N, 3): ground candidates in the cameras' world and units (for VGGT, ``point_cloud.ground_candidates``:
    confident pixels from the lower image rows); ``world_to_camera`` (S, 4, 4) or (S, 3, 4), OpenCV cameras
    (y down), finite. Up = the cameras' mean -y axis. The inlier threshold is ``threshold_fraction`` of the
    median distance from the points to the cameras' mean centre (1 % of the scene's depth, so it means the same
    in any units). Only level hypotheses are scored (``fit_plane_ransac``), so a wall or a parked truck larger
    than the visible road is never chosen: the largest level plane wins directly.

    Raises ``PlaneFitError`` with ``reason``: ``"too_few"`` (fewer than ``min_points`` finite points, or all at
    the cameras' centre), ``"degenerate"`` (collinear points), ``"up"`` (no common up axis), ``"tilt"`` (no plane
    within the tilt), ``"weak"`` (the best plane holds less than ``min_inlier_fraction`` of the points).
    ValueError for a non-(N, 3) ``points`` or non-finite poses.
    """
    P, finite = _finite_rows(points)
    T = cameras.as_matrix4(world_to_camera, "world_to_camera").reshape(-1, 4, 4)
    if len(T) == 0 or not np.all(np.isfinite(T)):
        raise ValueError("world_to_camera must hold at least one finite pose")
    up = cameras_up(T)
    centres = cameras.camera_centers(T)
    X = P[finite]
    dropped = len(P) - len(X)
    if len(X) < min_points:
        raise PlaneFitError("too_few", f"only {len(X)} ground candidate points"
                                       + (f" ({dropped} with NaN/inf left out)" if dropped else "")
                                       + f", fewer than {min_points}: too few to find the ground")
    depth_scale = float(np.median(np.linalg.norm(X - centres.mean(axis=0), axis=1)))
    if not depth_scale > 0:
        raise PlaneFitError("too_few", "every ground candidate point lies at the cameras' centre")
    threshold = threshold_fraction * depth_scale
    plane, inliers, rms = fit_plane_ransac(X, threshold, iterations=iterations, seed=seed, up=up,
                                           max_tilt_deg=max_tilt_deg)
    share = np.count_nonzero(inliers) / len(X)
    if share < min_inlier_fraction:
        raise PlaneFitError("weak", f"the best plane within {max_tilt_deg:g}° of the cameras' up axis holds only "
                                    f"{share:.1%} of the {len(X)} ground candidate points (at least "
                                    f"{min_inlier_fraction:.0%} needed): no road surface among them")
    if np.median(centres @ plane[:3] + plane[3]) < 0:
        plane = -plane
    mask = np.zeros(len(P), bool)
    mask[np.flatnonzero(finite)[inliers]] = True
    return GroundPlane(plane, mask, rms, plane_tilt_deg(plane, up), threshold, len(X), int(dropped))


def plane_height(plane: np.ndarray, x: float, y: float) -> float:
    """z of the plane above (x, y); the plane must not be vertical."""
    a, b, c, d = plane
    if abs(c) < 1e-9:
        raise ValueError("the plane is vertical: it has no height")
    return -(a * x + b * y + d) / c


def points_in_box(points: np.ndarray, box_to_world: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Mask of points inside an oriented box (rigid box_to_world, full ``size`` along its local axes)."""
    T = np.asarray(box_to_world, np.float64)
    local = (np.asarray(points, np.float64) - T[:3, 3]) @ T[:3, :3]
    return np.all(np.abs(local) <= np.asarray(size, np.float64) / 2, axis=1)


def proportion_deviation(asset_size: np.ndarray, target_size: np.ndarray) -> np.ndarray:
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
