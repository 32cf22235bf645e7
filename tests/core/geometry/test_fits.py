"""core.geometry.fits: RANSAC plane, box membership, stage-1 proportions."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.geometry import fits as G


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


# -- the one RANSAC plane fit: quality, robustness, determinism, refusals -------------------------------------

def _tilted_ground(n=4000, seed=0, noise=0.005, offset=(0.0, 0.0, 0.0)):
    """Points on z = 0.02 x - 0.01 y + 0.5 (+ offset) with Gaussian noise along z; returns (points, true plane)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-10, 10, (n, 2))
    z = 0.02 * xy[:, 0] - 0.01 * xy[:, 1] + 0.5 + rng.normal(0, noise, n)
    normal = np.array([-0.02, 0.01, 1.0])
    normal /= np.linalg.norm(normal)
    o = np.asarray(offset, np.float64)
    plane = np.array([*normal, -normal @ (np.array([0.0, 0.0, 0.5]) + o)])
    return np.column_stack([xy, z]) + o, plane


def _angle_deg(a, b):
    return np.degrees(np.arccos(min(1.0, abs(float(np.dot(a[:3], b[:3]))))))


def test_ransac_recovers_a_known_plane():
    pts, truth = _tilted_ground()
    plane, inl, rms = G.fit_plane_ransac(pts, threshold=0.02)
    assert _angle_deg(plane, truth) < 0.02
    assert abs(plane[3] - truth[3]) < 1e-3 and plane[2] > 0  # oriented along up
    assert inl.mean() > 0.99
    assert rms == pytest.approx(0.005, rel=0.1)  # the noise we put in
    # the inlier RMS is measured to the returned plane, over the returned inliers
    d = pts[inl] @ plane[:3] + plane[3]
    assert rms == pytest.approx(float(np.sqrt(np.mean(d ** 2))), rel=1e-9)
    assert np.all(np.abs(pts @ plane[:3] + plane[3])[~inl] >= 0.02)  # strict threshold, as open3d's


def test_ransac_ignores_outliers_and_larger_tilted_planes():
    """Clutter (60 % of the points) and a wall with more points than the ground: the level plane still wins."""
    ground, truth = _tilted_ground(3000, seed=1)
    rng = np.random.default_rng(2)
    clutter = rng.uniform([-10, -10, 0.6], [10, 10, 6], (4500, 3))
    wall = np.column_stack([np.full(6000, 8.0) + rng.normal(0, 0.003, 6000), rng.uniform(-10, 10, (6000, 2)) + [0, 3]])
    far = rng.normal(0, 1e4, (50, 3))  # wild points from a broken depth map
    pts = np.concatenate([clutter, wall, ground, far])
    plane, inl, rms = G.fit_plane_ransac(pts, threshold=0.02)
    assert _angle_deg(plane, truth) < 0.05 and abs(plane[3] - truth[3]) < 3e-3
    assert inl[-3050:-50].mean() > 0.99 and inl[4500:10500].mean() < 0.01  # only where the wall meets the road
    assert rms < 0.007


def test_ransac_is_seeded():
    pts, truth = _tilted_ground(seed=3)
    pts = np.concatenate([pts, np.random.default_rng(4).uniform(-10, 10, (3000, 3))])
    a = G.fit_plane_ransac(pts, threshold=0.02, seed=5)
    b = G.fit_plane_ransac(pts.copy(), threshold=0.02, seed=5)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]  # bit for bit
    c = G.fit_plane_ransac(pts, threshold=0.02, seed=6)  # another seed: another sample, the same plane
    assert _angle_deg(a[0], c[0]) < 0.05 and abs(a[0][3] - c[0][3]) < 2e-3


def test_ransac_far_from_the_origin():
    """1e5 m from the origin the plane is as exact as at the origin (everything is relative to the centroid)."""
    near, _ = _tilted_ground(seed=7)
    far, truth = _tilted_ground(seed=7, offset=(1e5, -2e5, 1e5))
    p0, i0, r0 = G.fit_plane_ransac(near, threshold=0.02)
    p1, i1, r1 = G.fit_plane_ransac(far, threshold=0.02)
    assert _angle_deg(p1, truth) < 0.02
    assert np.array_equal(i0, i1) and r1 == pytest.approx(r0, rel=1e-6)
    assert np.allclose(p1[:3], p0[:3], atol=1e-9)
    # the height over a point of the far scene: local (1, 2) is 0.02·1 − 0.01·2 + 0.5 = 0.5 over the offset
    x, y = 1e5 + 1.0, -2e5 + 2.0
    assert G.plane_height(p1, x, y) == pytest.approx(1e5 + 0.5, abs=5e-3)
    assert G.plane_height(p1, x, y) - 1e5 == pytest.approx(G.plane_height(p0, 1.0, 2.0), abs=1e-6)


def test_ransac_leaves_out_nan_rows():
    pts, truth = _tilted_ground(seed=8)
    bad = pts.copy()
    bad[::7] = np.nan
    bad[3::11, 2] = np.inf
    finite = np.all(np.isfinite(bad), axis=1)
    plane, inl, rms = G.fit_plane_ransac(bad, threshold=0.02)
    ref = G.fit_plane_ransac(bad[finite], threshold=0.02)
    assert np.array_equal(plane, ref[0]) and rms == ref[2]   # the same fit as without those rows
    assert inl.shape == (len(bad),) and not inl[~finite].any() and np.array_equal(inl[finite], ref[1])
    assert _angle_deg(plane, truth) < 0.02
    with pytest.raises(G.PlaneFitError, match="at least 3.*NaN") as e:
        G.fit_plane_ransac(np.full((50, 3), np.nan))
    assert e.value.reason == "too_few"


