"""Write the scene as a ``job.json`` (``core.job.Job``): active camera per frame, points, removal boxes, assets.

What the job renders is what Blender's render would (``rendered_objects``): the one points object and the
assets the view layer renders, themselves or through collection instances (scene/visibility.py: each drawing an
asset of its own), the removal boxes the points object's modifiers apply; a scene with nothing to render, or two
reconstructions, is refused. Each frame is seen by the camera Blender renders it with (the scene camera as timeline
markers switch it, unless a camera is given); a camera the renderer cannot draw (orthographic, panoramic) is refused
(``drawable_camera``); the size and K are those of the image the render writes (a cropped render region included,
scene/camera.py's ``render_region``). File paths stored relative to the .blend are resolved (scene/paths.py) and
written relative to the job file. ``warnings`` says what would come out wrong without failing (frames outside the
recording).
Per output frame the scene is evaluated, so keyframes, drivers, constraints and parents are all honoured: K,
world_to_camera and the resolution are scene/camera.py's (``K_of_camera_object``, ``world_to_camera``,
``output_size``), the removal boxes scene/placement.py's (``box_matrix``), the objects found by kind
(scene/kinds.py); an asset's object_to_world is its drawn world matrix (``Placed.matrix_world``) composed with
``scpainter_file_to_data``; the points' cleaning is the depth-edge ratio they were imported with
(``point_cleaning``), so the render loads the points the viewport shows. For labels: each asset's ``class`` and
``box`` (its box object in the PLY file's coordinates, scene/asset_box.py; an asset without one exports no box and
the backend estimates it), the scene's ``fps`` and ``scene.recorded_frames`` (``recorded_frames``); the recorded
objects (scene/recorded_objects.py, ``job_objects``) as ``scene.recorded_objects``, so every camera path's job
carries them.
What the scene does not use is left out: no reconstruction, no ``scene``; no (accepted) assets, no ``assets``; no
checkpoint, no ``generate``. Generation settings are not written: the backend takes them from the checkpoint
(window, guidance, fps) and ``core.job.GENERATE_DEFAULTS``; the one exception is the baseline's inpainting method
(``generate.inpaint``), written when the scene chooses one (``Scene.scpainter_baseline_inpaint`` not Default).
"""

from __future__ import annotations

import os

import bpy
import numpy as np

from ..core.geometry import point_cloud
from ..core import job as job_mod
from ..core import labels
from . import camera as camera_mod
from . import asset_box, keys, kinds, node_groups, paths, placement, props, visibility
from . import points as points_mod
from . import recorded_objects
from . import rig as rig_scene


def _m(value):
    return np.array(value, dtype=np.float64).reshape(4, 4)


def effective_vggt_to_world(obj) -> np.ndarray:
    """The points object's vggt_to_world after the artist moved it: matrix_world · (matrix at import)^-1 · W."""
    W = props.matrix_property(obj, keys.VGGT_TO_WORLD)
    at_import = _m(obj.get(keys.MATRIX_WORLD_AT_IMPORT, np.eye(4).ravel().tolist()))
    return np.array(obj.matrix_world, dtype=np.float64) @ np.linalg.inv(at_import) @ W


def source_frames(obj, scene_frame: int) -> list:
    """VGGT frames whose points go into an output frame, ascending: with the points object's *Current Frame Only*
    those whose scene frame (``points.scene_frame_offsets`` + the modifier's Frame Offset: for a multi-camera
    recording every sensor's frame grouped at a scene frame) lies within its Frame Window of ``scene_frame``, as the
    viewport shows them; every frame otherwise."""
    offsets = points_mod.scene_frame_offsets(obj)
    mod = points_mod.points_modifier(obj)
    if mod is not None and node_groups.get_input(mod, "Current Frame Only"):
        k = int(node_groups.get_input(mod, "Frame Window"))
        centre = scene_frame - int(node_groups.get_input(mod, "Frame Offset"))
        return [int(i) for i in np.flatnonzero(np.abs(offsets - centre) <= k)]
    return list(range(len(offsets)))


