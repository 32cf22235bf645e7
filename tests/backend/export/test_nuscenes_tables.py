"""The nuScenes tables' own rules (backend/export/nuscenes_tables.py): keyframes, visibility bins, attributes, the
devkit's point-in-box rule, the map raster's frame, a keyframe without its sweep."""

import os

import numpy as np
import pytest

from backend.export import nuscenes_tables as T
from scpainter_blender.core import categories, errors
from tests.backend.export import rig_fixtures as R


def test_visibility_bins_and_attributes_follow_nuscenes():
    assert [T.visibility_token(v, 100) for v in (0, 40, 41, 60, 79, 100)] == ["1", "1", "2", "2", "3", "4"]
    assert T.visibility_token(0, 0) == "1"
    assert T.attributes("vehicle.car", "car", 0.2, True) == ["vehicle.stopped"]
    assert T.attributes("vehicle.bicycle", "cyclist", 0.0, False) == ["cycle.with_rider"]
    assert T.attributes("human.pedestrian.adult", "pedestrian", 1.4, False) == ["pedestrian.moving"]
    assert T.attributes("movable_object.barrier", "barrier", None, False) == []
    assert T.keyframes([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 2.0) == [0, 5]
    assert T.keyframes([0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2], 2.0) == [0, 3, 6]   # a job of every 2nd frame
    assert {c.nuscenes for c in categories.CATEGORIES} <= {n for n, _ in categories.NUSCENES_CATEGORIES}


def test_points_in_boxes_is_the_devkits_rule():
    pytest.importorskip("nuscenes")
    from nuscenes.utils.data_classes import Box
    from nuscenes.utils.geometry_utils import points_in_box
    from pyquaternion import Quaternion

    rng = np.random.default_rng(3)
    pts = rng.uniform(-4.0, 4.0, (5000, 3)) + [10.0, 20.0, 1.0]
    q = [np.cos(0.35), 0.0, 0.0, np.sin(0.35)]                     # 40° about z
    centre, wlh = [10.5, 19.5, 0.8], [1.9, 4.5, 1.6]
    ours = T.points_in_boxes(pts, [centre], [wlh], [q])[0]
    assert ours == points_in_box(Box(centre, wlh, Quaternion(q)), pts.T).sum() > 100


def test_the_map_holds_the_ego_path_with_its_margin():
    path = np.array([[T.MAP_MARGIN_M, T.MAP_MARGIN_M], [T.MAP_MARGIN_M + 10.0, T.MAP_MARGIN_M + 2.0]])
    raster = T.map_raster(path)
    H, W = raster.shape
    assert (W, H) == (int(np.ceil((2 * T.MAP_MARGIN_M + 10) / T.MAP_RESOLUTION_M)),
                      int(np.ceil((2 * T.MAP_MARGIN_M + 2) / T.MAP_RESOLUTION_M)))
    for x, y in path:      # the devkit's MapMask: column x / res, row H - y / res
        assert raster[int(H - y / T.MAP_RESOLUTION_M), int(x / T.MAP_RESOLUTION_M)] == 255
    assert raster[0, 0] == 0 and 0 < raster.mean() / 255 < 0.01


def test_a_keyframe_without_its_sweep_names_the_file(tmp_path):
    clip = R.clip(R.build(str(tmp_path / "rig")))
    os.remove(clip.sweeps[5])
    with pytest.raises(errors.InputError) as e:
        T.Tables().add(clip)
    assert e.value.path == clip.sweeps[5] and "LIDAR_TOP" in e.value.message and "keyframe 15" in e.value.message
    clip = R.clip(R.build(str(tmp_path / "rig2")))
    os.remove(clip.sweeps[2])                          # a sweep between keyframes: that frame has no LIDAR_TOP data
    tables = T.Tables()
    tables.add(clip)
    lidar = [sd for sd in tables.records["sample_data"] if "LIDAR_TOP" in sd["filename"]]
    assert len(lidar) == 5 and all(a["next"] == b["token"] for a, b in zip(lidar, lidar[1:]))
    with open(clip.sweeps[0], "ab") as f:              # a torn file: not rows of five float32
        f.write(b"\0\0\0")
    with pytest.raises(errors.InputError) as e:
        T.Tables().add(clip)
    assert e.value.path == clip.sweeps[0] and "float32" in e.value.message
    os.remove(clip.sweeps[0])
    os.mkfifo(clip.sweeps[0])                          # a FIFO planted there: refused at once, never waited on
    with pytest.raises(errors.InputError) as e:
        T.Tables().add(clip)                          # not a sweep file: missing (the reader refuses it too)
    assert e.value.path == clip.sweeps[0] and "missing" in e.value.message


def _annotated(clip, frame_index: int = 0) -> set:
    tables = T.Tables(R.FPS)          # every frame a keyframe
    tables.add(clip)
    sample = tables.records["sample"][frame_index]["token"]
    return {a["track_id"] for a in tables.records["sample_annotation"] if a["sample_token"] == sample}


def test_a_car_one_camera_labels_is_kept_when_another_sees_a_sliver_of_it_points_missing(tmp_path):
    """The rule: annotated when any camera labels it normally; ``points_missing`` drops it only when every camera
    that sees it says so; ``ignore`` (the object's own) drops it whatever the other cameras say."""
    clip = R.clip(R.build(str(tmp_path / "rig")))
    van = next(o["track_id"] for o in clip.cameras[0].labels[0]["objects"] if o["name"] == "rec_van")
    assert van in _annotated(clip)
    seeing = [c for c in clip.cameras if next(o for o in c.labels[0]["objects"] if o["track_id"] == van)["in_view"]]
    other = next(c for c in clip.cameras if c not in seeing)   # a camera that sees no more than a sliver of it
    assert seeing
    sliver = next(o for o in other.labels[0]["objects"] if o["track_id"] == van)
    sliver.update(in_view=True, points_missing=True, visible_fraction=0.0)
    assert van in _annotated(clip)                             # before: dropped for the sliver
    for cam in seeing:                                         # every camera that sees it: its points are cut
        next(o for o in cam.labels[0]["objects"] if o["track_id"] == van)["points_missing"] = True
    assert van not in _annotated(clip)
    for cam in seeing:
        o = next(o for o in cam.labels[0]["objects"] if o["track_id"] == van)
        o["points_missing"] = False
    sliver.update(points_missing=False, ignore=True)           # ignore is the object's: one camera's word is enough
    assert van not in _annotated(clip)


def test_channels_other_than_nuscenes_six_cameras_are_warned(tmp_path, capsys):
    import json

    from backend.export import nuscenes

    clip = R.clip(R.build(str(tmp_path / "rig")))
    nuscenes.warn(clip, 2.0)                       # the six cameras and LIDAR_TOP: no word
    assert nuscenes.NOT_SIX_CAMERAS not in capsys.readouterr().out
    clip.cameras[1].name = "CAM_FRNOT_RIGHT"       # a typo
    clip.lidar = None                              # as the front preset, one camera: no LIDAR_TOP either
    nuscenes.warn(clip, 2.0)
    ev = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    said = next(e for e in ev if e.get("code") == nuscenes.NOT_SIX_CAMERAS)
    assert said["missing"] == ["CAM_FRONT_RIGHT"] and said["unknown"] == ["CAM_FRNOT_RIGHT"], said
    assert "CAM_FRNOT_RIGHT" in said["message"] and "KeyError" in said["message"]
    clip.cameras = [c for c in clip.cameras if c.name == "CAM_FRONT"]
    nuscenes.warn(clip, 2.0)
    said = next(json.loads(line) for line in capsys.readouterr().out.splitlines()
                if json.loads(line).get("code") == nuscenes.NOT_SIX_CAMERAS)
    assert len(said["missing"]) == 5 and said["unknown"] == []
