"""core.geometry.boxes: the upright box of an object's points, placing, describing and projecting boxes."""

import numpy as np
import pytest

from scpainter_blender.core import shapes
from scpainter_blender.core.geometry import boxes, cameras


def _rot_z(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])


def _box_surface(size, n=20000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.5, 0.5, (n, 3))
    face = rng.integers(0, 3, n)
    p[np.arange(n), face] = np.sign(p[np.arange(n), face]) * 0.5
    return p * size


@pytest.mark.parametrize("yaw", [0.0, 17.0, 33.0, 90.0, 151.0, -120.0])
def test_estimate_recovers_a_box_at_any_heading(yaw):
    size = np.array([1.9, 4.5, 1.5])
    R, t = _rot_z(yaw), np.array([1e5, -3e4, 0.75])     # far from the origin: relative arithmetic keeps it exact
    P = _box_surface(size) @ R.T + t
    T, got = boxes.estimate_box(P)
    assert np.allclose(got, size, atol=2e-3)
    assert np.allclose(T[:3, 3], t, atol=2e-3)
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12) and np.linalg.det(T[:3, :3]) > 0
    length_axis = R[:, 1]
    assert abs(abs(T[:3, 1] @ length_axis) - 1) < 1 - np.cos(np.radians(0.05))
    assert T[:3, 1] @ [0, 1, 0] >= -1e-9 or abs(T[:3, 1] @ [0, 1, 0]) < 1e-9   # the front: towards the frame's +y


def test_floaters_are_left_out():
    size = np.array([1.8, 4.4, 1.6])
    P = _box_surface(size, 30000)
    rng = np.random.default_rng(1)
    floaters = rng.uniform(-1, 1, (60, 3)) * [8, 8, 4] + [0, 0, 6]       # a cloud far above, and a few far out
    T, got = boxes.estimate_box(np.vstack([P, floaters, [[30.0, 0, 0], [np.nan, 0, 0]]]))
    assert np.allclose(got, size, atol=5e-3) and np.allclose(T[:3, 3], 0, atol=5e-3)


def test_procedural_car_box_within_5_cm():
    g = shapes.procedural_car_gaussians(count=20000, seed=3)
    T, size = boxes.estimate_box(g.means)
    # the car: chassis 1.8 x 4.4, wheels sticking out 2 cm a side, 1.58 m high, on z = 0, front +y
    assert np.allclose(size, [1.84, 4.4, 1.58], atol=0.05)
    assert np.allclose(T[:3, 3], [0, 0, 0.79], atol=0.05)
    assert T[1, 1] > 0.9998


def test_up_axis_of_a_trellis_file():
    size = np.array([1.9, 4.5, 1.5])
    P = _box_surface(size) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]]).T   # TRELLIS's file axes (x, -z, y)
    T, got = boxes.estimate_box(P, up=(0, -1, 0))
    assert np.allclose(got, size, atol=2e-3) and np.allclose(T[:3, 2], [0, -1, 0])
    assert np.allclose(T[:3, 1], [0, 0, 1])     # the front: the file's +z, where TRELLIS's +y (front) goes


def test_too_few_points():
    with pytest.raises(ValueError, match="at least 4"):
        boxes.estimate_box(np.array([[0, 0, 0], [1, 1, 1], [np.nan, 0, 0.0]]))


def test_place_box_through_a_similarity_and_a_stretch():
    box = np.eye(4)
    box[:3, 3] = [0.1, 0.2, 0.3]
    S = np.diag([2.0, 2.0, 2.0, 1.0])
    S[:3, :3] = 2.0 * _rot_z(30)
    S[:3, 3] = [5, 6, 7]
    T, size = boxes.place_box(box, [1, 2, 3], S)
    assert np.allclose(size, [2, 4, 6]) and np.allclose(T[:3, :3], _rot_z(30))
    assert np.allclose(T[:3, 3], S[:3, :3] @ [0.1, 0.2, 0.3] + [5, 6, 7])
    T, size = boxes.place_box(np.eye(4), [1, 1, 1], np.diag([1.0, 3.0, 0.5, 1.0]))   # non-uniform: exact too
    assert np.allclose(size, [1, 3, 0.5]) and np.allclose(T, np.eye(4))
    T, size = boxes.rigid_box(np.diag([2.0, 4.0, 1.5, 1.0]))
    assert np.allclose(size, [2, 4, 1.5])


def test_object_pose_conventions():
    T = np.eye(4)
    T[:3, :3] = _rot_z(-90)                    # the box's +y (front) turned to world +x
    T[:3, 3] = [1, 2, 3]
    pose = boxes.object_pose(T, [1.9, 4.5, 1.5])
    assert np.allclose(pose["size"], [4.5, 1.9, 1.5])
    assert abs(pose["yaw"]) < 1e-12           # forward along world +x: yaw 0
    assert np.allclose(pose["rotation"], np.eye(3)) and np.allclose(pose["quaternion"], [1, 0, 0, 0])
    pose = boxes.object_pose(np.eye(4), [1.9, 4.5, 1.5])
    assert np.isclose(pose["yaw"], np.pi / 2)
    assert np.allclose(cameras.quaternion_to_rotation(pose["quaternion"]), pose["rotation"])


