"""``blender -c scpainter import ...`` (``cli/import_predictions.py``): predictions imported headless, saved, and
the JSON summary of what loading decided and dropped."""

import os

import bpy
import numpy as np

from tests.cli import cli_support as CS


def test_import_and_save(addon, empty_scene, street, tmp_path, capsys):
    out = tmp_path / "not yet" / "batch.blend"     # a folder that does not exist yet is made
    objects = street.write_objects(str(tmp_path / "objects.json"))   # the street's cars as recorded objects
    code = CS.cli(addon).execute(["import", street.predictions_path, "--trajectory",
                                os.path.join(street.root, "metric.npz"), "--save", str(out), "--objects", objects,
                                "--proposals", "accept"])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    assert ev["recorded_objects"] == [f"car street_car_{i}" for i in range(1, 6)]
    assert ev["proposals"] == []   # every parked car the points show is covered by its recorded object
    assert ev["event"] == "done" and ev["scale_method"] == "trajectory"
    assert abs(ev["scale"] - float(street.metric()["metres_per_unit"])) < 1e-4
    assert ev["blend"] == str(out) and out.stat().st_size > 1_000_000
    assert sorted(os.listdir(out.parent)) == ["batch.blend"]       # no temporary file left
    bpy.ops.wm.open_mainfile(filepath=str(out))
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    assert len(pts.data.vertices) == ev["points"]
    M = np.array(pts["scpainter_vggt_to_world"]).reshape(4, 4)
    assert np.abs(M - street.metric()["vggt_to_world"]).max() < 1e-4
    recorded = [o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "recorded_object"]
    assert sorted(o["scpainter_track_id"] for o in recorded) == [f"street_car_{i}" for i in range(1, 6)]  # saved
    assert not any(o["scpainter_ignore"] for o in recorded)
    assert not [o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "proposal"]
    bpy.ops.wm.read_homefile(use_empty=True)


def test_import_convention_crop_and_report(addon, empty_scene, tmp_path, capsys):
    """--extrinsic-convention and --crop; the JSON summary says what loading decided and dropped."""
    from vggt_cases import drive, pad, write

    from scpainter_blender.core.geometry import cameras as C

    cli = CS.cli(addon)
    arrays, w2c, _ = drive(H=22, W=32)
    c2w = dict(pad(arrays, 5, 5), extrinsic=C.rigid_inverse(w2c))
    path = write(tmp_path, c2w)
    assert cli.execute(["import", path, "--scale-factor", "3"]) == 2
    msg = CS.last_event(capsys)["message"]
    assert "'extrinsic': holds camera-to-world poses" in msg and " m from the file's world_points" in msg
    assert "--extrinsic-convention on the command line): camera_to_world" in msg
    assert len(bpy.data.objects) == 0
    assert cli.execute(["import", path, "--crop", "1 2"]) == 2
    assert "crop '1 2'" in CS.last_event(capsys)["message"]
    assert cli.execute(["import", path, "--extrinsic-convention", "sideways"]) == 2
    capsys.readouterr()

    assert cli.execute(["import", path, "--extrinsic-convention", "camera_to_world", "--crop", "0 5 0 5"]) == 0
    ev = CS.last_event(capsys)
    rep = ev["predictions"]
    assert rep["extrinsic_convention"] == "camera_to_world" and not rep["extrinsic_convention_checked"]
    assert rep["crop"] == [0, 5, 0, 5] and rep["crop_requested"] == "explicit" and rep["original_size"] == [32, 32]
    assert (bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y) == (32, 22)
    bpy.ops.wm.read_homefile(use_empty=True)

    # no world_points, a few NaN depths: imported, and the summary says the convention was not checked
    plain = {k: v for k, v in arrays.items() if not k.startswith("world_points")}
    plain["depth"] = plain["depth"].copy()
    plain["depth"][0, 3, :2] = np.nan
    path = write(tmp_path, plain, "plain.npz")
    assert cli.execute(["import", path]) == 0
    ev = CS.last_event(capsys)
    rep = ev["predictions"]
    assert rep["extrinsic_convention"] == "world_to_camera" and rep["extrinsic_convention_checked"] is False
    assert rep["nonfinite_pixels"] == {"depth": [2, 0, 0, 0]} and rep["dropped_pixels"] == 2
    assert rep["crop"] == [0, 0, 0, 0] and rep["crop_requested"] == "auto"
    assert any("not checked (the file has no world_points)" in w for w in ev["warnings"])
    assert any("dropped 2 pixels" in w for w in ev["warnings"])
    bpy.ops.wm.read_homefile(use_empty=True)


def test_import_depth_edge_ratio(addon, empty_scene, tmp_path, capsys):
    """--depth-edge-ratio: a ratio, or off / 0; the default is the job's; the summary says what it left out; a
    ratio no job can hold is bad input named by the option."""
    from vggt_cases import drive, write

    from scpainter_blender.core import job as J

    cli = CS.cli(addon)
    S, H, W = 2, 12, 16
    path = write(tmp_path, drive(S=S, H=H, W=W)[0])  # random depth per pixel: every pixel is a depth edge
    default = J.POINT_CLEANING["depth_edge_ratio"]
    for args, ratio, points in (([], default, 0), (["--depth-edge-ratio", "off"], None, S * H * W),
                                (["--depth-edge-ratio", "0"], None, S * H * W),
                                (["--depth-edge-ratio", "100"], 100.0, S * H * W)):   # no jump is 100× a depth
        bpy.ops.wm.read_homefile(use_empty=True)
        assert cli.execute(["import", path, "--confidence-percentile", "0", *args]) == 0, args
        ev = CS.last_event(capsys)
        assert (ev["depth_edge_ratio"], ev["points"], ev["depth_edge_points"]) == (ratio, points, S * H * W - points)
        pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
        assert pts["scpainter_depth_edge_ratio"] == (ratio or 0.0) and len(pts.data.vertices) == points
    bpy.ops.wm.read_homefile(use_empty=True)
    for value in ("-0.1", "1e-5", "nan", "200", "sometimes"):
        assert cli.execute(["import", path, "--depth-edge-ratio", value]) == 2, value
        ev = CS.last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == "--depth-edge-ratio", ev
        assert "expected a fraction of the pixel's depth" in ev["message"] and "off" in ev["message"]
    assert len(bpy.data.objects) == 0