def point_cleaning(obj) -> job_mod.PointCleaning:
    """The job's point cleaning for a points object: the depth-edge ratio its viewport points were imported with
    (``scpainter_depth_edge_ratio``; 0.0 is off), so the backend renders the points the artist saw; a points object
    imported before that property existed was not filtered: null (off). Outlier removal, which the import does not
    run, stays at the job's default."""
    ratio = float(obj.get(keys.DEPTH_EDGE_RATIO, 0.0))
    return job_mod.PointCleaning(depth_edge_ratio=ratio if ratio > 0 else None)


def build_job(context, job_path: str, output_dir: str | None = None, checkpoint: str = "",
              camera=None) -> job_mod.Job:
    """The job for the scene's frame range, seen by ``camera``, or (None) by the camera Blender renders each frame
    with: the scene camera, switched by timeline markers bound to cameras as the render switches it."""
    scene = context.scene
    if camera is not None:
        drawable_camera(camera, None)
    elif scene.camera is None and not any(m.camera for m in scene.timeline_markers):
        drawable_camera(None, None)  # no camera at all; the ones the frames use are checked frame by frame below
    job_dir = os.path.dirname(os.path.abspath(job_path))
    frames = output_frames(scene)
    pts, assets = rendered_objects(context)
    boxes = placement.applied_removal_boxes(pts) if pts is not None else []
    out_frames = []
    asset_m = {a.name: {} for a in assets}
    asset_boxes = {}
    current = scene.frame_current
    rig = rig_obj = None
    try:
        for f in frames:
            scene.frame_set(f)  # also switches the scene camera by the markers, as the render does
            cam = drawable_camera(camera or scene.camera, f)
            if f == frames[0]:  # a camera path with a rig: a rig job, its rig as it stands at the first frame
                rig_obj, path_camera = kinds.rig_of(cam), cam
                if rig_obj is not None:
                    for c in kinds.rig_sensors(rig_obj, kinds.RIG_CAMERA):
                        drawable_camera(c, None)
                    rig = rig_scene.read_rig(rig_obj)
            elif cam != path_camera and (rig_obj is not None or kinds.rig_of(cam) is not None):
                rigged = path_camera if rig_obj is not None else cam
                raise props.SceneError("scene.timeline_markers", f"a timeline marker switches the camera from "
                                       f"{path_camera.name!r} to {cam.name!r} at frame {f}, and {rigged.name!r} "
                                       "has a camera rig: a rig job follows one camera path",
                                       hint="remove the markers bound to cameras, or run one camera path "
                                            "(All Camera Paths, --camera)")
            src = source_frames(pts, f) if pts is not None else []
            if rig is not None:
                out_frames.append(job_mod.Frame(f, None, None, src, ego_to_world=rig_scene.ego_to_world(rig_obj)))
            else:
                K, w2c = camera_mod.K_of_camera_object(scene, cam), camera_mod.world_to_camera(cam)
                out_frames.append(job_mod.Frame(f, K, w2c, src))
            for a in assets:
                asset_m[a.name][f] = a.matrix_world() @ props.matrix_property(a.obj, keys.FILE_TO_DATA)
                if a.name not in asset_boxes:  # the box in the asset's own frame, as it stands at the first frame
                    asset_boxes[a.name] = asset_box.job_box(a.obj)
    finally:
        scene.frame_set(current)
    size = None if rig is not None else camera_mod.output_size(scene)  # a rig's cameras have their own sizes
    if size is not None and min(size) < 1:
        raise props.SceneError("scene.render.border", f"the render region crops the frame to {size[0]} x {size[1]} "
                               "pixels", hint="widen the render region (Output Properties > Format > Render Region) "
                                              "or turn off Crop to Render Region")
    sc = None
    if pts is not None:
        sc = job_mod.Scene(_job_path(pts, job_dir), effective_vggt_to_world(pts),
                           confidence_percentile=float(pts.get(keys.CONFIDENCE_PERCENTILE,
                                                                    point_cloud.CONFIDENCE_PERCENTILE)),
                           # how the import read the file: the backend loads the same poses and pixels
                           extrinsic_convention=str(pts.get(keys.EXTRINSIC_CONVENTION, "world_to_camera")),
                           crop=[int(v) for v in pts.get(keys.CROP, [0, 0, 0, 0])],
                           removal_boxes=[job_mod.RemovalBox(*placement.box_matrix(b)) for b in boxes],
                           point_cleaning=point_cleaning(pts),
                           recorded_frames=recorded_frames(scene, pts),
                           recorded_objects=recorded_objects.job_objects(scene, frames))
    return job_mod.Job(size, out_frames, os.path.relpath(output_dir or job_dir, job_dir),
                       scene=sc,
                       assets=[job_mod.Asset(a.name, _job_path(a.obj, job_dir), asset_m[a.name],
                                             asset_box.category(a.obj), asset_boxes[a.name])
                               for a in assets],
                       generate=_generate_settings(checkpoint, props.baseline_inpaint(scene)),
                       fps=frame_rate(scene), rig=rig)


