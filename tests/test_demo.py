"""The README's main command (tools/demo.py), run as a user runs it, on the cached street."""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_demo_writes_blend_and_preview(street, tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "demo.py"), "--out", str(out),
                           "--samples", "1"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{"):])
    assert os.path.getsize(summary["blend"]) > 1_000_000
    assert os.path.getsize(summary["preview"]) > 10_000
    assert summary["street"] == street.root
    assert abs(summary["scale_error_percent"]) < 0.5  # camera-height scale against the street's truth
    assert summary["points"] > 1_000_000
    assert "Saved" in proc.stderr and summary["blend"] in proc.stderr

    import bpy

    bpy.ops.wm.open_mainfile(filepath=summary["blend"])  # the .blend opens with the import in it
    scene = bpy.context.scene
    kinds = sorted(o.get("scpainter_kind", "") for o in scene.objects)
    by_kind = {o.get("scpainter_kind"): o for o in scene.objects}
    scene.frame_set(scene.frame_start)
    gap = (by_kind["camera_path"].matrix_world.translation - by_kind["recorded_camera"].matrix_world.translation)
    assert scene.camera.name == summary["camera_path"] and abs(gap.length - 2.0) < 1e-3  # the 2 m shifted path
    bg = scene.camera.data.background_images   # the condition previews (Render Conditions), then the video
    path = summary["camera_path"]                     # results are named after the camera that saw them
    assert f"SCPainter Conditions · {path}" in bpy.data.images   # kept in the .blend although the video replaced it
    assert scene.camera.data.show_background_images and bg[0].image.name == f"SCPainter Baseline · {path}"
    assert os.path.dirname(summary["job"]) == os.path.join(str(out), "Camera_path_2_m_left")   # its own folder
    assert kinds == ["asset_box", "asset_front", "camera_path", "gaussian_asset", "points", "recorded_camera",
                     *["recorded_object"] * 5]   # the street's own parked cars, from their ground truth
    assert abs(summary["asset_location"][2]) < 0.05  # stood on the road (z = 0)
    from scpainter_blender.core import job

    j = job.load(summary["job"]).to_dict()
    assert len(j["frames"]) == 16 and j["assets"][0]["name"] == "car_01"
    assert sorted(o["id"] for o in j["scene"]["recorded_objects"]) == [f"street_car_{i}" for i in range(1, 6)]
    labelled = {o["track_id"] for fr in summary["labels"]["frames"] for o in fr["objects"] if not o["synthetic"]}
    assert len(labelled) >= 3   # the parked cars the 2 m path sees (3 of the 5) are labelled, as recorded objects
    # the condition layers of the 2 m shifted path, rendered by the backend: every frame, the car in view
    cond = summary["conditions"]
    assert cond["frames"] == 16 and len(cond["previews"]) == 16
    assert all(0.05 < h < 0.8 for h in cond["hole_fraction"])
    assert cond["asset_pixels"][0] > 1000  # the car fills part of the first frames
    from backend.render import channels

    first = os.path.join(cond["folder"], "frame_000001.exr")
    layers = channels.read(first)
    assert sorted(layers) == ["B", "G", "R", "Z", "asset_mask", "hole", "instance"]
    import OpenEXR

    with OpenEXR.File(first, header_only=True) as f:  # lossless ZIP, the passes named for compositors
        assert f.header()["compression"] == OpenEXR.ZIP_COMPRESSION
        assert sorted(c.name for c in f.header()["channels"]) == sorted(channels.FILE_NAMES.values())
    img = bpy.data.images.load(first)  # Blender opens it as one image of four passes
    node_tree = bpy.data.node_groups.new("demo_passes", "CompositorNodeTree")
    node = node_tree.nodes.new("CompositorNodeImage")
    node.image = img
    assert img.type == "MULTILAYER" and {"image", "hole", "asset_mask", "depth"} <= {o.name for o in node.outputs}
    bpy.data.node_groups.remove(node_tree)
    bpy.data.images.remove(img)
    assert "conditions" in proc.stderr
    # no checkpoint: the demo still ends in a video, the inpainting baseline, and says so and how to use the model
    gen = summary["generation"]
    assert gen["model"] == "baseline" and "no model" in gen["description"]
    assert "init-checkpoint" in gen["use_a_checkpoint"] and "--checkpoint" in gen["use_a_checkpoint"]
    assert "not the model" in proc.stderr and gen["video"] in proc.stderr
    from backend.generate.video import mp4_metadata, read_mp4

    assert read_mp4(gen["video"]).shape[0] == 16 and "no model" in mp4_metadata(gen["video"])["comment"]
    assert len([f for f in os.listdir(gen["frames_dir"]) if f.endswith(".png")]) == 16
    assert f"SCPainter Video (Baseline) · {path}" in bpy.data.movieclips  # the .blend was saved after the run
    # labels for every frame, the parked car among them, drawn on the previews and exported in three formats
    labs = summary["labels"]
    assert len(labs["frames"]) == 16 and len(labs["labelled_previews"]) == 16
    seen = [o for f in labs["frames"] for o in f["objects"] if o["synthetic"]]
    assert seen and all(o["track_id"] == 1 and o["class"] == "car" for o in seen)
    assert f"SCPainter Labels · {path}" in bpy.data.images
    ex = summary["exports"]
    assert sorted(os.listdir(os.path.join(ex["kitti"], "label_2")))[0] == "000000.txt"
    assert os.path.isfile(os.path.join(ex["coco"], "annotations.json"))
    assert os.path.isfile(os.path.join(ex["openlabel"], "openlabel.json"))
    bpy.ops.wm.read_homefile(use_empty=True)


def test_demo_generates_when_a_checkpoint_is_configured(street, tiny_checkpoint, tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "demo.py"), "--out", str(out),
                           "--checkpoint", tiny_checkpoint, "--steps", "2", "--device", "cpu", "--frames", "8",
                           "--no-exports", "--no-preview"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{"):])
    gen = summary["generation"]
    assert gen["skipped"] is False and os.path.getsize(gen["video"]) > 1000 and gen["model"] == "scpainter"
    assert "use_a_checkpoint" not in gen and "not the model" not in proc.stderr
    assert len([f for f in os.listdir(gen["frames_dir"]) if f.endswith(".png")]) == 8   # every frame of --frames 8
    assert "generate 2/2" in proc.stdout
    # the drive's first 8 frames (one sampler window), the exports and the preview left out: the plain demo's test
    # checks those on all 16 frames (the suite's time)
    assert summary["conditions"]["frames"] == 8
    assert summary["exports"] == {} and summary["preview"] is None and not os.path.exists(out / "preview.png")


def test_demo_surround_renders_the_rig_and_its_nuscenes_export_keeps_every_inserted_box(street, tmp_path):
    """``tools/demo.py --surround`` (docs/design.md §17): nuScenes' six cameras and LiDAR on the camera path, every
    camera rendered and labelled, a sweep per frame, and a nuScenes dataset that nuscenes-devkit loads and whose
    evaluation filter keeps every inserted box (their LiDAR points are the simulated sweeps')."""
    pytest.importorskip("nuscenes.nuscenes")
    from scpainter_blender.core import rig
    from tests.backend.export.nuscenes_checks import evaluation_filter

    out = tmp_path / "surround"
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "demo.py"), "--out", str(out), "--surround"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{"):])
    assert summary["rig"]["cameras"] == list(rig.NUSCENES_CAMERAS) and summary["rig"]["resolution"] == [320, 180]
    assert len(summary["rig_objects"]) == 6 and summary["frames"] == 16
    assert all(s["returns"] > 3000 for s in summary["sweeps"])            # the street around it, every frame
    assert max(s["returns_per_source"]["car_01"] for s in summary["sweeps"]) > 50   # the parked car is hit
    for name, folder in summary["camera_folders"].items():
        assert len([f for f in os.listdir(os.path.join(folder, "conditions")) if f.startswith("labels_")]) == 16
    assert all(os.path.getsize(p) > 10_000 for p in summary["surround_pictures"])
    from nuscenes.nuscenes import NuScenes

    version = [d for d in os.listdir(summary["nuscenes"]) if d.startswith("v1.0")][0]
    nusc = NuScenes(version, summary["nuscenes"], verbose=False)
    assert sorted(nusc.sample[0]["data"]) == sorted(list(rig.NUSCENES_CAMERAS) + ["LIDAR_TOP"])
    inserted, kept_inserted, kept = evaluation_filter(nusc)
    assert inserted >= 2 and kept_inserted == inserted      # the car at every keyframe it is in: none dropped
    assert kept > inserted                                  # the street's parked cars are annotated and kept too
