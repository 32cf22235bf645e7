"""VGGT predictions: what VGGT's arrays mean, and the objects that hold a clip's predictions once validated.

VGGT's conventions (facebookresearch/vggt), which this package converts from:

* World frame = the first camera's OpenCV frame (x right, y down, z forward), scale normalised (not metric).
* ``extrinsic`` (S, 3, 4) world-to-camera; ``intrinsic`` (S, 3, 3) with the principal point at the image centre
  and pixel (u, v) unprojected at *integer* coordinates: x = (u - cx) d / fx. Our pixel convention puts pixel
  centres at u + 0.5 (``core.geometry.cameras``), so our K is VGGT's with cx + 0.5, cy + 0.5 and both unproject
  identically.
* ``depth`` (S, H, W, 1) camera z; ``depth_conf`` (S, H, W) = 1 + exp(x) >= 1; ``images`` (S, 3, H, W) in [0, 1]
  (sRGB-encoded display values); optional ``world_points`` (S, H, W, 3) and ``world_points_conf``.
* The demo squeezes a batch axis of 1 before saving; files with it are accepted too, and so are one-frame files
  saved with every size-1 axis squeezed (depth (H, W), extrinsic (3, 4), intrinsic (3, 3), images (3, H, W)).

Where the rest lives (each module numpy only, no bpy, no torch):

* ``core.vggt.npz`` reads and writes predictions files (``load_predictions``, ``save_predictions``): shapes,
  dtypes, NaN/inf pixels (dropped and counted in ``LoadReport``), refusals naming file and key;
* ``core.vggt.crop`` VGGT's white "pad" borders and explicit crops;
* ``core.vggt.convention`` whether ``extrinsic`` holds world-to-camera (VGGT's) or camera-to-world poses, checked
  against the point head;
* ``core.geometry.unproject`` pixels to points and VGGT's confidence filter; ``core.geometry.point_cloud`` a clip's
  coloured points;
* ``core.geometry.metric_scale`` ``vggt_to_world``: VGGT's world to Blender's in metres.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import errors

if TYPE_CHECKING:  # for the annotation only: vggt_convention imports this module
    from .convention import ConventionCheck

REQUIRED_KEYS = ("images", "depth", "depth_conf", "extrinsic", "intrinsic")
OPTIONAL_KEYS = ("world_points", "world_points_conf")

#: What ``extrinsic`` holds: VGGT's own world-to-camera, or camera-to-world as some tools around VGGT save it
#: (facebookresearch/vggt issues 275, 370). ``"auto"`` (when loading only) checks against ``world_points``.
EXTRINSIC_CONVENTIONS = ("world_to_camera", "camera_to_world")

#: Per-pixel arrays hold measurements: VGGT saves them as float32. An integer depth map (millimetres, as depth
#: cameras write) or a boolean mask under these names would be read as VGGT units without a word: refused.
FLOAT_KEYS = ("depth", "depth_conf", "world_points", "world_points_conf")


class PredictionsError(errors.InputError):
    """A predictions (or trajectory) file that cannot be used; the message names the file and the key (``key``,
    also ``field``; None / "(file)" for the file as a whole)."""

    def __init__(self, path, key, message, hint=None):
        key = None if key == "(file)" else key  # files' callbacks name the whole file so
        errors.InputError.__init__(self, path, key, message, hint)
        self.key = key
        where = f"{os.path.basename(self.path)}" + (f": '{key}'" if key else "")
        self.args = (f"{where}: {message} ({self.path})",)  # the text it has always had


def numeric(arr, path, key):
    """``arr`` as a numpy array of numbers: floats (and, but for the per-pixel measurements of FLOAT_KEYS,
    integers); booleans, objects, strings, complex numbers refused naming the key (PredictionsError)."""
    a = np.asarray(arr)
    if a.dtype.kind == "b" or a.dtype.kind not in "fiu":
        raise PredictionsError(path, key, f"is not an array of numbers (dtype {a.dtype}); VGGT saves float32")
    if key in FLOAT_KEYS and a.dtype.kind != "f":
        raise PredictionsError(path, key, f"holds integers (dtype {a.dtype}), VGGT saves float32: convert it to "
                                          "VGGT's units as floats (an integer depth map in millimetres would "
                                          "otherwise be read as units)")
    return a


@dataclass
class VGGTPredictions:
    """Validated VGGT predictions for S frames of H x W pixels (batch axis removed)."""

    path: str
    images: np.ndarray            # (S, H, W, 3) float32, sRGB-encoded, [0, 1]
    depth: np.ndarray             # (S, H, W) float32, camera z in VGGT units
    depth_conf: np.ndarray        # (S, H, W) float32
    world_to_camera: np.ndarray   # (S, 4, 4) float64, VGGT world -> OpenCV camera, as stored (float32 rotations
    #                               are orthonormal to ~1e-7 only: unprojection uses them as VGGT does, camera
    #                               placement goes through cameras.orthonormalize)
    intrinsic_vggt: np.ndarray    # (S, 3, 3) float64, VGGT's pixel convention
    world_points: np.ndarray | None = None        # (S, H, W, 3) float32, VGGT world
    world_points_conf: np.ndarray | None = None   # (S, H, W) float32
    valid: np.ndarray | None = None               # (S, H, W) bool: finite depth and depth_conf (None: all are)
    world_points_valid: np.ndarray | None = None  # (S, H, W) bool: finite world point and its confidence
    report: LoadReport = field(default_factory=lambda: LoadReport())  # what loading decided and dropped

    @property
    def num_frames(self) -> int:
        return self.depth.shape[0]

    @property
    def height(self) -> int:
        return self.depth.shape[1]

    @property
    def width(self) -> int:
        return self.depth.shape[2]

    @property
    def K(self) -> np.ndarray:
        """Intrinsics (S, 3, 3) in our convention (pixel centres at +0.5): VGGT's with cx + 0.5, cy + 0.5."""
        return vggt_K_to_ours(self.intrinsic_vggt)


