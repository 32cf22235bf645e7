"""Clip folders: the street exported as a clip, and the errors bad clips give."""

import json
import os
import shutil

import numpy as np
import pytest

from backend.train import clip as clip_mod
from scpainter_blender.core.job import JobError  # ClipError is one; the shared validators raise it


def test_street_clip_loads_with_metric_poses_cars_and_views(street, street_clip_path):
    c = clip_mod.load(os.path.dirname(street_clip_path))
    m = street.metric()
    assert c.metric and c.num_frames == street.params.num_frames
    assert c.image_size == (street.params.width, street.params.height)
    np.testing.assert_allclose(c.world_to_camera, m["world_to_camera"])
    np.testing.assert_allclose(c.K_for(259, 147)[0, :2], m["K"][0, :2] / 2)
    assert len(c.cars) == len(street.info["cars"]) and all(car.asset for car in c.cars)
    assert sorted(c.views) == sorted(street.params.shifts_m)
    assert os.path.samefile(c.views[2.0][5], street.frame_path("left_2m", 5))


def _copy(street_clip_path, tmp_path, edit):
    folder = tmp_path / "clip"
    shutil.copytree(os.path.dirname(street_clip_path), folder)
    with open(folder / "clip.json") as f:
        data = json.load(f)
    edit(data, folder)
    with open(folder / "clip.json", "w") as f:
        json.dump(data, f)
    return folder


@pytest.mark.parametrize("edit, field", [
    (lambda d, f: d.update(schema="nope"), "schema"),
    (lambda d, f: d.update(predictions="missing.npz"), "predictions"),
    (lambda d, f: d.update(frames=["frames/frame_000000.png"]), "frames"),
    (lambda d, f: os.remove(f / "frames" / "frame_000015.png"), "frames[15]"),
    (lambda d, f: d["cars"][0]["boxes"].update({"99": np.eye(4).tolist()}), "cars[0].boxes.99"),
    (lambda d, f: d["cars"][1].update(size=[1, -2, 1]), "cars[1].size"),
    (lambda d, f: d["cars"][0]["boxes"].update({"0": (2 * np.eye(4)).tolist()}), "cars[0].boxes.0"),
    (lambda d, f: d["cars"][0].update(asset="assets/none.ply"), "cars[0].asset"),
    (lambda d, f: np.savez(f / "poses.npz", K=np.zeros((16, 3, 3))), "world_to_camera"),
])
def test_bad_clips_name_the_field(street_clip_path, tmp_path, edit, field):
    folder = _copy(street_clip_path, tmp_path, edit)
    with pytest.raises(JobError, match=f"{field.replace('[', '.').replace(']', '.')}"):
        clip_mod.load(folder)


def test_clip_without_poses_uses_vggt_cameras_scaled_to_the_frames(street_clip_path, tmp_path):
    folder = _copy(street_clip_path, tmp_path, lambda d, f: [d.pop("poses"), d.pop("views")])
    c = clip_mod.load(folder)
    assert not c.metric
    np.testing.assert_allclose(c.world_from_vggt, np.eye(4))
    np.testing.assert_allclose(c.K, c.predictions.K, atol=1e-4)  # the street's frames are VGGT's size
    np.testing.assert_allclose(c.world_to_camera[0], np.eye(4), atol=1e-6)
