"""What the exporters share: the pixel convention of the formats and a frame of input.

Our pixel coordinates (``core.geometry.cameras``, docs/design.md §3): pixel (u, v) covers [u, u+1) x [v, v+1), its
centre at (u + 0.5, v + 0.5); ``K`` maps to those coordinates. KITTI (devkit: 0-based pixel indices, ``P2``
projecting onto them) and OpenLABEL (its ``camera_matrix`` "as in OpenCV") put pixel centres at integer
coordinates: their coordinates are ours − 0.5, and their principal point is ours − 0.5 (``opencv_K``). COCO's
boxes and masks (pycocotools ``toBbox``: x = first column, w = number of columns) use ours unchanged.

numpy only.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass

import numpy as np

#: Our pixel coordinates minus this are OpenCV's (pixel centres at integers).
OPENCV_SHIFT = 0.5


@dataclass
class ExportFrame:
    """One output frame to export: its ``labels`` (``core.labels``' dict), the ``image`` file (PNG) shown with
    them, and its ``instance`` layer (H, W) (ids: 0 none, k = job.assets[k − 1]; None when the format needs none)."""
    labels: dict
    image: str
    instance: np.ndarray | None = None


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
    """The frame's PNG into the dataset (a copy: the export must survive a later render or generate)."""
    shutil.copyfile(src, dst)


def exported(obj: dict) -> bool:
    """Whether an object of the labels appears in the image: some visible pixel, not removed, and a box (labels
    leave it out, ``box_world`` null, when the object's transform overflows)."""
    return obj["visible_pixels"] > 0 and not obj["removed"] and obj["box_world"] is not None


def class_name(category: str) -> str:
    """A class as KITTI spells its types: the first letter upper-cased (``car`` -> ``Car``)."""
    return category[:1].upper() + category[1:]