#: Blender camera types the condition renderer draws (an OpenCV pinhole): perspective only.
DRAWABLE_CAMERA_TYPES = ("PERSP",)


def drawable_camera(cam, frame: int | None):
    """``cam`` when the renderer can draw what it sees: a camera object of a ``DRAWABLE_CAMERA_TYPES`` type.
    SceneError naming the camera (and the frame, for a camera the markers switch to) otherwise: none at all, not a
    camera, or an orthographic or panoramic one, which a pinhole job would draw wrong (never exported as one)."""
    at = f" at frame {frame}" if frame is not None else ""
    if cam is None:
        raise props.SceneError("scene.camera", "the scene has no active camera",
                               hint="add one (or a camera path) before exporting a job")
    if cam.type != "CAMERA":
        raise props.SceneError(f"objects[{cam.name!r}]", f"is not a camera{at}", hint="give a camera object")
    kind = cam.data.type
    if kind not in DRAWABLE_CAMERA_TYPES:
        what = ("orthographic" if kind == "ORTHO" else
                f"panoramic ({getattr(cam.data, 'panorama_type', '?')})" if kind == "PANO" else kind)
        raise props.SceneError(f"objects[{cam.name!r}].data.type", f"the camera{at} is {what} ({kind}): the "
                               "renderer draws perspective cameras only",
                               hint="set its Camera Properties > Lens > Type to Perspective, or render through "
                                    "another camera")
    return cam


def _job_path(obj, job_dir: str) -> str:
    """The file ``obj`` was imported from (``keys.SOURCE``: absolute or relative to the .blend, ``paths``), relative
    to the job's folder (absolute when no relative path reaches it: another drive)."""
    return paths.relative_to(paths.resolve(obj[keys.SOURCE]), job_dir)


def output_frames(scene) -> list:
    """The job's frames: the scene's frame range, first to last, every ``frame_step``-th frame as Blender's own
    render takes them."""
    return list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))


def rendered_objects(context) -> tuple:
    """(points object or None, [assets]) a job of ``context``'s scene renders: what Blender's render of the view
    layer includes (scene/visibility.py), the assets not rejected at stage 2. SceneError when two reconstructions
    render (``visibility.points_object``) or nothing does: a job of holes only would "succeed" with nothing in it."""
    scene, view_layer = context.scene, context.view_layer
    pts = visibility.points_object(scene, view_layer)
    in_scene = kinds.gaussian_assets(scene)
    # a collection instance may draw a car from a collection the scene does not hold (only in the .blend's data)
    elsewhere = [o for o in bpy.data.objects if kinds.is_kind(o, kinds.GAUSSIAN_ASSET) and o not in set(in_scene)]
    candidates = [o for o in in_scene + elsewhere if o.get(keys.REVIEW) != "rejected"]
    assets = visibility.rendered_placements(candidates, view_layer)
    if pts is None and not assets:
        left_out = [o.name for o in kinds.point_clouds(scene)] + [o.name for o in candidates]
        why = (f"; not rendered (hidden from renders, or in a collection excluded from the view layer): "
               f"{', '.join(map(repr, left_out))}") if left_out else ""
        raise props.SceneError("scene.objects", f"nothing to render: no reconstruction and no car asset{why}",
                               hint="import one (Import VGGT Reconstruction, or Import Gaussian Asset for a car) or "
                                    "show the hidden one in renders; a job of the camera alone would be all holes")
    return pts, assets


