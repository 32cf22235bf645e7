"""core.rig_convert: a single-camera job made a rig job (``python -m backend rig``'s work)."""

import json
import os

import numpy as np
import pytest

from scpainter_blender.core import job as J, job_inputs, rig as R, rig_convert
from scpainter_blender.core.errors import ArgumentError, InputError
from tests_support import small_job


def _turning_path(n=3):
    """world_to_camera of a camera driving along world y and turning, OpenCV axes, 1.4 m above the road."""
    out = []
    for i in range(n):
        yaw = 0.2 * i
        fwd = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        right = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        R_cw = np.stack([right, [0, 0, -1.0], fwd])          # rows: camera axes in world
        c = np.array([0.5 * i, 3.0 * i, 1.4])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_cw, -R_cw @ c
        out.append(T)
    return out


def _single(n=3):
    return J.Job((64, 36), [J.Frame(i + 1, np.array([[50.0, 0, 32], [0, 50, 18], [0, 0, 1]]), T, [0])
                            for i, T in enumerate(_turning_path(n))], "out", fps=10.0)


@pytest.mark.parametrize("follow", [None, "CAM_BACK_LEFT"])
def test_the_followed_camera_rides_on_the_base_path(follow):
    rig = R.preset("nuscenes", scale=0.04)
    job = rig_convert.rig_job(_single(), rig, follow)
    assert job.rig is rig and job.resolution is None and [f.frame for f in job.frames] == [1, 2, 3]
    name = follow or "CAM_FRONT"
    cam_job = dict((c.name, j) for c, j in job.camera_jobs())[name]
    for f, T in zip(cam_job.frames, _turning_path()):
        np.testing.assert_allclose(f.world_to_camera, T, atol=1e-9)
    for f in job.frames:   # the ego stays upright (within the real mounts' 1-2 degree tilts): z up
        np.testing.assert_allclose(f.ego_to_world[:3, 2], [0, 0, 1], atol=0.03)
    with pytest.raises(ArgumentError) as e:
        rig_convert.rig_job(_single(), rig, "CAM_TOP")
    assert e.value.field == "--follow" and "CAM_FRONT" in e.value.hint


def test_choose_rig_presets_files_scale_and_lidar(tmp_path):
    assert [c.resolution for c in rig_convert.choose_rig("front", 0.1).cameras] == [(160, 90)]
    assert rig_convert.choose_rig("front").lidar is None
    assert rig_convert.choose_rig("nuscenes").lidar.model == "nuscenes-32"
    assert rig_convert.choose_rig("nuscenes", lidar="none").lidar is None
    front = rig_convert.choose_rig("front", lidar="velodyne-64")
    assert front.lidar.model == "velodyne-64" and front.lidar.name == "LIDAR_TOP"
    np.testing.assert_allclose(front.lidar.lidar_to_ego[:3, 3], [0.943713, 0, 1.84023])
    R.save(tmp_path / "mine.json", R.preset("front", scale=0.5))
    assert rig_convert.choose_rig(str(tmp_path / "mine.json"), 0.5).cameras[0].resolution == (400, 225)
    for args, field, words in ((("bogus",), "--preset", "['front', 'nuscenes']"),
                               ((str(tmp_path / "missing.json"),), "--preset", "no such rig file"),
                               (("front", 0.0), "--scale", "(0, 4]"),
                               (("front", float("nan")), "--scale", "(0, 4]"),
                               (("front", 1.0, "hdl-9000"), "--lidar", "nuscenes-32")):
        with pytest.raises(ArgumentError) as e:
            rig_convert.choose_rig(*args)
        assert e.value.field == field and words in e.value.message


@pytest.mark.parametrize("edit,field", [
    (lambda d: d["cameras"][0].update(name="LIDAR_TOP"), "lidar.name"),               # two sensors, one name
    (lambda d: d["cameras"][0]["K"][0].__setitem__(2, 5000.0), "cameras[0].K"),       # K for another size
    (lambda d: d["cameras"][0].update(camera_to_ego=np.diag([1.0, 1, 3, 1]).tolist()), "cameras[0].camera_to_ego"),
])
def test_a_bad_rig_file_is_named_with_its_field(tmp_path, edit, field):
    d = {"schema": R.RIG_SCHEMA, **R.preset("front", lidar=True, scale=0.1).to_dict()}
    edit(d)
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError) as e:
        rig_convert.choose_rig(str(tmp_path / "bad.json"))
    assert e.value.path == str(tmp_path / "bad.json") and e.value.field == field


def test_make_writes_a_job_valid_from_its_own_folder(tmp_path):
    base = small_job(tmp_path / "drive")
    rig = R.preset("front", scale=0.02)
    # beside the base: every path relative, the job's folder its output folder
    job, outside = rig_convert.make(base, rig, tmp_path / "drive" / "rig.json")
    d = json.loads((tmp_path / "drive" / "rig.json").read_text())
    assert outside == [] and d["output_dir"] == "." and d["scene"]["predictions"] == "predictions.npz"
    assert d["assets"][0]["ply"] == "car.ply" and "resolution" not in d and "ego_to_world" in d["frames"][0]
    job_inputs.check_inputs(tmp_path / "drive" / "rig.json", job)      # confined to its folder: fine
    # in a folder of its own: the base's files named absolutely, and the folder to trust said
    job, outside = rig_convert.make(base, rig, tmp_path / "surround" / "job.json")
    assert outside == [str(tmp_path / "drive")] and os.path.isabs(job.scene.predictions)
    with pytest.raises(J.JobError):
        job_inputs.check_inputs(tmp_path / "surround" / "job.json", job)
    job_inputs.check_inputs(tmp_path / "surround" / "job.json", job, data_roots=[str(tmp_path / "drive")])
    # the base itself, or a rig job as base: refused
    with pytest.raises(ArgumentError) as e:
        rig_convert.make(base, rig, base)
    assert e.value.field == "--out"
    with pytest.raises(J.JobError) as e:
        rig_convert.make(tmp_path / "drive" / "rig.json", rig, tmp_path / "again.json")
    assert e.value.field == "rig"


def test_make_confines_the_base_as_render_does(tmp_path):
    base = small_job(tmp_path / "drive")
    d = json.loads(open(base).read())
    os.rename(tmp_path / "drive" / "predictions.npz", tmp_path / "predictions.npz")
    d["scene"]["predictions"] = "../predictions.npz"
    J.save(base, d)
    with pytest.raises(J.JobError) as e:
        rig_convert.make(base, R.preset("front", scale=0.02), tmp_path / "drive" / "rig.json")
    assert e.value.field == "scene.predictions"
    assert not os.path.exists(tmp_path / "drive" / "rig.json")
    job, outside = rig_convert.make(base, R.preset("front", scale=0.02), tmp_path / "drive" / "rig.json",
                                    data_roots=[str(tmp_path)])
    assert outside == [str(tmp_path)] and job.scene.predictions == str(tmp_path / "predictions.npz")
