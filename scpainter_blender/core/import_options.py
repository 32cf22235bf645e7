"""The import's options, the one place each is written: its default, choices, bounds and the words that describe
it (``OPTIONS``), the values an import takes (``ImportOptions``) and their validation (``ImportOptions.check``).

Both user interfaces are made from ``OPTIONS``: the File > Import operator's properties (operators/import_vggt.py
turns ``blender_properties()`` into ``bpy.props``) and the ``blender -c scpainter import`` options
(cli/import_predictions.py calls ``add_arguments`` and ``from_arguments``). Adding an option is an entry here, a
field of ``ImportOptions`` and its use in the import (scene/importer.py).

A refused option is ``errors.InputError`` with path ``ERROR_PATH`` ("(import options)") and the option's name as
field; on the command line ``from_arguments`` names the flag instead (``errors.ArgumentError``). No bpy: numpy only.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import numpy as np

from . import errors
from . import job as job_mod
from .geometry import point_cloud
from .recording import reader as recording
from .vggt import predictions as vggt

#: The ``path`` of an InputError about an import option (``field``: the ``ImportOptions`` name).
ERROR_PATH = "(import options)"
#: The depth-edge test's ratio when none is given: the job's own default (``core.job.POINT_CLEANING``, the one place
#: it is written), so the viewport shows the points a job exported with no further setting renders.
DEPTH_EDGE_RATIO = job_mod.POINT_CLEANING["depth_edge_ratio"]


@dataclass(frozen=True)
class Option:
    """One import option as both user interfaces show it.

    ``name``: the ``ImportOptions`` field and the operator's property; ``label``: the property's name in the UI;
    ``description``: its tooltip and the ``--help`` text; ``items``: the choices, (value, label, description);
    ``min``/``max``: hard bounds the property keeps to; ``flag``: the command-line option (None: not on the command
    line); ``scale_mode``: the metric-scale mode this option gives the value of (shown, and on the command line
    implied, only with it); ``ui``: Blender display keywords only (subtype, unit, soft limits, precision, step).
    """

    name: str
    label: str
    default: object
    description: str
    items: tuple = ()
    min: float | None = None
    max: float | None = None
    flag: str | None = None
    scale_mode: str | None = None
    cli_help: str = ""    # appended to ``description`` on the command line
    ui: dict = field(default_factory=dict)

    @property
    def choices(self) -> tuple:
        return tuple(value for value, _, _ in self.items)


_OPTIONS = (   # in the order the operator draws them
    Option("confidence_percentile", "Confidence Percentile", point_cloud.CONFIDENCE_PERCENTILE,
           "Drop the points below this percentile of the clip's confidence (VGGT demo semantics)",
           min=0.0, max=100.0, flag="--confidence-percentile", ui={"subtype": "PERCENTAGE"}),
    Option("depth_edge_ratio", "Depth Edge Ratio", DEPTH_EDGE_RATIO,
           "Drop pixels whose depth jumps by more than this fraction of their own depth to one of their 8 "
           "neighbours: VGGT's \"flying pixels\", smeared across depth edges, which show as streaks from a shifted "
           "camera. 0 turns it off. The exported job renders with the same setting",
           min=0.0, max=job_mod.DEPTH_EDGE_RATIO_BOUNDS[1], flag="--depth-edge-ratio", cli_help="; off: keep them",
           ui={"soft_max": 0.5, "precision": 3, "step": 1}),
    Option("point_source", "Points From", "depth", "Where the points come from",
           items=(("depth", "Depth", "Unproject the depth maps with each frame's camera (VGGT's recommended branch)"),
                  ("world_points", "Point Map", "VGGT's world_points head")),
           flag="--point-source"),
    Option("scale_mode", "Metric Scale", "FACTOR", "How the reconstruction gets its metric scale",
           items=(("FACTOR", "Factor", "Metres per VGGT unit"),
                  ("TRAJECTORY", "Metric Trajectory", "Fit the camera path to a metric one (Umeyama)"),
                  ("CAMERA_HEIGHT", "Camera Height", "Known camera height over the road: RANSAC ground plane in the "
                                                     "lower image rows, scale = height / camera-to-plane distance"))),
    Option("scale_factor", "Scale Factor", 1.0, "Metres per VGGT unit", flag="--scale-factor", scale_mode="FACTOR",
           ui={"min": 1e-6, "soft_max": 1000.0}),
    Option("trajectory_path", "Trajectory", "", "Metric camera path (.npz world_to_camera, xyz or TUM text)",
           flag="--trajectory", scale_mode="TRAJECTORY", ui={"subtype": "FILE_PATH"}),
    Option("camera_height", "Camera Height", 1.6, "Height of the camera over the road, metres (the road must show "
                                                  "in the lower part of the images)",
           flag="--camera-height", scale_mode="CAMERA_HEIGHT", ui={"min": 0.01, "unit": "LENGTH"}),
    Option("extrinsic_convention", "Extrinsic Convention", "auto", "What the file's extrinsic holds",
           items=(("auto", "Auto (Check)", "VGGT's world-to-camera, checked against the file's world_points: a "
                                           "file holding camera-to-world poses is refused with a message"),
                  (vggt.EXTRINSIC_CONVENTIONS[0], "World to Camera", "The extrinsic maps world to camera (VGGT's "
                                                                     "own output); not checked"),
                  (vggt.EXTRINSIC_CONVENTIONS[1], "Camera to World", "The extrinsic holds camera poses (camera to "
                                                                     "world), as some tools around VGGT save them; "
                                                                     "inverted, not checked")),
           flag="--extrinsic-convention"),
    Option("crop", "Crop", "auto", "Borders to leave out, in pixels: 'auto' (the white padding of VGGT's pad "
                                   "preprocessing), 'none', or 'left top right bottom'. The camera's principal point "
                                   "and resolution follow", flag="--crop"),
    Option("sensors", "Sensors", "", "A multi-camera recording's sidecar (scpainter.sensors/1 JSON: each VGGT frame's "
                                     "sensor and timestamp): one recorded camera per sensor and the recording's "
                                     "camera rig. Default: <predictions stem>.sensors.json beside the predictions "
                                     "when there is one, else one recorded camera",
           flag="--sensors", ui={"subtype": "FILE_PATH"}),
    Option("objects", "Recorded Objects", "", "The drive's tracked 3D boxes, imported as recorded objects (labelled "
                                              "in every export): a nuScenes tables folder, a KITTI tracking "
                                              "label_02/NNNN.txt (calib/ beside it), an OpenLABEL JSON or a "
                                              "scpainter.objects/1 JSON, of the same frames as the predictions",
           flag="--objects", ui={"subtype": "FILE_PATH"}),
    Option("objects_format", "Objects Format", recording.AUTO, "The recorded objects file's format",
           items=((recording.AUTO, "Auto", "By the file's content"),
                  ("nuscenes", "nuScenes", "A folder of the devkit's JSON tables (one scene)"),
                  ("kitti", "KITTI Tracking", "label_02/NNNN.txt with calib/NNNN.txt"),
                  ("openlabel", "OpenLABEL", "ASAM OpenLABEL 1.0 JSON with cuboids"),
                  ("plain", "Plain JSON", "scpainter.objects/1 (docs/design.md §15)")),
           flag="--objects-format"),
    Option("objects_scene", "Objects Scene", "", "nuScenes: the scene's name or token (needed when the tables hold "
                                                 "several scenes)", flag="--objects-scene"),
    Option("objects_camera", "Objects Camera", "", "The recording's camera the predictions were made from: a "
                                                   "nuScenes channel (default CAM_FRONT), KITTI image_02 or image_03 "
                                                   "(default image_02), an OpenLABEL coordinate system (default "
                                                   "'camera', or the only sensor)", flag="--objects-camera"),
    Option("point_radius", "Point Radius", 0.03, "Radius of each point in the viewport, metres", min=0.0,
           ui={"unit": "LENGTH"}),
    Option("current_frame_only", "Current Frame Only", False,
           "Show only the points of the current frame (± window)"),
    Option("frame_window", "Frame Window", 0, "With Current Frame Only: also the points of this many frames before "
                                              "and after", min=0),
)
#: Every import option a user sets, by name.
OPTIONS = {o.name: o for o in _OPTIONS}
SCALE_MODES = OPTIONS["scale_mode"].choices
#: The option holding each scale mode's value.
SCALE_VALUE = {o.scale_mode: o.name for o in _OPTIONS if o.scale_mode}


def _default(name):
    return OPTIONS[name].default


@dataclass
class ImportOptions:
    """What one import does; the defaults are ``OPTIONS``'. ``frame_start`` (the scene's first frame) and
    ``set_scene_camera`` are the caller's, not options a user sets."""

    confidence_percentile: float = _default("confidence_percentile")
    point_source: str = _default("point_source")
    scale_mode: str = _default("scale_mode")
    scale_factor: float = _default("scale_factor")          # metres per VGGT unit (FACTOR)
    trajectory_path: str = _default("trajectory_path")      # metric camera path (TRAJECTORY)
    camera_height: float = _default("camera_height")        # metres over the road (CAMERA_HEIGHT)
    point_radius: float = _default("point_radius")          # metres
    current_frame_only: bool = _default("current_frame_only")
    frame_window: int = _default("frame_window")
    frame_start: int = 1
    set_scene_camera: bool = True
    extrinsic_convention: str = _default("extrinsic_convention")
    crop: str = _default("crop")                            # "auto", "none", or "left top right bottom" pixels
    sensors: str = _default("sensors")                      # sensors sidecar ("": <stem>.sensors.json if any)
    objects: str = _default("objects")                      # recorded objects file ("": none), core.recording
    objects_format: str = _default("objects_format")        # core.recording.reader.FORMATS or auto
    objects_scene: str = _default("objects_scene")          # nuScenes scene name or token
    objects_camera: str = _default("objects_camera")        # the recording's camera (per format)
    # drop pixels whose depth jumps by more than this fraction of their own to a neighbour (VGGT's "flying pixels",
    # core.geometry.point_cloud.depth_edges); None or 0: off. Stored on the objects; the exported job renders with it.
    depth_edge_ratio: float | None = _default("depth_edge_ratio")

    @property
    def edge_ratio(self) -> float | None:
        """The depth-edge ratio as ``point_cloud`` and the job take it: None when off (None or 0)."""
        return None if self.depth_edge_ratio is None or self.depth_edge_ratio == 0 else float(self.depth_edge_ratio)

    def check(self) -> "ImportOptions":
        """Refuse options no import can use, before any file is read: InputError with path ``ERROR_PATH`` and the
        option's name as field (the UI's property limits keep the panel inside these; scripts and the command
        line are not)."""
        def bad(name, message, hint=None):
            return errors.InputError(ERROR_PATH, name, message, hint)

        number = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)  # noqa: E731
        lo, hi = OPTIONS["confidence_percentile"].min, OPTIONS["confidence_percentile"].max
        if not (number(self.confidence_percentile) and lo <= self.confidence_percentile <= hi):
            raise bad("confidence_percentile", f"expected a percentile in [{lo:g}, {hi:g}], "
                                               f"got {self.confidence_percentile}")
        for o in _OPTIONS:
            if o.items and getattr(self, o.name) not in o.choices:
                raise bad(o.name, f"expected one of {list(o.choices)}, got {getattr(self, o.name)!r}")
        if self.scale_mode == "FACTOR" and not (number(self.scale_factor) and self.scale_factor > 0):
            raise bad("scale_factor", f"expected metres per VGGT unit > 0, got {self.scale_factor}")
        if not (number(self.point_radius) and self.point_radius >= OPTIONS["point_radius"].min):
            raise bad("point_radius", f"expected metres >= 0, got {self.point_radius}")
        if isinstance(self.frame_window, bool) or not isinstance(self.frame_window, int) or \
                self.frame_window < OPTIONS["frame_window"].min:
            raise bad("frame_window", f"expected a number of frames >= 0, got {self.frame_window!r}")
        lo, hi = job_mod.DEPTH_EDGE_RATIO_BOUNDS  # the job's bounds: whatever the import takes, the export writes
        r = self.depth_edge_ratio
        if r is not None and not (number(r) and (r == 0 or lo <= r <= hi)):
            raise bad("depth_edge_ratio", f"expected a fraction of the pixel's depth in [{lo:g}, {hi:g}], or 0 for "
                                          f"off, got {r!r}",
                      hint=f"0 turns the depth-edge test off; the default is {DEPTH_EDGE_RATIO}")
        return self


