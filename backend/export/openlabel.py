"""ASAM OpenLABEL 1.0 JSON (``openlabel.json``; valid against the official schema,
``openlabel_json_schema-v1.0.0.json``, draft-07) and the frames' images (``images/NNNNNN.png``).

Conventions, with their sources:

- **Frames**: OpenLABEL frame numbers are the frames' positions in the job (0, 1, …: the schema allows only
  non-negative keys, scene frames may be negative); ``frame_properties`` carries ``timestamp`` (seconds from the
  job's first frame, the labels' ``timestamp_s``), ``scene_frame`` and the image (``streams.camera.uri``).
- **Coordinate systems**: ``odom`` (type ``scene_cs``, the root: the job's world, Z up, metres) and ``camera``
  (``sensor_cs``, child of ``odom``); each lists its ``children`` (an empty list for the leaf ``camera``: the
  schema lets it be left out, but Vicomtech's ``vcd`` toolkit walks every ``children`` list to chain transforms,
  ``vcd.scl.Scene.get_transform``, and fails without it). The camera's axes are OpenCV's, x right, y down, z forward: what the
  schema's ``camera_matrix`` assumes ("x-to-right, y-down, z-forward") and what Vicomtech's VCD tutorial
  ``02_From_pose_to_transform_opencv_camera`` sets up — the same axes as ours, so no axis change is needed.
- **Transforms**: ``matrix4x4`` row-major (VCD reads it with ``reshape(4, 4)``), mapping column vectors
  X_dst = M · X_src (the schema's words). ``pose_wrt_parent`` is the pose of the child in its parent, i.e. the
  child-to-parent transform (VCD's tutorial: ``T_fv_to_lcs = P_fv_wrt_lcs``): the camera's is camera_to_world of
  the first frame, and every frame has ``transforms.camera_to_odom`` (src ``camera``, dst ``odom``) with that
  frame's camera_to_world.
- **Stream** ``camera``: ``intrinsics_pinhole`` with ``width_px``, ``height_px``, ``camera_matrix_3x4`` (and the
  schema's ``camera_matrix``: the same 12 numbers) = K [I | 0] in OpenCV's pixel convention (pixel centres at
  integers: ``common.opencv_K``), ``distortion_coeffs`` five zeros (a rendered pinhole). A frame whose K differs
  from the first frame's repeats the stream's properties in its ``frame_properties.streams``.
- **Objects**: one per track (key = the labels' ``track_id``), ``type`` the class, static
  ``boolean synthetic``; per frame (every frame whose labels list it) ``cuboid`` ``box3d`` in ``odom``:
  [x, y, z, qx, qy, qz, qw, sx, sy, sz] with the object frame x forward, y left, z up (ISO 8855, OpenLABEL's
  object convention) and sizes length, width, height; ``bbox`` ``visible`` and ``amodal`` in ``camera``:
  [cx, cy, w, h] (centre, OpenCV pixel convention) when known; ``num`` the measures the labels say exports carry
  (``core.labels.CARRIED_MEASURES``: ``visible_fraction``, ``occlusion`` …; one that is null left out);
  ``boolean`` ``removed``. ``frame_intervals`` say where each exists. An object seen but not labelled
  (``ignore`` or ``points_missing``) is never such an object.
- **Ignore regions** (``core.labels.ignore_region``): objects of type ``ignore`` (``core.categories.IGNORE``),
  keyed by the object's track id plus ``ignore_key_offset`` (the largest track id of the document: a track that is
  labelled in some frames and unlabelled in others keeps both), with the static ``text`` ``class`` and ``num``
  ``track_id`` of the object they stand for; per frame a ``bbox`` ``region`` in ``camera`` ([cx, cy, w, h]) and
  the object's carried measures as ``num``.
"""

from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core import categories, labels, outputs

from . import common

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

