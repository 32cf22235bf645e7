"""core/rig.py: presets, the rig file, checks naming the field, scaling, ego paths."""

import numpy as np
import pytest

from scpainter_blender.core import errors, rig
from scpainter_blender.core.geometry import cameras


def test_nuscenes_preset_cameras_look_where_their_names_say():
    r = rig.preset("nuscenes")
    assert [c.name for c in r.cameras] == list(rig.NUSCENES_CAMERAS)
    assert r.lidar is not None and r.lidar.name == "LIDAR_TOP" and r.lidar.model == "nuscenes-32"
    expected_yaw = {"CAM_FRONT": 0, "CAM_FRONT_LEFT": 55, "CAM_FRONT_RIGHT": -55, "CAM_BACK": 180,
                    "CAM_BACK_LEFT": 110, "CAM_BACK_RIGHT": -110}
    for c in r.cameras:
        forward = c.camera_to_ego[:3, :3] @ [0, 0, 1]       # the optical axis in the ego frame
        down = c.camera_to_ego[:3, :3] @ [0, 1, 0]
        yaw = np.degrees(np.arctan2(forward[1], forward[0]))
        assert abs((yaw - expected_yaw[c.name] + 180) % 360 - 180) < 6, (c.name, yaw)
        assert down[2] < -0.99                                # level cameras, image rows down
        assert 1.4 < c.camera_to_ego[2, 3] < 1.7              # mounted ~1.5 m up
        assert c.resolution == (1600, 900) and cameras.intrinsics_problem(c.K, c.resolution) is None
    # nuScenes' CAM_FRONT intrinsic, in our pixel convention (+0.5)
    K = r.camera("CAM_FRONT").K
    assert K[0, 2] == pytest.approx(816.2670197447984 + 0.5) and K[1, 2] == pytest.approx(491.50706579294757 + 0.5)
    assert rig.preset("front").sensor_names == ["CAM_FRONT"]
    assert rig.preset("nuscenes", lidar=False).lidar is None


def test_a_rig_file_round_trips(tmp_path):
    r = rig.preset("nuscenes", scale=0.25)
    rig.save(tmp_path / "rig.json", r)
    back = rig.load(tmp_path / "rig.json")
    assert back.to_dict() == r.to_dict()
    assert back.cameras[0].resolution == (400, 225)


def test_scaling_keeps_each_pixel_ray():
    r = rig.preset("front")
    s = r.scaled(0.25)
    K, Ks = r.cameras[0].K, s.cameras[0].K
    # the same ray through the centre of the full-size image lands at the centre of the small one
    ray = np.linalg.inv(K) @ [800.0, 450.0, 1.0]
    p = Ks @ ray
    assert p[:2] / p[2] == pytest.approx([200.0, 112.5])


def test_ego_path_puts_the_followed_camera_on_the_path():
    r = rig.preset("nuscenes")
    c2w = np.eye(4)[None].repeat(3, 0)
    c2w[:, :3, 3] = [[0, 0, 0], [5, 1e5, 2], [10, 1e5, 2]]
    ego = rig.ego_path(c2w, r, "CAM_FRONT")
    back = rig.camera_to_world(ego, r.camera("CAM_FRONT").camera_to_ego)
    assert np.abs(back - c2w).max() < 1e-9
    w2c = rig.world_to_camera(ego[1], r.camera("CAM_BACK").camera_to_ego)
    assert np.abs(w2c @ rig.camera_to_world(ego[1], r.camera("CAM_BACK").camera_to_ego) - np.eye(4)).max() < 1e-9


def _bad(mutate):
    d = rig.preset("nuscenes", scale=0.25).to_dict()
    mutate(d)
    with pytest.raises(errors.InputError) as e:
        rig.Rig.from_dict(d, "job.json")
    return e.value


def test_bad_rigs_are_refused_naming_the_field():
    e = _bad(lambda d: d["cameras"][1].update(name="CAM_FRONT"))
    assert e.field == "rig.cameras[1].name" and "two sensors with one name" in str(e)
    e = _bad(lambda d: d["lidar"].update(name="CAM_BACK"))
    assert e.field == "rig.lidar.name"
    e = _bad(lambda d: d["cameras"][2].update(resolution=[40, 22]))   # K of 400 x 225 at 40 x 22
    assert e.field == "rig.cameras[2].K" and "40 x 22" in str(e)
    e = _bad(lambda d: d["cameras"][0]["camera_to_ego"][0].__setitem__(0, 2.0))
    assert e.field == "rig.cameras[0].camera_to_ego" and "rotation" in str(e)
    e = _bad(lambda d: d["lidar"].update(model="hdl-999"))
    assert e.field == "rig.lidar.model" and "nuscenes-32" in str(e)
    e = _bad(lambda d: d["cameras"][0].update(name="../x"))
    assert e.field == "rig.cameras[0].name"
    e = _bad(lambda d: d.update(cameras=[]))
    assert e.field == "rig.cameras"
    with pytest.raises(errors.ArgumentError) as a:
        rig.preset("waymo")
    assert a.value.field == "--rig" and "nuscenes" in str(a.value)


def test_a_K_for_another_resolution_is_refused():
    """nuScenes' full-size K (cx 816, cy 492) at 800 x 450 passes the single-camera rule (principal point at most one
    image size outside) but renders an almost black camera: a rig camera's principal point must be in the middle
    half of its image."""
    full = rig.preset("nuscenes", lidar=False)
    d = full.to_dict()
    d["cameras"][3]["resolution"] = [800, 450]                  # K still 1600 x 900's
    assert cameras.intrinsics_problem(np.asarray(d["cameras"][3]["K"]), (800, 450)) is None
    with pytest.raises(errors.InputError) as e:
        rig.Rig.from_dict(d, "rig.json")
    assert e.value.field == "rig.cameras[3].K" and "800 x 450" in str(e.value)
    assert "another resolution" in str(e.value.hint) and "--scale" in str(e.value.hint)
    rig.Rig.from_dict(full.scaled(0.5).to_dict(), "rig.json")      # scaled with the image: accepted
    for name in rig.PRESETS:                                       # every preset at every usual scale passes
        for f in (1.0, 0.5, 0.25, 0.1):
            rig.Rig.from_dict(rig.preset(name, scale=f).to_dict(), "rig.json")


def test_an_unknown_preset_or_lidar_model_suggests_the_close_name():
    """``--rig nuscene`` had no hint; ``--lidar NUSCENES-32`` stays refused (names are exact) but says which one."""
    with pytest.raises(errors.ArgumentError) as a:
        rig.preset("nuscene")
    assert "did you mean 'nuscenes'?" in str(a.value) and "front, nuscenes" in a.value.hint
    assert ".json" in a.value.hint
    assert "did you mean 'nuscenes-32'?" in rig.lidar_model_problem("NUSCENES-32")
    assert "did you mean" not in rig.lidar_model_problem("hdl-999")
    assert errors.did_you_mean("Velodyne64", ["nuscenes-32", "velodyne-64"]) == " (did you mean 'velodyne-64'?)"
