"""KITTI tracking export read back as the tracking devkit lays it out: one sequence, label lines with frame and
track ids (DontCare −1), one calibration carrying the tilt, per-frame poses of the label frame."""

import json
import os

import numpy as np
import pytest

from tests.backend.export import export_fixtures as F
from tests.backend.export.test_kitti import _devkit_box2d, _parse, _read_calib
from backend.export import common, kitti, kitti_tracking


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The fixture job seen by a camera pitched 8° down and rolled 5° that moves 0.1 m a frame."""
    tmp = tmp_path_factory.mktemp("tracking")
    frames = F.export_frames(tmp, [F.tilted_camera(0.1 * i) for i in range(len(F.FRAMES))])
    out = tmp / "dataset"
    out.mkdir()
    return out, frames, kitti_tracking.write(str(out), frames)


def test_layout_and_index(exported):
    out, frames, counts = exported
    assert sorted(os.listdir(out)) == ["calib", "frames.json", "image_02", "label_02", "pose"]
    assert sorted(os.listdir(out / "image_02" / "0000")) == ["000000.png", "000001.png"]
    for sub in ("label_02", "calib", "pose"):
        assert os.listdir(out / sub) == ["0000.txt"]
    for i, fr in enumerate(frames):
        assert (out / "image_02" / "0000" / f"00000{i}.png").read_bytes() == open(fr.image, "rb").read()
    index = json.loads((out / "frames.json").read_text())
    assert index["sequence"] == "0000"
    assert [(e["index"], e["frame"], e["tilt_change_deg"]) for e in index["frames"]] == [(0, 4, 0.0), (1, 5, 0.0)]
    assert counts == {"frames": 2, "objects": 6, "ignore_regions": 2}


def test_lines_carry_frame_and_track_ids_and_reproject_through_the_one_P2(exported):
    out, frames, _ = exported
    calib = _read_calib(out / "calib" / "0000.txt")
    assert list(calib) == ["P0", "P1", "P2", "P3", "R_rect", "Tr_velo_cam", "Tr_imu_velo"]
    text = (out / "calib" / "0000.txt").read_text().splitlines()
    assert text[4].startswith("R_rect 1.0") and text[2].startswith("P2: ")
    P2 = calib["P2"].reshape(3, 4)
    level_to_camera = np.linalg.solve(common.opencv_K(F.K), P2[:, :3])
    poses = np.loadtxt(out / "pose" / "0000.txt").reshape(-1, 3, 4)
    assert poses.shape == (2, 3, 4)
    lines = [line.split(" ", 2) for line in (out / "label_02" / "0000.txt").read_text().splitlines()]
    assert [int(f) for f, _, _ in lines] == sorted(int(f) for f, _, _ in lines)      # sorted by frame
    for i, fr in enumerate(frames):
        mine = [(int(t), rest) for f, t, rest in lines if int(f) == i]
        labelled = [o for o in fr.labels["objects"] if common.exported(o, hidden=True)]
        ignored = [o for o in fr.labels["objects"] if o["ignore"]]
        assert [t for t, _ in mine] == [o["track_id"] for o in labelled] + [-1] * len(ignored)
        assert [rest for _, rest in mine] == [c for _, c in kitti.frame_lines(fr.labels, level_to_camera)]
        for (_, rest), o in zip(mine, labelled):
            v = _parse(rest)
            h, w, l = v["hwl"]
            assert np.abs(_devkit_box2d(P2, h, w, l, v["loc"], v["ry"]) - v["bbox"]).max() < 1.0, o["name"]
            centre = poses[i] @ [*(v["loc"] - [0.0, h / 2, 0.0]), 1.0]          # label frame -> world
            assert np.abs(centre - o["box_world"]["center"]).max() < 1e-3, o["name"]
        assert mine[-1][1].startswith("DontCare -1 -1 -10 ")


def test_a_camera_that_changes_its_tilt_is_reported(tmp_path):
    frames = F.export_frames(tmp_path, [F.tilted_camera(0.0, 8.0, 5.0), F.tilted_camera(0.1, 10.0, 5.0)])
    out = tmp_path / "d"
    out.mkdir()
    kitti_tracking.write(str(out), frames)
    index = json.loads((out / "frames.json").read_text())["frames"]
    assert index[0]["tilt_change_deg"] == 0.0 and index[1]["tilt_change_deg"] == pytest.approx(2.0, abs=1e-6)
