"""``blender -c scpainter``'s dispatch (``scpainter_blender/cli/__init__.py``), called as Blender calls it
(execute(argv)): bad input is exit 2 naming its file and field, anything else exit 1; --help returns;
execute with the bpy module, the add-on not enabled."""

import json
import os
import sys

import bpy
import numpy as np

from tests.cli import cli_support as CS


def test_bad_input_exit_code_2(addon, empty_scene, tmp_path, capsys):
    cli = CS.cli(addon)
    assert cli.execute(["import", str(tmp_path / "nope.npz")]) == 2
    assert "nope.npz" in CS.last_event(capsys)["message"]
    assert cli.execute(["import"]) == 2  # argparse errors are reported, not sys.exit() from inside Blender
    assert "predictions" in CS.last_event(capsys)["message"]
    assert cli.execute(["import", "x.npz", "--camera-height", "1.6", "--scale-factor", "2"]) == 2
    # options no import can use are bad input named by the option, not an internal error (0 was taken for 1.0)
    for args, flag in ((["--scale-factor", "0"], "--scale-factor"), (["--scale-factor", "nan"], "--scale-factor"),
                       (["--confidence-percentile", "150"], "--confidence-percentile")):
        assert cli.execute(["import", str(tmp_path / "x.npz"), *args]) == 2, args
        ev = CS.last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == flag, ev
    assert len(bpy.data.objects) == 0
    not_blend = tmp_path / "predictions.npz"                   # a scene command given the wrong kind of file
    np.savez(not_blend, depth=np.zeros(3))
    assert cli.execute(["render", str(not_blend)]) == 2
    ev = CS.last_event(capsys)
    assert ev["file"] == str(not_blend) and "cannot open it as a scene" in ev["message"]
    # batch: a data root that is no folder, and a list's misplaced data-root: line, before any work
    assert cli.execute(["batch", "a.blend", "--data-root", str(not_blend)]) == 2
    ev = CS.last_event(capsys)
    assert ev["file"] == "(command line)" and ev["field"] == "--data-root" and "is not a folder" in ev["message"]
    (tmp_path / "list.txt").write_text("a.blend\ndata-root: .\n")   # a data-root: line after a path
    assert cli.execute(["batch", "--list", str(tmp_path / "list.txt")]) == 2
    ev = CS.last_event(capsys)
    assert ev["file"] == str(tmp_path / "list.txt") and ev["field"] == "line 2"


def test_input_error_by_name_is_exit_2_anything_else_exit_1(addon, empty_scene, tmp_path, capsys, monkeypatch):
    """Bad input is an InputError, caught by name (exit 2, file and field); a plain ValueError is a bug (exit 1,
    its traceback on standard error), as in the backend."""
    cli = CS.cli(addon)
    errors = sys.modules[addon + ".scpainter_blender.core.errors"]
    importer = sys.modules[addon + ".scpainter_blender.scene.importer"]
    for argv, field in ((["batch", "--command", "render"], "items"), (["render", "x.blend", "--device", "gpu"],
                                                                     "--device"),
                        (["batch", "a.blend", "--shard", "2/2"], "--shard"), (["batch", "a.blend", "--shard", "x"],
                                                                              "--shard"),
                        (["render", "x.blend", "--backend-python", "/nonexistent/python"], "--backend-python"),
                        (["generate", "x.blend", "--checkpoint", str(tmp_path / "none")], "--checkpoint")):
        assert cli.execute(argv) == 2, argv
        ev = CS.last_event(capsys)
        assert ev["event"] == "error" and ev["file"] == errors.COMMAND_LINE and ev["field"] == field, ev

    def shape_bug(*args, **kwargs):
        raise ValueError("shape bug: (3,) and (4,)")

    monkeypatch.setattr(importer, "import_vggt", shape_bug)
    assert cli.execute(["import", str(tmp_path / "p.npz")]) == 1
    captured = capsys.readouterr()
    ev = json.loads([line for line in captured.out.splitlines() if line.startswith("{")][-1])
    assert ev["message"] == "ValueError: shape bug: (3,) and (4,)" and "file" not in ev
    assert "not a problem with the input" in ev["hint"]
    assert "Traceback (most recent call last)" in captured.err and "in shape_bug" in captured.err

    def bad_file(context, path, opts):
        raise errors.InputError(path, "depth", "expected (S, H, W) or (S, H, W, 1)", hint="save it again")

    monkeypatch.setattr(importer, "import_vggt", bad_file)
    assert cli.execute(["import", str(tmp_path / "p.npz")]) == 2
    ev = CS.last_event(capsys)
    assert ev["file"] == str(tmp_path / "p.npz") and ev["field"] == "depth" and ev["hint"] == "save it again"


def test_help_returns_instead_of_exiting(addon, capsys):
    """--help prints the usage and returns 0: argparse's sys.exit would end Blender."""
    cli = CS.cli(addon)
    for argv in (["--help"], ["render", "--help"], ["batch", "--help"]):
        assert cli.execute(argv) == 0, argv
        assert capsys.readouterr().out.startswith("usage: "), argv


def test_execute_works_with_the_bpy_module_without_the_add_on_enabled(tmp_path):
    # README: "with the bpy module the same entry point is execute(argv)": it must not need register() first
    import subprocess

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    blend = tmp_path / "empty.blend"
    script = ("import sys, json, bpy; bpy.ops.wm.read_homefile(use_empty=True); "
              f"bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r}); "
              "from scpainter_blender import cli; sys.exit(cli.execute(['batch', sys.argv[1]]))")
    r = subprocess.run([sys.executable, "-c", script, str(blend)], cwd=root, capture_output=True, text=True,
                       timeout=300)
    done = json.loads([line for line in r.stdout.splitlines() if line.startswith("{")][-1])
    assert r.returncode == 1 and done["event"] == "done", r.stderr[-2000:]
    (item,) = done["items"]
    # the scene has nothing to render: bad input named, not an AttributeError reported as a bug
    assert item["status"] == "failed" and "bug" not in item and item.get("field"), item
    assert done["counts"] == {"failed": 1} and done["jobs"] == 1
