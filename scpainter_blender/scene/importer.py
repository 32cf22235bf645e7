"""Import a VGGT reconstruction: points + recorded camera + scene settings, in metric Blender world.

The heavy lifting is numpy in ``core``; this module only turns arrays into Blender data. The options and their
checks live in ``core.import_options``. All three metric-scale modes run here, in Blender's own process (the
camera-height one is ``core.geometry.metric_scale.camera_height_fit``; no backend). With ``objects`` the drive's
tracked boxes come in too (``core.recording``, mapped through the recorded camera in metres: scene/recorded_objects.py).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.geometry import cameras, metric_scale, point_cloud, similarity
from ..core import errors
from ..core.import_options import DEPTH_EDGE_RATIO, ERROR_PATH, SCALE_MODES, ImportOptions
from ..core.recording import reader as recording
from ..core.vggt import predictions as vggt, npz as vggt_io
from . import camera as camera_mod
from . import keys, kinds, paths
from . import node_groups
from . import points as points_mod
from . import recorded_objects as recorded_mod


@dataclass
class ImportResult:
    points: bpy.types.Object
    camera: bpy.types.Object
    fit: metric_scale.MetricFit
    num_points: int
    timings: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    load_report: vggt.LoadReport | None = None   # convention (checked?), crop, NaN/inf pixels dropped
    depth_edge_ratio: float | None = None        # the depth-edge test's ratio used (None: off)
    depth_edge_points: int = 0                   # confident pixels it left out
    # the camera path that stays the scene camera (the import adds the recorded camera without taking its place)
    kept_camera: bpy.types.Object | None = None
    recorded_objects: list = field(default_factory=list)   # the recorded objects made (``opts.objects``)


def metric_fit(pred: vggt.VGGTPredictions, opts: ImportOptions) -> metric_scale.MetricFit:
    """vggt_to_world by the chosen method (docs/design.md §3)."""
    if opts.scale_mode == "FACTOR":
        return metric_scale.vggt_to_world_by_factor(opts.scale_factor)
    if opts.scale_mode == "TRAJECTORY":
        if not opts.trajectory_path:
            raise errors.InputError(ERROR_PATH, "trajectory_path", "scale mode TRAJECTORY needs a metric trajectory "
                                    "file", hint="choose the file: .npz world_to_camera, xyz or TUM text")
        path = bpy.path.abspath(opts.trajectory_path)
        w2c, centres = metric_scale.load_metric_trajectory(path, pred.num_frames)
        return metric_scale.vggt_to_world_by_trajectory(pred.world_to_camera, w2c, centres, path=path)
    if opts.scale_mode == "CAMERA_HEIGHT":
        return metric_scale.camera_height_fit(pred, opts.camera_height, opts.confidence_percentile)
    raise ValueError(f"unknown scale mode {opts.scale_mode!r}; expected one of {SCALE_MODES}")


def _tag(obj, kind, filepath, fit, opts, rep: vggt.LoadReport):
    kinds.mark(obj, kind)
    obj[keys.SOURCE] = paths.stored(filepath)  # relative to the saved .blend: a moved project reads its own
    obj[keys.VGGT_TO_WORLD] = np.asarray(fit.vggt_to_world, np.float64).ravel().tolist()
    obj[keys.SCALE_METHOD] = fit.method
    obj[keys.SCALE_RESIDUAL_M] = float(fit.residual_m)
    obj[keys.CONFIDENCE_PERCENTILE] = float(opts.confidence_percentile)
    obj[keys.EXTRINSIC_CONVENTION] = rep.extrinsic_convention
    obj[keys.CROP] = [int(c) for c in rep.crop]
    # a custom property cannot hold None: 0.0 is off. A scene imported before this property existed has none: its
    # points were not filtered, and job_export writes null (off) for it
    obj[keys.DEPTH_EDGE_RATIO] = opts.edge_ratio or 0.0


def import_vggt(context, filepath: str, opts: ImportOptions | None = None, collection=None) -> ImportResult:
    """Import ``filepath`` into ``context.scene``; returns the new objects, the metric fit and timings. The objects
    go into ``collection`` (default: a new "SCPainter <folder>" collection). With ``opts.set_scene_camera`` the
    recorded camera becomes the scene camera, unless the scene camera is a camera path: an artist re-importing
    keeps looking through (and rendering) their path (``ImportResult.kept_camera``)."""
    opts = (opts or ImportOptions()).check()
    t0 = time.perf_counter()
    filepath = os.path.abspath(bpy.path.abspath(filepath))
    # every check and refusal happens here, before anything is created: a refused file leaves the scene as it was
    pred = vggt_io.load_predictions(filepath, world_points=opts.point_source == "world_points",
                                    extrinsic_convention=opts.extrinsic_convention, crop=opts.crop,
                                    metres_per_unit=opts.scale_factor if opts.scale_mode == "FACTOR" else None)
    t_load = time.perf_counter()
    fit = metric_fit(pred, opts)
    t_fit = time.perf_counter()
    pts = point_cloud.point_cloud(pred, opts.confidence_percentile, opts.point_source, fit.vggt_to_world,
                                  depth_edge_ratio=opts.edge_ratio)
    t_unproject = time.perf_counter()
    w2c = similarity.transform_world_to_camera(cameras.orthonormalize(pred.world_to_camera), fit.vggt_to_world)
    mapped = None
    if opts.objects:  # read, mapped and checked against the recording before anything is made
        rec = recording.read(os.path.abspath(bpy.path.abspath(opts.objects)), opts.objects_format,
                             opts.objects_scene, opts.objects_camera)
        mapped = recording.recorded_objects(rec, w2c, opts.frame_start)
        recorded_mod.check_new(context.scene, mapped.objects)

    scene = context.scene
    stem = os.path.splitext(os.path.basename(filepath))[0]
    parent_name = os.path.basename(os.path.dirname(filepath)) or stem
    coll = collection
    if coll is None:
        coll = bpy.data.collections.new(f"SCPainter {parent_name}")
        scene.collection.children.link(coll)
    obj = points_mod.create_point_cloud(f"{parent_name} points", pts.positions, pts.colors, pts.frame, coll,
                                        radius=opts.point_radius, frame_offset=opts.frame_start)
    mod = points_mod.points_modifier(obj)
    node_groups.set_input(mod, "Current Frame Only", bool(opts.current_frame_only))
    node_groups.set_input(mod, "Frame Window", int(opts.frame_window))
    t_points = time.perf_counter()

    cam, p0, warnings = camera_mod.create_recorded_camera(f"{parent_name} recorded camera", w2c, pred.K,
                                                          pred.width, pred.height, opts.frame_start, coll)
    camera_mod.apply_render_settings(scene, p0)
    scene.frame_start = opts.frame_start
    scene.frame_end = opts.frame_start + pred.num_frames - 1
    kept = scene.camera if kinds.is_kind(scene.camera, kinds.CAMERA_PATH) else None
    if opts.set_scene_camera and kept is None:
        scene.camera = cam
    for o, kind in ((obj, kinds.POINTS), (cam, kinds.RECORDED_CAMERA)):
        _tag(o, kind, filepath, fit, opts, pred.report)
    obj[keys.NUM_FRAMES] = pred.num_frames
    obj[keys.MATRIX_WORLD_AT_IMPORT] = np.array(obj.matrix_basis, dtype=np.float64).ravel().tolist()
    cam[keys.INTRINSICS] = pred.K.ravel().tolist()
    cam[keys.FRAME_START] = int(opts.frame_start)
    made = recorded_mod.add_objects(context, mapped.objects) if mapped is not None else []
    if mapped is not None:
        warnings = list(warnings) + list(mapped.warnings)
    t_end = time.perf_counter()
    timings = {"load": t_load - t0, "metric_fit": t_fit - t_load, "unproject": t_unproject - t_fit,
               "points_object": t_points - t_unproject, "camera": t_end - t_points, "total": t_end - t0}
    if pts.depth_edge_points > len(pts):  # a ratio too small for the clip's resolution: most points gone
        warnings = list(warnings) + [
            f"the depth-edge test left out {pts.depth_edge_points:,} of {pts.depth_edge_points + len(pts):,} points: "
            f"the ratio {opts.edge_ratio} is small for this clip (the default is {DEPTH_EDGE_RATIO}; 0 turns it off)"]
    return ImportResult(obj, cam, fit, len(pts), timings, list(pred.report.warnings) + list(warnings), pred.report,
                        opts.edge_ratio, pts.depth_edge_points, kept if opts.set_scene_camera else None, made)