IMAGES, FILE = "images", "openlabel.json"
#: Whether ``write`` reads the frames' instance layers (``command.FORMATS``).
NEEDS_INSTANCE = False
SCHEMA_VERSION = "1.0.0"
WORLD, CAMERA = "odom", "camera"


def _matrix(m) -> list:
    return [float(v) for v in np.asarray(m, np.float64).ravel()]


def intrinsics(K: np.ndarray, width: int, height: int) -> dict:
    """The camera stream's ``stream_properties`` for our intrinsics ``K``."""
    P = _matrix(np.hstack([common.opencv_K(K), np.zeros((3, 1))]))
    return {"intrinsics_pinhole": {"width_px": int(width), "height_px": int(height), "camera_matrix_3x4": P,
                                   "camera_matrix": P, "distortion_coeffs": [0.0] * 5}}


def cuboid_val(box_world: dict) -> list:
    """[x, y, z, qx, qy, qz, qw, sx, sy, sz] of a labels ``box_world`` (quaternion (w, x, y, z), size l w h)."""
    w, x, y, z = box_world["quaternion"]
    return [*map(float, box_world["center"]), float(x), float(y), float(z), float(w), *map(float, box_world["size"])]


def bbox_val(box: list) -> list:
    """[cx, cy, w, h] in OpenCV pixel coordinates of our [x0, y0, x1, y1]."""
    x0, y0, x1, y1 = box
    return [(x0 + x1) / 2 - common.OPENCV_SHIFT, (y0 + y1) / 2 - common.OPENCV_SHIFT, x1 - x0, y1 - y0]


def intervals(indices: Iterable[int]) -> list:
    """Closed ``frame_interval``s covering the sorted frame ``indices``."""
    out = []
    for i in indices:
        if out and out[-1]["frame_end"] == i - 1:
            out[-1]["frame_end"] = i
        else:
            out.append({"frame_start": i, "frame_end": i})
    return out


def _measures(o: dict) -> list:
    """The ``num`` entries of an object's carried measures (``labels.CARRIED_MEASURES``; a null one left out)."""
    return [{"name": n, "val": float(o[n])} for n in labels.CARRIED_MEASURES if o[n] is not None]


def _frame_object(o: dict) -> dict:
    data = {"cuboid": [{"name": "box3d", "val": cuboid_val(o["box_world"]), "coordinate_system": WORLD}]}
    boxes = [{"name": n, "val": bbox_val(o[k]), "coordinate_system": CAMERA}
             for n, k in (("visible", "bbox_visible"), ("amodal", "bbox_amodal")) if o[k] is not None]
    if boxes:
        data["bbox"] = boxes
    data["num"] = _measures(o)
    data["boolean"] = [{"name": "removed", "val": bool(o["removed"])}]
    return {"object_data": data}


def ignore_key_offset(frames: list) -> int:
    """What is added to a track id to key its ignore-region object: the largest track id of ``frames``' labels."""
    return max((int(o["track_id"]) for fr in frames for o in fr.labels["objects"]), default=0)


