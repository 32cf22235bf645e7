"""Casting a LiDAR sweep into surface samples: the rule, its settings, and the float64 numpy reference that the numba
fast path (``cast_cpu``) must match (docs/design.md §10a).

A reconstruction's points (and a splat car's Gaussian means) are samples of surfaces, not geometry: a ray almost
never passes through one. So, per ray (unit direction d0, with e1 the azimuth tangent and e2 the elevation tangent,
``core.lidar_model``'s conventions):

1. **Candidates**: the points inside the ray's angular footprint, a cone of half-angle α = ``footprint_deg``
   around d0. A point p (sensor frame) has depth q = p · d0 > 0 along the ray and gnomonic offsets
   u = (p · e1) / q, v = (p · e2) / q; it is a candidate when u² + v² ≤ tan² α. Points nearer than the model's
   ``min_range_m`` are invisible (the sensor's blind radius: rays go through them); points beyond
   ``max_range_m`` plus one gap cannot make a return. A ray with more than ``max_candidates`` keeps every k-th of
   them in point order (``thin``).
2. **Surfaces**: the candidates sorted by q split into clusters where the next one is further than
   gap = max(``gap_m``, ``gap_rel`` · q) behind the last (a car's flank in front of the road behind it) while the
   cluster's plane is not known, and where it is off that plane (step 4's fit) by more than
   tol = max(``tol_m``, ``tol_rel`` · q) in depth once it is known: the cluster has 3 points or more spread over
   the footprint (the smaller standard deviation of its offsets at least ``spread`` × tan α). A sparse patch of far
   road has gaps wider than any fixed one between points of one plane. The plane is fitted again each time the cluster has grown
   by half since its last fit (at 3 points, then 5, 8, 12, ...: a fit per point would cost most of a sweep). The
   second rule separates surfaces that meet at a corner (a car's far side behind its near side); a grazing patch
   of road, long in q (about 2 r² α / h) and sparse, stays on its plane and stays one surface.
3. **The surface hit**: the nearest cluster that covers the ray, i.e. whose mean offset (ū, v̄) is at most
   tan α · (``coverage`` + 0.25 / √n) from it (n its points). A surface that covers half the footprint, its edge
   through the ray, has a mean offset 4/(3π) ≈ 0.42 of the radius, so ``coverage`` 0.42 puts the silhouette of an
   object where its edge is, instead of a footprint further out; the 0.25 / √n term keeps a sparse but centred
   surface from being taken for an edge (the mean offset of n points spread evenly over the footprint scatters by
   about 0.25 / √n of its radius in each direction). When no cluster covers the ray, it has no return.
4. **The range**: for a plane n · x = h, a ray in direction d0 + u e1 + v e2 meets it at depth q with
   1 / q = (n · d0 + u n · e1 + v n · e2) / h, exactly linear in (u, v). So 1 / q = a + b u + c v is fitted to the
   cluster by least squares (a small ridge ``ridge`` · n · tan² α on b and c, so one point or a line of points
   gives their mean and a line's slope), and the ray's range is 1 / a: exact on a plane whatever the sampling, but
   for the ridge's bias (micrometres at 10 m).
   A fit that lands outside the cluster's depth span by more than a gap (a plane known as in step 2), or by more
   than tol (a plane not known: too few points, or on a line), falls back to the harmonic mean of its depths. A
   surface seen on one side of the ray only (at its edge, or sparse) reaches the ray by extrapolation: its span
   may not hold the hit. A range outside [min_range_m, max_range_m] is no return.
5. **Intensity**: 255 × the mean luminance (Rec. 709 weights of the stored sRGB colour, 0..1) of the cluster's
   points — a reconstruction has no reflectance, so the return's brightness stands for it (0 without colours).

Settings: ``LidarSettings``; the reference here: ``cast_reference`` (a brute-force loop over the rays, every point
tested against every ray: slow, for tests and small scenes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scpainter_blender.core.lidar_model import LidarModel

#: Rec. 709 luminance weights of an (R, G, B) colour.
LUMA = (0.2126, 0.7152, 0.0722)


@dataclass(frozen=True)
class LidarSettings:
    """How a sweep is cast (see the module docstring): ``footprint_deg`` α, the cone's half-angle; ``gap_m`` and
    ``gap_rel`` the depth gap that separates two surfaces; ``tol_m``, ``tol_rel`` the depth off a
    cluster's plane that does, once its offsets' smaller standard deviation reaches ``spread`` × tan α;
    ``coverage`` the mean
    offset (a fraction of the footprint) beyond which a surface only grazes the ray; ``ridge`` the fit's ridge;
    ``opacity_min`` the opacity from which a Gaussian's mean counts as a surface sample; ``max_candidates`` the
    candidates a ray keeps at most (``thin``). The default footprint,
    0.3°, is about the nuScenes sensor's azimuth step (1/3°): each point serves about one column; a narrower one
    needs denser points for the same returns (``bench/lidar.py``'s table)."""
    footprint_deg: float = 0.3
    gap_m: float = 0.5
    gap_rel: float = 0.05
    tol_m: float = 0.05
    tol_rel: float = 0.005
    spread: float = 0.15
    coverage: float = 0.42
    ridge: float = 1e-4
    opacity_min: float = 0.5
    max_candidates: int = 64

    def params(self, model: LidarModel) -> np.ndarray:
        """(12,) float64 in the numba kernels' order: tan α, tan² α, gap_m, gap_rel, coverage, ridge, min range,
        max range, tol_m, tol_rel, spread, max_candidates."""
        t = np.tan(np.deg2rad(self.footprint_deg))
        return np.array([t, t * t, self.gap_m, self.gap_rel, self.coverage, self.ridge, model.min_range_m,
                         model.max_range_m, self.tol_m, self.tol_rel, self.spread, self.max_candidates], np.float64)


def ray_bases(model: LidarModel) -> tuple:
    """(d0, e1, e2), each (A, B, 3) float64: each ray's unit direction, its azimuth tangent (towards growing φ) and
    its elevation tangent (upwards), sensor frame, [column, row]."""
    e = np.deg2rad(np.asarray(model.elevations_deg, np.float64))[None, :]
    phi = np.deg2rad(np.arange(model.columns) * (360.0 / model.columns))[:, None]
    sp, cp, se, ce = np.sin(phi), np.cos(phi), np.sin(e), np.cos(e)
    zero = np.zeros_like(sp * ce)
    d0 = np.stack([sp * ce, cp * ce, np.broadcast_to(se, zero.shape)], -1)
    e1 = np.stack([np.broadcast_to(cp, zero.shape), np.broadcast_to(-sp, zero.shape), zero], -1)
    e2 = np.stack([-sp * se, -cp * se, np.broadcast_to(ce, zero.shape)], -1)
    return d0, e1, e2


def luminance(rgb: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) float64 luminance in 0..1 of colours (n, 3) in 0..1 (zeros when ``rgb`` is None)."""
    if rgb is None:
        return np.zeros(n)
    return np.asarray(rgb, np.float64) @ np.array(LUMA)


def resolve_ray(q: np.ndarray, u: np.ndarray, v: np.ndarray, lum: np.ndarray, p: np.ndarray) -> tuple:
    """Steps 2-5 for one ray's candidates (depths ``q``, offsets ``u``, ``v``, luminances ``lum``, any order;
    ``p`` = ``LidarSettings.params``): (range m or NaN, intensity 0..255, the position of the cluster's nearest
    candidate in the given arrays, or -1)."""
    tan_a, tan2, gap_m, gap_rel, coverage, ridge, rmin, rmax, tol_m, tol_rel, spread = p[:11]
    order = np.argsort(q, kind="stable")
    q, u, v, lum = q[order], u[order], v[order], lum[order]
    n_all = len(q)
    start = 0
    while start < n_all:
        stop = start + 1
        fitted, plane = 0, None
        while stop < n_all:
            if plane is None and q[stop] - q[stop - 1] > max(gap_m, gap_rel * q[stop - 1]):
                break
            k = stop - start
            if k >= 3 and 2 * k >= 3 * fitted and min_spread(u[start:stop], v[start:stop]) >= spread * tan_a:
                plane, fitted = fit(u[start:stop], v[start:stop], q[start:stop], ridge * k * tan2), k
            # |q - 1/(a + b u + c v)| > tol, to first order
            if plane is not None and not abs(q[stop] * (plane @ (1.0, u[stop], v[stop])) - 1.0) <= max(
                    tol_m, tol_rel * q[stop]) / q[stop]:
                break
            stop += 1
        cu, cv, cq = u[start:stop], v[start:stop], q[start:stop]
        n = stop - start
        if np.hypot(cu.mean(), cv.mean()) <= tan_a * (coverage + 0.25 / np.sqrt(n)):
            w = 1.0 / cq
            a = fit(cu, cv, cq, ridge * n * tan2)[0]
            s = 1.0 / a if a > 0 else np.inf
            reach = (gap_m, gap_rel) if n >= 3 and min_spread(cu, cv) >= spread * tan_a else (tol_m, tol_rel)
            if not (cq[0] - max(reach[0], reach[1] * cq[0]) <= s <= cq[-1] + max(reach[0], reach[1] * cq[-1])):
                s = n / w.sum()
            if not rmin <= s <= rmax:
                return np.nan, 0.0, -1
            return s, 255.0 * lum[start:stop].mean(), int(order[start])
        start = stop
    return np.nan, 0.0, -1


def fit(u: np.ndarray, v: np.ndarray, q: np.ndarray, lam: float) -> np.ndarray:
    """(a, b, c): the least-squares 1 / q = a + b u + c v with the ridge ``lam`` on b and c."""
    X = np.stack([np.ones(len(u)), u, v], 1)
    return np.linalg.solve(X.T @ X + np.diag([0.0, lam, lam]), X.T @ (1.0 / q))


def min_spread(u: np.ndarray, v: np.ndarray) -> float:
    """The smaller standard deviation of the offsets (u, v): the square root of their covariance's smaller
    eigenvalue."""
    mu, mv = u.mean(), v.mean()
    cuu, cuv, cvv = (u * u).mean() - mu * mu, (u * v).mean() - mu * mv, (v * v).mean() - mv * mv
    return float(np.sqrt(max(0.0, (cuu + cvv) / 2 - np.hypot((cuu - cvv) / 2, cuv))))


def thin(n: int, cap: int) -> np.ndarray:
    """The positions kept of a ray's ``n`` candidates (in point order) when it has more than ``cap``: every k-th,
    k = ceil(n / cap). A ray grazing the far road holds thousands (its footprint's patch grows as r³: 20 m long at
    60 m); thinned evenly they describe the same plane, and sorting them no longer costs most of a sweep."""
    return np.arange(0, n, -(-n // cap) if n > cap else 1)


def candidates(xyz: np.ndarray, d0: np.ndarray, e1: np.ndarray, e2: np.ndarray, p: np.ndarray) -> tuple:
    """Step 1 for one ray against every point: (index, q, u, v) of the candidates of points ``xyz`` (N, 3) float64
    sensor frame."""
    tan_a, tan2, gap_m, gap_rel, _, _, rmin, rmax = p[:8]
    rho2 = np.einsum("ij,ij->i", xyz, xyz)
    q = xyz @ d0
    nu, nv = xyz @ e1, xyz @ e2
    far = rmax + max(gap_m, gap_rel * rmax)
    # u² + v² <= tan² α with u = nu / q, v = nv / q, tested as the kernels test it (no division)
    ok = (q > 0) & (rho2 >= rmin * rmin) & (rho2 <= far * far) & (nu * nu + nv * nv <= tan2 * q * q)
    i = np.flatnonzero(ok)
    return i, q[i], nu[i] / q[i], nv[i] / q[i]


def cast_reference(model: LidarModel, xyz: np.ndarray, rgb: np.ndarray | None, settings: LidarSettings) -> tuple:
    """The sweep of points ``xyz`` (N, 3) float64 in the sensor frame (rows with NaN/inf never count), colours
    ``rgb`` (N, 3) 0..1 or None: (range (A, B) float64 metres, NaN = no return; intensity (A, B) float64 0..255;
    source (A, B) int64, the index of the nearest point of the surface hit, -1 = none), [column, row]. Float64
    throughout; one ray at a time against every point (O(rays · N))."""
    xyz = np.asarray(xyz, np.float64)
    finite = np.isfinite(xyz).all(1)
    idx_all = np.flatnonzero(finite)
    pts = xyz[finite]
    lum = luminance(None if rgb is None else np.asarray(rgb)[finite], len(pts))
    p = settings.params(model)
    d0, e1, e2 = ray_bases(model)
    A, B = model.columns, model.beams
    rng = np.full((A, B), np.nan)
    inten = np.zeros((A, B))
    src = np.full((A, B), -1, np.int64)
    for c in range(A):
        for b in range(B):
            i, q, u, v = candidates(pts, d0[c, b], e1[c, b], e2[c, b], p)
            keep = thin(len(i), int(p[11]))
            i, q, u, v = i[keep], q[keep], u[keep], v[keep]
            if len(i):
                s, it, k = resolve_ray(q, u, v, lum[i], p)
                if k >= 0:
                    rng[c, b], inten[c, b], src[c, b] = s, it, idx_all[i[k]]
    return rng, inten, src
