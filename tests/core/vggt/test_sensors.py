"""core/vggt/sensors.py: the sensors sidecar of a multi-camera reconstruction, read, checked, written; scene frames."""

import json

import numpy as np
import pytest

from scpainter_blender.core import rig
from scpainter_blender.core.errors import InputError
from scpainter_blender.core.vggt import sensors as S


def _doc(frames=None, sensors=None, **extra):
    frames = frames if frames is not None else [
        {"sensor": ch, "timestamp_us": 1_000_000 + 500_000 * i + 10_000 * k}
        for i in range(3) for k, ch in enumerate(("CAM_FRONT", "CAM_BACK"))]
    d = {"schema": S.SCHEMA, "frames": frames, **extra}
    if sensors is not None:
        d["sensors"] = sensors
    return d


def _write(tmp_path, d, name="predictions.sensors.json"):
    p = tmp_path / name
    p.write_text(json.dumps(d))
    return str(p)


def test_round_trip_and_default_path(tmp_path):
    back = rig.preset("nuscenes").camera("CAM_BACK").camera_to_ego
    path = _write(tmp_path, _doc(sensors=[{"name": "CAM_BACK", "camera_to_ego": back.tolist(),
                                           "resolution": [1600, 900]}]))
    assert S.default_path(str(tmp_path / "predictions.npz")) == path
    s = S.read(path)
    assert s.num_frames == 6 and s.names == ["CAM_FRONT", "CAM_BACK"] and s.reference == "CAM_FRONT"
    assert list(s.frames_of("CAM_BACK")) == [1, 3, 5]
    np.testing.assert_array_equal(s.info["CAM_BACK"].camera_to_ego, back)
    assert s.info["CAM_BACK"].resolution == (1600, 900) and "CAM_FRONT" not in s.info
    S.write(tmp_path / "again.json", s)
    again = S.read(tmp_path / "again.json")
    assert again.sensor == s.sensor and np.array_equal(again.timestamp_us, s.timestamp_us)
    np.testing.assert_array_equal(again.info["CAM_BACK"].camera_to_ego, back)
    assert s.check_frames(6, "predictions.npz") is s


def test_frame_count_differs_from_the_predictions(tmp_path):
    """The issue's bad input: a sidecar whose frame count differs from the predictions'."""
    s = S.read(_write(tmp_path, _doc()))
    with pytest.raises(InputError) as e:
        s.check_frames(8, str(tmp_path / "predictions.npz"))
    assert e.value.path.endswith("predictions.sensors.json") and e.value.field == "frames"
    assert "6 frames, but the predictions predictions.npz hold 8" in e.value.message


@pytest.mark.parametrize("change, field, words", [
    (lambda d: d.update(extra=1), "extra", "unknown field"),
    (lambda d: d["frames"][2].update(camera="x"), "frames[2].camera", "unknown field"),
    (lambda d: d.update(schema="scpainter.sensors/9"), "schema", "expected 'scpainter.sensors/1'"),
    (lambda d: d.update(frames=[]), "frames", "non-empty list"),
    (lambda d: d["frames"][1].update(sensor="CAM/BACK"), "frames[1].sensor", "is not a sensor name"),
    (lambda d: d["frames"][3].update(timestamp_us=1.5), "frames[3].timestamp_us", "expected an integer"),
    (lambda d: d["frames"][4].update(timestamp_us=1_000_000), "frames[4].timestamp_us",
     "is not after CAM_FRONT's previous frame (frames[2]"),
    (lambda d: d.update(sensors=[{"name": "CAM_BACK", "camera_to_ego": (2 * np.eye(4)).tolist()}]),
     "sensors[0].camera_to_ego", "is not a rotation + translation"),
    (lambda d: d.update(sensors=[{"name": "CAM_BACK", "resolution": [0, 9]}]), "sensors[0].resolution[0]",
     "expected an integer in [1, 16384]"),
    (lambda d: d.update(sensors=[{"name": "CAM_SIDE"}]), "sensors[0].name", "has no frame"),
    (lambda d: d.update(sensors=[{"name": "CAM_BACK", "fov": 70}]), "sensors[0].fov", "unknown field"),
])
def test_bad_sidecars_name_the_field(tmp_path, change, field, words):
    d = _doc()
    change(d)
    with pytest.raises(InputError) as e:
        S.read(_write(tmp_path, d))
    assert e.value.field == field and words in e.value.message, (e.value.field, e.value.message)
    assert e.value.path.endswith("predictions.sensors.json")


def test_scene_frames_group_each_reference_frame(tmp_path):
    """Scene frame k is the reference sensor's (CAM_FRONT's, though not first) k-th frame; the others go to the
    nearest; a sensor with two frames at one reference frame is refused naming its timestamp."""
    frames = [{"sensor": "CAM_BACK", "timestamp_us": 95}, {"sensor": "CAM_FRONT", "timestamp_us": 100},
              {"sensor": "CAM_BACK", "timestamp_us": 204}, {"sensor": "CAM_FRONT", "timestamp_us": 200},
              {"sensor": "CAM_FRONT", "timestamp_us": 300}, {"sensor": "CAM_BACK", "timestamp_us": 310}]
    s = S.read(_write(tmp_path, _doc(frames)))
    assert s.reference == "CAM_FRONT" and s.names == ["CAM_BACK", "CAM_FRONT"]
    assert list(s.scene_frames()) == [0, 0, 1, 1, 2, 2]
    frames[2]["timestamp_us"] = 120   # CAM_BACK twice nearest to CAM_FRONT's frame 0
    s = S.read(_write(tmp_path, _doc(frames)))
    with pytest.raises(InputError) as e:
        s.scene_frames()
    assert e.value.field == "frames[2].timestamp_us" and "two frames nearest" in e.value.message
    # without CAM_FRONT the first frame's sensor is the reference
    s = S.read(_write(tmp_path, _doc([{"sensor": "cam_b", "timestamp_us": 5}, {"sensor": "cam_a", "timestamp_us": 6}])))
    assert s.reference == "cam_b" and list(s.scene_frames()) == [0, 0]


def test_camera_frames_put_the_reference_first():
    """One recorded camera per sensor, the reference's first (CAM_FRONT wherever its first frame is; without it the
    first frame's sensor), each with its VGGT frames in order."""
    got = S.camera_frames(["CAM_BACK", "CAM_FRONT", "CAM_BACK", "CAM_FRONT_LEFT", "CAM_FRONT"])
    assert list(got) == ["CAM_FRONT", "CAM_BACK", "CAM_FRONT_LEFT"]
    assert [list(v) for v in got.values()] == [[1, 4], [0, 2], [3]]
    assert list(S.camera_frames(["B", "A", "B"])) == ["B", "A"] and S.reference_of(["B", "A"]) == "B"
    s = S.Sensors(["CAM_BACK", "CAM_FRONT"], np.array([1, 2], np.int64))
    assert s.reference == "CAM_FRONT" and list(s.camera_frames()) == ["CAM_FRONT", "CAM_BACK"]
