"""backend.mesh.box: the upright oriented box (stage-1 size, yaw only) and the 3D box, degenerate footprints."""

import numpy as np
import pytest
import trimesh

from backend.mesh import box as mesh_box


@pytest.mark.parametrize("yaw", [0.0, 30.0, -55.0, 90.0, 12.5])
def test_upright_box_of_a_rotated_car(yaw):
    L, W, H = 4.5, 1.9, 1.5
    box = trimesh.creation.box((W, L, H))                  # length along local +Y, as the project's boxes
    T = trimesh.transformations.rotation_matrix(np.radians(yaw), (0, 0, 1))
    T[:3, 3] = (10.0, -3.0, H / 2)
    box.apply_transform(T)
    ob = mesh_box.upright_box(box.vertices)
    np.testing.assert_allclose(ob["size"], [L, W, H], atol=1e-6)
    assert ob["yaw_deg"] == pytest.approx(yaw, abs=1e-6)
    np.testing.assert_allclose(ob["center"], [10.0, -3.0, H / 2], atol=1e-6)
    np.testing.assert_allclose(mesh_box.oriented_box_3d(box.vertices), [L, W, H], atol=1e-4)
    if yaw in (30.0, -55.0):   # the axis-aligned box is wrong by far more than the 20 % stage-1 tolerance
        aabb = np.array(ob["aabb_size"])
        assert np.abs(aabb[1] / W - 1) > 0.2


def test_upright_box_of_degenerate_footprints():
    line = np.array([[0, 0, 0], [1, 1, 0], [2, 2, 1]], float)
    ob = mesh_box.upright_box(line)
    assert ob["size"][0] == pytest.approx(2 * np.sqrt(2)) and ob["size"][1] == pytest.approx(0, abs=1e-9)
    assert ob["yaw_deg"] == pytest.approx(-45.0)
    assert mesh_box.upright_box([[1, 2, 3]])["size"] == [0.0, 0.0, 0.0]
