"""backend/lidar/cast.py: the rule on single rays, in float64: a plane's range exact whatever its sampling, the
nearest surface that covers the ray, an edge that does not, the range window, and the intensity."""

import numpy as np
import pytest

from backend.lidar import cast
from scpainter_blender.core.lidar_model import LidarModel

MODEL = LidarModel("test", (0.0, -10.0), 90.0, 1.0, 50.0, 10.0)  # 2 beams x 4 columns
SETTINGS = cast.LidarSettings(footprint_deg=0.5)
P = SETTINGS.params(MODEL)


def _ray(column, row):
    d0, e1, e2 = cast.ray_bases(MODEL)
    return d0[column, row], e1[column, row], e2[column, row]


def _disk(rng, n, d0, e1, e2, radius):
    """n directions spread evenly over the footprint disk (gnomonic offsets)."""
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    d = d0 + (r * np.cos(a))[:, None] * e1 + (r * np.sin(a))[:, None] * e2
    return d, r * np.cos(a), r * np.sin(a)


def _resolve(xyz, lum=None):
    d0, e1, e2 = _ray(0, 1)
    i, q, u, v = cast.candidates(xyz, d0, e1, e2, P)
    return cast.resolve_ray(q, u, v, np.zeros(len(i)) if lum is None else lum[i], P)


def test_ray_bases_are_orthonormal_and_point_where_the_model_says():
    d0, e1, e2 = cast.ray_bases(MODEL)
    for a, b in ((d0, e1), (d0, e2), (e1, e2)):
        assert np.allclose((a * b).sum(-1), 0)
    assert np.allclose(d0, MODEL.directions())
    assert np.allclose(e2[..., 2], np.cos(np.deg2rad(MODEL.elevations_deg)))  # upwards


def test_a_tilted_plane_sampled_unevenly_gives_its_range():
    rng = np.random.default_rng(1)
    d0, e1, e2 = _ray(0, 1)
    n = np.array([0.2, -0.9, 0.4])
    n /= np.linalg.norm(n)
    h = -12.0  # the plane n.x = h, met by the ray at 12 / (n . -d0)
    dirs, _, _ = _disk(rng, 40, d0, e1, e2, np.tan(np.deg2rad(0.45)))
    dirs = dirs[dirs @ e2 < 0.002]  # only the lower part and a sliver: uneven
    xyz = dirs * (h / (dirs @ n))[:, None]
    s, _, k = _resolve(xyz)
    assert k >= 0 and s == pytest.approx(h / (d0 @ n), abs=1e-4)  # the ridge biases it by micrometres


def test_the_nearest_surface_that_covers_the_ray_wins_and_a_grazing_edge_does_not():
    rng = np.random.default_rng(2)
    d0, e1, e2 = _ray(0, 1)
    t = np.tan(np.deg2rad(0.5))
    dirs, u, v = _disk(rng, 300, d0, e1, e2, t)
    wall = dirs * (20.0 / (dirs @ d0))[:, None]        # a wall facing the sensor at depth 20
    near = dirs * (8.0 / (dirs @ d0))[:, None]         # a panel at depth 8
    s, _, _ = _resolve(np.concatenate([wall, near]))
    assert s == pytest.approx(8.0, abs=1e-9)
    # the panel covering only a strip at the footprint's edge (u > 0.6 t): the ray passes it and hits the wall
    s, _, _ = _resolve(np.concatenate([wall, near[u > 0.6 * t]]))
    assert s == pytest.approx(20.0, abs=1e-9)
    # covering a little more than half: the panel is hit (its edge is inside the footprint, beyond the ray)
    s, _, _ = _resolve(np.concatenate([wall, near[u > -0.1 * t]]))
    assert s == pytest.approx(8.0, abs=1e-9)


def test_the_range_window_and_nothing_in_the_footprint():
    rng = np.random.default_rng(3)
    d0, e1, e2 = _ray(0, 1)
    dirs, _, _ = _disk(rng, 50, d0, e1, e2, np.tan(np.deg2rad(0.4)))
    for depth, hit in ((0.5, False), (49.0, True), (60.0, False)):
        s, _, k = _resolve(dirs * (depth / (dirs @ d0))[:, None])
        assert (k >= 0) == hit and (np.isnan(s) != hit)
    s, inten, k = _resolve(np.zeros((0, 3)))
    assert np.isnan(s) and k == -1 and inten == 0
    # a point well outside the footprint only
    s, _, k = _resolve((d0 + 0.1 * e1)[None] * 10)
    assert k == -1


def test_intensity_is_the_mean_luminance_of_the_surface_hit():
    rng = np.random.default_rng(4)
    d0, e1, e2 = _ray(0, 1)
    dirs, _, _ = _disk(rng, 30, d0, e1, e2, np.tan(np.deg2rad(0.4)))
    xyz = dirs * (10.0 / (dirs @ d0))[:, None]
    rgb = np.tile([1.0, 0.5, 0.0], (30, 1))
    _, inten, _ = _resolve(xyz, cast.luminance(rgb, 30))
    assert inten == pytest.approx(255 * (0.2126 + 0.7152 * 0.5))
    assert np.all(cast.luminance(None, 3) == 0)


def test_reference_sweep_skips_nan_rows_and_reports_the_nearest_point():
    rng = np.random.default_rng(5)
    d0, e1, e2 = _ray(2, 0)
    dirs, _, _ = _disk(rng, 40, d0, e1, e2, np.tan(np.deg2rad(0.4)))
    xyz = np.concatenate([np.full((3, 3), np.nan), dirs * (15.0 / (dirs @ d0))[:, None]])
    rng_, inten, src = cast.cast_reference(MODEL, xyz, None, SETTINGS)
    assert rng_.shape == (4, 2) and np.isfinite(rng_).sum() == 1
    assert rng_[2, 0] == pytest.approx(15.0) and src[2, 0] >= 3
    q = xyz[3:] @ d0
    assert src[2, 0] == 3 + np.argmin(q)


def test_a_crowded_ray_keeps_every_kth_candidate():
    assert list(cast.thin(10, 4)) == [0, 3, 6, 9] and list(cast.thin(4, 4)) == [0, 1, 2, 3]
    assert len(cast.thin(3221, 256)) <= 256
