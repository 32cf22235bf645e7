"""KITTI export read back as the devkit reads it: labels' columns and conventions, calib, images, index; the level
frame at any camera tilt (8° pitch, 5° roll) reprojected through P2 as the devkit does; DontCare lines."""

import json
import math
import os

import numpy as np
import pytest

from tests.backend.export import export_fixtures as F
from backend.export import common, kitti, openlabel
from scpainter_blender.core import categories, errors, labels
from scpainter_blender.core.geometry import cameras


def _read_calib(path) -> dict:
    """A calib file as the readers parse it: ``key[:] v1 v2 …`` per line."""
    out = {}
    for line in open(path, encoding="utf-8"):
        key, *values = line.split()
        out[key.rstrip(":")] = np.array([float(v) for v in values])
    return out


def _devkit_corners(h, w, l, loc, ry) -> np.ndarray:
    """The KITTI devkit's ``computeBox3D``: the box built from its bottom centre, ``corners = R(ry) · box corners +
    location`` with R(ry) the rotation by ry about y."""
    x = [l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2]
    y = [0, 0, 0, 0, -h, -h, -h, -h]
    z = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
    R = np.array([[math.cos(ry), 0, math.sin(ry)], [0, 1, 0], [-math.sin(ry), 0, math.cos(ry)]])
    return (R @ np.array([x, y, z])).T + loc


def _devkit_box2d(P2, h, w, l, loc, ry) -> np.ndarray:
    """The devkit's ``projectToImage(corners, P2)``: P2 · [corners; 1], divided by the third row; their extent."""
    corners = _devkit_corners(h, w, l, loc, ry)
    uvw = P2 @ np.vstack([corners.T, np.ones(8)])
    uv = uvw[:2] / uvw[2]
    assert (uvw[2] > 0).all()           # fully in front of the camera
    return np.array([*uv.min(1), *uv.max(1)])


def _parse(line: str) -> dict:
    v = line.split()
    return {"type": v[0], "truncated": float(v[1]), "occluded": int(v[2]), "alpha": float(v[3]),
            "bbox": np.array(v[4:8], float), "hwl": np.array(v[8:11], float), "loc": np.array(v[11:14], float),
            "ry": float(v[14])}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    return F.write_dataset(tmp_path_factory, kitti, "kitti")


@pytest.fixture(scope="module")
def tilted(tmp_path_factory):
    """The fixture job seen by a camera pitched 8° down and rolled 5°, exported as KITTI and OpenLABEL."""
    tmp = tmp_path_factory.mktemp("tilted")
    frames = F.export_frames(tmp, [F.tilted_camera(0.1 * i) for i in range(len(F.FRAMES))])
    out = {}
    for name, module in (("kitti", kitti), ("openlabel", openlabel)):
        out[name] = tmp / name
        out[name].mkdir()
        module.write(str(out[name]), frames)
    return out, frames


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
    assert index[0]["unlabelled_fraction"] == frames[0].labels["unlabelled_fraction"] > 0
    assert counts == {"frames": 2, "objects": 6, "ignore_regions": 2}
    # per label line, in the line's order, what the devkit's columns cannot hold (issue 41: hole_fraction)
    for i, fr in enumerate(frames):
        lines = (out / "label_2" / f"00000{i}.txt").read_text().splitlines()
        extras = index[i]["lines"]
        assert len(extras) == len(lines)
        by_track = {o["track_id"]: o for o in fr.labels["objects"]}
        for line, extra in zip(lines, extras):
            if line.startswith("DontCare"):
                assert extra == {"track_id": extra["track_id"], "dontcare": "ignore"}
                assert by_track[extra["track_id"]]["ignore"]
            else:
                o = by_track[extra["track_id"]]
                assert line.split()[0] == labels_kitti_type(o) and extra["hole_fraction"] == o["hole_fraction"]
                assert set(extra) == set(labels.CARRIED_IDENTITY + labels.CARRIED_MEASURES)


def labels_kitti_type(o: dict) -> str:
    from scpainter_blender.core import categories

    return categories.category(o["class"]).kitti


