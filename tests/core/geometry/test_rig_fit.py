"""core/geometry/rig_fit.py: a known rig (nuScenes' six cameras) recovered from a drive along a curved path, with
noise and outlier frames; the spread reported; the sidecar's extrinsics kept."""

import numpy as np
import pytest

from scpainter_blender.core import rig as R
from scpainter_blender.core.errors import InputError
from scpainter_blender.core.geometry import rig_fit
from scpainter_blender.core.vggt import sensors as S

from .rig_cases import recording

RIG = R.preset("nuscenes", scale=0.01, lidar=False)   # 16 x 9 px
#: CAM_FRONT's lateral offset from the ego's x axis: not observable from the motion (the estimate puts the ego
#: origin on the axis through the camera), so every estimated translation may be off by it.
LATERAL_M = abs(RIG.camera("CAM_FRONT").camera_to_ego[1, 3])


def _errors(fit, rig):
    """{name: (translation error m, rotation error deg)} of the fitted rig against ``rig``."""
    out = {}
    for cam in rig.cameras:
        E = fit.rig.camera(cam.name).camera_to_ego
        dt, dr = rig_fit._deviations(E[None], cam.camera_to_ego[:3, 3], cam.camera_to_ego[:3, :3])
        out[cam.name] = (float(dt[0]), float(dr[0]))
    return out


def _K(sensors, rig):
    return np.stack([rig.camera(n).K for n in sensors.sensor])


def test_exact_drive_gives_the_rig_back():
    sensors, c2w = recording(RIG)
    fit = rig_fit.fit(sensors, c2w, _K(sensors, RIG), (16, 9))
    assert fit.rig.name == "recording" and [c.name for c in fit.rig.cameras] == list(R.NUSCENES_CAMERAS)
    assert fit.reference == "CAM_FRONT" and fit.notes == []
    # the rear axle found from the turn: CAM_FRONT 1.70 m ahead of it (its 1.6 cm lateral offset unobservable)
    assert abs(fit.rear_axle_m - RIG.camera("CAM_FRONT").camera_to_ego[0, 3]) < 0.02
    for name, (dt, dr) in _errors(fit, RIG).items():
        assert dt < LATERAL_M + 0.01 and dr < 1e-5, (name, dt, dr)
        f = fit.sensors[name]
        assert f.source == "estimated" and f.used == f.frames == 8 and f.outliers == []
        assert f.translation_m[1] < 1e-6 and f.rotation_deg[1] < 1e-5 and f.K_spread_px == (0.0, 0.0)
        np.testing.assert_allclose(fit.rig.camera(name).K, RIG.camera(name).K)
        assert fit.rig.camera(name).resolution == (16, 9)


def _relative_errors(fit, rig, to="CAM_FRONT"):
    """{name: (m, deg)} of each fitted camera's pose relative to camera ``to`` against the truth's: what the
    reconstruction observes, whatever the ego origin."""
    F, Ft = (np.linalg.inv(r.camera(to).camera_to_ego) for r in (fit.rig, rig))
    out = {}
    for cam in rig.cameras:
        true = Ft @ cam.camera_to_ego
        dt, dr = rig_fit._deviations((F @ fit.rig.camera(cam.name).camera_to_ego)[None], true[:3, 3], true[:3, :3])
        out[cam.name] = (float(dt[0]), float(dr[0]))
    return out


def test_noise_and_outliers():
    """1 cm / 0.2° noise on every pose and two frames 1.2 m off. The cameras relative to each other within 3 cm /
    0.3°; the rear axle within 3 standard errors (its error, reported, moves every mount along x by the same
    amount); the outliers left out; the spread reported per sensor at the noise's size."""
    sensors, c2w = recording(RIG, noise_m=0.01, noise_deg=0.2, outliers=(7, 20))
    fit = rig_fit.fit(sensors, c2w, _K(sensors, RIG), (16, 9))
    axle_error = abs(fit.rear_axle_m - RIG.camera("CAM_FRONT").camera_to_ego[0, 3])
    assert 0.01 < fit.rear_axle_std_m < 0.1 and axle_error < 3 * fit.rear_axle_std_m
    for name, (dt, dr) in _errors(fit, RIG).items():
        assert dt < axle_error + LATERAL_M + 0.03 and dr < 0.3, (name, dt, dr)
    for name, (dt, dr) in _relative_errors(fit, RIG).items():
        assert dt < 0.03 and dr < 0.3, (name, dt, dr)
    assert fit.sensors["CAM_FRONT_RIGHT"].outliers == [7] and fit.sensors["CAM_FRONT_LEFT"].outliers == [20]
    assert sum(len(f.outliers) for f in fit.sensors.values()) == 2
    for f in fit.sensors.values():
        assert 0.002 < f.translation_m[0] < 0.04 and f.translation_m[1] < 0.06
        assert 0.02 < f.rotation_deg[0] < 0.4 and f.rotation_deg[1] < 0.6
        assert "spread" in f.sentence() and f.to_json()["translation_m"]["p95"] == f.translation_m[1]


