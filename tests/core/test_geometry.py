"""core.geometry: RANSAC plane, box membership, stage-1 proportions."""

import numpy as np
import pytest

from scpainter_blender.core import geometry as G


def test_ransac_finds_ground_under_clutter():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-5, 5, (3000, 2))
    ground = np.column_stack([xy, 0.02 * xy[:, 0] + 0.01 * xy[:, 1] + 1e5 + rng.normal(0, 0.005, 3000)])
    car = rng.uniform([-1, -2, 1e5], [1, 2, 1e5 + 1.5], (2500, 3))  # a box of clutter standing on it
    plane, inl, rms = G.fit_plane_ransac(np.concatenate([ground, car]), threshold=0.03)
    n = plane[:3]
    assert np.allclose(n / n[2], [-0.02, -0.01, 1.0], atol=2e-3)
    assert G.plane_height(plane, 0.0, 0.0) == pytest.approx(1e5, abs=0.01)
    assert inl[:3000].mean() > 0.95 and rms < 0.01
    a, b = G.fit_plane_ransac(ground), G.fit_plane_ransac(ground)
    assert np.array_equal(a[0], b[0])  # seeded


def test_ransac_rejects_walls_and_tiny_sets():
    rng = np.random.default_rng(1)
    wall = np.column_stack([np.zeros(500), rng.uniform(-5, 5, (500, 2))])
    with pytest.raises(ValueError, match="tilt"):
        G.fit_plane_ransac(wall)
    with pytest.raises(ValueError, match="at least 3"):
        G.fit_plane_ransac(wall[:2])


def test_points_in_box():
    T = np.eye(4)
    c, s = np.cos(0.5), np.sin(0.5)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [10, 20, 0.8]
    local = np.array([[0, 0, 0], [2.2, 0, 0], [2.3, 0, 0], [0, 0.9, 0.7], [0, 0.96, 0]])
    world = local @ T[:3, :3].T + T[:3, 3]
    assert G.points_in_box(world, T, [4.5, 1.9, 1.6]).tolist() == [True, True, False, True, False]


def test_proportion_deviation():
    d = G.proportion_deviation([0.98, 0.4, 0.35], [4.5, 1.9, 1.6])
    assert d[0] == 0.0
    assert d[1] == pytest.approx(0.4 * 4.5 / 0.98 / 1.9 - 1)
    with pytest.raises(ValueError):
        G.proportion_deviation([0, 1, 1], [1, 1, 1])
