"""The README's main command: build the ground-truth street, import it into a new .blend (with the street's own
parked cars as recorded objects, from their ground truth written as a scpainter.objects/1 file), park a procedural
Gaussian car beside the road, add a camera path 2 m to the left of the drive, export the job, render the
condition layers and their labels with the backend (``python -m backend render``), generate the video — with the
SCPainter model when a checkpoint is configured (``--checkpoint`` or ``$SCPAINTER_CHECKPOINT``), otherwise the
OpenCV inpainting baseline, saying so and how to use a checkpoint instead —, export the labels in every dataset
format (``EXPORT_FORMATS``) and render a Cycles preview.

    .venv/bin/python tools/demo.py [--out build/demo] [--scale camera_height|trajectory|factor]
                                   [--checkpoint DIR --steps N] [--frames N] [--no-exports] [--no-preview]
    .venv/bin/python tools/demo.py --surround [--rig-scale 0.2]

``--surround`` (docs/design.md §17) is the surround variant: the same street, car and camera path, then *Add Camera
Rig* mounts nuScenes' six cameras and its 32-beam top LiDAR on the path (the cameras at ``--rig-scale`` of
1600 x 900), *Render Conditions* renders every camera and casts the LiDAR's sweeps, and *Export Labels* writes the
nuScenes dataset (``export/nuscenes``); it leaves out the generation, the single-camera exports and the preview.

Prints one JSON object at the end: where the .blend and the preview are, the metric scale found against the
street's ground truth, and timings (``--frames N``: the drive's first N frames; ``--no-exports``, ``--no-preview``:
without those steps, ``exports`` empty and ``preview`` null: what the test of the checkpoint's generation runs, the
plain demo's test checking the rest). Blender's own configuration is not touched: the add-on is built with
Blender's extension tool and installed into a private user folder under --out.
"""