def document(frames: list, image_names: list, name: str = "scpainter") -> dict:
    """The OpenLABEL document of ``frames`` (``common.ExportFrame``, in order) whose images are ``image_names``
    (relative to the document)."""
    first = frames[0].labels
    K0 = np.asarray(first["camera"]["K"], np.float64)
    W, H = first["image_size"]
    offset = ignore_key_offset(frames)
    objects, seen = {}, {}
    out_frames = {}
    for i, (fr, image) in enumerate(zip(frames, image_names)):
        lab = fr.labels
        stream = {"uri": image}
        if not np.array_equal(np.asarray(lab["camera"]["K"], np.float64), K0):
            stream["stream_properties"] = intrinsics(lab["camera"]["K"], *lab["image_size"])
        props = {"timestamp": float(lab["timestamp_s"]), "scene_frame": int(lab["frame"]), **common.frame_quality(lab),
                 "streams": {CAMERA: stream},
                 "transforms": {f"{CAMERA}_to_{WORLD}": {"src": CAMERA, "dst": WORLD, "transform_src_to_dst": {
                     "matrix4x4": _matrix(lab["camera"]["camera_to_world"])}}}}
        frame_objects = {}
        for k, o in enumerate(lab["objects"]):
            region = labels.ignore_region(o)
            if region is not None:
                common.category(lab, k)           # a class the table lacks is an error here too
                key = str(int(o["track_id"]) + offset)
                objects.setdefault(key, {"name": o["name"], "type": categories.IGNORE, "object_data": {
                    "text": [{"name": "class", "val": o["class"]}],
                    "num": [{"name": "track_id", "val": int(o["track_id"])}]}})
                frame_objects[key] = {"object_data": {
                    "bbox": [{"name": "region", "val": bbox_val(region), "coordinate_system": CAMERA}],
                    "num": _measures(o)}}
            elif o["box_world"] is None or labels.unlabelled(o):
                continue      # no box to give (its transform overflows: core.labels), or seen but not labelled
            else:
                common.category(lab, k)
                key = str(int(o["track_id"]))
                objects.setdefault(key, {"name": o["name"], "type": o["class"], "object_data": {
                    "boolean": [{"name": "synthetic", "val": bool(o["synthetic"])}]}})
                frame_objects[key] = _frame_object(o)
            seen.setdefault(key, []).append(i)
        out_frames[str(i)] = {"frame_properties": props, **({"objects": frame_objects} if frame_objects else {})}
    for key, idx in seen.items():
        objects[key]["frame_intervals"] = intervals(idx)
    doc = {"metadata": {"schema_version": SCHEMA_VERSION, "name": name, "annotator": "SCPainter (rendered labels)",
                        "comment": "world: the job's (Z up, metres); camera: OpenCV axes; see backend/export/"
                                   "openlabel.py"},
           "coordinate_systems": {
               WORLD: {"type": "scene_cs", "parent": "", "children": [CAMERA]},
               CAMERA: {"type": "sensor_cs", "parent": WORLD, "children": [],
                        "pose_wrt_parent": {"matrix4x4": _matrix(first["camera"]["camera_to_world"])}}},
           "streams": {CAMERA: {"type": "camera", "description": "the rendered camera (pinhole, no distortion)",
                                "stream_properties": intrinsics(K0, W, H)}},
           "frame_intervals": [{"frame_start": 0, "frame_end": len(frames) - 1}],
           "frames": out_frames}
    if objects:
        doc["objects"] = dict(sorted(objects.items(), key=lambda kv: int(kv[0])))
    return {"openlabel": doc}


def write(folder: str, frames: list, progress: Callable[[int], None] | None = None, name: str = "scpainter") -> dict:
    """``openlabel.json`` and ``images/`` into ``folder`` (existing, empty). Returns {"frames", "objects",
    "ignore_regions"} (per-frame entries of labelled objects, of ignore regions)."""
    outputs.make_folder(os.path.join(folder, IMAGES))
    names = [f"{IMAGES}/{common.index_name(i, '.png')}" for i in range(len(frames))]
    for i, (fr, rel) in enumerate(zip(frames, names)):
        common.copy_image(fr.image, os.path.join(folder, rel))
        if progress:
            progress(i)
    doc = document(frames, names, name)
    with outputs.atomic_write(os.path.join(folder, FILE), "w") as f:
        json.dump(doc, f, allow_nan=False)
    return {"frames": len(frames), **counts(doc)}


def counts(doc: dict) -> dict:
    """{"objects", "ignore_regions"} of a ``document``: its per-frame entries of labelled objects, of ignore
    regions (objects of type ``ignore``)."""
    kinds = doc["openlabel"].get("objects", {})
    entries = [kinds[key]["type"] for f in doc["openlabel"]["frames"].values() for key in f.get("objects", {})]
    regions = entries.count(categories.IGNORE)
    return {"objects": len(entries) - regions, "ignore_regions": regions}
