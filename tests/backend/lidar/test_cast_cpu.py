"""backend/lidar/cast_cpu.py: the numba kernels give the float64 reference's returns (same rays, ranges to a
micrometre, same intensities and source points), whatever the thread count, over two point sets read as one; the
tables that cull points keep every candidate."""

import dataclasses

import numba
import numpy as np
import pytest

from backend.lidar import cast, cast_cpu
from scpainter_blender.core.lidar_model import MODELS, LidarModel

from tests.backend.lidar.lidar_scenes import PlaneBox

MODEL = LidarModel("small", tuple(np.linspace(4.0, -24.0, 8)), 2.0, 1.0, 40.0, 10.0)
SETTINGS = cast.LidarSettings(footprint_deg=0.7)


def _scene():
    """Points float32-exact relative to the sensor at the origin: the plane and box, clutter, NaN rows."""
    sc = PlaneBox(half_side=15.0, sensor=(0.0, 0.0, 0.0))
    pts, rgb = sc.sample(12_000, 300.0, seed=3)
    pts[:, 2] -= 1.84  # the ground below the sensor
    rng = np.random.default_rng(4)
    clutter = rng.uniform(-20, 20, (2000, 3))
    pts = np.concatenate([pts, clutter, np.full((5, 3), np.nan)]).astype(np.float32)
    rgb = np.concatenate([rgb, rng.uniform(0, 1, (2005, 3))]).astype(np.float32)
    return pts, rgb


@pytest.mark.parametrize("settings", [SETTINGS, dataclasses.replace(SETTINGS, max_candidates=8)],
                         ids=["default", "thinned"])
def test_numba_matches_the_float64_reference(settings):
    pts, rgb = _scene()
    ref = cast.cast_reference(MODEL, pts.astype(np.float64), rgb.astype(np.float64), settings)
    k = len(pts) // 3
    got = cast_cpu.cast(MODEL, pts[:k], rgb[:k], pts[k:], rgb[k:], np.eye(3), np.zeros(3), settings)
    hit = np.isfinite(ref[0])
    assert hit.sum() > 400  # the scene is seen
    assert np.array_equal(np.isfinite(got[0]), hit)
    assert np.abs(got[0][hit] - ref[0][hit]).max() < 1e-6  # a micrometre: Cramer vs LAPACK on the same sums
    assert np.allclose(got[1], ref[1], rtol=1e-9, atol=1e-9)
    assert np.array_equal(got[2], ref[2])


def test_the_result_does_not_depend_on_the_thread_count():
    pts, rgb = _scene()
    R = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # a quarter turn
    before = numba.get_num_threads()
    try:
        runs = []
        for threads in sorted({1, before}):
            numba.set_num_threads(threads)
            runs.append(cast_cpu.cast(MODEL, pts, rgb, pts[:0], rgb[:0], R, np.array([0.5, 0, 0]), SETTINGS))
    finally:
        numba.set_num_threads(before)
    for a, b in zip(runs[0], runs[-1]):
        assert np.array_equal(a, b, equal_nan=True)


def test_the_culling_tables_are_conservative():
    m = MODELS["nuscenes-32"]
    a = 0.3
    table = cast_cpu.elevation_table(m, a)
    halfw = cast_cpu.azimuth_halfwidths(m, a)
    rng = np.random.default_rng(0)
    d0, e1, e2 = cast.ray_bases(m)
    # directions inside random rays' footprints: their bin lists the row, their azimuth is within the half-width
    for _ in range(2000):
        c, b = rng.integers(m.columns), rng.integers(m.beams)
        r, t = np.tan(np.deg2rad(a)) * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
        d = d0[c, b] + r * (np.cos(t) * e1[c, b] + np.sin(t) * e2[c, b])
        d /= np.linalg.norm(d)
        lo, hi = table[min(int((d[2] * abs(d[2]) + 1) * 0.5 * len(table)), len(table) - 1)]
        assert lo <= b <= hi
        dphi = np.angle(np.exp(1j * (np.arctan2(d[0], d[1]) - c * 2 * np.pi / m.columns)))
        assert abs(dphi) <= halfw[b]
    # and the fast atan2 is within its margin
    x, y = rng.normal(size=(2, 10_000))
    fast = np.array([cast_cpu._atan2.py_func(a_, b_) for a_, b_ in zip(x, y)])
    assert np.abs(fast - np.arctan2(x, y)).max() < cast_cpu.AZIMUTH_MARGIN / 2


def test_warm_compiles_the_kernels():
    assert cast_cpu.warm() >= 0
    assert cast_cpu.kernels_cached() in (True, None)  # compiled and written to the cache (None: numba changed)
    for k in cast_cpu.kernels():
        assert k.signatures  # compiled (or loaded) for the argument types a sweep passes
