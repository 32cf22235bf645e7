"""``blender -c scpainter export ...`` (``cli/export.py``): a scene's labels written headless (KITTI, COCO)."""

import os
import sys

import numpy as np

from tests.cli import cli_support as CS


def test_export_arguments_are_bad_input(addon, empty_scene, tmp_path, capsys):
    cli = CS.cli(addon)
    errors = sys.modules[addon + ".scpainter_blender.core.errors"]
    for argv in (["export", "x.blend"], ["export", "x.blend", "--format", "yolo"]):
        assert cli.execute(argv) == 2, argv
        ev = CS.last_event(capsys)
        assert ev["file"] == errors.COMMAND_LINE and ev["field"] == "--format", ev
    not_blend = tmp_path / "predictions.npz"
    np.savez(not_blend, depth=np.zeros(3))
    assert cli.execute(["export", str(not_blend), "--format", "coco"]) == 2
    assert CS.last_event(capsys)["file"] == str(not_blend)


def test_export_headless(addon, street, tmp_path, capsys):
    cli = CS.cli(addon)
    blend = CS.street_blend(street, tmp_path)
    code = cli.execute(["export", blend, "--format", "kitti", "--device", "cpu", "--backend-python", sys.executable])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    out = tmp_path / "scpainter" / "Scene" / CS.CAM_DIR
    assert ev["command"] == "export" and ev["output_dir"] == str(out) and ev["format"] == "kitti"
    assert ev["out"] == str(out / "export" / "kitti") and ev["frames"] == 3 and ev["images"] == "conditions"
    assert sorted(os.listdir(out / "export" / "kitti" / "label_2")) == [f"00000{i}.txt" for i in range(3)]
    assert ev["objects"] >= 1                                        # the car beside the road
    code = cli.execute(["export", blend, "--format", "coco", "--out", str(tmp_path / "coco"), "--device", "cpu",
                        "--backend-python", sys.executable])
    ev = CS.last_event(capsys)
    assert code == 0 and ev["out"] == str(tmp_path / "coco") and ev["rendered"] == 0, ev
