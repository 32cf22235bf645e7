"""The numba fast path of ``cast.cast_reference``: the same rule (``cast``'s docstring), the same returns.

Input: two point sets (the reconstruction's points and the cars' Gaussian means, so neither is copied into one
array), each (N, 3) float32 relative to a local origin o, with colours (N, 3) float32 0..1; the sensor's rotation
``R`` (3, 3) float64 (world to sensor) and position ``t`` (3,) float64 relative to o. Every point is moved to the
sensor frame in float64, s = R (p − t): the float32 storage costs what float32 costs at the distance from o (the
renderer's scene origin: sub-millimetre), never the sensor's distance from the world's origin.

Parallel and deterministic without atomics, a counting sort of (point, ray) pairs:

1. ``_count`` (parallel over T chunks of each point set): each chunk counts, in its own row of a (2T, rays) table,
   the rays whose footprint holds each of its points. A point is culled first by its elevation alone (a table
   over sin e |sin e| = s_z |s_z| / |s|² gives the rows whose band [e_b − α, e_b + α] may hold it: most points of a
   scene lie between two beams), then only the columns within the footprint's azimuth half-width are tested
   exactly.
2. the offsets (exclusive prefix sum over rays, then chunks): every ray's candidates in one segment, chunk after
   chunk, each chunk's in point order, so the segment's order does not depend on T.
3. ``_fill`` (parallel over the chunks): the same test again for the points pass 1 marked, writing each pair's
   depth q, offsets u, v and point index as one row into its slot.
4. ``_resolve`` (parallel over rays): the segment sorted by q in place (stable insertion sort), then the clusters,
   the coverage test, the fit and the intensity, in the reference's order of summation.

Kernels are cached (``cache=True``) in ``NUMBA_CACHE_DIR`` like the renderer's (``backend/render/warmup.py``): the
first sweep after an install (or a change of this file) compiles them, 5 s on an idle two-core machine (up to 30 s
when it is busy); later processes load them in a fraction of a second. ``warm()`` compiles or loads them on a tiny
sweep, ``kernels_cached()`` says which it will be (so a caller can say so before a long first sweep).
"""

from __future__ import annotations

import time

import numpy as np
from numba import get_num_threads, njit, prange

from scpainter_blender.core.lidar_model import LidarModel

from .cast import LUMA, LidarSettings

#: Bins of the elevation table over sin e |sin e| in [-1, 1] (the first bins either side of the horizon span 0.3°).
ELEVATION_BINS = 32768
#: A ray with more candidates than this is sorted by a merge sort rather than an insertion sort.
INSERTION_MAX = 48
#: Radians added to each row's azimuth half-width: more than ``_atan2``'s error.
AZIMUTH_MARGIN = 1e-4


def elevation_table(model: LidarModel, footprint_deg: float, bins: int = ELEVATION_BINS) -> np.ndarray:
    """(bins, 2) int32: for each bin of t = sin e · |sin e| = z |z| / |s|² over [-1, 1] (no square root per point),
    the first and last row (0 = top) whose band [e_b − α, e_b + α] overlaps the bin's elevations (last < first:
    none)."""
    e = np.deg2rad(np.asarray(model.elevations_deg, np.float64))
    a = np.deg2rad(footprint_deg)
    t = np.linspace(-1.0, 1.0, bins + 1)
    edges = np.sign(t) * np.sqrt(np.abs(t))
    lo_e, hi_e = np.arcsin(edges[:-1]), np.arcsin(edges[1:])
    hit = (e[None, :] - a <= hi_e[:, None] + 1e-12) & (e[None, :] + a >= lo_e[:, None] - 1e-12)  # (bins, B)
    first = np.where(hit.any(1), hit.argmax(1), 0)
    last = np.where(hit.any(1), len(e) - 1 - hit[:, ::-1].argmax(1), -1)
    return np.stack([first, last], 1).astype(np.int32)