def test_label_columns_follow_the_devkit(exported):
    out, frames, _ = exported
    for i, fr in enumerate(frames):
        lines = (out / "label_2" / f"00000{i}.txt").read_text().splitlines()
        objs = [o for o in fr.labels["objects"] if o["visible_pixels"] > 0 and not o["removed"] and not o["ignore"]]
        assert len(lines) == len(objs) + 1 == 4 and lines[-1].startswith("DontCare ")
        K = np.asarray(fr.labels["camera"]["K"])
        w2c = np.asarray(fr.labels["camera"]["world_to_camera"])
        P2 = _read_calib(out / "calib" / f"00000{i}.txt")["P2"].reshape(3, 4)
        for line, o in zip(lines, objs):
            v = _parse(line)
            assert len(line.split()) == 15 and v["type"] == categories.category(o["class"]).kitti
            assert v["type"] == {"car": "Car", "van": "Van"}[o["class"]]
            assert v["truncated"] == pytest.approx(o["truncation"], abs=0.005) and v["occluded"] == o["occlusion"]
            h, w, l = v["hwl"]
            length, width, height = o["box_world"]["size"]
            assert (h, w, l) == pytest.approx((height, width, length), abs=5e-5)   # h w l order
            # a level camera: the level frame is the camera's; location the bottom centre (x right, y down)
            bw = np.asarray(o["box_world"]["center"]) - [0.0, 0.0, height / 2]      # upright boxes: world z up
            assert v["loc"] == pytest.approx(w2c[:3, :3] @ bw + w2c[:3, 3], abs=5e-5)
            assert v["ry"] == pytest.approx(o["box_camera"]["yaw"], abs=5e-5)
            assert v["alpha"] == pytest.approx(kitti.alpha(v["ry"], v["loc"][0], v["loc"][2]), abs=1e-4)
            # the length axis points along (cos ry, 0, -sin ry): the object's forward axis in the camera
            fwd = w2c[:3, :3] @ cameras.quaternion_to_rotation(o["box_world"]["quaternion"])[:, 0]
            assert fwd == pytest.approx([math.cos(v["ry"]), 0.0, -math.sin(v["ry"])], abs=1e-4)
            projected = _devkit_box2d(P2, h, w, l, v["loc"], v["ry"]).clip(0, [F.W - 1, F.H - 1] * 2)
            if o["truncation"] == 0:
                assert v["bbox"] == pytest.approx(projected, abs=0.3), o["name"]
            ours = np.array(o["bbox_amodal"]) - 0.5
            assert v["bbox"] == pytest.approx(ours.clip(0, [F.W - 1, F.H - 1] * 2), abs=0.006)
            assert np.allclose(P2[:, :3], common.opencv_K(K)) and np.allclose(P2[:, 3], 0)


def test_tilted_camera_labels_are_level_and_reproject_through_P2(tilted):
    """At 8° pitch and 5° roll: every label's 8 corners through P2 (the devkit's computeBox3D/projectToImage)
    give its 2D box within 1 px, the boxes are upright in the level frame, and the KITTI bottom centre, mapped
    through the same camera, is OpenLABEL's cuboid centre within 1 mm."""
    out, frames = tilted
    doc = json.loads((out["openlabel"] / "openlabel.json").read_text())["openlabel"]
    checked = 0
    for i, fr in enumerate(frames):
        K = np.asarray(fr.labels["camera"]["K"])
        P2 = _read_calib(out["kitti"] / "calib" / f"00000{i}.txt")["P2"].reshape(3, 4)
        level_to_camera = np.linalg.solve(common.opencv_K(K), P2[:, :3])
        assert np.allclose(level_to_camera @ level_to_camera.T, np.eye(3), atol=1e-9)   # P2 = K [R | 0]
        w2c = np.asarray(fr.labels["camera"]["world_to_camera"])
        # the level frame's y axis is world down: the tilt lives in P2, not in the boxes
        assert w2c[:3, :3].T @ level_to_camera[:, 1] == pytest.approx([0, 0, -1], abs=1e-9)
        camera_to_odom = np.array(doc["frames"][str(i)]["frame_properties"]["transforms"]["camera_to_odom"][
            "transform_src_to_dst"]["matrix4x4"]).reshape(4, 4)
        lines = (out["kitti"] / "label_2" / f"00000{i}.txt").read_text().splitlines()
        shown = [o for o in fr.labels["objects"] if common.exported(o, hidden=True)]
        for line, o in zip(lines, shown):
            v = _parse(line)
            h, w, l = v["hwl"]
            assert o["truncation"] == 0
            assert np.abs(_devkit_box2d(P2, h, w, l, v["loc"], v["ry"]) - v["bbox"]).max() < 1.0, o["name"]
            centre_level = v["loc"] - [0.0, h / 2, 0.0]                     # up is −y in the level frame
            centre_world = camera_to_odom @ [*(level_to_camera @ centre_level), 1.0]
            cuboid = doc["frames"][str(i)]["objects"][str(o["track_id"])]["object_data"]["cuboid"][0]["val"]
            assert np.abs(centre_world[:3] - cuboid[:3]).max() < 1e-3, o["name"]
            checked += 1
    assert checked == 6