def blender_properties() -> dict:
    """``{name: (bpy.props function name, keywords)}`` for every option, in drawing order: the operator's
    properties (``getattr(bpy.props, kind)(**keywords)``; Blender ≥ 4.2). A property cannot hold None: a None
    default is 0 (off)."""
    out = {}
    for o in _OPTIONS:
        kw = {"name": o.label, "description": o.description}
        default = 0.0 if o.default is None else o.default
        if o.items:
            kind, kw["items"] = "EnumProperty", [tuple(i) for i in o.items]
        else:
            kind = {bool: "BoolProperty", int: "IntProperty", float: "FloatProperty", str: "StringProperty"}[
                type(default)]
        kw["default"] = default
        kw.update({k: v for k, v in (("min", o.min), ("max", o.max)) if v is not None})
        kw.update(o.ui)
        out[o.name] = (kind, kw)
    return out


def ratio_or_off(text: str) -> float | None:
    """``--depth-edge-ratio``'s argparse type: a number, or "off" (None); its range is ``ImportOptions.check``'s."""
    if text.strip().lower() == "off":
        return None
    try:
        return float(text)
    except ValueError:  # (float() of the user's text)
        raise argparse.ArgumentTypeError(f"{text!r}: expected a fraction of the pixel's depth such as 0.05, "
                                         f"or off") from None


