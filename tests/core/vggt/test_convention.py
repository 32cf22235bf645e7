"""core.vggt.convention: world-to-camera files pass the point-head check, camera-to-world files and files
neither reading fits are refused naming the frame."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.geometry import point_cloud, unproject
from scpainter_blender.core.vggt import predictions as vggt, convention as vggt_convention, npz as vggt_io
from vggt_cases import drive, write


def test_world_to_camera_file_passes_the_check(tmp_path):
    arrays, w2c, _ = drive()
    pred = vggt_io.load_predictions(write(tmp_path, arrays), extrinsic_convention="auto")
    rep = pred.report
    assert rep.extrinsic_convention == "world_to_camera" and rep.convention_checked
    assert np.abs(pred.world_to_camera - w2c).max() < 1e-6
    chk = rep.check
    assert list(chk.frames) == [0, 1, 2, 3] and chk.agrees("world_to_camera") and not chk.agrees("camera_to_world")
    assert chk.relative["world_to_camera"].max() < 0.06   # the 2 % point-head noise, not more
    assert "world-to-camera agrees" in rep.info[0] and not rep.warnings
    # the default (and the backend's reading) does not check, and needs no world_points
    plain = vggt_io.load_predictions(write(tmp_path, arrays), world_points=False)
    assert plain.report.check is None and np.array_equal(plain.world_to_camera, pred.world_to_camera)


def test_camera_to_world_file_refused_then_imported_as_such(tmp_path):
    arrays, w2c, _ = drive()
    arrays["extrinsic"] = C.rigid_inverse(w2c)  # what some tools write under 'extrinsic'
    path = write(tmp_path, arrays)
    for world_points in (True, False):  # the check reads world_points even when the caller will not use them
        with pytest.raises(vggt.PredictionsError) as e:
            vggt_io.load_predictions(path, world_points=world_points, extrinsic_convention="auto")
        msg = str(e.value)
        assert msg.startswith("predictions.npz: 'extrinsic': holds camera-to-world poses") and path in msg
        assert "VGGT units" in msg and "inverted poses agree" in msg
        assert "--extrinsic-convention on the command line): camera_to_world (" in msg
    # with a known scale the disagreement is in metres: the median distance of the worst frame, scaled
    with pytest.raises(vggt.PredictionsError) as e:
        vggt_io.load_predictions(path, extrinsic_convention="auto", metres_per_unit=2.0)
    chk = vggt_convention.check_extrinsic_convention(vggt_io.load_predictions(path))
    k = chk.worst("world_to_camera")
    assert f"frame {chk.frames[k]} lands {2.0 * chk.distance['world_to_camera'][k]:.3g} m" in str(e.value)
    pred = vggt_io.load_predictions(path, extrinsic_convention="camera_to_world")
    assert pred.report.extrinsic_convention == "camera_to_world" and not pred.report.convention_checked
    assert np.abs(pred.world_to_camera - w2c).max() < 1e-6
    good = vggt_io.load_predictions(write(tmp_path, drive()[0], "good.npz"))
    ours, theirs = point_cloud.point_cloud(pred, 0.0), point_cloud.point_cloud(good, 0.0)
    assert np.abs(ours.positions - theirs.positions).max() < 1e-5


def test_camera_to_world_file_of_a_slow_drive_refused(tmp_path):
    """A slow drive: read the wrong way, its frames miss by less than the tolerance that VGGT's point-head noise
    needs, but the inverse fits them decisively better: still refused."""
    arrays, w2c, _ = drive(S=3)
    for i in range(3):  # 0.1 units forward per frame and a 1° turn: metres in a real clip
        yaw = np.radians(1.0 * i)
        R = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
        w2c[i, :3, :3], w2c[i, :3, 3] = R, -R @ np.array([0.0, 0.0, 0.1 * i])
    wp = unproject.unproject_depth(arrays["depth"], vggt.vggt_K_to_ours(arrays["intrinsic_vggt"]), w2c)
    wp += np.random.default_rng(1).normal(0.0, 0.01, wp.shape) * arrays["depth"][..., None]  # point-head noise
    arrays["world_points"] = wp.astype(np.float32)
    arrays["extrinsic"] = C.rigid_inverse(w2c)
    path = write(tmp_path, arrays)
    chk = vggt_convention.check_extrinsic_convention(vggt_io.load_predictions(path))
    assert chk.relative["world_to_camera"].max() < vggt_convention.CONVENTION_TOLERANCE  # inside the tolerance alone
    assert not chk.agrees("world_to_camera") and chk.agrees("camera_to_world")
    with pytest.raises(vggt.PredictionsError, match="holds camera-to-world poses"):
        vggt_io.load_predictions(path, extrinsic_convention="auto")
    arrays["extrinsic"] = w2c  # and the right file of the same drive passes
    ok = vggt_io.load_predictions(write(tmp_path, arrays, "ok.npz"), extrinsic_convention="auto")
    assert ok.report.convention_checked


def test_neither_convention_fits(tmp_path):
    arrays, w2c, _ = drive()
    arrays["world_points"] = drive(seed=1)[0]["world_points"][:, ::-1]  # another depth, mirrored: unrelated
    path = write(tmp_path, arrays)
    with pytest.raises(vggt.PredictionsError) as e:
        vggt_io.load_predictions(path, extrinsic_convention="auto")
    msg = str(e.value)
    assert "'extrinsic': neither reading of the poses fits the file's world_points: in frame" in msg
    assert "VGGT units" in msg and "world_to_camera or camera_to_world (no check)" in msg
    with pytest.raises(vggt.PredictionsError, match=r"in frame \d the depth lands [\d.]+ m from them"):
        vggt_io.load_predictions(path, extrinsic_convention="auto", metres_per_unit=3.0)
    # an explicit convention imports it anyway
    assert vggt_io.load_predictions(path, extrinsic_convention="world_to_camera").num_frames == 4


def test_convention_not_checkable_without_world_points(tmp_path):
    arrays, _, _ = drive()
    del arrays["world_points"], arrays["world_points_conf"]
    pred = vggt_io.load_predictions(write(tmp_path, arrays), extrinsic_convention="auto")
    rep = pred.report
    assert rep.extrinsic_convention == "world_to_camera" and not rep.convention_checked
    assert "not checked (the file has no world_points)" in rep.warnings[0]
    assert rep.to_json()["extrinsic_convention_checked"] is False
    with pytest.raises(ValueError, match="extrinsic_convention"):
        vggt_io.load_predictions(write(tmp_path, arrays), extrinsic_convention="c2w")