def test_ignore_regions_are_dontcare_lines(exported):
    out, frames, _ = exported
    for i, fr in enumerate(frames):
        (o,) = [o for o in fr.labels["objects"] if o["ignore"]]
        region = labels.ignore_region(o)
        assert region == o["bbox_visible"]
        x0, y0, x1, y1 = np.array(region) - 0.5
        (line,) = [line for line in (out / "label_2" / f"00000{i}.txt").read_text().splitlines()
                   if line.startswith("DontCare")]
        assert line == f"DontCare -1 -1 -10 {x0:.2f} {y0:.2f} {x1:.2f} {y1:.2f} -1 -1 -1 -1000 -1000 -1000 -10"


def test_alpha_is_the_angle_seen_from_the_camera():
    # straight ahead alpha = ry; to the right (x = z) alpha = ry - 45 deg; wrapped into [-pi, pi)
    assert kitti.alpha(0.3, 0.0, 10.0) == pytest.approx(0.3)
    assert kitti.alpha(0.3, 10.0, 10.0) == pytest.approx(0.3 - math.pi / 4)
    assert kitti.alpha(3.0, -10.0, 10.0) == pytest.approx(3.0 + math.pi / 4 - 2 * math.pi)


def test_level_rotation_keeps_the_heading():
    R = kitti.level_rotation(F.tilted_camera(0.0, 8.0, 5.0))
    c2w = np.linalg.inv(F.tilted_camera(0.0, 8.0, 5.0))[:3, :3]
    level_to_world = c2w @ R
    assert level_to_world == pytest.approx(np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]), abs=1e-12)
    assert kitti.level_rotation(F.world_to_camera()) == pytest.approx(np.eye(3), abs=1e-12)
    down = np.eye(4)                                           # looking straight down, image top towards +y
    down[:3, :3] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
    assert (np.linalg.inv(down)[:3, :3] @ kitti.level_rotation(down))[:, 2] == pytest.approx([0, 1, 0])


def test_calib_keys_and_shapes(exported):
    out, frames, _ = exported
    calib = _read_calib(out / "calib" / "000000.txt")
    assert list(calib) == ["P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo"]
    assert all(len(calib[f"P{i}"]) == 12 and np.array_equal(calib[f"P{i}"], calib["P2"]) for i in range(4))
    assert np.array_equal(calib["R0_rect"].reshape(3, 3), np.eye(3))
    for key in ("Tr_velo_to_cam", "Tr_imu_to_velo"):
        assert np.array_equal(calib[key].reshape(3, 4), np.hstack([np.eye(3), np.zeros((3, 1))]))
    text = (out / "calib" / "000000.txt").read_text().splitlines()
    assert text[2].startswith("P2: 6.000000000000e+01 ")   # the devkit's %e layout; P2 on line 2 (OpenPCDet)
    assert [t.split()[0] for t in text[4:6]] == ["R0_rect:", "Tr_velo_to_cam:"]


def test_removed_out_of_view_and_unknown_objects(tmp_path):
    """KITTI lists occluded objects (3D detectors expect them, marked occluded 2 or 3): an object wholly hidden but
    in view stays; a removed one, one out of view, one without a box go; a class the table lacks is an error
    naming it."""
    frames = F.export_frames(tmp_path)
    objs = frames[0].labels["objects"]
    objs[0]["removed"] = True
    objs[1]["visible_pixels"], objs[1]["occlusion"] = 0, 2
    out = tmp_path / "d"
    out.mkdir()
    kitti.write(str(out), frames[:1])
    lines = (out / "label_2" / "000000.txt").read_text().splitlines()
    assert [line.split()[0] for line in lines] == ["Car", "Van", "DontCare"]
    assert lines[0].split()[2] == "2"
    objs[1]["in_view"], objs[2]["box_world"], objs[3]["in_view"] = False, None, False
    again = tmp_path / "e"
    again.mkdir()
    kitti.write(str(again), frames[:1])
    assert (again / "label_2" / "000000.txt").read_text() == ""
    objs[1]["in_view"], objs[1]["class"] = True, "hovercraft"
    (tmp_path / "f").mkdir()
    with pytest.raises(errors.InputError) as e:
        kitti.write(str(tmp_path / "f"), frames[:1])
    assert e.value.field == "objects[1].class" and "hovercraft" in e.value.message and "car" in e.value.message


