"""``blender -c scpainter import ...``: the headless command, called as Blender calls it (execute(argv))."""

import json
import os
import sys

import bpy
import numpy as np


def _cli(addon):
    return sys.modules[addon + ".scpainter_blender.scene.cli"]


def _last_event(capsys):
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    return json.loads(lines[-1])


def test_import_and_save(addon, empty_scene, street, tmp_path, capsys):
    out = tmp_path / "batch.blend"
    code = _cli(addon).execute(["import", street.predictions_path, "--trajectory",
                                os.path.join(street.root, "metric.npz"), "--save", str(out)])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert ev["event"] == "done" and ev["scale_method"] == "trajectory"
    assert abs(ev["scale"] - float(street.metric()["metres_per_unit"])) < 1e-4
    assert ev["blend"] == str(out) and out.stat().st_size > 1_000_000
    assert not list(tmp_path.glob("*.tmp.blend"))
    bpy.ops.wm.open_mainfile(filepath=str(out))
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    assert len(pts.data.vertices) == ev["points"]
    M = np.array(pts["scpainter_world_from_vggt"]).reshape(4, 4)
    assert np.abs(M - street.metric()["world_from_vggt"]).max() < 1e-4
    bpy.ops.wm.read_homefile(use_empty=True)


def test_bad_input_exit_code_2(addon, empty_scene, tmp_path, capsys):
    cli = _cli(addon)
    assert cli.execute(["import", str(tmp_path / "nope.npz")]) == 2
    assert "nope.npz" in _last_event(capsys)["message"]
    assert cli.execute(["import"]) == 2  # argparse errors are reported, not sys.exit() from inside Blender
    assert "predictions" in _last_event(capsys)["message"]
    assert cli.execute(["import", "x.npz", "--camera-height", "1.6", "--scale-factor", "2"]) == 2
    assert len(bpy.data.objects) == 0
