"""Variations from Blender: ``blender -c scpainter vary`` (a .blend, or predictions imported with the import
options) and *Make Variations*, with a library holding a mesh car (converted once by the backend)."""

import json
import os
import sys

import bpy
import numpy as np
import pytest

from scpainter_blender.core import job as J, shapes
from scpainter_blender.core.output_layout import VariationLayout


def _cli(addon):
    return sys.modules[addon + ".scpainter_blender.cli"]


def _events(capsys):
    return [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A Gaussian car and a mesh car (a car-sized box, as a GLB)."""
    import trimesh

    d = tmp_path_factory.mktemp("library")
    shapes.save_as_amodal3r(str(d / "blue.ply"), shapes.procedural_car_gaussians(count=6000, seed=7,
                                                                                paint=(0.1, 0.3, 0.8)))
    box = trimesh.creation.box(extents=(1.8, 1.5, 4.4))  # glTF is Y up: x width, y height, z length
    box.visual.face_colors = [200, 30, 30, 255]
    box.export(str(d / "van.glb"))
    return str(d)


def test_vary_headless_from_predictions_and_from_a_blend(addon, empty_scene, street, library, tmp_path, capsys):
    cli = _cli(addon)
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"variants": 4, "seed": 1, "resolution": [128, 72],
                                "camera": {"shifts_m": [-2, 2]}, "cars": {"count": [1, 2]}}))
    out = tmp_path / "npz"
    args = ["vary", street.predictions_path, "--trajectory", os.path.join(street.root, "metric.npz"),
            "--out", str(out), "--spec", str(spec), "--library", library]
    assert cli.execute(args) == 0
    done = _events(capsys)[-1]
    assert done["event"] == "done" and done["summary"]["variants"] == 4
    manifest = json.loads((out / "variation.json").read_text())
    assert {a["name"] for a in manifest["library"]} == {"blue.ply", "van.glb"}
    van = next(a for a in manifest["library"] if a["name"] == "van.glb")
    assert van["ply"].startswith(str(out / "library")) and np.allclose(sorted(van["size_m"]), [1.5, 1.8, 4.4],
                                                                        atol=0.1)
    mtime = os.stat(van["ply"]).st_mtime_ns
    base = J.load(VariationLayout(str(out)).base_job)
    assert base.scene is not None and len(base.frames) == 16

    # the same from a saved .blend, seen from a camera path, a second time: the mesh is not converted again
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"))
    bpy.ops.scpainter.new_camera_path(shift=2.0)
    path_cam = bpy.context.scene.camera.name
    bpy.context.scene.camera = next(o for o in bpy.context.scene.objects if o.type == "CAMERA" and o.name != path_cam)
    blend = str(tmp_path / "street.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    args[1:4] = [blend]
    assert cli.execute(args + ["--camera", path_cam]) == 0
    assert os.stat(van["ply"]).st_mtime_ns == mtime
    base2 = J.load(VariationLayout(str(out)).base_job)
    moved = base2.frames[0].world_to_camera[:3, 3] - base.frames[0].world_to_camera[:3, 3]
    assert np.linalg.norm(moved) == pytest.approx(2.0, abs=0.01)   # the camera path, not the scene camera

    assert cli.execute(args + ["--camera", "No Such Camera"]) == 2
    err = _events(capsys)[-1]
    assert err["field"] == "--camera" and path_cam in err["message"]
    assert cli.execute(args + ["--variants", "0"]) == 2
    assert _events(capsys)[-1]["field"] == "--variants"
    assert cli.execute(args + ["--camera-height", "1.6"]) == 2    # an import option, for a .blend: refused
    assert _events(capsys)[-1]["field"] == "--camera-height"


def test_make_variations_operator(addon, empty_scene, street, library, tmp_path):
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"))
    out = tmp_path / "ops"
    assert bpy.ops.scpainter.make_variations(library=library, folder=str(out), variants=3, seed=2) == {"FINISHED"}
    manifest = json.loads((out / "variation.json").read_text())
    assert manifest["summary"]["variants"] == 3
    placed = [e for e in manifest["variants"] if e["outcome"] == "placed"]
    for e in placed:
        job = J.load(out / e["job"])
        assert len(job.assets) == len(e["cars"]) >= 1


    # a spec file's variants and seed stand unless the artist changes them in the dialog (or a caller gives them):
    # the dialog's own values (16, 0) never replace them, nor do the values Blender remembers from the last run
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"variants": 2, "seed": 5, "resolution": [64, 36], "cars": {"count": [0, 0]}}))

    def run(name, **chosen):
        folder = tmp_path / name
        assert bpy.ops.scpainter.make_variations(spec=str(spec), folder=str(folder), **chosen) == {"FINISHED"}
        m = json.loads((folder / "variation.json").read_text())
        return m["summary"]["variants"], m["variants"][0]["seed"][0]

    assert run("spec") == (2, 5)
    assert run("chosen", variants=3, seed=9) == (3, 9)
    assert run("spec_again") == (2, 5)  # 3 and 9 are remembered by Blender, not chosen this time