def vggt_K_to_ours(K) -> np.ndarray:
    """Our K (pixel centres at +0.5) of VGGT's (..., 3, 3): cx + 0.5, cy + 0.5; float64, a copy."""
    K = np.array(K, dtype=np.float64, copy=True)
    K[..., 0, 2] += 0.5
    K[..., 1, 2] += 0.5
    return K


def ours_K_to_vggt(K) -> np.ndarray:
    """VGGT's K (integer pixel coordinates) of ours (..., 3, 3): cx - 0.5, cy - 0.5; float64, a copy."""
    K = np.array(K, dtype=np.float64, copy=True)
    K[..., 0, 2] -= 0.5
    K[..., 1, 2] -= 0.5
    return K


@dataclass
class LoadReport:
    """What loading decided and dropped: the extrinsic convention (and whether it was checked), the crop, and the
    pixels with NaN/inf values. ``info`` and ``warnings`` are sentences for the import report."""

    extrinsic_convention: str = "world_to_camera"  # resolved: never "auto"
    convention_requested: str = "world_to_camera"
    convention_checked: bool = False
    check: ConventionCheck | None = None           # core.vggt.convention's figures (None: not checked)
    crop: tuple = (0, 0, 0, 0)                     # (left, top, right, bottom) pixels removed
    crop_requested: str = "none"                   # "none", "auto" or "explicit"
    original_size: tuple = (0, 0)                  # (W, H) before the crop
    nonfinite: dict = field(default_factory=dict)  # key -> per-frame counts of NaN/inf pixels (keys with any)
    dropped_pixels: list = field(default_factory=list)  # per frame: pixels dropped from depth points (NaN/inf)
    info: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    def to_json(self) -> dict:
        return {"extrinsic_convention": self.extrinsic_convention,
                "extrinsic_convention_requested": self.convention_requested,
                "extrinsic_convention_checked": self.convention_checked,
                "convention_check": None if self.check is None else self.check.to_json(),
                "crop": list(self.crop), "crop_requested": self.crop_requested,
                "original_size": list(self.original_size),
                "nonfinite_pixels": {k: list(v) for k, v in self.nonfinite.items()},
                "dropped_pixels": int(sum(self.dropped_pixels)), "info": list(self.info),
                "warnings": list(self.warnings)}
