"""Import a VGGT reconstruction: points + recorded camera + scene settings, in metric Blender world.

The heavy lifting is numpy in ``core``; this module only turns arrays into Blender data. All three metric-scale
modes run here, in Blender's own process (the camera-height one with ``core.geometry.fits``'s RANSAC; no backend).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.geometry import cameras, fits as geometry, metric_scale, point_cloud, similarity
from ..core import errors
from ..core.vggt import predictions as vggt, npz as vggt_io
from ..core import job as job_mod
from . import camera as camera_mod
from . import kinds
from . import node_groups
from . import points as points_mod

SCALE_MODES = ("FACTOR", "TRAJECTORY", "CAMERA_HEIGHT")
#: The ``path`` of an InputError about an import option (``field``: the ``ImportOptions`` name).
OPTIONS = "(import options)"
#: The depth-edge test's ratio when none is given: the job's own default (``core.job.POINT_CLEANING``, the one place
#: it is written), so the viewport shows the points a job exported with no further setting renders.
DEPTH_EDGE_RATIO = job_mod.POINT_CLEANING["depth_edge_ratio"]


@dataclass
class ImportOptions:
    confidence_percentile: float = 50.0
    point_source: str = "depth"          # "depth" or "world_points"
    scale_mode: str = "FACTOR"           # one of SCALE_MODES
    scale_factor: float = 1.0            # metres per VGGT unit (FACTOR)
    trajectory_path: str = ""            # metric camera path (TRAJECTORY)
    camera_height: float = 1.6           # metres over the road (CAMERA_HEIGHT)
    point_radius: float = 0.03           # metres
    current_frame_only: bool = False
    frame_window: int = 0
    frame_start: int = 1
    set_scene_camera: bool = True
    extrinsic_convention: str = "auto"   # "auto" (check against world_points), "world_to_camera", "camera_to_world"
    crop: str = "auto"                   # "auto" (VGGT's white padding), "none", or "left top right bottom" pixels
    # drop pixels whose depth jumps by more than this fraction of their own to a neighbour (VGGT's "flying pixels",
    # core.geometry.point_cloud.depth_edges); None or 0: off. Stored on the objects; the exported job renders with it.
    depth_edge_ratio: float | None = DEPTH_EDGE_RATIO

    @property
    def edge_ratio(self) -> float | None:
        """The depth-edge ratio as ``point_cloud`` and the job take it: None when off (None or 0)."""
        return None if self.depth_edge_ratio is None or self.depth_edge_ratio == 0 else float(self.depth_edge_ratio)

    def check(self) -> "ImportOptions":
        """Refuse options no import can use, before any file is read: InputError with path ``OPTIONS`` and the
        option's name as field (the UI's property limits keep the panel inside these; scripts and the command
        line are not)."""
        def bad(name, message):
            return errors.InputError(OPTIONS, name, message)

        number = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)  # noqa: E731
        if not (number(self.confidence_percentile) and 0 <= self.confidence_percentile <= 100):
            raise bad("confidence_percentile", f"expected a percentile in [0, 100], got {self.confidence_percentile}")
        if self.scale_mode not in SCALE_MODES:
            raise bad("scale_mode", f"expected one of {list(SCALE_MODES)}, got {self.scale_mode!r}")
        if self.point_source not in ("depth", "world_points"):
            raise bad("point_source", f"expected 'depth' or 'world_points', got {self.point_source!r}")
        if self.scale_mode == "FACTOR" and not (number(self.scale_factor) and self.scale_factor > 0):
            raise bad("scale_factor", f"expected metres per VGGT unit > 0, got {self.scale_factor}")
        if not (number(self.point_radius) and self.point_radius >= 0):
            raise bad("point_radius", f"expected metres >= 0, got {self.point_radius}")
        if isinstance(self.frame_window, bool) or not isinstance(self.frame_window, int) or self.frame_window < 0:
            raise bad("frame_window", f"expected a number of frames >= 0, got {self.frame_window!r}")
        lo, hi = job_mod.DEPTH_EDGE_RATIO_BOUNDS  # the job's bounds: whatever the import takes, the export writes
        r = self.depth_edge_ratio
        if r is not None and not (number(r) and (r == 0 or lo <= r <= hi)):
            raise errors.InputError(OPTIONS, "depth_edge_ratio", f"expected a fraction of the pixel's depth in "
                                   f"[{lo:g}, {hi:g}], or 0 for off, got {r!r}",
                                   hint=f"0 turns the depth-edge test off; the default is {DEPTH_EDGE_RATIO}")
        return self


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


def metric_fit(pred: vggt.VGGTPredictions, opts: ImportOptions) -> metric_scale.MetricFit:
    """vggt_to_world by the chosen method (docs/design.md §3)."""
    if opts.scale_mode == "FACTOR":
        return metric_scale.vggt_to_world_by_factor(opts.scale_factor)
    if opts.scale_mode == "TRAJECTORY":
        if not opts.trajectory_path:
            raise errors.InputError(OPTIONS, "trajectory_path", "scale mode TRAJECTORY needs a metric trajectory file",
                                   hint="choose the file: .npz world_to_camera, xyz or TUM text")
        path = bpy.path.abspath(opts.trajectory_path)
        w2c, centres = metric_scale.load_metric_trajectory(path, pred.num_frames)
        return metric_scale.vggt_to_world_by_trajectory(pred.world_to_camera, w2c, centres, path=path)
    if opts.scale_mode == "CAMERA_HEIGHT":
        return camera_height_fit(pred, opts.camera_height, opts.confidence_percentile)
    raise ValueError(f"unknown scale mode {opts.scale_mode!r}; expected one of {SCALE_MODES}")


class GroundPlaneError(vggt.PredictionsError):
    """Camera-height scale impossible for this predictions file: too few confident points in the lower image rows,
    or only collinear ones (``field`` "depth"); no level plane among them holding enough of them, or a plane the
    cameras do not stand over (``field`` "(camera height)"). The hint says what to do instead."""


#: What to do instead, for each way the camera-height fit fails.
_GROUND_HINTS = {
    "depth": "the ground is found among the confident pixels of the lower 40 % of each image: lower the "
             "Confidence Percentile, or give the scale as a factor or a metric trajectory",
    "(camera height)": "the road must be visible in the lower part of the images, under cameras looking ahead; "
                       "otherwise give the scale as a factor or a metric trajectory",
}


def camera_height_fit(pred: vggt.VGGTPredictions, camera_height: float, confidence_percentile: float = 50.0,
                      seed: int = 0) -> metric_scale.MetricFit:
    """Metric ``vggt_to_world`` from a known camera height (metres) over the road, in this process.

    Ground candidates (``point_cloud.ground_candidates``: confident pixels of the lower 40 % of each image, at most
    200,000, seeded) → ``geometry.fit_ground_plane`` (seeded RANSAC within 30° of the cameras' up axis, inliers
    closer than 1 % of the median candidate distance, refined by least squares) → ``vggt_to_world_by_camera_height``
    (scale = height / median camera-to-plane distance; the road becomes z = 0). ``details`` adds the plane fit's
    ``inliers``, ``candidates``, ``nonfinite_candidates``, ``inlier_rms_vggt``, ``tilt_deg``, ``threshold_vggt``
    (VGGT units) to the fit's own (``plane_inlier_rms_m`` among them). Raises ``GroundPlaneError`` naming
    ``pred.path``.
    """
    if not (np.isfinite(camera_height) and camera_height > 0):
        raise GroundPlaneError(pred.path, "(camera height)", f"the camera height must be a positive number of "
                                                             f"metres, got {camera_height}",
                               hint="give the camera's height over the road in metres, such as 1.6")
    pts = point_cloud.ground_candidates(pred, confidence_percentile, seed=seed)
    try:
        g = geometry.fit_ground_plane(pts, pred.world_to_camera, seed=seed)
    except geometry.PlaneFitError as e:
        field = "depth" if e.reason in ("too_few", "degenerate") else "(camera height)"
        raise GroundPlaneError(pred.path, field, f"no road plane for the camera-height scale: {e}",
                               hint=_GROUND_HINTS[field]) from None
    try:
        fit = metric_scale.vggt_to_world_by_camera_height(g.plane, pred.world_to_camera, camera_height,
                                                            plane_inlier_rms=g.inlier_rms, path=pred.path)
    except errors.InputError as e:  # cameras on the plane or looking straight down at it: same error type here
        field = "(camera height)" if e.field == "(file)" else e.field
        raise GroundPlaneError(pred.path, field, e.message, hint=e.hint or _GROUND_HINTS["(camera height)"]) \
            from None
    fit.details.update({"inliers": g.num_inliers, "candidates": g.candidates, "nonfinite_candidates": g.nonfinite,
                        "inlier_rms_vggt": g.inlier_rms, "tilt_deg": g.tilt_deg, "threshold_vggt": g.threshold})
    return fit


def _tag(obj, kind, filepath, fit, opts, rep: vggt.LoadReport):
    kinds.mark(obj, kind)
    obj["scpainter_source"] = filepath
    obj["scpainter_vggt_to_world"] = np.asarray(fit.vggt_to_world, np.float64).ravel().tolist()
    obj["scpainter_scale_method"] = fit.method
    obj["scpainter_scale_residual_m"] = float(fit.residual_m)
    obj["scpainter_confidence_percentile"] = float(opts.confidence_percentile)
    obj["scpainter_extrinsic_convention"] = rep.extrinsic_convention
    obj["scpainter_crop"] = [int(c) for c in rep.crop]
    # a custom property cannot hold None: 0.0 is off. A scene imported before this property existed has none: its
    # points were not filtered, and job_export writes null (off) for it
    obj["scpainter_depth_edge_ratio"] = opts.edge_ratio or 0.0


def import_vggt(context, filepath: str, opts: ImportOptions | None = None) -> ImportResult:
    """Import ``filepath`` into ``context.scene``; returns the new objects, the metric fit and timings."""
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

    scene = context.scene
    stem = os.path.splitext(os.path.basename(filepath))[0]
    parent_name = os.path.basename(os.path.dirname(filepath)) or stem
    coll = bpy.data.collections.new(f"SCPainter {parent_name}")
    scene.collection.children.link(coll)
    obj = points_mod.create_point_cloud(f"{parent_name} points", pts.positions, pts.colors, pts.frame, coll,
                                        radius=opts.point_radius, frame_offset=opts.frame_start)
    mod = points_mod.points_modifier(obj)
    node_groups.set_input(mod, "Current Frame Only", bool(opts.current_frame_only))
    node_groups.set_input(mod, "Frame Window", int(opts.frame_window))
    t_points = time.perf_counter()

    w2c = similarity.transform_world_to_camera(cameras.orthonormalize(pred.world_to_camera), fit.vggt_to_world)
    cam, p0, warnings = camera_mod.create_recorded_camera(f"{parent_name} recorded camera", w2c, pred.K,
                                                          pred.width, pred.height, opts.frame_start, coll)
    camera_mod.apply_render_settings(scene, p0)
    scene.frame_start = opts.frame_start
    scene.frame_end = opts.frame_start + pred.num_frames - 1
    if opts.set_scene_camera:
        scene.camera = cam
    for o, kind in ((obj, kinds.POINTS), (cam, kinds.RECORDED_CAMERA)):
        _tag(o, kind, filepath, fit, opts, pred.report)
    obj["scpainter_num_frames"] = pred.num_frames
    obj["scpainter_matrix_world_at_import"] = np.array(obj.matrix_basis, dtype=np.float64).ravel().tolist()
    cam["scpainter_intrinsics"] = pred.K.ravel().tolist()
    cam["scpainter_frame_start"] = int(opts.frame_start)
    t_end = time.perf_counter()
    timings = {"load": t_load - t0, "metric_fit": t_fit - t_load, "unproject": t_unproject - t_fit,
               "points_object": t_points - t_unproject, "camera": t_end - t_points, "total": t_end - t0}
    if pts.depth_edge_points > len(pts):  # a ratio too small for the clip's resolution: most points gone
        warnings = list(warnings) + [
            f"the depth-edge test left out {pts.depth_edge_points:,} of {pts.depth_edge_points + len(pts):,} points: "
            f"the ratio {opts.edge_ratio} is small for this clip (the default is {DEPTH_EDGE_RATIO}; 0 turns it off)"]
    return ImportResult(obj, cam, fit, len(pts), timings, list(pred.report.warnings) + list(warnings), pred.report,
                        opts.edge_ratio, pts.depth_edge_points)
