"""core.cameras: conventions, exact round trips (also 1e5 m from the origin), trajectories, similarity fits."""

import numpy as np
import pytest

from scpainter_blender.core import cameras as C


def random_rotation(rng):
    q = rng.standard_normal(4)
    return C.quaternion_to_rotation(q)


def random_w2c(rng, n=None, offset=0.0):
    shape = () if n is None else (n,)
    T = np.tile(np.eye(4), shape + (1, 1))
    R = random_rotation(rng) if n is None else np.stack([random_rotation(rng) for _ in range(n)])
    centres = rng.uniform(-50, 50, shape + (3,)) + offset
    T[..., :3, :3] = R
    T[..., :3, 3] = -np.einsum("...ij,...j->...i", R, centres)
    return T


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_matrix_world_round_trip_exact(offset):
    rng = np.random.default_rng(1)
    T = random_w2c(rng, 50, offset)
    M = C.blender_matrix_world(T)
    back = C.world_to_camera_from_blender(M)
    assert np.abs(back - T).max() <= 1e-9 * max(1.0, offset)
    # the camera centre is the Blender object's location, exactly
    assert np.abs(M[:, :3, 3] - C.camera_centers(T)).max() <= 1e-9 * max(1.0, offset)


def test_blender_camera_axes():
    """An OpenCV camera looking along +Y (x right = +X, y down = -Z) is Blender's camera rotated 90° about X."""
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    M = C.blender_matrix_world(T)
    assert np.allclose(M[:3, 2], [0, -1, 0])  # Blender camera looks down its -Z: -(-Y) = +Y forward
    assert np.allclose(M[:3, 1], [0, 0, 1])   # its +Y is up


def test_non_rigid_matrix_world_rejected():
    M = np.diag([2.0, 2.0, 2.0, 1.0])
    with pytest.raises(ValueError, match="not a rigid transform"):
        C.world_to_camera_from_blender(M)


@pytest.mark.parametrize("fit", ["HORIZONTAL", "VERTICAL", "AUTO"])
@pytest.mark.parametrize("W,H", [(518, 294), (294, 518), (1024, 576), (640, 640), (1, 1000)])
@pytest.mark.parametrize("aspect", [1.0, 1.1, 0.93])
def test_K_round_trip_exact(fit, W, H, aspect):
    rng = np.random.default_rng(W * 7 + H)
    fx = rng.uniform(100, 2000)
    K = np.array([[fx, 0, W / 2 + rng.uniform(-40, 40)], [0, fx / aspect, H / 2 + rng.uniform(-40, 40)], [0, 0, 1]])
    cam = C.blender_camera_from_K(K, W, H, sensor_fit=fit)
    assert cam.pixel_aspect_x >= 1.0 and cam.pixel_aspect_y >= 1.0
    K2 = C.K_from_blender_camera(cam)
    assert np.abs(K2 - K).max() <= 1e-9 * fx


def test_K_centred_has_no_shift():
    K = np.array([[400.0, 0, 259], [0, 400, 147], [0, 0, 1]])
    cam = C.blender_camera_from_K(K, 518, 294)
    assert cam.shift_x == 0 and cam.shift_y == 0
    assert cam.lens == pytest.approx(400 * 36 / 518)  # lens = fx · sensor_width / W


@pytest.mark.parametrize("bad", [
    [[0, 0, 1], [0, 1, 1], [0, 0, 1]],
    [[100, 5, 1], [0, 100, 1], [0, 0, 1]],
    [[100, 0, np.nan], [0, 100, 1], [0, 0, 1]],
])
def test_bad_K_rejected(bad):
    with pytest.raises(ValueError):
        C.blender_camera_from_K(np.array(bad, float), 100, 100)


def test_quaternion_round_trip_including_half_turns():
    rng = np.random.default_rng(2)
    Rs = [random_rotation(rng) for _ in range(200)]
    Rs += [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]), np.eye(3)]
    Rs = np.stack(Rs)
    q = C.rotation_to_quaternion(Rs)
    assert np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-15
    assert np.abs(C.quaternion_to_rotation(q) - Rs).max() < 1e-14


def test_continuous_quaternions():
    q = np.array([[1.0, 0, 0, 0], [-0.99, -0.1, 0, 0], [0.98, 0.2, 0, 0]])
    c = C.continuous_quaternions(q)
    assert np.all(np.sum(c[1:] * c[:-1], axis=1) > 0)


def test_project_behind_camera_has_negative_depth():
    K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])
    uv, z = C.project(K, np.eye(4), [[0, 0, 2.0], [0, 0, -2.0], [0, 0, 0.0]])
    assert z.tolist() == [2.0, -2.0, 0.0]
    assert np.allclose(uv[0], [50, 50])


# -- trajectories ------------------------------------------------------------------------------------------------

def test_heading_straight_and_curved():
    y = np.arange(20.0)
    straight = np.stack([np.zeros(20), y, np.full(20, 1.6)], 1)
    h = C.heading_directions(straight)
    assert np.allclose(h, [0, 1, 0])
    ang = np.linspace(0, np.pi / 2, 50)
    arc = np.stack([100 * np.cos(ang), 100 * np.sin(ang), np.zeros(50)], 1)
    h = C.heading_directions(arc, window_m=0.5)
    tangent = np.stack([-np.sin(ang), np.cos(ang), np.zeros(50)], 1)
    assert np.degrees(np.arccos(np.clip((h * tangent).sum(1), -1, 1))).max() < 2.0  # chord vs tangent at ends