#: The argparse ``type`` of an option whose command-line text is not its Python type's.
_ARG_TYPES = {"depth_edge_ratio": ratio_or_off}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that are on the command line (``flag``), as ``parser``'s arguments with dest the option's
    name. The scale values are mutually exclusive, each implying its scale mode, and default to None (no scale
    given: ``FACTOR`` with the default factor); the others default to ``OPTIONS``'."""
    scale = parser.add_mutually_exclusive_group()
    for o in _OPTIONS:
        if o.flag is None:
            continue
        help_ = o.description + o.cli_help
        kw = {"dest": o.name}
        if o.items:
            kw["choices"] = list(o.choices)
            help_ += " (" + "; ".join(f"{value}: {text}" for value, _, text in o.items) + ")"
        else:  # named as the flag, not the field (--trajectory TRAJECTORY)
            kw["metavar"] = o.flag.lstrip("-").replace("-", "_").upper()
            if not isinstance(o.default, str):
                kw["type"] = _ARG_TYPES.get(o.name, type(o.default))
        if o.scale_mode:  # given or not: from_arguments decides the mode
            scale.add_argument(o.flag, help=help_, **kw)
        else:
            help_ += f" (default {o.default})" if o.default != "" else ""
            parser.add_argument(o.flag, default=o.default, help=help_, **kw)


