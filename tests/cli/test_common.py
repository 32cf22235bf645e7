"""What ``cli/common.py`` gives the scene commands (render, generate, export): ``--camera`` and ``run_scene``,
the one scene run."""

import json
import sys

import bpy

from tests.cli import cli_support as CS


def test_camera_option_runs_that_camera_into_its_folder(addon, street, tmp_path, capsys):
    """--camera NAME: that camera object's job, in its own folder inside the scene's; a name that is no camera of
    the scene is bad input naming the option and listing the cameras; without it, the scene camera."""
    cli = CS.cli(addon)
    blend = CS.street_blend(street, tmp_path, second_path=True)
    common = ["--device", "cpu", "--backend-python", sys.executable]
    scene_dir = tmp_path / "scpainter" / "Scene"
    code = cli.execute(["render", blend, "--camera", "Camera path 2 m right", *common])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    right = scene_dir / "Camera_path_2_m_right"
    assert ev["camera"] == "Camera path 2 m right" and ev["output_dir"] == str(right) and ev["frames"] == 3
    assert len(list((right / "conditions").glob("frame_*.exr"))) == 3 and not (scene_dir / CS.CAM_DIR).exists()
    code = cli.execute(["render", blend, *common])                     # the scene camera, into its own folder
    ev = CS.last_event(capsys)
    assert code == 0 and ev["camera"] == CS.CAM and ev["output_dir"] == str(scene_dir / CS.CAM_DIR), ev
    jobs = [json.loads((d / "job.json").read_text()) for d in (right, scene_dir / CS.CAM_DIR)]
    assert jobs[0]["frames"][0]["world_to_camera"] != jobs[1]["frames"][0]["world_to_camera"]
    for command, name, what in (("render", "Nope", "is no object of the scene"),
                                ("generate", "car", "is a mesh, not a camera"),
                                ("export", "Nope", "is no object of the scene")):
        extra = ["--format", "kitti"] if command == "export" else []
        assert cli.execute([command, blend, "--camera", name, *extra, *common]) == 2, command
        ev = CS.last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == "--camera", ev
        assert (f"--camera: {name!r} {what} in {blend}; its cameras: 'Camera path 2 m left', 'Camera path 2 m "
                "right', ") in ev["message"], ev
        assert "recorded camera" in ev["message"]
    bpy.ops.wm.read_homefile(use_empty=True)


def test_progress_lines_name_a_rig_camera(addon, capsys):
    """A rig job's progress events name their rig camera: six cameras' "render 1/16" are told apart."""
    common = sys.modules[addon + ".scpainter_blender.cli.common"]
    common.progress({"event": "progress", "stage": "render", "done": 1, "total": 16, "camera": "CAM_BACK"})
    common.progress({"event": "progress", "stage": "render", "done": 2, "total": 16})
    assert capsys.readouterr().err.splitlines() == ["scpainter CAM_BACK: render 1/16", "scpainter: render 2/16"]
