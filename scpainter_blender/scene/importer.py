"""Import a VGGT reconstruction: points + recorded camera + scene settings, in metric Blender world.

The heavy lifting is numpy in ``core``; this module only turns arrays into Blender data. The options and their
checks live in ``core.import_options``. All three metric-scale modes run here, in Blender's own process (the
camera-height one is ``core.geometry.metric_scale.camera_height_fit``; no backend). With ``objects`` the drive's
tracked boxes come in too (``core.recording``, mapped through the recorded camera in metres: scene/recorded_objects.py).

A multi-camera recording (a sensors sidecar, ``core.vggt.sensors``: ``opts.sensors``, or
``<predictions stem>.sensors.json`` beside the predictions) gets one recorded camera per sensor, named
``"<folder> <SENSOR>"``, each keyed only at its own frames' scene frames (``Sensors.scene_frames``: scene frame k is
the reference sensor's k-th frame; the others' frames go to the reference frame nearest in time), the reference
sensor's camera first (the scene camera; the one ``kinds.recorded_camera_of`` finds); and the recording's rig
(``core.geometry.rig_fit``), stored on the points object as JSON (``keys.RECORDING_RIG``, read back by
``scene/recording_rig.py``), its sensor per VGGT frame (``keys.FRAME_SENSORS``: *Import Recorded Objects* maps
through the same camera, ``recorded_objects.map_recording``) and its scene frame per VGGT frame
(``keys.SCENE_FRAMES``, per point the ``scene_frame`` attribute: scene/points.py), so *Current Frame Only* and a
job's source frames take every sensor's frame grouped at a scene frame.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.geometry import cameras, metric_scale, point_cloud, rig_fit, similarity
from ..core import errors
from ..core.import_options import DEPTH_EDGE_RATIO, ERROR_PATH, SCALE_MODES, ImportOptions
from ..core.recording import reader as recording
from ..core.vggt import predictions as vggt, npz as vggt_io, sensors as sensors_mod
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
    # a multi-camera recording: every recorded camera (the reference sensor's first, ``camera``), the sidecar read
    # and the rig fitted (None: one recorded camera, as before)
    cameras: list = field(default_factory=list)
    sensors_path: str | None = None
    rig_fit: rig_fit.RigFit | None = None


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


def read_sensors(filepath: str, opts: ImportOptions, num_frames: int) -> sensors_mod.Sensors | None:
    """The sensors sidecar of the predictions ``filepath`` (absolute): ``opts.sensors``, else
    ``<stem>.sensors.json`` beside them when there is one; None without (one recorded camera). Its frame count must
    be the predictions' (InputError naming the sidecar's ``frames``)."""
    path = os.path.abspath(bpy.path.abspath(opts.sensors)) if opts.sensors else sensors_mod.default_path(filepath)
    if not opts.sensors and not os.path.isfile(path):
        return None
    return sensors_mod.read(path).check_frames(num_frames, filepath)


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
    sensors = read_sensors(filepath, opts, pred.num_frames)   # a refused sidecar: before the points are made
    t_load = time.perf_counter()
    fit = metric_fit(pred, opts)
    t_fit = time.perf_counter()
    pts = point_cloud.point_cloud(pred, opts.confidence_percentile, opts.point_source, fit.vggt_to_world,
                                  depth_edge_ratio=opts.edge_ratio)
    t_unproject = time.perf_counter()
    w2c = similarity.transform_world_to_camera(cameras.orthonormalize(pred.world_to_camera), fit.vggt_to_world)
    fitted = offsets = None
    # which VGGT frames each recorded camera gets, the reference sensor's first: {name: frame indices}
    groups = {"": np.arange(pred.num_frames)}
    if sensors is not None:
        fitted = rig_fit.fit(sensors, cameras.rigid_inverse(w2c), pred.K, (pred.width, pred.height))
        offsets = sensors.scene_frames()
        groups = sensors.camera_frames()   # the reference (fitted.reference) first
    mapped = None
    if opts.objects:  # read, mapped and checked against the recording before anything is made
        rec = recording.read(os.path.abspath(bpy.path.abspath(opts.objects)), opts.objects_format,
                             opts.objects_scene, opts.objects_camera)
        # a multi-camera recording: the boxes are seen from the sensor they name (default: the reference); the
        # same path as Import Recorded Objects later
        scene_offsets = offsets if offsets is not None else np.arange(pred.num_frames)
        mapped = recorded_mod.map_recording(rec, groups, scene_offsets, opts.frame_start, opts.objects_camera,
                                            lambda _, idx, __: w2c[idx])
        recorded_mod.check_new(context.scene, mapped.objects)

    scene = context.scene
    stem = os.path.splitext(os.path.basename(filepath))[0]
    parent_name = os.path.basename(os.path.dirname(filepath)) or stem
    coll = collection
    if coll is None:
        coll = bpy.data.collections.new(f"SCPainter {parent_name}")
        scene.collection.children.link(coll)
    # a multi-camera recording's points carry their scene frame too: Current Frame Only shows every sensor's
    obj = points_mod.create_point_cloud(f"{parent_name} points", pts.positions, pts.colors, pts.frame, coll,
                                        radius=opts.point_radius, frame_offset=opts.frame_start,
                                        scene_frame=offsets[pts.frame] if offsets is not None else None)
    mod = points_mod.points_modifier(obj)
    node_groups.set_input(mod, "Current Frame Only", bool(opts.current_frame_only))
    node_groups.set_input(mod, "Frame Window", int(opts.frame_window))
    t_points = time.perf_counter()

    made_cameras, warnings, p0 = [], [], None
    for name, idx in groups.items():
        frames = opts.frame_start + (offsets[idx] if offsets is not None else np.arange(len(idx)))
        c, p, w = camera_mod.create_recorded_camera(f"{parent_name} {name or 'recorded camera'}", w2c[idx],
                                                    pred.K[idx], pred.width, pred.height, opts.frame_start, coll,
                                                    frames=frames)
        p0 = p if p0 is None else p0
        warnings += [f"{name}: {x}" if name else x for x in w]
        _tag(c, kinds.RECORDED_CAMERA, filepath, fit, opts, pred.report)
        c[keys.INTRINSICS] = pred.K[idx].ravel().tolist()
        c[keys.FRAME_START] = int(frames[0])
        if name:
            c[keys.SENSOR] = name
        made_cameras.append(c)
    cam = made_cameras[0]
    camera_mod.apply_render_settings(scene, p0)
    scene.frame_start = opts.frame_start
    scene.frame_end = opts.frame_start + (int(offsets.max()) if offsets is not None else pred.num_frames - 1)
    kept = scene.camera if kinds.is_kind(scene.camera, kinds.CAMERA_PATH) else None
    if opts.set_scene_camera and kept is None:
        scene.camera = cam
    _tag(obj, kinds.POINTS, filepath, fit, opts, pred.report)
    obj[keys.NUM_FRAMES] = pred.num_frames
    if offsets is not None:  # which VGGT frames a job's output frame takes (scene/job_export.py's source_frames)
        obj[keys.SCENE_FRAMES] = [int(v) for v in offsets]
        obj[keys.FRAME_SENSORS] = [str(v) for v in sensors.sensor]   # which recorded camera each VGGT frame is
    obj[keys.MATRIX_WORLD_AT_IMPORT] = np.array(obj.matrix_basis, dtype=np.float64).ravel().tolist()
    if fitted is not None:
        obj[keys.RECORDING_RIG] = json.dumps(fitted.rig.to_dict())
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
                        opts.edge_ratio, pts.depth_edge_points, kept if opts.set_scene_camera else None, made,
                        made_cameras, sensors.path if sensors is not None else None, fitted)
