"""Our plain per-frame objects file, schema ``scpainter.objects/1``: a documented JSON any tool can write.

::

    {"schema": "scpainter.objects/1",
     "num_frames": 16,                       # frames of the recording: 0 .. num_frames − 1, the reconstruction's
     "frame": "camera",                      # "camera" or "world": the frame the boxes are given in
     "world_to_camera": [[4x4], ...],        # with "world" only: each frame's camera pose, OpenCV axes, metres
     "objects": [
       {"id": "car 1",                       # the track's name, unique
        "class": "car",                      # a class of core.categories (default "car")
        "ignore": false,                     # optional: seen but not to be labelled (an ignore region)
        "size": [1.84, 4.4, 1.58],           # [width, length, height] metres, > 0
        "boxes": {"0": [[4x4]], "1": ...}}   # recording frame -> box_to_camera (or box_to_world with "world")
     ]}

Boxes follow ``core.geometry.boxes``: the box frame is centred, x across the width, y along the length (+y the
front), z up; matrices are rigid, row-major nested lists (the job's own convention). With ``"frame": "world"`` a box
becomes ``world_to_camera[f] @ box_to_world`` in that frame's camera, and the path is compared with the
reconstruction's (``tracks``' module docstring).
"""

from __future__ import annotations

import numpy as np

from .. import categories, files
from . import tracks

SCHEMA = "scpainter.objects/1"
FRAMES = ("camera", "world")
KEYS = ("schema", "num_frames", "frame", "world_to_camera", "objects")
OBJECT_KEYS = ("id", "class", "ignore", "size", "boxes")


def _class(name):
    return name if name in categories.BY_NAME else None


def read(path: str, data: dict | None = None) -> tracks.Recording:
    """The tracks of plain objects file ``path`` (``data``: its JSON when already read)."""
    d = files.read_json(path) if data is None else data
    if not isinstance(d, dict) or d.get("schema") != SCHEMA:
        raise tracks.bad(path, "schema", f"expected {SCHEMA!r}")
    unknown = sorted(set(d) - set(KEYS))
    if unknown:
        raise tracks.bad(path, unknown[0], f"unknown field; the fields are {list(KEYS)}")
    n = d.get("num_frames")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise tracks.bad(path, "num_frames", f"expected the recording's number of frames (≥ 1), got {n!r}")
    frame = d.get("frame", "camera")
    if frame not in FRAMES:
        raise tracks.bad(path, "frame", f"expected one of {list(FRAMES)}, got {frame!r}")
    w2c = None
    if frame == "world":
        poses = d.get("world_to_camera")
        if not isinstance(poses, list) or len(poses) != n:
            raise tracks.bad(path, "world_to_camera", f"expected {n} camera poses (one per frame) with frame 'world'")
        w2c = np.stack([tracks.rigid(m, path, f"world_to_camera[{i}]", "camera pose") for i, m in enumerate(poses)])
    objects = d.get("objects")
    if not isinstance(objects, list):
        raise tracks.bad(path, "objects", "expected a list of objects")
    out, ids = [], set()
    for i, o in enumerate(objects):
        where = f"objects[{i}]"
        if not isinstance(o, dict):
            raise tracks.bad(path, where, "expected an object")
        unknown = sorted(set(o) - set(OBJECT_KEYS))
        if unknown:
            raise tracks.bad(path, f"{where}.{unknown[0]}", f"unknown field; the fields are {list(OBJECT_KEYS)}")
        tid = o.get("id")
        if not isinstance(tid, str) or not tid or tid in ids:
            raise tracks.bad(path, f"{where}.id", f"expected a unique non-empty track name, got {tid!r}")
        ids.add(tid)
        cls = tracks.category(o.get("class", "car"), _class, path, f"{where}.class", "name")
        ignore = o.get("ignore", False)
        if not isinstance(ignore, bool):
            raise tracks.bad(path, f"{where}.ignore", f"expected true or false, got {ignore!r}")
        size = tracks.check_size(tracks.number_list(o.get("size"), 3, path, f"{where}.size"), path, f"{where}.size")
        boxes = o.get("boxes")
        if not isinstance(boxes, dict) or not boxes:
            raise tracks.bad(path, f"{where}.boxes", "expected a non-empty object {recording frame: 4x4 box}")
        frame_boxes = {}
        for k, m in boxes.items():
            try:
                f = int(k)
            except ValueError:
                raise tracks.bad(path, f"{where}.boxes[{k!r}]", "expected a frame number as the key") from None
            tracks.check_frame(f, n, path, f"{where}.boxes[{k!r}]")
            B = tracks.rigid(m, path, f"{where}.boxes[{k!r}]")
            frame_boxes[f] = B if w2c is None else w2c[f] @ B
        out.append(tracks.track(tid, cls, [size], frame_boxes, ignore))
    return tracks.Recording(path, "plain", n, out, w2c)


def document(num_frames: int, objects: list, world_to_camera=None) -> dict:
    """A ``scpainter.objects/1`` document: ``objects`` [{"id", "class", "size", "boxes": {frame: 4x4}, "ignore"?}],
    the boxes in each frame's camera, or in the world when ``world_to_camera`` (num_frames, 4, 4) is given."""
    d = {"schema": SCHEMA, "num_frames": int(num_frames), "frame": "camera" if world_to_camera is None else "world"}
    if world_to_camera is not None:
        d["world_to_camera"] = [np.asarray(m, np.float64).tolist() for m in world_to_camera]
    d["objects"] = [{**{k: v for k, v in o.items() if k != "boxes"},
                     "size": [float(v) for v in o["size"]],
                     "boxes": {str(f): np.asarray(m, np.float64).tolist() for f, m in sorted(o["boxes"].items())}}
                    for o in objects]
    return d