def warnings(context) -> list:
    """What a job of the scene would render wrong without failing, as ``warning`` events' fields (``message``,
    ``code``): output frames outside the recording (``labels.OUTSIDE_FLAG``), where the recorded camera and the
    camera paths made from it stand still and the points are only what the recording saw. [] when the scene does not
    say which frames it recorded. SceneError as ``rendered_objects`` (two reconstructions render)."""
    pts = visibility.points_object(context.scene, context.view_layer)
    recorded = recorded_frames(context.scene, pts) if pts is not None else None
    if recorded is None:
        return []
    frames = output_frames(context.scene)
    outside = [f for f in frames if not recorded[0] <= f <= recorded[1]]
    if not outside:
        return []
    return [{"code": labels.OUTSIDE_FLAG,
             "message": f"{len(outside)} of the {len(frames)} output frames ({_spans(outside)}) lie outside the "
                        f"recording (frames {recorded[0]}–{recorded[1]}): there the camera stands still and the "
                        f"condition images are mostly holes; set the frame range to {recorded[0]}–{recorded[1]} "
                        "(Output Properties > Frame Range) unless that is what you want"}]


def job_notes(context) -> list:
    """For the panel, before anything runs: ("WARNING", message) per ``warnings``, or ("ERROR", why and what to
    do) when a job of the scene would be refused for its reconstructions (two render)."""
    try:
        return [("WARNING", w["message"]) for w in warnings(context)]
    except props.SceneError as e:
        return [("ERROR", f"{e.message} ({e.hint})" if e.hint else e.message)]


def _spans(frames) -> str:
    """Sorted frame numbers as spans: "1–3, 17–24"."""
    spans = []
    for f in frames:
        if spans and f == spans[-1][1] + 1:
            spans[-1][1] = f
        else:
            spans.append([f, f])
    return ", ".join(str(a) if a == b else f"{a}–{b}" for a, b in spans)


def frame_rate(scene) -> float | None:
    """The job's ``fps``: the scene's frames per second, ``render.fps / render.fps_base``; None (not written) when
    outside the job's bounds (``GENERATE_NUMBER_BOUNDS["fps"]``), which only label timestamps would use."""
    fps = scene.render.fps / scene.render.fps_base
    lo, hi = job_mod.GENERATE_NUMBER_BOUNDS["fps"]
    return float(fps) if lo <= fps <= hi else None


def recorded_frames(scene, pts) -> list | None:
    """``scene.recorded_frames``: [first, last] scene frames the recording covers, [frame_start, frame_start +
    the last scene frame offset] from the recorded camera imported with ``pts`` (``kinds.recorded_camera_of``: a
    multi-camera recording's reference sensor's, which starts it) and the points' scene frame per VGGT frame
    (``points.scene_frame_offsets``: ``scpainter_num_frames`` frames of one camera, or the scene frames a
    multi-camera recording's frames are grouped in); None when either is missing (a .blend imported before them,
    or a recorded camera deleted)."""
    cam = kinds.recorded_camera_of(scene, pts)
    if cam is None or keys.FRAME_START not in cam or keys.NUM_FRAMES not in pts:
        return None
    start, offsets = int(cam[keys.FRAME_START]), points_mod.scene_frame_offsets(pts)
    return [start, start + int(offsets.max())] if len(offsets) else None


def _generate_settings(checkpoint: str, inpaint: str | None) -> job_mod.GenerateSettings | None:
    """``generate``: the checkpoint (when the preferences name one) and the baseline's inpainting method (when the
    scene chooses one); None when neither, so the backend's defaults and its ``auto`` generator apply."""
    if not checkpoint and inpaint is None:
        return None
    return job_mod.GenerateSettings(checkpoint=checkpoint or None, inpaint=inpaint)


def export_job(context, job_path: str, **kw) -> job_mod.Job:
    """``build_job``, validated and written to ``job_path``."""
    return job_mod.save(job_path, build_job(context, job_path, **kw))
