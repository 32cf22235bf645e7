"""KITTI export read back as the devkit reads it: labels' columns and conventions, calib, images, index."""

import json
import math
import os

import numpy as np
import pytest

from tests.backend.export import export_fixtures as F
from backend.export import common, kitti
from scpainter_blender.core.geometry import cameras


def _read_calib(path) -> dict:
    out = {}
    for line in open(path, encoding="utf-8"):
        key, _, values = line.partition(":")
        out[key] = np.array([float(v) for v in values.split()])
    return out


def _devkit_corners(h, w, l, loc, ry) -> np.ndarray:
    """The KITTI devkit's ``computeBox3D``: the box built from its bottom centre, rotated by ry about y."""
    x = [l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2]
    y = [0, 0, 0, 0, -h, -h, -h, -h]
    z = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
    R = np.array([[math.cos(ry), 0, math.sin(ry)], [0, 1, 0], [-math.sin(ry), 0, math.cos(ry)]])
    return (R @ np.array([x, y, z])).T + loc


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    return F.write_dataset(tmp_path_factory, kitti, "kitti")


def test_layout_images_and_index(exported):
    out, frames, counts = exported
    assert sorted(os.listdir(out)) == ["calib", "frames.json", "image_2", "label_2"]
    for sub, ext in (("image_2", ".png"), ("label_2", ".txt"), ("calib", ".txt")):
        assert sorted(os.listdir(out / sub)) == [f"00000{i}{ext}" for i in range(len(frames))]
    for i, fr in enumerate(frames):
        assert (out / "image_2" / f"00000{i}.png").read_bytes() == open(fr.image, "rb").read()
    index = json.loads((out / "frames.json").read_text())["frames"]
    assert [(e["index"], e["frame"]) for e in index] == [("000000", 4), ("000001", 5)]
    assert index[1]["timestamp_s"] == pytest.approx(0.1)
    assert counts == {"frames": 2, "objects": 6}


def test_label_columns_follow_the_devkit(exported):
    out, frames, _ = exported
    for i, fr in enumerate(frames):
        lines = (out / "label_2" / f"00000{i}.txt").read_text().splitlines()
        objs = [o for o in fr.labels["objects"] if o["visible_pixels"] > 0 and not o["removed"]]
        assert len(lines) == len(objs) == 3
        K = np.asarray(fr.labels["camera"]["K"])
        w2c = np.asarray(fr.labels["camera"]["world_to_camera"])
        P2 = _read_calib(out / "calib" / f"00000{i}.txt")["P2"].reshape(3, 4)
        for line, o in zip(lines, objs):
            v = line.split()
            assert len(v) == 15 and v[0] == {"car": "Car", "van": "Van"}[o["class"]]
            trunc, occ, alpha = float(v[1]), int(v[2]), float(v[3])
            box2d = np.array(v[4:8], float)
            h, w, l = map(float, v[8:11])
            loc = np.array(v[11:14], float)
            ry = float(v[14])
            assert trunc == pytest.approx(o["truncation"], abs=0.005) and occ == o["occlusion"]
            length, width, height = o["box_world"]["size"]
            assert (h, w, l) == pytest.approx((height, width, length), abs=0.005)   # h w l order
            # location: the bottom centre, in camera coordinates (x right, y down, z forward)
            bw = np.asarray(o["box_world"]["center"]) - [0.0, 0.0, height / 2]      # upright boxes: world z up
            assert loc == pytest.approx(w2c[:3, :3] @ bw + w2c[:3, 3], abs=0.006)
            assert ry == pytest.approx(o["box_camera"]["yaw"], abs=0.006)
            assert alpha == pytest.approx(kitti.alpha(ry, loc[0], loc[2]), abs=0.011)
            # the length axis points along (cos ry, 0, -sin ry): the object's forward axis in the camera
            fwd = w2c[:3, :3] @ cameras.quaternion_to_rotation(o["box_world"]["quaternion"])[:, 0]
            assert fwd == pytest.approx([math.cos(ry), 0.0, -math.sin(ry)], abs=0.006)
            # the devkit's box through P2 gives the 2D box (objects inside the image: no clipping)
            corners = _devkit_corners(h, w, l, loc, ry)
            uvw = (P2 @ np.hstack([corners, np.ones((8, 1))]).T).T
            uv = uvw[:, :2] / uvw[:, 2:]
            projected = np.array([*uv.min(0), *uv.max(0)]).clip(0, [F.W - 1, F.H - 1] * 2)
            if o["truncation"] == 0:
                assert box2d == pytest.approx(projected, abs=0.3), o["name"]
            ours = np.array(o["bbox_amodal"]) - 0.5
            assert box2d == pytest.approx(ours.clip(0, [F.W - 1, F.H - 1] * 2), abs=0.006)
            assert np.allclose(P2[:, :3], common.opencv_K(K)) and np.allclose(P2[:, 3], 0)


def test_alpha_is_the_angle_seen_from_the_camera():
    # straight ahead alpha = ry; to the right (x = z) alpha = ry - 45 deg; wrapped into [-pi, pi)
    assert kitti.alpha(0.3, 0.0, 10.0) == pytest.approx(0.3)
    assert kitti.alpha(0.3, 10.0, 10.0) == pytest.approx(0.3 - math.pi / 4)
    assert kitti.alpha(3.0, -10.0, 10.0) == pytest.approx(3.0 + math.pi / 4 - 2 * math.pi)


def test_calib_keys_and_shapes(exported):
    out, frames, _ = exported
    calib = _read_calib(out / "calib" / "000000.txt")
    assert list(calib) == ["P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo"]
    assert all(len(calib[f"P{i}"]) == 12 and np.array_equal(calib[f"P{i}"], calib["P2"]) for i in range(4))
    assert np.array_equal(calib["R0_rect"].reshape(3, 3), np.eye(3))
    for key in ("Tr_velo_to_cam", "Tr_imu_to_velo"):
        assert np.array_equal(calib[key].reshape(3, 4), np.hstack([np.eye(3), np.zeros((3, 1))]))
    text = (out / "calib" / "000000.txt").read_text().splitlines()[2]
    assert text.startswith("P2: 6.000000000000e+01 ")   # the devkit's %e layout


def test_removed_and_out_of_view_objects_are_left_out_hidden_ones_kept(tmp_path):
    """KITTI lists occluded objects (3D detectors expect them, marked occluded 2 or 3): an object wholly hidden but
    in view stays; a removed one, one out of view, one without a box go."""
    frames = F.export_frames(tmp_path)
    objs = frames[0].labels["objects"]
    objs[0]["removed"] = True
    objs[1]["visible_pixels"], objs[1]["occlusion"] = 0, 2
    out = tmp_path / "d"
    out.mkdir()
    kitti.write(str(out), frames[:1])
    lines = (out / "label_2" / "000000.txt").read_text().splitlines()
    assert [line.split()[0] for line in lines] == [objs[1]["class"].capitalize(), "Van"]
    assert lines[0].split()[2] == "2"
    objs[1]["in_view"], objs[2]["box_world"] = False, None
    again = tmp_path / "e"
    again.mkdir()
    kitti.write(str(again), frames[:1])
    assert (again / "label_2" / "000000.txt").read_text() == ""