def test_a_rig_cameras_lidar_is_velodyne_points_and_tr_velo_to_cam(tmp_path):
    """A camera of a rig with a LiDAR (``ExportFrame.sweep``): the LiDAR mounted 0.3 m above the level camera and
    turned so its own forward is 90° left of the camera's heading; the sweep holds each labelled box's centre.
    OpenPCDet's ``calibration_kitti`` (``lidar_to_rect``, ``rect_to_img``: exact for this level camera) puts each
    at its label's centre and pixel; the velodyne frame's x is the camera's heading (KITTI's axes: Tr_velo_to_cam's
    rotation is KITTI's x forward, y left, z up into the camera's x right, y down, z forward)."""
    frames = F.export_frames(tmp_path)
    sensor_axes = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])   # columns: its x right, y forward, z up in world
    for i, fr in enumerate(frames):
        lidar_to_world = np.eye(4)
        lidar_to_world[:3, :3] = sensor_axes
        lidar_to_world[:3, 3] = np.asarray(fr.labels["camera"]["camera_to_world"])[:3, 3] + [0.0, 0.0, 0.3]
        centres = np.array([o["box_world"]["center"] for o in fr.labels["objects"] if o["box_world"]])
        in_sensor = (centres - lidar_to_world[:3, 3]) @ sensor_axes
        rows = np.column_stack([in_sensor, np.full(len(centres), 51.0), np.full(len(centres), 3.0)])
        path = tmp_path / f"sweep_{i}.pcd.bin"
        path.write_bytes(rows.astype("<f4").tobytes())
        fr.sweep = common.ExportSweep(str(path), lidar_to_world)
    out = tmp_path / "kitti"
    out.mkdir()
    kitti.write(str(out), frames)
    canonical = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    for i, fr in enumerate(frames):
        velo = np.fromfile(out / "velodyne" / f"{i:06d}.bin", "<f4").reshape(-1, 4)
        assert np.allclose(velo[:, 3], 0.2) and (velo[:, 0] > 0).all()     # reflectance 51/255; all ahead
        calib = _read_calib(out / "calib" / f"{i:06d}.txt")
        V2C, R0, P2 = calib["Tr_velo_to_cam"].reshape(3, 4), calib["R0_rect"].reshape(3, 3), calib["P2"].reshape(3, 4)
        assert np.allclose(V2C[:, :3], canonical, atol=1e-12)
        assert np.allclose(V2C[:, 3], [0.0, -0.3, 0.0], atol=1e-12)        # the LiDAR 0.3 m above the camera
        hom = np.hstack([velo[:, :3], np.ones((len(velo), 1))])
        rect = hom @ (V2C.T @ R0.T)                                           # OpenPCDet lidar_to_rect
        img = ((np.hstack([rect, np.ones((len(rect), 1))]) @ P2.T)[:, :2].T / rect[:, 2]).T   # its rect_to_img
        lines = [_parse(x) for x in open(out / "label_2" / f"{i:06d}.txt") if not x.startswith("DontCare")]
        assert lines
        for lab in lines:
            h = lab["hwl"][0]
            centre = lab["loc"] - [0.0, h / 2, 0.0]                           # the bottom centre, up half the height
            k = int(np.argmin(np.linalg.norm(rect - centre, axis=1)))
            assert np.linalg.norm(rect[k] - centre) < 1e-3                    # 4 decimals, float32 points
            pixel = common.opencv_K(fr.labels["camera"]["K"]) @ centre
            assert np.allclose(img[k], pixel[:2] / pixel[2], atol=1e-3)
    assert sorted(os.listdir(out / "velodyne")) == ["000000.bin", "000001.bin"]
