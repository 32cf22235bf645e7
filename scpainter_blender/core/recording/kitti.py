"""KITTI tracking labels: ``label_02/NNNN.txt`` with the sequence's ``calib/NNNN.txt`` (KITTI tracking devkit,
readme.txt).

One object per line, space separated: ``frame track_id type truncated occluded alpha left top right bottom height
width length x y z rotation_y [score]``. ``x y z`` is the bottom centre of the box in the rectified camera-0 frame
(OpenCV axes, metres), ``rotation_y`` the yaw about that camera's y axis, 0 when the object's front points along the
camera's +x; ``DontCare`` lines (track −1) mark image regions without a 3D box and are skipped. Frames are the
sequence's image numbers from 0, the reconstruction's frames in order; the file lists only frames with objects, so
the recording's length is not known (``Recording.num_frames`` None).

The boxes are moved into the colour camera the reconstruction was made from (``image_02``: ``P2``, or ``image_03``:
``P3``): a rectified camera j sees x_j = x_0 + t_j with t_j = K_j⁻¹ P_j[:, 3] (the calib line ``Pj`` = K_j
[I | t_j]).
Classes map through ``core.categories.from_kitti``.
"""

from __future__ import annotations

import os

import numpy as np

from .. import categories, files
from . import tracks

#: The colour cameras a reconstruction can be made from and their projection line in calib/NNNN.txt.
CAMERAS = {"image_02": "P2", "image_03": "P3"}
DEFAULT_CAMERA = "image_02"
FIELDS = ("frame", "track_id", "type", "truncated", "occluded", "alpha", "left", "top", "right", "bottom",
          "height", "width", "length", "x", "y", "z", "rotation_y")
DONT_CARE = "DontCare"
MAX_BYTES = 64 * 2 ** 20


def calib_path(label_path: str) -> str:
    """The sequence's calibration beside its labels: ``<root>/label_02/0000.txt`` -> ``<root>/calib/0000.txt``."""
    folder = os.path.dirname(os.path.dirname(os.path.abspath(label_path)))
    return os.path.join(folder, "calib", os.path.basename(label_path))


def _lines(path) -> list:
    with files.open_regular(path) as f:
        data = f.read(MAX_BYTES + 1)
    if len(data) > MAX_BYTES:
        raise tracks.bad(path, "(file)", f"is larger than {MAX_BYTES // 2 ** 20} MB: not a KITTI label file")
    try:
        return data.decode("utf-8").splitlines()
    except UnicodeDecodeError as e:
        raise tracks.bad(path, "(file)", f"is not text (byte {e.start})") from None


def camera_offset(path: str, camera: str = DEFAULT_CAMERA) -> np.ndarray:
    """t_j (3,) metres of the colour camera ``camera`` from rectified camera 0, read from calib file ``path``."""
    key = CAMERAS.get(camera)
    if key is None:
        raise tracks.bad(path, "camera", f"unknown KITTI camera {camera!r}; one of {list(CAMERAS)}")
    if not os.path.isfile(path):
        raise tracks.bad(path, "(file)", "the sequence's calibration is missing (the labels are in camera 0, the "
                                         "reconstruction in a colour camera)",
                         hint="KITTI tracking keeps it in calib/NNNN.txt beside label_02/")
    for i, line in enumerate(_lines(path)):
        parts = line.split()
        if parts and parts[0].rstrip(":") == key:
            try:
                P = tracks.number_list([float(v) for v in parts[1:]], 12, path, f"line {i + 1} ({key})").reshape(3, 4)
            except ValueError:
                raise tracks.bad(path, f"line {i + 1} ({key})", "expected 12 numbers") from None
            if abs(np.linalg.det(P[:, :3])) < 1e-12:
                raise tracks.bad(path, f"line {i + 1} ({key})", "the camera matrix is singular")
            return np.linalg.solve(P[:, :3], P[:, 3])
    raise tracks.bad(path, key, f"no {key} line (the projection of {camera})")


def read(path: str, camera: str = "") -> tracks.Recording:
    """The tracks of KITTI tracking label file ``path`` in colour camera ``camera`` (default ``image_02``)."""
    camera = camera or DEFAULT_CAMERA
    offset = camera_offset(calib_path(path), camera)
    seen = {}   # track id -> (class, sizes, boxes)
    for i, line in enumerate(_lines(path)):
        parts = line.split()
        if not parts:
            continue
        where = f"line {i + 1}"
        if len(parts) not in (len(FIELDS), len(FIELDS) + 1):
            raise tracks.bad(path, where, f"expected {len(FIELDS)} fields ({' '.join(FIELDS)} [score]), got "
                                          f"{len(parts)}", hint="is this a KITTI *tracking* label_02 file?")
        if parts[2] == DONT_CARE:
            continue
        try:
            frame, track_id = int(parts[0]), int(parts[1])
            values = np.array([float(v) for v in parts[10:17]])
        except ValueError:
            raise tracks.bad(path, where, "frame and track_id must be integers, the box numbers") from None
        tracks.check_frame(frame, None, path, f"{where} (frame)")
        h, w, l, x, y, z, ry = values
        size = tracks.check_size([w, l, h], path, f"{where} (height width length)")
        if not np.all(np.isfinite([x, y, z, ry])):
            raise tracks.bad(path, f"{where} (x y z rotation_y)", "expected finite numbers")
        cls = tracks.category(parts[2], categories.from_kitti, path, f"{where} (type)", "kitti")
        # KITTI's object frame: x the front, y down, z = x × y; ours: x = −z_k, y = x_k, z = −y_k
        c, s = np.cos(ry), np.sin(ry)
        R_obj = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        R = R_obj @ np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
        centre = np.array([x, y - h / 2, z]) + offset      # bottom centre -> centre; camera 0 -> camera j
        entry = seen.setdefault(track_id, (cls, [], {}))
        if entry[0] != cls:
            raise tracks.bad(path, f"{where} (type)", f"track {track_id} was {entry[0]!r} before, now {cls!r}")
        if frame in entry[2]:
            raise tracks.bad(path, f"{where} (frame)", f"track {track_id} is in frame {frame} twice")
        entry[1].append(size)
        entry[2][frame] = tracks.pose(R, centre)
    return tracks.Recording(path, "kitti", None,
                            [tracks.track(str(t), cls, sizes, b) for t, (cls, sizes, b) in sorted(seen.items())])