def test_ransac_refuses_degenerate_clouds():
    for empty in (np.zeros((0, 3)), [], np.zeros((2, 3))):
        with pytest.raises(G.PlaneFitError, match="at least 3") as e:
            G.fit_plane_ransac(empty)
        assert e.value.reason == "too_few"
    t = np.linspace(0, 10, 200)
    for cloud in (np.column_stack([t, 2 * t, np.zeros_like(t)]),   # a line
                  np.tile([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], (100, 1)),   # two points, repeated
                  np.ones((100, 3))):                                   # one point
        with pytest.raises(G.PlaneFitError, match="collinear") as e:
            G.fit_plane_ransac(cloud)
        assert e.value.reason == "degenerate"
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        G.fit_plane_ransac(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="threshold"):
        G.fit_plane_ransac(np.zeros((10, 3)), threshold=0.0)


# -- the road under forward-looking cameras -------------------------------------------------------------------

def _street(height=1.6, frames=5, seed=0):
    """Cameras ``height`` over z = 0 looking along +Y, a road, a building wall beside it (more points than the
    road) and clutter. Returns (points, world_to_camera (S, 4, 4))."""
    rng = np.random.default_rng(seed)
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # OpenCV camera: x right, y down (-Z), z forward (+Y)
    for i in range(frames):
        c = np.array([0.0, 2.0 * i, height])
        w2c[i, :3, :3], w2c[i, :3, 3] = R, -R @ c
    road = np.column_stack([rng.uniform(-4, 4, 3000), rng.uniform(2, 30, 3000), rng.normal(0, 0.01, 3000)])
    wall = np.column_stack([np.full(5000, 5.0), rng.uniform(2, 30, 5000), rng.uniform(0, 8, 5000)])
    clutter = rng.uniform([-4, 2, 0.2], [4, 30, 2], (1000, 3))
    return np.concatenate([road, wall, clutter]), w2c


def test_fit_ground_plane_finds_the_road():
    pts, w2c = _street()
    g = G.fit_ground_plane(pts, w2c)
    assert _angle_deg(g.plane, [0, 0, 1, 0]) < 0.1 and abs(g.plane[3]) < 0.01
    assert g.plane[2] > 0  # towards the cameras
    assert g.tilt_deg < 0.1 and g.candidates == len(pts) and g.nonfinite == 0
    assert g.inliers[:3000].mean() > 0.99
    assert np.all(pts[3000:8000][g.inliers[3000:8000], 2] < 2 * g.threshold)  # only the wall's foot
    centre = C.camera_centers(w2c).mean(axis=0)
    assert g.threshold == pytest.approx(0.01 * np.median(np.linalg.norm(pts - centre, axis=1)))
    assert g.inlier_rms < 0.02
    # the same cloud in VGGT's frame (first camera's OpenCV axes, another scale): the same plane there
    s = 0.37
    vggt_to_world = np.eye(4)
    vggt_to_world[:3, :3] = s * w2c[0, :3, :3].T
    vggt_to_world[:3, 3] = C.camera_centers(w2c)[0]
    world_to_vggt = np.linalg.inv(vggt_to_world)
    pv = pts @ world_to_vggt[:3, :3].T + world_to_vggt[:3, 3]
    w2c_v = w2c @ vggt_to_world
    w2c_v[:, :3, :] /= s  # rigid again: the camera frame scaled with the world
    w2c_v[:, 3, :] = [0, 0, 0, 1]
    gv = G.fit_ground_plane(pv, w2c_v)
    assert np.array_equal(gv.inliers, g.inliers)
    up_v = world_to_vggt[:3, :3] @ [0, 0, 1] / s
    assert _angle_deg(gv.plane, up_v) < 0.1 and gv.threshold == pytest.approx(g.threshold / s)


def test_fit_ground_plane_refusals():
    pts, w2c = _street()
    with pytest.raises(G.PlaneFitError, match="only 99 ground candidate points") as e:
        G.fit_ground_plane(pts[:99], w2c)
    assert e.value.reason == "too_few"
    nan = pts[:150].copy()
    nan[:60] = np.nan
    with pytest.raises(G.PlaneFitError, match="60 with NaN/inf left out") as e:
        G.fit_ground_plane(nan, w2c)
    with pytest.raises(G.PlaneFitError, match="allowed tilt") as e:
        G.fit_ground_plane(pts[3000:8000], w2c)  # the wall alone
    assert e.value.reason == "tilt"
    rng = np.random.default_rng(1)
    with pytest.raises(G.PlaneFitError, match="holds only") as e:  # a box of scattered points: no road
        G.fit_ground_plane(rng.uniform([-5, 2, 0], [5, 30, 10], (5000, 3)), w2c)
    assert e.value.reason == "weak"
    with pytest.raises(ValueError, match="finite pose"):
        G.fit_ground_plane(pts, np.full((2, 4, 4), np.nan))
