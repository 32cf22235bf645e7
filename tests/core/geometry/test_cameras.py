"""core.geometry.cameras: conventions, exact round trips (also 1e5 m from the origin), intrinsics <-> Blender cameras."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from tests.core.geometry.camera_fixtures import random_rotation, random_w2c


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


def test_rigid_problem_names_the_first_bad_matrix():
    T = np.tile(np.eye(4), (4, 1, 1))
    assert C.rigid_problem(T) is None
    T[2, :3, :3] *= 2.0
    T[3, :3, :3] = np.diag([1.0, 1.0, -1.0])  # a reflection
    assert C.rigid_problem(T) == (2, "frame 2 is not a rotation + translation (|R^T R - I| = 3.00e+00)")
    T[2] = np.eye(4)
    assert C.rigid_problem(T, name="pose", what="pose")[1].startswith("pose 3 is not a rotation")
    T[3] = np.eye(4)
    T[1, 3, 0] = 0.5
    assert C.rigid_problem(T, name="pose", what="pose") == (1, "the last row of a 4x4 pose must be [0, 0, 0, 1] "
                                                               "(pose 1)")
