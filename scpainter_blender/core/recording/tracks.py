"""What every recording reader gives (``Recording``: tracks of boxes per recording frame, in that frame's camera)
and the checks they share.

The one frame every reader converts to: a track's box at recording frame ``i`` is ``box_to_camera`` (4, 4) rigid,
from the box frame (``core.geometry.boxes``: centred, x across the width, y along the length with +y the front, z up)
to the OpenCV camera frame (x right, y down, z forward, metres) of the camera that took frame ``i``. KITTI labels are
already in a camera; nuScenes and OpenLABEL boxes are carried there through the file's own poses; the plain format
says its frame. ``reader.recorded_objects`` then maps each box through the imported recorded camera of that frame.
Frames are 0-based positions in the recording, which must be the reconstruction's frames in order.

A recording that also knows where its camera was (nuScenes' ego poses, OpenLABEL's per-frame transforms, the plain
format's ``world_to_camera``) gives ``world_to_camera`` (F, 4, 4) in its own metric world: the reader compares that
path with the reconstruction's to catch a file of another drive or frames in another order.

Errors are ``errors.InputError`` naming the file and the field (``sample_annotation.json``, ``size``). numpy only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .. import categories, errors
from ..geometry import boxes


@dataclass(eq=False)
class Track:
    """One tracked object: ``id`` (the file's track name), ``category`` (a ``core.categories`` class), ``size`` (3,)
    [width, length, height] metres (the median over its frames: one box size per object, as the job holds it),
    ``boxes`` {recording frame: (4, 4) rigid box_to_camera} and ``ignore`` (seen, not to be labelled)."""
    id: str
    category: str
    size: np.ndarray
    boxes: dict
    ignore: bool = False


@dataclass(eq=False)
class Recording:
    """A file's tracks: ``path`` (what was read), ``format`` (``reader.FORMATS``), ``num_frames`` (the recording's
    frames; None when the file does not say: KITTI labels list only frames with objects), ``tracks`` and, when the
    file has them, ``world_to_camera`` (F, 4, 4) the camera's poses in the recording's metric world."""
    path: str
    format: str
    num_frames: int | None
    tracks: list = field(default_factory=list)
    world_to_camera: np.ndarray | None = None


def bad(path, where: str, message: str, hint: str | None = None) -> errors.InputError:
    """The readers' one error: ``errors.InputError`` of ``path`` at field ``where``."""
    return errors.InputError(path, where, message, hint)


def number_list(value, n: int | tuple, path, where: str) -> np.ndarray:
    """``value`` as a float64 array of ``n`` (or any count in the tuple ``n``) finite numbers, else InputError."""
    counts = n if isinstance(n, tuple) else (n,)
    ok = isinstance(value, (list, tuple)) and len(value) in counts and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    arr = np.asarray(value, np.float64) if ok else None
    if arr is None or not np.all(np.isfinite(arr)):
        what = " or ".join(map(str, counts))
        raise bad(path, where, f"expected {what} finite numbers, got {str(value)[:80]}")
    return arr


def check_size(size, path, where: str) -> np.ndarray:
    """A box's [width, length, height] (3,) metres: finite and > 0, else InputError (NaN or zero sizes make boxes no
    label can use)."""
    s = np.asarray(size, np.float64)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise bad(path, where, f"expected a box size of 3 positive finite numbers (metres), got {s.tolist()}",
                  hint="a box with NaN or zero size cannot be labelled: fix or drop that annotation")
    return s


def rigid(matrix, path, where: str, what: str = "box") -> np.ndarray:
    """A (4, 4) rigid transform from 16 numbers (nested or flat), rotation made exactly orthonormal; InputError
    for one that is not finite or not a rotation (off by more than 1e-3)."""
    M = np.asarray(matrix, np.float64) if isinstance(matrix, (list, tuple, np.ndarray)) else np.zeros(0)
    if M.size != 16 or not np.all(np.isfinite(M)):
        raise bad(path, where, f"expected a {what} as a 4x4 matrix of finite numbers")
    M = M.reshape(4, 4)
    R = M[:3, :3]
    if not np.allclose(M[3], [0, 0, 0, 1]) or not np.allclose(R.T @ R, np.eye(3), atol=1e-3) or \
            np.linalg.det(R) <= 0:
        raise bad(path, where, f"the {what} is not a rigid transform (rotation and translation)")
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = boxes.nearest_rotation(R), M[:3, 3]
    return out


def pose(rotation: np.ndarray, translation) -> np.ndarray:
    """(4, 4) rigid from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation, np.asarray(translation, np.float64)
    return T


def object_box(object_to_x: np.ndarray) -> np.ndarray:
    """box_to_x (4, 4) of a box whose pose is given for the object frame (x forward, y left, z up: nuScenes,
    OpenLABEL, ISO 8855): turned by ``boxes.OBJECT_TO_BOX``'s inverse into ours (x across, y forward, z up)."""
    T = np.array(object_to_x, np.float64)
    T[:3, :3] = T[:3, :3] @ boxes.OBJECT_TO_BOX.T
    return T


def category(name: str, mapper: Callable[[str], str | None], path, where: str, spelling: str) -> str:
    """Our class for a file's class ``name`` through ``mapper`` (``categories.from_kitti``, ``from_nuscenes``, ...);
    InputError naming the file, the field and the table when the table has no row for it."""
    ours = mapper(name)
    if ours is None:
        known = sorted({getattr(c, spelling, c.name) for c in categories.CATEGORIES})
        raise bad(path, where, f"class {name!r} is not in the class table (core/categories.py CATEGORIES, "
                               f"{spelling} names: {known})",
                  hint="remove those annotations, or map the class in core/categories.py (append a row)")
    return ours


def track(track_id: str, category_: str, sizes: list, frame_boxes: dict, ignore: bool = False) -> Track:
    """A ``Track`` from its per-frame sizes (each already checked) and boxes: the size is their median."""
    return Track(str(track_id), category_, np.median(np.asarray(sizes, np.float64), axis=0), dict(frame_boxes),
                 bool(ignore))


def check_frame(frame: int, num_frames: int | None, path, where: str) -> int:
    """A recording frame index inside the recording (0 .. num_frames − 1 when known), else InputError."""
    if frame < 0 or (num_frames is not None and frame >= num_frames):
        span = f"0–{num_frames - 1}" if num_frames else "≥ 0"
        raise bad(path, where, f"frame {frame} is outside the recording (frames {span})",
                  hint="a track may only name frames the recording has")
    return frame