def test_rotation_y_follows_kitti():
    # a car ahead driving to the camera's right (+x): ry = 0; towards the camera (-z): ry = pi/2
    assert abs(boxes.rotation_y(np.eye(3))) < 1e-12
    R = np.array([[0, 1, 0], [0, 0, -1], [-1, 0, 0.0]])    # object x (forward) -> camera -z
    assert np.isclose(boxes.rotation_y(R), np.pi / 2)


K = np.array([[100.0, 0, 80], [0, 100.0, 48], [0, 0, 1]])


def _camera_looking_along_y(centre):
    w2c = np.eye(4)
    w2c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    w2c[:3, 3] = -w2c[:3, :3] @ np.asarray(centre, np.float64)
    return w2c


def test_project_box_inside_cut_and_behind():
    w2c = _camera_looking_along_y([0, 0, 1.5])
    T = np.eye(4)
    T[:3, 3] = [0, 12, 0.8]
    p = boxes.project_box(T, [1.8, 4.4, 1.6], K, w2c, 160, 96)
    uv = cameras.project(K, w2c, boxes.corners(T, [1.8, 4.4, 1.6]))[0]
    assert np.allclose(p["bbox"], [uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
    assert p["truncation"] == 0.0
    T[:3, 3] = [9.0, 12, 0.8]                   # across the right border
    p = boxes.project_box(T, [1.8, 4.4, 1.6], K, w2c, 160, 96)
    assert p["bbox"][2] == 160 and 0.1 < p["truncation"] < 0.9
    T[:3, 3] = [0, -10, 0.8]                    # behind the camera
    p = boxes.project_box(T, [1.8, 4.4, 1.6], K, w2c, 160, 96)
    assert p["bbox"] is None and p["truncation"] == 1.0 and len(p["polygon"]) == 0
    T[:3, 3] = [0, 1.0, 1.5]                    # around the camera: cut at the near plane, fills the image
    p = boxes.project_box(T, [1.8, 4.4, 1.6], K, w2c, 160, 96)
    assert p["bbox"] == [0.0, 0.0, 160.0, 96.0] and p["truncation"] > 0.5
    assert boxes.contains(T, [1.8, 4.4, 1.6], [0, 0, 1.5])


def _random_boxes(n, seed):
    """(box_to_world (n, 4, 4), size (n, 3)): boxes all round a camera at the origin looking along +y, some
    behind it, some cut by its near plane, some off the image, some inside it, at any heading."""
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = cameras.quaternion_to_rotation(rng.normal(size=(n, 4)))
    T[:, :3, 3] = rng.normal(size=(n, 3)) * [15.0, 15.0, 3.0]
    T[: n // 8, :3, 3] = rng.normal(size=(n // 8, 3)) * 0.5          # around the camera
    return T, rng.uniform(0.5, 6.0, size=(n, 3))


def test_project_boxes_is_project_box_at_once():
    T, size = _random_boxes(400, 3)
    w2c = _camera_looking_along_y([0, 0, 0])
    kinds = set()
    for p, t, s in zip(boxes.project_boxes(T, size, K, w2c, 160, 96), T, size):
        q = boxes.project_box(t, s, K, w2c, 160, 96)
        kinds.add((q["bbox"] is None, q["depth_range"] is None))
        assert p["bbox"] == q["bbox"] and p["truncation"] == q["truncation"]
        assert p["depth_range"] == q["depth_range"]
        # bit for bit the same hull, but off the image one may be left out (then it was finite: labels test that)
        if not (q["bbox"] is None and len(p["polygon"]) == 0 and np.isfinite(q["polygon"]).all()):
            assert p["polygon"].shape == q["polygon"].shape and p["polygon"].tobytes() == q["polygon"].tobytes()
    assert kinds == {(False, False), (True, False), (True, True)}   # in view, off the image, behind
    z = (boxes.corners(T, size) @ w2c[:3, :3].T + w2c[:3, 3])[..., 2]
    assert ((z < 0.05).any(1) & (z >= 0.05).any(1)).sum() > 10         # and cut by the near plane


def test_object_pose_and_corners_of_many_boxes_are_each_boxs():
    T, size = _random_boxes(50, 4)
    many = boxes.object_pose(T, size)
    assert many["yaw"].shape == (50,) and many["quaternion"].shape == (50, 4)
    for n, (t, s) in enumerate(zip(T, size)):
        one = boxes.object_pose(t, s)
        assert isinstance(one["yaw"], float) and one["yaw"] == many["yaw"][n]
        for key in ("center", "size", "rotation", "quaternion"):
            assert one[key].tobytes() == many[key][n].tobytes(), key
        assert boxes.corners(t, s).tobytes() == boxes.corners(T, size)[n].tobytes()


def test_polygon_mask_counts_pixel_centres():
    square = np.array([[2.0, 2.0], [6.0, 2.0], [6.0, 5.0], [2.0, 5.0]])
    m = boxes.polygon_mask(square, 10, 8)
    assert m.sum() == 12 and m[2:5, 2:6].all()
    assert boxes.polygon_mask(square[::-1], 10, 8).sum() == 12     # either winding
    assert boxes.polygon_mask(square + 100, 10, 8).sum() == 0
