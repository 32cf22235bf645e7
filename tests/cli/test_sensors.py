"""``blender -c scpainter sensors`` (``cli/sensors.py``): the sensors sidecar written from a nuScenes scene's tables,
then imported with its predictions: nuScenes' own rig, saved as a rig file (``import --save-rig``)."""

import bpy
import numpy as np

from scpainter_blender.core import rig as R
from scpainter_blender.core.geometry import metric_scale
from scpainter_blender.core.vggt import npz as vggt_io
from scpainter_blender.core.vggt import sensors as S
from tests.cli import cli_support as CS
from tests.core.geometry.rig_cases import predictions, small_rig
from tests.core.recording.recording_fixtures import EXTRA_CAMERAS, drive, write_nuscenes


def test_sidecar_from_nuscenes_tables(addon, tmp_path, capsys):
    d = drive(2)
    folder = write_nuscenes(str(tmp_path / "v1.0-mini"), d, extra_cameras=("CAM_BACK",))
    out = tmp_path / "predictions.sensors.json"
    cli = CS.cli(addon)
    traj = tmp_path / "metric.npz"
    assert cli.execute(["sensors", folder, "--scene", "scene-0001", "--out", str(out), "--trajectory-out",
                        str(traj)]) == 0
    ev = CS.last_event(capsys)
    w2c, _ = metric_scale.load_metric_trajectory(str(traj), 4)     # what the import's --trajectory reads
    np.testing.assert_allclose(w2c[::2], d["world_to_camera"], atol=1e-9)
    assert ev["trajectory"] == str(traj)
    assert ev["sensors"] == ["CAM_FRONT", "CAM_BACK"] and ev["frames"] == 4 and ev["sensors_file"] == str(out)
    assert ev["calibrated"] == ["CAM_BACK", "CAM_FRONT"]
    assert ev["images"] == ["samples/CAM_FRONT/sd-cam-0.jpg", "samples/CAM_BACK/0.jpg",
                            "samples/CAM_FRONT/sd-cam-1.jpg", "samples/CAM_BACK/1.jpg"]
    s = S.read(out)
    np.testing.assert_allclose(s.info["CAM_BACK"].camera_to_ego, EXTRA_CAMERAS["CAM_BACK"], atol=1e-12)
    assert cli.execute(["sensors", folder, "--scene", "scene-0001", "--channels", "CAM_BACK", "--no-calibration",
                        "--out", str(out)]) == 0
    assert S.read(out).sensor == ["CAM_BACK", "CAM_BACK"] and S.read(out).info == {}
    capsys.readouterr()
    assert cli.execute(["sensors", folder, "--out", str(out)]) == 2    # two scenes in the tables: name one
    assert "2 scenes among" in CS.last_event(capsys)["message"]


def test_import_with_sidecar_saves_the_rig(addon, empty_scene, tmp_path, capsys):
    """``import --sensors SIDECAR --save-rig FILE``: the sidecar's calibration is the rig, written as a rig file;
    ``--save-rig`` without a multi-camera recording is refused by name."""
    rig = small_rig()
    arrays, sensors, _ = predictions(rig)
    sensors.info = {n: S.SensorInfo(rig.camera(n).camera_to_ego, (32, 24)) for n in ("CAM_FRONT", "CAM_BACK")}
    path = str(tmp_path / "predictions.npz")
    vggt_io.save_predictions(path, **arrays)
    S.write(tmp_path / "cams.json", sensors)
    cli = CS.cli(addon)
    rig_file = tmp_path / "rigs" / "recording.json"
    assert cli.execute(["import", path, "--sensors", str(tmp_path / "cams.json"), "--save-rig", str(rig_file),
                        "--proposals", "off"]) == 0
    ev = CS.last_event(capsys)
    assert ev["cameras"] == [f"{tmp_path.name} CAM_FRONT", f"{tmp_path.name} CAM_BACK"]   # the reference first
    assert ev["recording_rig"]["sensors"]["CAM_BACK"]["source"] == "sidecar"
    assert ev["recording_rig"]["sensors"]["CAM_BACK"]["translation_m"]["p95"] < 1e-3   # the frames agree with it
    saved = R.load(rig_file)
    assert ev["rig_file"] == str(rig_file) and saved.name == "recording"
    for c in saved.cameras:
        np.testing.assert_allclose(c.camera_to_ego, rig.camera(c.name).camera_to_ego)
        assert c.resolution == (32, 24)
        np.testing.assert_allclose(c.K, np.diag([2.0, 2.0, 1.0]) @ rig.camera(c.name).K, atol=1e-4)
    bpy.ops.wm.read_homefile(use_empty=True)
    assert cli.execute(["import", path, "--save-rig", str(rig_file), "--proposals", "off"]) == 2
    ev = CS.last_event(capsys)
    assert ev["field"] == "--save-rig" and "imported as one camera" in ev["message"]
    bpy.ops.wm.read_homefile(use_empty=True)