def given(args) -> list:
    """The flags of ``add_arguments``' options that ``args`` sets to something else than their default (a scale
    value: at all), in ``OPTIONS`` order: for a command that takes them only with some inputs."""
    out = []
    for o in _OPTIONS:
        if o.flag is None:
            continue
        value = getattr(args, o.name, None)
        if (value not in (None, "")) if o.scale_mode else value != o.default:
            out.append(o.flag)
    return out


def from_arguments(args) -> ImportOptions:
    """``ImportOptions`` from ``add_arguments``' parsed ``args``, checked: ``ArgumentError`` names the flag."""
    opts = ImportOptions(**{o.name: getattr(args, o.name) for o in _OPTIONS if o.flag and not o.scale_mode})
    for o in _OPTIONS:   # the scale value given (argparse lets one at most through) chooses the scale mode
        if o.scale_mode and getattr(args, o.name) not in (None, ""):
            opts.scale_mode = o.scale_mode
            setattr(opts, o.name, getattr(args, o.name))
    try:
        return opts.check()
    except errors.InputError as e:  # named as the option the user typed
        flag = OPTIONS[e.field].flag if e.field in OPTIONS else None
        raise errors.ArgumentError(flag or "--" + e.field.replace("_", "-"), e.message, hint=e.hint) from None
