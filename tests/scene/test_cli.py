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


def _street_blend(street, folder):
    """A saved scene: the street, a car, a 2 m path, half resolution, frames 1-3."""
    from tests_support import street_with_car

    street_with_car(street, folder, count=2000, seed=3)
    bpy.context.scene.render.resolution_percentage = 50
    bpy.context.scene.frame_end = 3
    path = str(folder / "street.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def test_render_generate_and_batch_headless(addon, street, tmp_path, capsys, tiny_checkpoint):
    import hashlib

    cli = _cli(addon)
    blend = _street_blend(street, tmp_path)
    digest = hashlib.sha256(open(blend, "rb").read()).hexdigest()
    common = ["--device", "cpu", "--backend-python", sys.executable]
    code = cli.execute(["render", blend, *common])
    ev = _last_event(capsys)
    assert code == 0, ev
    out = tmp_path / "scpainter" / "Scene"                       # the default: //scpainter/<scene name>/
    assert ev["output_dir"] == str(out) and ev["frames"] == 3 and len(list((out / "conditions").glob("*.exr"))) == 3
    code = cli.execute(["generate", blend, *common, "--checkpoint", tiny_checkpoint, "--output",
                        str(tmp_path / "gen")])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert os.path.isfile(ev["video"]) and ev["video"].startswith(str(tmp_path / "gen"))
    # a batch over a scene, a missing scene and the job file the first run wrote: one summary, exit 1
    (tmp_path / "list.txt").write_text("scpainter/Scene/job.json\n")
    code = cli.execute(["batch", blend, str(tmp_path / "missing.blend"), "--list", str(tmp_path / "list.txt"),
                        "--command", "render", *common])
    ev = _last_event(capsys)
    assert code == 1 and ev["failed"] == 1 and [r["status"] for r in ev["items"]] == ["ok", "failed", "ok"]
    assert "missing.blend" in ev["items"][1]["error"] and ev["items"][2]["skipped"] == 3   # already rendered
    code = cli.execute(["batch", blend, str(tmp_path / "missing.blend"), "--shard", "0/2", "--command", "render",
                        *common])
    ev = _last_event(capsys)
    assert code == 0 and [r["item"] for r in ev["items"]] == [blend] and ev["shard"] == "0/2"
    assert hashlib.sha256(open(blend, "rb").read()).hexdigest() == digest   # the .blend is never written
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = "", "AUTO", ""
    bpy.ops.wm.read_homefile(use_empty=True)