import argparse
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from scpainter_blender.core.backend_protocol import DEFAULT_DEVICE, DEVICE_NAMES, EXPORT_FORMATS  # noqa: E402
from scpainter_blender.core.output_layout import OutputLayout  # noqa: E402
from tools import blender_env  # noqa: E402


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=os.path.join(ROOT, "build", "demo"))
    p.add_argument("--scale", choices=["camera_height", "trajectory", "factor"], default="camera_height",
                   help="how the import finds metric scale (default: the known 1.6 m camera height)")
    p.add_argument("--samples", type=int, default=4, help="Cycles samples for the preview")
    p.add_argument("--shift", type=float, default=2.0, help="sideways shift of the new camera path (m, + left)")
    p.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE, help="backend device")
    p.add_argument("--checkpoint", default=os.environ.get("SCPAINTER_CHECKPOINT", ""),
                   help="SCPainter checkpoint folder (python -m backend init-checkpoint makes one); set as the "
                        "add-on preference, so the exported job generates")
    p.add_argument("--steps", type=int, help="sampler steps for the generation (default: the job's, 25)")
    p.add_argument("--surround", action="store_true",
                   help="the surround variant: nuScenes' six cameras and LiDAR on the camera path, rendered and "
                        "exported as a nuScenes dataset (no generation, no other exports, no preview)")
    p.add_argument("--frames", type=int, help="the drive's first N frames only (default: all 16)")
    p.add_argument("--no-exports", action="store_true", help="leave out the labels' dataset exports")
    p.add_argument("--no-preview", action="store_true", help="leave out the Cycles preview")
    p.add_argument("--rig-scale", type=float, default=0.2,
                   help="--surround: each camera's resolution as a share of nuScenes' 1600 x 900 (default 0.2)")
    args = p.parse_args(argv)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()

    from scpainter_blender.street.dataset import ensure_street

    log("street: generating or loading from the cache ...")
    if args.checkpoint:  # checked before minutes of work: a wrong path is one clear message, exit 2
        from backend.model import checkpoint as ckpt_mod
        from scpainter_blender.core.errors import InputError

        try:
            ckpt_mod.check(ckpt_mod.resolve(args.checkpoint))
        except InputError as e:
            log(f"demo: --checkpoint: {e}" + (f" ({e.hint})" if e.hint else ""))
            return 2
    street = ensure_street(log=lambda m: None)
    made = street.info.get("generated_in_s")
    log(f"street: {street.root} ({'generated in %.0f s' % made if made else 'cached'})")

    pkg = blender_env.install_for_script(out)
    import bpy

    log(f"add-on: {pkg} installed and enabled")

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.name = "street"
    # the street's own cars as the recording's tracked boxes: imported with the reconstruction, so every parked car
    # the camera sees is labelled (core/recording, scene/recorded_objects.py)
    kw = {"scale_mode": args.scale.upper(),
          "objects": street.write_objects(os.path.join(out, "street_objects.json"))}
    if args.scale == "camera_height":
        kw["camera_height"] = street.params.camera_height_m
    elif args.scale == "trajectory":
        kw["trajectory_path"] = os.path.join(street.root, "metric.npz")
    t_import = time.perf_counter()
    if bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, **kw) != {"FINISHED"}:
        raise SystemExit("import failed")
    t_import = time.perf_counter() - t_import
    if args.frames:  # the scene's range, which the camera path, the job and every result follow
        scene.frame_end = min(scene.frame_end, scene.frame_start + max(1, args.frames) - 1)
    from scpainter_blender.scene import kinds

    pts, cam = kinds.point_cloud(scene), kinds.recorded_camera(scene)
    import numpy as np

    # a procedural car saved the way Amodal3R saves its output, parked on the left strip, stood on the road
    from scpainter_blender.core import shapes

    car_ply = os.path.join(out, "car_01.ply")
    shapes.save_as_amodal3r(car_ply, shapes.procedural_car_gaussians(count=30000, seed=7, paint=(0.1, 0.3, 0.8)))
    scene.cursor.location = (-6.25, 9.0, 0.5)
    if bpy.ops.scpainter.import_gaussians(filepath=car_ply) != {"FINISHED"}:
        raise SystemExit("asset import failed")
    car = bpy.context.active_object
    bpy.ops.scpainter.snap_to_ground()
    bpy.ops.scpainter.check_assets()
    # the new camera path: the drive shifted sideways, keyed on every frame; it becomes the scene camera
    scene.camera = cam
    if bpy.ops.scpainter.new_camera_path(shift=args.shift) != {"FINISHED"}:
        raise SystemExit("camera path failed")
    path_cam = scene.camera
    if args.checkpoint:
        bpy.context.preferences.addons[pkg].preferences.checkpoint_dir = os.path.abspath(args.checkpoint)
    scene.scpainter_output_dir = out  # jobs, conditions and the video go here (saved with the .blend)
    from scpainter_blender.scene import keys, props

    cam_out = props.camera_output_dir(scene, path_cam)  # the camera path's own folder: <out>/<its name>/
    job_path = OutputLayout(cam_out).job
    bpy.ops.scpainter.export_job(filepath=job_path)
    truth = float(street.metric()["metres_per_unit"])
    scale = float(np.cbrt(np.linalg.det(np.array(pts[keys.VGGT_TO_WORLD]).reshape(4, 4)[:3, :3])))

    blend = os.path.join(out, "street_surround.blend" if args.surround else "street_demo.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    if args.surround:
        return surround(args, bpy, pkg, path_cam, cam_out, job_path, blend, street, t0, t_import)

    # the condition layers (I, M, M_a, Z per frame) and, with a checkpoint, the video: the add-on's own operators
    # (blocking in background mode) run the backend in a subprocess and load the results behind the camera
    prefs = bpy.context.preferences.addons[pkg].preferences
    prefs.device = args.device.upper()
    log("backend: rendering the condition layers ...")
    t_cond = time.perf_counter()
    if bpy.ops.scpainter.render_conditions() != {"FINISHED"}:
        raise SystemExit("rendering the conditions failed: see the message above")
    t_cond = time.perf_counter() - t_cond
    cond = conditions_summary(cam_out)

    t_gen = time.perf_counter()
    log(f"backend: generating the video with {args.checkpoint} ..." if args.checkpoint else
        "backend: generating the baseline video (no checkpoint: OpenCV inpainting of the holes, no model) ...")
    if bpy.ops.scpainter.generate(steps=args.steps or 0) != {"FINISHED"}:
        raise SystemExit("generation failed: see the message above")
    generation = generation_summary(cam_out)
    t_gen = time.perf_counter() - t_gen

    # the labels as datasets: every frame's boxes, masks and camera (rendered with the conditions) in each format
    t_export = time.perf_counter()
    exports = {}
    for fmt in () if args.no_exports else EXPORT_FORMATS:
        log(f"backend: exporting the labels as {fmt} ...")
        if bpy.ops.scpainter.export_labels(format=fmt) != {"FINISHED"}:
            raise SystemExit(f"the {fmt} export failed: see the message above")
        exports[fmt] = OutputLayout(cam_out).export(fmt)
    t_export = time.perf_counter() - t_export
    labels = labels_summary(cam_out)
    bpy.ops.wm.save_mainfile()  # again, now with the results loaded behind the camera path

    preview, t_render = (None, 0.0) if args.no_preview else render_preview(bpy, scene, out, args.samples)

    summary = {"blend": blend, "preview": preview, "job": job_path, "asset": car_ply,
               "recorded_objects": [o.name for o in kinds.recorded_objects(scene)],
               "camera_path": path_cam.name, "shift_m": args.shift, "conditions": cond, "generation": generation,
               "labels": labels, "exports": exports,
               "asset_location": list(car.location), "asset_stage1": car[keys.STAGE1],
               "ground_truth_frame": street.frame_path("recorded", 0),
               "street": street.root, "points": len(pts.data.vertices), "camera": cam.name,
               "scale_method": pts[keys.SCALE_METHOD], "scale_m_per_unit": scale,
               "scale_truth_m_per_unit": truth, "scale_error_percent": 100 * (scale / truth - 1),
               "scale_residual_m": pts[keys.SCALE_RESIDUAL_M],
               "seconds": {"street": made or 0.0, "import": t_import, "conditions": t_cond, "generation": t_gen,
                           "exports": t_export, "preview": t_render,
                           "total": time.perf_counter() - t0}}
    print(json.dumps(summary, indent=1))
    log(f"\nSaved {blend}" + (f"\n      {preview}" if preview else "")
        + f"\n      {cond['folder']} ({cond['frames']} frames of condition layers)"
        f"\n      {generation['video']} ({generation['description']})"
        f"\n      {labels['labelled_previews'][0] if labels['labelled_previews'] else ''} (labels drawn; "
        f"{len(labels['labelled_previews'])} frames)"
        + "".join(f"\n      {path} ({fmt})" for fmt, path in exports.items()))
    if generation["model"] == "baseline":
        log(f"\nThis video is the baseline, not the model. {USE_A_CHECKPOINT}")
    return 0


def surround(args, bpy, pkg, path_cam, cam_out, job_path, blend, street, t0, t_import) -> int:
    """The surround variant (``--surround``): nuScenes' rig on the camera path, rendered with its LiDAR and exported
    as nuScenes; prints its summary."""
    from scpainter_blender.core import files
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.scene import kinds

    scene = bpy.context.scene
    bpy.context.view_layer.objects.active = path_cam
    if bpy.ops.scpainter.add_camera_rig(preset="nuscenes", scale=args.rig_scale, lidar=True) != {"FINISHED"}:
        raise SystemExit("adding the camera rig failed: see the message above")
    scene.camera = path_cam
    bpy.ops.scpainter.export_job(filepath=job_path)
    bpy.ops.wm.save_mainfile()
    job = job_mod.load(job_path)
    prefs = bpy.context.preferences.addons[pkg].preferences
    prefs.device = args.device.upper()
    log(f"backend: rendering {len(job.rig.cameras)} cameras and the {job.rig.lidar.name} sweeps ...")
    t_cond = time.perf_counter()
    if bpy.ops.scpainter.render_conditions() != {"FINISHED"}:
        raise SystemExit("rendering the rig failed: see the message above")
    t_cond = time.perf_counter() - t_cond
    log("backend: exporting the rig as nuScenes ...")
    t_export = time.perf_counter()
    if bpy.ops.scpainter.export_labels(format="nuscenes") != {"FINISHED"}:
        raise SystemExit("the nuScenes export failed: see the message above")
    t_export = time.perf_counter() - t_export
    bpy.ops.wm.save_mainfile()
    layout = OutputLayout(cam_out)
    sweeps = [files.read_json(layout.lidar_sweep_info(e.frame, job.rig.lidar.name)) for e in job.frames]
    summary = {"blend": blend, "job": job_path, "camera_path": path_cam.name, "street": street.root,
               "rig": {"cameras": [c.name for c in job.rig.cameras], "resolution": list(job.rig.cameras[0].resolution),
                       "lidar": job.rig.lidar.model},
               "rig_objects": sorted(o.name for o in kinds.objects_of_kind(scene, kinds.RIG_CAMERA)),
               "frames": len(job.frames),
               "camera_folders": {c.name: layout.camera(c.name).root for c in job.rig.cameras},
               "sweeps": [{"frame": s_["frame"], "returns": s_["returns"],
                           "returns_per_source": s_["returns_per_source"]} for s_ in sweeps],
               "surround_pictures": [layout.surround(e.frame) for e in job.frames],
               "nuscenes": layout.export("nuscenes"),
               "seconds": {"import": t_import, "render": t_cond, "export": t_export,
                           "total": time.perf_counter() - t0}}
    print(json.dumps(summary, indent=1))
    log(f"\nSaved {blend}\n      {layout.root} ({len(job.rig.cameras)} cameras x {len(job.frames)} frames, "
        f"{len(sweeps)} LiDAR sweeps)\n      {summary['surround_pictures'][0]} (the cameras and the sweep from above)"
        f"\n      {summary['nuscenes']} (nuScenes)")
    return 0


#: What the demo says after a baseline video: how to get the model's instead.
USE_A_CHECKPOINT = ("For SCPainter's video, make a checkpoint from a Stable Video Diffusion img2vid(-xt) snapshot on "
                    "disk (`.venv/bin/python -m backend init-checkpoint --svd SVD_DIR --out CHECKPOINT_DIR`) and run "
                    "`make demo ARGS=\"--checkpoint CHECKPOINT_DIR\"` (or set $SCPAINTER_CHECKPOINT).")


def generation_summary(output_dir: str) -> dict:
    """Where the video is and which generator made it (``generated/manifest.json``'s ``model``, ``description``)."""
    from scpainter_blender.core import files

    layout = OutputLayout(output_dir)
    manifest = files.read_json(layout.manifest)
    summary = {"video": layout.video, "frames_dir": layout.generated, "skipped": False,
               "model": manifest["model"], "description": manifest["description"]}
    if manifest["model"] == "baseline":
        summary["use_a_checkpoint"] = USE_A_CHECKPOINT
    return summary


def render_preview(bpy, scene, out: str, samples: int) -> tuple[str, float]:
    """A viewport-free preview: Cycles on the CPU from the recorded camera, points in their own colours, saved as
    ``out/preview.png``; (its path, seconds)."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"  # emission colour = source image colour
    world = bpy.data.worlds.new("preview background")
    world.color = (0.05, 0.05, 0.05)
    scene.world = world
    scene.frame_set(scene.frame_start)
    scene.render.image_settings.file_format = "PNG"
    preview = os.path.join(out, "preview.png")
    scene.render.filepath = preview
    t_render = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return preview, time.perf_counter() - t_render


def labels_summary(output_dir: str) -> dict:
    """The labels render wrote: per frame the objects seen (track, class, synthetic and the measures exports carry:
    ``core.labels.CARRIED_MEASURES``) and the flags; where the labelled previews are."""
    from scpainter_blender.core import files, labels
    from scpainter_blender.core.output_layout import FRAME_LABELS, LABELLED_PREVIEW

    folder = OutputLayout(output_dir).conditions
    frames = []
    for path in FRAME_LABELS.in_folder(folder):
        lab = files.read_json(path)
        frames.append({"frame": lab["frame"], "timestamp_s": lab["timestamp_s"], "coverage": lab["coverage"],
                       "flags": lab["flags"],
                       "objects": [{"track_id": o["track_id"], "class": o["class"], "synthetic": o["synthetic"],
                                    **{k: o[k] for k in labels.CARRIED_MEASURES}}
                                   for o in lab["objects"] if o["visible_pixels"]]})
    return {"frames": frames, "labelled_previews": LABELLED_PREVIEW.in_folder(folder)}


def conditions_summary(output_dir: str) -> dict:
    """Where the condition layers are and what they hold: per-frame hole fraction and asset-mask coverage."""
    from backend.render import channels
    from scpainter_blender.core.output_layout import CONDITION_EXR, CONDITION_PREVIEW

    folder = OutputLayout(output_dir).conditions
    exrs = CONDITION_EXR.in_folder(folder)
    holes, asset_pixels = [], []
    for f in exrs:
        layers = channels.read(f)
        holes.append(float(layers[channels.HOLE].mean()))
        asset_pixels.append(int((layers[channels.ASSET_MASK] > 0.5).sum()))
    return {"folder": folder, "frames": len(exrs), "hole_fraction": holes, "asset_pixels": asset_pixels,
            "previews": CONDITION_PREVIEW.in_folder(folder)}


if __name__ == "__main__":
    sys.exit(main())
