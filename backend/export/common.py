"""What the exporters share: the pixel convention of the formats and a frame of input.

Our pixel coordinates (``core.geometry.cameras``, docs/design.md §3): pixel (u, v) covers [u, u+1) x [v, v+1), its
centre at (u + 0.5, v + 0.5); ``K`` maps to those coordinates. KITTI (devkit: 0-based pixel indices, ``P2``
projecting onto them) and OpenLABEL (its ``camera_matrix`` "as in OpenCV") put pixel centres at integer
coordinates: their coordinates are ours − 0.5, and their principal point is ours − 0.5 (``opencv_K``). COCO's
boxes and masks (pycocotools ``toBbox``: x = first column, w = number of columns) use ours unchanged.

numpy and ``core`` only.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass

import numpy as np

from scpainter_blender.core import categories, errors, labels, outputs

#: Our pixel coordinates minus this are OpenCV's (pixel centres at integers).
OPENCV_SHIFT = 0.5


@dataclass
class ExportSweep:
    """A rig job's LiDAR sweep at an exported frame (docs/design.md §17): ``path`` its ``.pcd.bin``
    (``backend.lidar.sweep``: rows x, y, z, intensity 0..255, ring in the sensor frame, x right, y forward, z up),
    ``lidar_to_world`` (4, 4) rigid: that sensor frame to the world at the frame."""
    path: str
    lidar_to_world: np.ndarray


@dataclass
class ExportFrame:
    """One output frame to export: its ``labels`` (``core.labels``' dict), the ``image`` file (PNG) shown with
    them, its ``instance`` layer (H, W) (ids: 0 none, k = job.assets[k − 1]; None when the format needs none) and,
    for a camera of a rig job with a LiDAR, that frame's ``sweep`` (None otherwise: only KITTI's writers read it)."""
    labels: dict
    image: str
    instance: np.ndarray | None = None
    sweep: ExportSweep | None = None


def opencv_K(K) -> np.ndarray:
    """Our intrinsics (pixel centres at +0.5) in OpenCV's pixel convention (centres at integers)."""
    out = np.array(K, np.float64)
    out[0, 2] -= OPENCV_SHIFT
    out[1, 2] -= OPENCV_SHIFT
    return out


def index_name(index: int, ext: str) -> str:
    """``NNNNNN<ext>``: the sequential name of the index-th exported frame (KITTI's six digits)."""
    return f"{int(index):06d}{ext}"


def copy_image(src: str, dst: str) -> None:
    """The frame's PNG into the dataset (a copy: the export must survive a later render or generate), written as
    every output is (``outputs.atomic_path``: relative to the checked folder, never through a link)."""
    with outputs.atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)


def exported(obj: dict, hidden: bool = False) -> bool:
    """Whether an object of the labels is exported as a label: not removed, not an object seen but not labelled
    (``ignore`` or ``points_missing``: those are ignore regions or nothing, ``core.labels.ignore_region``), with a
    box (labels leave it out, ``box_world`` null, when the object's transform overflows), and some visible pixel —
    or, with ``hidden`` (KITTI, whose 3D detectors expect occluded objects, marked ``occluded`` 2 or 3), only its
    projected box in the image."""
    if obj["removed"] or obj["box_world"] is None or labels.unlabelled(obj):
        return False
    return obj["in_view"] if hidden else obj["visible_pixels"] > 0


#: An object's fields every export carries beside its format's own (``core.labels``: which object, then its
#: measures by name): COCO's extra annotation keys, KITTI's per-line entries of ``frames.json``.
CARRIED_KEYS = labels.CARRIED_IDENTITY + tuple(sorted(labels.CARRIED_MEASURES))


def carried(obj: dict) -> dict:
    """``CARRIED_KEYS`` of an object of the labels."""
    return {k: obj[k] for k in CARRIED_KEYS}


def ignore_regions(labels_: dict) -> list:
    """(object, [x0, y0, x1, y1]) of each ignore region of a frame's labels (``core.labels.ignore_region``), in
    the labels' order."""
    out = []
    for o in labels_["objects"]:
        region = labels.ignore_region(o)
        if region is not None:
            out.append((o, region))
    return out


def category(labels_: dict, index: int) -> categories.Category:
    """The class table's row (``core.categories.CATEGORIES``) of the ``index``-th object of a frame's labels; an
    ``InputError`` naming the frame and the object's ``class`` when the table has no such class."""
    name = labels_["objects"][index]["class"]
    try:
        return categories.category(name)
    except (KeyError, TypeError):
        raise errors.InputError(f"(labels of frame {labels_['frame']})", f"objects[{index}].class",
                                f"class {name!r} is not in the class table {list(categories.NAMES)}",
                                hint="label the object with a class of core/categories.py (the job's class), "
                                     "then render again") from None


def frame_quality(labels: dict) -> dict:
    """What every format carries of a frame's quality, so a pipeline reading only the export can drop weak
    frames: ``coverage`` and ``flags`` (``core.labels.FLAGS``: low coverage, outside the recording, the camera
    inside an object) and ``unlabelled_fraction`` (the share of the image's pixels showing objects seen but not
    labelled: ignore regions)."""
    return {"coverage": float(labels["coverage"]), "flags": list(labels["flags"]),
            "unlabelled_fraction": float(labels["unlabelled_fraction"])}
