"""core.job's rig jobs (docs/design.md §17): a job whose frames carry ego_to_world, rendered as one ordinary
single-camera job per rig camera (``Job.camera_jobs``)."""

import copy
import os

import numpy as np
import pytest

from scpainter_blender.core import job as J
from scpainter_blender.core import rig as R


def ego_pose(x: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [x, 0.3 * x, 0.0]
    return T


def rig_job(frames=(1, 2, 3), rig=None) -> dict:
    rig = rig or R.preset("nuscenes", scale=0.04)  # 64 x 36 cameras
    return {"schema": J.SCHEMA, "rig": rig.to_dict(),
            "frames": [{"frame": f, "ego_to_world": ego_pose(f, 0.1 * f).tolist(), "source_frames": [0, 1]}
                       for f in frames],
            "assets": [{"name": "car", "ply": "car.ply",
                        "object_to_world": {str(f): np.eye(4).tolist() for f in frames}}],
            "output_dir": "out", "fps": 10.0, "generate": {"steps": 3}}


def test_a_rig_job_round_trip(tmp_path):
    d = rig_job()
    job = J.Job.from_dict(d)
    assert job.resolution is None and isinstance(job.rig, R.Rig) and len(job.rig.cameras) == 6
    assert job.frames[0].K is None and job.frames[0].world_to_camera is None
    assert job.frames[1].ego_to_world.shape == (4, 4)
    assert job.to_dict() == {**d, "rig": job.rig.to_dict()}
    J.save(tmp_path / "job.json", job)
    assert J.load(tmp_path / "job.json").to_dict() == job.to_dict()


def test_camera_jobs_are_ordinary_single_camera_jobs():
    job = J.Job.from_dict(rig_job())
    pairs = job.camera_jobs()
    assert [c.name for c, _ in pairs] == list(R.NUSCENES_CAMERAS)
    for cam, cj in pairs:
        assert cj.rig is None and cj.resolution == tuple(cam.resolution) == (64, 36)
        assert cj.output_dir == os.path.join("out", cam.name)
        assert cj.scene is job.scene and cj.assets is job.assets and cj.fps == 10.0 and cj.generate is job.generate
        assert [f.frame for f in cj.frames] == [1, 2, 3] and cj.frames[0].source_frames == [0, 1]
        for f, e in zip(cj.frames, job.frames):
            assert f.ego_to_world is None and np.array_equal(f.K, cam.K) and f.K.dtype == np.float64
            expected = np.linalg.inv(e.ego_to_world @ cam.camera_to_ego)
            assert f.world_to_camera.dtype == np.float64
            np.testing.assert_allclose(f.world_to_camera, expected, atol=1e-12)
        assert J.Job.from_dict(cj.to_dict()).to_dict() == cj.to_dict()  # a valid job file of its own
    # CAM_FRONT (mounted 1.70 m ahead of the rear axle) sees a point 10 m ahead of the ego 8.3 m in front of it,
    # CAM_BACK sees it behind
    ahead = job.frames[0].ego_to_world @ [10.0, 0, 1.5, 1]
    in_front = pairs[0][1].frames[0].world_to_camera @ ahead
    assert 8.2 < in_front[2] < 8.4 and abs(in_front[0]) < 0.1
    assert (pairs[3][1].frames[0].world_to_camera @ ahead)[2] < -9
    plain = J.Job.from_dict(_single())
    assert plain.camera_jobs() == [(None, plain)]


def _single() -> dict:
    return {"schema": J.SCHEMA, "resolution": [64, 36],
            "frames": [{"frame": 1, "K": [[50, 0, 32], [0, 50, 18], [0, 0, 1]], "world_to_camera": np.eye(4).tolist()}],
            "output_dir": "out"}


@pytest.mark.parametrize("mutate,field", [
    (lambda j: j.update(resolution=[64, 36]), "resolution"),
    (lambda j: j["frames"][1].pop("ego_to_world"), "frames[1].ego_to_world"),
    (lambda j: j["frames"][0].update(ego_to_world=np.diag([2.0, 2, 2, 1]).tolist()), "frames[0].ego_to_world"),
    (lambda j: j["frames"][2].update(K=[[50, 0, 32], [0, 50, 18], [0, 0, 1]]), "frames[2].K"),
    (lambda j: j["frames"][0].update(world_to_camera=np.eye(4).tolist()), "frames[0].world_to_camera"),
    (lambda j: j["rig"]["cameras"][2].update(K=[[50, 0, 500], [0, 50, 18], [0, 0, 1]]), "rig.cameras[2].K"),
    (lambda j: j["rig"]["cameras"][3].update(name="CAM_FRONT"), "rig.cameras[3].name"),
    (lambda j: j["rig"]["lidar"].update(name="CAM_BACK"), "rig.lidar.name"),
    (lambda j: j["rig"]["cameras"][0].update(camera_to_ego=np.diag([1.0, 1, 2, 1]).tolist()),
     "rig.cameras[0].camera_to_ego"),
    (lambda j: j["rig"]["lidar"].update(model="hdl-9000"), "rig.lidar.model"),
    (lambda j: j["rig"].update(cameras=[]), "rig.cameras"),
    (lambda j: j.update(rig=[]), "rig"),
    (lambda j: j["rig"]["cameras"][4].update(name="conditions"), "rig.cameras[4].name"),
])
def test_a_rig_jobs_fields_are_checked(mutate, field):
    d = copy.deepcopy(rig_job())
    mutate(d)
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict(d, "/jobs/job.json")
    assert e.value.field == field and e.value.path == "/jobs/job.json"


def test_a_single_camera_job_refuses_ego_to_world_and_needs_its_resolution():
    d = _single()
    d["frames"][0]["ego_to_world"] = np.eye(4).tolist()
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict(d)
    assert e.value.field == "frames[0].ego_to_world" and "rig" in e.value.message
    d = _single()
    del d["resolution"]
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict(d)
    assert e.value.field == "resolution"
    d = _single()
    del d["frames"][0]["K"]
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict(d)
    assert e.value.field == "frames[0].K"


def test_what_takes_one_camera_says_so():
    job = J.Job.from_dict(rig_job())
    with pytest.raises(ValueError, match="camera_jobs"):
        job.width
    with pytest.raises(J.JobError) as e:
        job.require_single_camera("/jobs/job.json", "evaluate")
    assert e.value.field == "rig" and "CAM_FRONT" in e.value.message and "evaluate" in e.value.message
    single = J.Job.from_dict(_single())
    assert single.require_single_camera("job.json", "evaluate") is single and single.width == 64


def test_layers_dict_of_a_rig_job():
    d = rig_job()
    base = J.Job.from_dict(d).layers_dict()
    assert "lidar" not in base["rig"] and "generate" not in base and "output_dir" not in base and "fps" not in base
    d2 = copy.deepcopy(d)
    d2["rig"]["lidar"]["model"] = "velodyne-64"      # the cameras' layers do not depend on the LiDAR
    assert J.Job.from_dict(d2).layers_dict() == base
    d3 = copy.deepcopy(d)
    d3["rig"]["cameras"][1]["K"][0][0] += 1.0         # one camera's K: the rig's layers change ...
    changed = J.Job.from_dict(d3)
    assert changed.layers_dict() != base
    # ... and of its camera jobs only that camera's
    same = [a.layers_dict() == b.layers_dict() for (_, a), (_, b) in
            zip(J.Job.from_dict(d).camera_jobs(), changed.camera_jobs())]
    assert same == [True, False, True, True, True, True]
