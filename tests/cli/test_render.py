"""``blender -c scpainter render ...`` (``cli/render.py``): a scene's conditions rendered headless."""

import json
import sys

import bpy

from tests.cli import cli_support as CS


def test_render_warns_of_frames_outside_the_recording(addon, empty_scene, tmp_path, capsys):
    """``render`` of a scene whose frame range runs past its recording sends a ``warning`` event (code
    ``outside_recording``) saying which frames, before the backend runs, and counts it in the summary."""
    from vggt_cases import drive, write

    arrays, _, _ = drive(S=2, H=12, W=16)
    assert bpy.ops.scpainter.import_vggt(filepath=write(tmp_path, arrays), depth_edge_ratio=0.0) == {"FINISHED"}
    bpy.context.scene.frame_end = 4  # the recording is frames 1-2
    blend = str(tmp_path / "short.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.read_homefile(use_empty=True)
    code = CS.cli(addon).execute(["render", blend, "--device", "cpu", "--backend-python", sys.executable])
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert code == 0, events[-1]
    (w,) = [e for e in events if e["event"] == "warning" and "output frames" in e["message"]]
    assert w["code"] == "outside_recording"
    assert w["message"].startswith("2 of the 4 output frames (3–4) lie outside the recording (frames 1–2)")
    assert events.index(w) < len(events) - 1 and events[-1]["event"] == "done" and events[-1]["warnings"] >= 1