def test_sidecar_extrinsics_are_kept_and_checked():
    """A sensor whose camera_to_ego the sidecar gives keeps it; the reference's gives the ego path exactly; the
    spread then measures how far the reconstruction is from the calibration. Resolution scales K."""
    sensors, c2w = recording(RIG)
    sensors.info = {"CAM_FRONT": S.SensorInfo(RIG.camera("CAM_FRONT").camera_to_ego, (1600, 900)),
                    "CAM_BACK": S.SensorInfo(np.eye(4), None)}
    fit = rig_fit.fit(sensors, c2w, _K(sensors, RIG), (16, 9))
    assert fit.yaw_offset_deg is None and fit.rear_axle_m is None
    errors = _errors(fit, RIG)
    assert errors["CAM_FRONT"] == (0.0, 0.0)
    # the ego path exact between frames too (the screw motion follows the arc)
    assert all(dt < 1e-9 and dr < 1e-5 for n, (dt, dr) in errors.items() if n != "CAM_BACK")
    np.testing.assert_array_equal(fit.rig.camera("CAM_BACK").camera_to_ego, np.eye(4))
    assert fit.sensors["CAM_BACK"].source == "sidecar" and fit.sensors["CAM_BACK"].rotation_deg[0] > 90
    assert fit.rig.camera("CAM_FRONT").resolution == (1600, 900)
    np.testing.assert_allclose(fit.rig.camera("CAM_FRONT").K, R.preset("front").camera("CAM_FRONT").K, rtol=1e-6)


def test_straight_drive_puts_the_origin_below_the_reference():
    """Without a turn the rear axle is not observable: the ego origin is below CAM_FRONT, said in a note."""
    rig = R.Rig("two", [RIG.camera("CAM_FRONT"), RIG.camera("CAM_BACK")])
    sensors, c2w = recording(rig, samples=2)
    fit = rig_fit.fit(sensors, c2w, _K(sensors, rig), (16, 9))
    assert fit.rear_axle_m is None and "origin is taken below the reference camera" in fit.notes[0]
    front = fit.rig.camera("CAM_FRONT").camera_to_ego
    assert abs(front[0, 3]) < 1e-9 and abs(front[2, 3] - RIG.camera("CAM_FRONT").camera_to_ego[2, 3]) < 1e-9
    # what is observable is exact: one camera relative to the other
    rel = np.linalg.inv(front) @ fit.rig.camera("CAM_BACK").camera_to_ego
    true = np.linalg.inv(RIG.camera("CAM_FRONT").camera_to_ego) @ RIG.camera("CAM_BACK").camera_to_ego
    np.testing.assert_allclose(rel, true, atol=1e-6)


def test_a_sensor_out_of_reach_without_extrinsics_is_refused():
    rig = R.Rig("two", [RIG.camera("CAM_FRONT"), RIG.camera("CAM_BACK")])
    sensors, c2w = recording(rig, samples=3)
    sensors.timestamp_us[1::2] += 10_000_000   # CAM_BACK 10 s later than every CAM_FRONT frame
    with pytest.raises(InputError) as e:
        rig_fit.fit(sensors, c2w, _K(sensors, rig), (16, 9))
    assert e.value.field == "frames" and "no CAM_BACK frame is within 0.25 s" in e.value.message
    sensors.info["CAM_BACK"] = S.SensorInfo(RIG.camera("CAM_BACK").camera_to_ego)
    fit = rig_fit.fit(sensors, c2w, _K(sensors, rig), (16, 9))   # given: kept, no frame to compare
    assert fit.sensors["CAM_BACK"].used == 0 and fit.sensors["CAM_BACK"].source == "sidecar"


def test_one_moment_of_every_camera():
    """VGGT on the six images of one sample: the ego pose is the reference frame's for every camera (they fire
    within 40 ms, at 8 m/s: the camera poses differ from the rig by that motion, ≤ 0.33 m, said in a note)."""
    sensors, c2w = recording(RIG, samples=1)
    fit = rig_fit.fit(sensors, c2w, _K(sensors, RIG), (16, 9))
    assert any("one CAM_FRONT frame" in n for n in fit.notes) and all(f.used == 1 for f in fit.sensors.values())
    for name, (dt, dr) in _relative_errors(fit, RIG).items():
        assert dt <= 8.0 * 0.008 * R.NUSCENES_CAMERAS.index(name) + 1e-6 and dr < 1e-5, (name, dt, dr)


def test_K_median_and_its_spread():
    """K varies a little per frame (VGGT predicts it per frame): the rig camera gets the median, the spread says how
    far the frames are from it."""
    rig = R.Rig("two", [RIG.camera("CAM_FRONT"), RIG.camera("CAM_BACK")])
    sensors, c2w = recording(rig, samples=5)
    K = _K(sensors, rig)
    K[0::2, 0, 0] += [0.1, -0.2, 0.0, 0.3, -0.1]     # CAM_FRONT's fx: median + 0
    K[1::2, 1, 2] += [0.0, 0.05, -0.4, 0.02, 0.01]   # CAM_BACK's cy: median + 0.01
    fit = rig_fit.fit(sensors, c2w, K, (16, 9))
    np.testing.assert_allclose(fit.rig.camera("CAM_FRONT").K, rig.camera("CAM_FRONT").K)
    assert fit.rig.camera("CAM_BACK").K[1, 2] == pytest.approx(rig.camera("CAM_BACK").K[1, 2] + 0.01)
    assert fit.sensors["CAM_FRONT"].K_spread_px == pytest.approx((0.1, 0.3))
    assert fit.sensors["CAM_BACK"].K_spread_px == pytest.approx((0.01, 0.41))