def azimuth_halfwidths(model: LidarModel, footprint_deg: float) -> np.ndarray:
    """(B,) float64 radians: per row, the largest azimuth difference of a point inside a footprint of that row.
    Two directions (φ1, e1), (φ2, e2) an angle δ apart have sin²(δ/2) = sin²(Δe/2) + cos e1 cos e2 sin²(Δφ/2),
    and a point within α of the ray has |e − e_b| <= α, so |Δφ| <= 2 asin(sin(α/2) / √(cos e_b cos(|e_b| + α)))
    (π once that passes 1), plus ``AZIMUTH_MARGIN``."""
    e = np.abs(np.deg2rad(np.asarray(model.elevations_deg, np.float64)))
    a = np.deg2rad(footprint_deg)
    c = np.cos(e) * np.cos(np.minimum(e + a, np.pi / 2))
    with np.errstate(divide="ignore"):
        x = np.sin(a / 2) / np.sqrt(c)
    return np.where(x < 1, 2 * np.arcsin(np.minimum(x, 1.0)), np.pi) + AZIMUTH_MARGIN


@njit(inline="always")
def _atan2(y, x):
    """atan2(y, x) within 2.5e-5 rad (a degree-11 odd polynomial of min/max): libm's costs 60 ms a sweep of 3 M
    points on two cores, this 8; it only bounds the columns a point may fall in (``AZIMUTH_MARGIN``), the
    footprint test itself is exact."""
    ax, ay = abs(x), abs(y)
    hi, lo = max(ax, ay), min(ax, ay)
    a = lo / hi if hi > 0.0 else 0.0
    s = a * a
    r = ((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s * a + a
    if ay > ax:
        r = 1.5707963267948966 - r
    if x < 0.0:
        r = 3.141592653589793 - r
    return -r if y < 0.0 else r


@njit(inline="always")
def _sensor(xyz, i, R, t):
    x = np.float64(xyz[i, 0]) - t[0]
    y = np.float64(xyz[i, 1]) - t[1]
    z = np.float64(xyz[i, 2]) - t[2]
    return (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z, R[1, 0] * x + R[1, 1] * y + R[1, 2] * z,
            R[2, 0] * x + R[2, 1] * y + R[2, 2] * z)


@njit(parallel=True, cache=True, nogil=True)
def _count(xyz_a, xyz_b, R, t, p, table, halfw, sphi, cphi, se, ce, step, hist, mark):
    """Pass 1: hist[k, ray] = the (point, ray) pairs of chunk k (ray = column · B + row); mark[i] = 1 for a point
    in some pair (pass 3 skips the others unread)."""
    na = xyz_a.shape[0]
    chunks = hist.shape[0] // 2  # chunks of the first set, then as many of the second
    A, B = sphi.shape[0], se.shape[0]
    bins = table.shape[0]
    tan2, gap_m, gap_rel, rmin, rmax = p[1], p[2], p[3], p[6], p[7]
    far = rmax + max(gap_m, gap_rel * rmax)
    for k in prange(2 * chunks):
        xyz = xyz_a if k < chunks else xyz_b
        base = 0 if k < chunks else na
        kk = k % chunks
        n = xyz.shape[0]
        for j in range(kk * n // chunks, (kk + 1) * n // chunks):
            i = base + j
            sx, sy, sz = _sensor(xyz, j, R, t)
            r2 = sx * sx + sy * sy + sz * sz
            if not (r2 >= rmin * rmin and r2 <= far * far):
                continue  # NaN fails too
            sb = int((sz * abs(sz) / r2 + 1.0) * 0.5 * bins)
            sb = min(max(sb, 0), bins - 1)
            lo, hi = table[sb, 0], table[sb, 1]
            if hi < lo:
                continue
            phi = _atan2(sx, sy)
            for b in range(lo, hi + 1):
                c0 = int(np.ceil((phi - halfw[b]) / step))
                c1 = int(np.floor((phi + halfw[b]) / step))
                for c in range(c0, c1 + 1):
                    cc = c % A
                    h = sphi[cc] * sx + cphi[cc] * sy  # the point's horizontal component along the column
                    q = ce[b] * h + se[b] * sz
                    if q <= 0.0:
                        continue
                    nu = cphi[cc] * sx - sphi[cc] * sy
                    nv = ce[b] * sz - se[b] * h
                    if nu * nu + nv * nv <= tan2 * q * q:  # u² + v² <= tan² α without dividing
                        hist[k, cc * B + b] += 1
                        mark[i] = 1


@njit(parallel=True, cache=True, nogil=True)
def _fill(xyz_a, xyz_b, R, t, p, table, halfw, sphi, cphi, se, ce, step, mark, slot, pairs):
    """Pass 3: the pairs (q, u, v, point index as a float64: exact below 2**53) written as rows of ``pairs`` at
    slot[k, ray] onwards (slot: the offsets, advanced as they are used); one row per pair keeps each write in one
    cache line. It walks exactly ``_count``'s candidates (the footprint test is written out in both, each one tight
    loop inside its ``prange``: a change to one is a change to the other, and the tests compare the pairs with the
    float64 reference's)."""
    na = xyz_a.shape[0]
    chunks = slot.shape[0] // 2
    A, B = sphi.shape[0], se.shape[0]
    bins = table.shape[0]
    tan2 = p[1]
    for k in prange(2 * chunks):
        xyz = xyz_a if k < chunks else xyz_b
        base = 0 if k < chunks else na
        kk = k % chunks
        n = xyz.shape[0]
        for j in range(kk * n // chunks, (kk + 1) * n // chunks):
            i = base + j
            if mark[i] == 0:
                continue
            sx, sy, sz = _sensor(xyz, j, R, t)
            r2 = sx * sx + sy * sy + sz * sz
            sb = int((sz * abs(sz) / r2 + 1.0) * 0.5 * bins)
            sb = min(max(sb, 0), bins - 1)
            lo, hi = table[sb, 0], table[sb, 1]
            if hi < lo:
                continue
            phi = _atan2(sx, sy)
            for b in range(lo, hi + 1):
                c0 = int(np.ceil((phi - halfw[b]) / step))
                c1 = int(np.floor((phi + halfw[b]) / step))
                for c in range(c0, c1 + 1):
                    cc = c % A
                    h = sphi[cc] * sx + cphi[cc] * sy
                    q = ce[b] * h + se[b] * sz
                    if q <= 0.0:
                        continue
                    nu = cphi[cc] * sx - sphi[cc] * sy
                    nv = ce[b] * sz - se[b] * h
                    if nu * nu + nv * nv <= tan2 * q * q:
                        r = cc * B + b
                        j = slot[k, r]
                        slot[k, r] = j + 1
                        pairs[j, 0], pairs[j, 1], pairs[j, 2], pairs[j, 3] = q, nu / q, nv / q, i


@njit(inline="always")
def _solve(n, su, sv, suu, suv, svv, sw, swu, swv, lam):
    """(a, b, c) of the normal equations [[n, su, sv], [su, suu+lam, suv], [sv, suv, svv+lam]] (a b c) = (sw swu
    swv), by Cramer's rule (``cast.fit``)."""
    m11, m12, m22 = suu + lam, suv, svv + lam
    c00 = m11 * m22 - m12 * m12
    c01 = su * m22 - m12 * sv
    c02 = su * m12 - m11 * sv
    det = n * c00 - su * c01 + sv * c02
    a = (sw * c00 - su * (swu * m22 - m12 * swv) + sv * (swu * m12 - m11 * swv)) / det
    b = (n * (swu * m22 - m12 * swv) - sw * c01 + sv * (su * swv - swu * sv)) / det
    c = (n * (m11 * swv - swu * m12) - su * (su * swv - swu * sv) + sw * c02) / det
    return a, b, c


@njit(parallel=True, cache=True, nogil=True)
def _resolve(start, P, rgb_a, rgb_b, p, luma, rng, inten, src):
    """Pass 4: per ray r (rows start[r]..start[r+1] of the pairs ``P``), its range (NaN: none), intensity and
    source point."""
    tan_a, tan2, gap_m, gap_rel, coverage, ridge, rmin, rmax = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]
    tol_m, tol_rel, spread2, cap = p[8], p[9], (p[10] * p[0]) ** 2, np.int64(p[11])
    na = rgb_a.shape[0]
    for r in prange(start.shape[0] - 1):
        s0, s1 = start[r], start[r + 1]
        rng[r], inten[r], src[r] = np.nan, 0.0, -1
        if s1 - s0 > cap:  # thinned to every k-th candidate in point order (``cast.thin``)
            k = (s1 - s0 + cap - 1) // cap
            m = 0
            for j in range(s0, s1, k):
                P[s0 + m, 0], P[s0 + m, 1], P[s0 + m, 2], P[s0 + m, 3] = P[j, 0], P[j, 1], P[j, 2], P[j, 3]
                m += 1
            s1 = s0 + m
        # the rows sorted by depth, stably: insertion sort for the tens of candidates most rays hold, a merge sort
        # for the hundreds of a ray that grazes the far road (its footprint's patch grows as r³)
        if s1 - s0 > INSERTION_MAX:
            order = np.argsort(P[s0:s1, 0], kind="mergesort")
            P[s0:s1] = P[s0:s1][order]
        for j in range(s0 + 1, s1):
            q, u, v, ii = P[j, 0], P[j, 1], P[j, 2], P[j, 3]
            m = j - 1
            while m >= s0 and P[m, 0] > q:
                P[m + 1, 0], P[m + 1, 1], P[m + 1, 2], P[m + 1, 3] = P[m, 0], P[m, 1], P[m, 2], P[m, 3]
                m -= 1
            P[m + 1, 0], P[m + 1, 1], P[m + 1, 2], P[m + 1, 3] = q, u, v, ii
        a0 = s0
        while a0 < s1:
            # grow the cluster a0..a1 with its running sums (the fit's)
            q, u, v = P[a0, 0], P[a0, 1], P[a0, 2]
            w = 1.0 / q
            su, sv, suu, suv, svv, sw, swu, swv = u, v, u * u, u * v, v * v, w, w * u, w * v
            fitted, pa, pb, pc = 0, 0.0, 0.0, 0.0
            a1 = a0 + 1
            while a1 < s1:
                q, u, v = P[a1, 0], P[a1, 1], P[a1, 2]
                if not fitted and q - P[a1 - 1, 0] > max(gap_m, gap_rel * P[a1 - 1, 0]):
                    break
                k = a1 - a0
                if k >= 3 and 2 * k >= 3 * fitted:  # refit when the cluster has grown by half
                    mu, mv = su / k, sv / k
                    cuu, cuv, cvv = suu / k - mu * mu, suv / k - mu * mv, svv / k - mv * mv
                    if (cuu + cvv) / 2 - np.hypot((cuu - cvv) / 2, cuv) >= spread2:
                        pa, pb, pc = _solve(k, su, sv, suu, suv, svv, sw, swu, swv, ridge * k * tan2)
                        fitted = k
                if fitted and not abs(q * (pa + pb * u + pc * v) - 1.0) <= max(tol_m, tol_rel * q) / q:
                    break
                w = 1.0 / q
                su += u
                sv += v
                suu += u * u
                suv += u * v
                svv += v * v
                sw += w
                swu += w * u
                swv += w * v
                a1 += 1
            n = a1 - a0
            if np.hypot(su / n, sv / n) <= tan_a * (coverage + 0.25 / np.sqrt(n)):
                a, b, c = _solve(n, su, sv, suu, suv, svv, sw, swu, swv, ridge * n * tan2)
                s = 1.0 / a if a > 0.0 else np.inf
                # how far beyond its depth span the fit may reach: a gap when the plane is known, else tol
                q0, q1 = P[a0, 0], P[a1 - 1, 0]
                lo, hi = q0 - max(tol_m, tol_rel * q0), q1 + max(tol_m, tol_rel * q1)
                if n >= 3:
                    mu, mv = su / n, sv / n
                    cuu, cuv, cvv = suu / n - mu * mu, suv / n - mu * mv, svv / n - mv * mv
                    if (cuu + cvv) / 2 - np.hypot((cuu - cvv) / 2, cuv) >= spread2:
                        lo, hi = q0 - max(gap_m, gap_rel * q0), q1 + max(gap_m, gap_rel * q1)
                if not (s >= lo and s <= hi):
                    s = n / sw
                if s >= rmin and s <= rmax:
                    sl = 0.0
                    for j in range(a0, a1):
                        ii = np.int64(P[j, 3])
                        if ii < na:
                            sl += luma[0] * rgb_a[ii, 0] + luma[1] * rgb_a[ii, 1] + luma[2] * rgb_a[ii, 2]
                        else:
                            sl += (luma[0] * rgb_b[ii - na, 0] + luma[1] * rgb_b[ii - na, 1]
                                   + luma[2] * rgb_b[ii - na, 2])
                    rng[r], inten[r], src[r] = s, 255.0 * sl / n, np.int64(P[a0, 3])
                break
            a0 = a1


@njit(cache=True, nogil=True)
def _offsets(hist, slot, start):
    """Exclusive prefix sums: slot[k, r] where chunk k's pairs of ray r begin, start[r] where ray r's do."""
    chunks, rays = hist.shape
    total = 0
    for r in range(rays):
        start[r] = total
        for k in range(chunks):
            slot[k, r] = total
            total += hist[k, r]
    start[rays] = total
    return total


def cast(model: LidarModel, xyz_a: np.ndarray, rgb_a: np.ndarray, xyz_b: np.ndarray, rgb_b: np.ndarray,
         R: np.ndarray, t: np.ndarray, settings: LidarSettings) -> tuple:
    """``cast_reference``'s (range, intensity, source), each (A, B) [column, row], for the points ``xyz_a`` then
    ``xyz_b`` (float32 (N, 3) relative to a local origin; colours float32 (N, 3) 0..1; ``source`` indexes the two
    sets one after the other) seen by a sensor at ``t`` (3,) float64 (relative to the same origin) with
    world-to-sensor rotation ``R`` (3, 3) float64."""
    A, B = model.columns, model.beams
    p = settings.params(model)
    table = elevation_table(model, settings.footprint_deg)
    halfw = azimuth_halfwidths(model, settings.footprint_deg)
    phi = np.arange(A) * (2 * np.pi / A)
    e = np.deg2rad(np.asarray(model.elevations_deg, np.float64))
    args = (np.ascontiguousarray(xyz_a, np.float32), np.ascontiguousarray(xyz_b, np.float32),
            np.ascontiguousarray(R, np.float64), np.ascontiguousarray(t, np.float64), p, table, halfw,
            np.sin(phi), np.cos(phi), np.sin(e), np.cos(e), 2 * np.pi / A)
    chunks = max(1, get_num_threads())
    hist = np.zeros((2 * chunks, A * B), np.int64)  # chunks of each point set
    mark = np.zeros(len(xyz_a) + len(xyz_b), np.uint8)
    _count(*args, hist, mark)
    slot = np.empty_like(hist)
    start = np.empty(A * B + 1, np.int64)
    total = _offsets(hist, slot, start)
    pairs = np.empty((total, 4))
    _fill(*args, mark, slot, pairs)
    rng, inten, src = np.empty(A * B), np.empty(A * B), np.empty(A * B, np.int64)
    _resolve(start, pairs, np.ascontiguousarray(rgb_a, np.float32), np.ascontiguousarray(rgb_b, np.float32),
             p, np.array(LUMA), rng, inten, src)
    return rng.reshape(A, B), inten.reshape(A, B), src.reshape(A, B)


def kernels() -> list:
    """The numba dispatchers of this module (``cache=True``)."""
    return [_count, _fill, _resolve, _offsets]


def kernels_cached() -> bool | None:
    """Whether every kernel has compiled code in numba's cache for its current source (its index read as numba
    reads it, like ``backend.render.warmup.kernels_cached``); None when this numba's cache cannot be inspected."""
    try:
        return all(bool(k._cache._cache_file._load_index()) for k in kernels())
    except AttributeError:
        return None


def warm() -> float:
    """Compile (or load from the cache) every kernel by casting a tiny sweep; its seconds."""
    from scpainter_blender.core.lidar_model import MODELS

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-10, 10, (200, 3)).astype(np.float32)
    rgb = rng.uniform(0, 1, (200, 3)).astype(np.float32)
    cast(MODELS["nuscenes-32"], xyz, rgb, xyz[:10], rgb[:10], np.eye(3), np.zeros(3), LidarSettings())
    return time.perf_counter() - t0
