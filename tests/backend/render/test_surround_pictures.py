"""backend/render/surround_pictures.py: nuScenes' tile layout, the bird's-eye view's axes (forward up, left left)."""

import numpy as np

from backend.render import surround_pictures as S
from scpainter_blender.core import rig as R


def test_nuscenes_cameras_tile_as_the_devkit_shows_them_and_others_in_rig_order():
    assert S.tile_rows(list(R.NUSCENES_CAMERAS)) == [["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"],
                                                    ["CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT"]]
    assert S.tile_rows(["A", "B", "C", "D"]) == [["A", "B", "C"], ["D"]]


def test_bird_eye_puts_forward_up_and_left_left():
    size, rng = 200, 20.0
    ahead = {"box_world": {"center": [10.0, 0, 0.8], "size": [4.0, 2.0, 1.6], "quaternion": [1, 0, 0, 0]},
             "class": "car", "track_id": 1, "synthetic": True, "ignore": False, "points_missing": False}
    left = {"box_world": {"center": [0.0, 10.0, 0.8], "size": [4.0, 2.0, 1.6], "quaternion": [1, 0, 0, 0]},
            "class": "car", "track_id": 2, "synthetic": False, "ignore": False, "points_missing": False}
    img = S.bird_eye(np.array([[0.0, -10.0, 0.0]]), [ahead, left], np.eye(4), size=size, range_m=rng)
    assert img.shape == (size, size, 3)
    s = size / (2 * rng)
    lit = img.max(axis=2) > 100

    def any_lit(row, col, r=3):
        return lit[int(row) - r:int(row) + r + 1, int(col) - r:int(col) + r + 1].any()

    # the car ahead: its front edge 12 m ahead is above the centre; the car to the left: left of the centre
    assert any_lit(size / 2 - 12 * s, size / 2)
    assert any_lit(size / 2 - 2 * s, size / 2 - 10 * s + 1 * s)
    # the return 10 m to the right (y = -10): right of the centre
    assert lit[size // 2, int(size / 2 + 10 * s)]