def test_heading_stable_when_vehicle_stops():
    """Repeated positions (a stop, with 1 mm jitter) keep the heading of the motion around them."""
    rng = np.random.default_rng(0)
    before = np.stack([np.zeros(10), np.arange(10.0), np.zeros(10)], 1)
    stop = np.tile(before[-1], (30, 1)) + rng.normal(0, 1e-3, (30, 3)) * [1, 1, 0]
    after = before[-1] + np.stack([np.zeros(10), np.arange(1, 11.0), np.zeros(10)], 1)
    path = np.concatenate([before, stop, after])
    h = C.heading_directions(path, window_m=2.0)
    assert np.degrees(np.arccos(np.clip(h @ [0, 1, 0], -1, 1))).max() < 1.0


def test_heading_parked_uses_fallback_or_explains():
    path = np.tile([3.0, 4.0, 1.6], (5, 1))
    with pytest.raises(ValueError, match="does not move"):
        C.heading_directions(path)
    h = C.heading_directions(path, fallback=[0.0, 1.0, -0.2])
    assert np.allclose(h, [0, 1, 0])


def test_heading_far_from_origin():
    y = np.arange(10.0)
    path = np.stack([np.full(10, 1e5), 1e5 + y, np.zeros(10)], 1)
    assert np.allclose(C.heading_directions(path), [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_shift_trajectory_left_is_left_and_exact(offset):
    S = 12
    T = np.tile(np.eye(4), (S, 1, 1))
    T[:, :3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # looking along +Y
    centres = np.stack([np.full(S, offset), offset + np.arange(S) * 1.5, np.full(S, 1.6)], 1)
    T[:, :3, 3] = -np.einsum("nij,nj->ni", T[:, :3, :3], centres)
    out = C.shift_trajectory(T, left_m=2.0)
    d = C.camera_centers(out) - centres
    assert np.abs(d - [-2.0, 0, 0]).max() < 1e-9 * max(1, offset)  # driving along +Y, left is -X
    assert np.array_equal(out[:, :3, :3], T[:, :3, :3])
    right = C.shift_trajectory(T, left_m=-3.0, up_m=0.5)
    assert np.abs(C.camera_centers(right) - centres - [3.0, 0, 0.5]).max() < 1e-9 * max(1, offset)


# -- similarity fits ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_umeyama_recovers_similarity(offset):
    rng = np.random.default_rng(3)
    R = random_rotation(rng)
    s, t = 7.3, np.array([offset, -offset, 12.0])
    x = rng.standard_normal((100, 3))
    y = s * x @ R.T + t
    fit = C.umeyama(x, y)
    assert fit.scale == pytest.approx(s, rel=1e-12)
    assert np.abs(fit.rotation - R).max() < 1e-12
    assert np.abs(fit.apply(x) - y).max() < 1e-9
    assert fit.rms < 1e-9


def test_umeyama_collinear_is_a_clear_error():
    x = np.stack([np.arange(10.0), np.zeros(10), np.zeros(10)], 1)
    with pytest.raises(ValueError, match="collinear"):
        C.umeyama(x, 2 * x)


def test_umeyama_with_noise_reports_residual():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((500, 3)) * 10
    y = 2 * x + rng.normal(0, 0.01, x.shape)
    fit = C.umeyama(x, y)
    assert 0.005 < fit.rms < 0.03


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_fit_to_cameras_straight_drive(offset):
    """A straight drive is collinear, but camera orientations fix the roll: the fit is still exact."""
    rng = np.random.default_rng(5)
    S = 10
    src = np.tile(np.eye(4), (S, 1, 1))
    src[:, 2, 3] = -np.arange(S) * 0.1  # moving along its own +z, unit-less
    R = random_rotation(rng)
    M = C.similarity_matrix(3.5, R, [offset, 2.0, offset])
    dst = C.transform_world_to_camera(src, M)
    fit = C.fit_similarity_to_cameras(src, dst)
    assert np.abs(fit.matrix() - M).max() < 1e-9 * max(1, offset)
    assert fit.rms < 1e-9 * max(1, offset) and fit.rotation_rms_deg < 1e-6


def test_transform_world_to_camera_preserves_pixels():
    rng = np.random.default_rng(6)
    K = np.array([[300.0, 0, 200], [0, 300, 150], [0, 0, 1]])
    T = random_w2c(rng)
    X = C.camera_centers(T) + rng.uniform(-5, 5, (40, 3))
    uv, z = C.project(K, T, X)
    M = C.similarity_matrix(0.37, random_rotation(rng), [1e5, 3, -2])
    X2 = (0.37 * X) @ M[:3, :3].T / 0.37 + M[:3, 3]
    uv2, z2 = C.project(K, C.transform_world_to_camera(T, M), X2)
    assert np.abs(uv2 - uv)[z > 0].max() < 1e-6
    assert np.allclose(z2, 0.37 * z)


def test_decompose_similarity_rejects_shear():
    M = np.eye(4)
    M[0, 1] = 0.5
    with pytest.raises(ValueError):
        C.decompose_similarity(M)
