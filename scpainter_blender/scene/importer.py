"""Import a VGGT reconstruction: points + recorded camera + scene settings, in metric Blender world.

The heavy lifting is numpy in ``core``; this module only turns arrays into Blender data. Metric scale from a
camera height needs open3d, which Blender's Python lacks, so that one step runs in the backend subprocess.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import backend_client
from ..core import cameras, vggt
from . import camera as camera_mod
from . import points as points_mod

SCALE_MODES = ("FACTOR", "TRAJECTORY", "CAMERA_HEIGHT")


@dataclass
class ImportOptions:
    confidence_percentile: float = 50.0
    point_source: str = "depth"          # "depth" or "world_points"
    scale_mode: str = "FACTOR"           # one of SCALE_MODES
    scale_factor: float = 1.0            # metres per VGGT unit (FACTOR)
    trajectory_path: str = ""            # metric camera path (TRAJECTORY)
    camera_height: float = 1.6           # metres over the road (CAMERA_HEIGHT)
    backend_python: str = ""
    point_radius: float = 0.03           # metres
    current_frame_only: bool = False
    frame_window: int = 0
    frame_start: int = 1
    set_scene_camera: bool = True
    extrinsic_convention: str = "auto"   # "auto" (check against world_points), "world_to_camera", "camera_to_world"
    crop: str = "auto"                   # "auto" (VGGT's white padding), "none", or "left top right bottom" pixels


@dataclass
class ImportResult:
    points: bpy.types.Object
    camera: bpy.types.Object
    fit: vggt.MetricFit
    num_points: int
    timings: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    load_report: vggt.LoadReport | None = None   # convention (checked?), crop, NaN/inf pixels dropped


def metric_fit(pred: vggt.VGGTPredictions, opts: ImportOptions) -> vggt.MetricFit:
    """world_from_vggt by the chosen method (DESIGN §3)."""
    if opts.scale_mode == "FACTOR":
        return vggt.world_from_vggt_by_factor(opts.scale_factor)
    if opts.scale_mode == "TRAJECTORY":
        if not opts.trajectory_path:
            raise ValueError("scale mode TRAJECTORY needs a metric trajectory file")
        w2c, centres = vggt.load_metric_trajectory(bpy.path.abspath(opts.trajectory_path), pred.num_frames)
        return vggt.world_from_vggt_by_trajectory(pred.world_to_camera, w2c, centres)
    if opts.scale_mode == "CAMERA_HEIGHT":
        rep = pred.report  # the backend loads the file as it was loaded here: same poses, same pixels
        done = backend_client.run(["ground-plane", pred.path, "--camera-height", opts.camera_height,
                                   "--confidence-percentile", opts.confidence_percentile,
                                   "--extrinsic-convention", rep.extrinsic_convention,
                                   "--crop", *rep.crop],
                                  python=opts.backend_python)
        r = done["result"]
        return vggt.MetricFit(np.array(r["world_from_vggt"]), r["method"], r["scale"], r["residual_m"],
                              r["max_error_m"], r["details"])
    raise ValueError(f"unknown scale mode {opts.scale_mode!r}; expected one of {SCALE_MODES}")


def _tag(obj, kind, filepath, fit, opts, rep: vggt.LoadReport):
    obj["scpainter_kind"] = kind
    obj["scpainter_source"] = filepath
    obj["scpainter_world_from_vggt"] = np.asarray(fit.world_from_vggt, np.float64).ravel().tolist()
    obj["scpainter_scale_method"] = fit.method
    obj["scpainter_scale_residual_m"] = float(fit.residual_m)
    obj["scpainter_confidence_percentile"] = float(opts.confidence_percentile)
    obj["scpainter_extrinsic_convention"] = rep.extrinsic_convention
    obj["scpainter_crop"] = [int(c) for c in rep.crop]


def import_vggt(context, filepath: str, opts: ImportOptions | None = None) -> ImportResult:
    """Import ``filepath`` into ``context.scene``; returns the new objects, the metric fit and timings."""
    opts = opts or ImportOptions()
    t0 = time.perf_counter()
    filepath = os.path.abspath(bpy.path.abspath(filepath))
    # every check and refusal happens here, before anything is created: a refused file leaves the scene as it was
    pred = vggt.load_predictions(filepath, world_points=opts.point_source == "world_points",
                                 extrinsic_convention=opts.extrinsic_convention, crop=opts.crop,
                                 metres_per_unit=opts.scale_factor if opts.scale_mode == "FACTOR" else None)
    t_load = time.perf_counter()
    fit = metric_fit(pred, opts)
    t_fit = time.perf_counter()
    pts = vggt.point_cloud(pred, opts.confidence_percentile, opts.point_source, fit.world_from_vggt)
    t_unproject = time.perf_counter()

    scene = context.scene
    stem = os.path.splitext(os.path.basename(filepath))[0]
    parent_name = os.path.basename(os.path.dirname(filepath)) or stem
    coll = bpy.data.collections.new(f"SCPainter {parent_name}")
    scene.collection.children.link(coll)
    obj = points_mod.create_point_cloud(f"{parent_name} points", pts.positions, pts.colors, pts.frame, coll,
                                        radius=opts.point_radius, frame_offset=opts.frame_start)
    mod = points_mod.points_modifier(obj)
    points_mod.set_input(mod, "Current Frame Only", bool(opts.current_frame_only))
    points_mod.set_input(mod, "Frame Window", int(opts.frame_window))
    t_points = time.perf_counter()

    w2c = cameras.transform_world_to_camera(cameras.orthonormalize(pred.world_to_camera), fit.world_from_vggt)
    cam, p0, warnings = camera_mod.create_recorded_camera(f"{parent_name} recorded camera", w2c, pred.K,
                                                          pred.width, pred.height, opts.frame_start, coll)
    camera_mod.apply_render_settings(scene, p0)
    scene.frame_start = opts.frame_start
    scene.frame_end = opts.frame_start + pred.num_frames - 1
    if opts.set_scene_camera:
        scene.camera = cam
    for o, kind in ((obj, "points"), (cam, "recorded_camera")):
        _tag(o, kind, filepath, fit, opts, pred.report)
    obj["scpainter_num_frames"] = pred.num_frames
    obj["scpainter_matrix_world_at_import"] = np.array(obj.matrix_basis, dtype=np.float64).ravel().tolist()
    cam["scpainter_intrinsics"] = pred.K.ravel().tolist()
    cam["scpainter_frame_start"] = int(opts.frame_start)
    t_end = time.perf_counter()
    timings = {"load": t_load - t0, "metric_fit": t_fit - t_load, "unproject": t_unproject - t_fit,
               "points_object": t_points - t_unproject, "camera": t_end - t_points, "total": t_end - t0}
    return ImportResult(obj, cam, fit, len(pts), timings, list(pred.report.warnings) + list(warnings), pred.report)
