"""ASAM OpenLABEL 1.0 JSON (``openlabel_json_schema-v1.0.0.json``): objects with ``cuboid`` data.

What is read: ``openlabel.objects`` (per object ``type``, the class, and static ``object_data``), ``frames[f].objects``
(per frame ``object_data``), each object's first ``cuboid`` per frame (a static one holds in every frame of the
object's ``frame_intervals``, else of the recording), ``coordinate_systems`` (``parent``, ``pose_wrt_parent``) and
per-frame ``frame_properties.transforms`` ({src, dst, transform_src_to_dst}). A cuboid ``val`` is (x, y, z, qx, qy,
qz, qw, sx, sy, sz) or (x, y, z, rx, ry, rz, sx, sy, sz) with Euler angles applied as R = Rz(rz) Ry(ry) Rx(rx), the
object frame x forward, y left, z up (ISO 8855: sx the length, sy the width); in ``coordinate_system`` (the object's,
else the root's).

Transforms follow the schema's words: ``X_dst = matrix4x4 · X_src`` (row-major), and ``pose_wrt_parent`` is the
child's pose in its parent (child-to-parent, as Vicomtech's VCD reads it); a frame's transform between a system and
its parent takes the place of the static pose in that frame. Each cuboid goes into the camera system (``camera``:
the one named; default the system called ``camera``, else the file's only ``sensor_cs``), whose axes are OpenCV's
(the schema's ``camera_matrix`` convention). Frames are the numbers of ``frames`` from the recording's first
(``frame_intervals``; without them, from 0); the camera system's pose in each frame is the recording's path.

Classes: our class names, KITTI types or nuScenes names (``core.categories``); type ``ignore`` (what our own export
writes for an ignore region) is an ignore region.
"""

from __future__ import annotations

import numpy as np

from .. import categories, files
from ..geometry import cameras
from . import tracks

ROOT_PARENT = ""


def _class(name: str) -> str | None:
    if name in categories.BY_NAME:
        return name
    low = name.lower()
    return low if low in categories.BY_NAME else (categories.from_kitti(name) or categories.from_nuscenes(name))


def _axis(axis: str, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _euler(angles, sequence: str = "ZYX") -> np.ndarray:
    """R = R_{s0}(a0) · R_{s1}(a1) · R_{s2}(a2) for ``sequence`` s (e.g. "ZYX") and ``angles`` in that order."""
    return _axis(sequence[0], angles[0]) @ _axis(sequence[1], angles[1]) @ _axis(sequence[2], angles[2])


def transform(data, path, where: str) -> np.ndarray:
    """A ``transform_data`` (matrix4x4, quaternion (x, y, z, w) + translation, or euler_angles + sequence +
    translation) as a (4, 4) rigid transform."""
    if not isinstance(data, dict):
        raise tracks.bad(path, where, "expected a transform (matrix4x4, quaternion or euler_angles)")
    if "matrix4x4" in data:
        return tracks.rigid(tracks.number_list(data["matrix4x4"], 16, path, f"{where}.matrix4x4"), path,
                            f"{where}.matrix4x4", "transform")
    t = tracks.number_list(data.get("translation"), 3, path, f"{where}.translation")
    if "quaternion" in data:
        x, y, z, w = tracks.number_list(data["quaternion"], 4, path, f"{where}.quaternion")
        if np.linalg.norm([w, x, y, z]) < 1e-9:
            raise tracks.bad(path, f"{where}.quaternion", "a quaternion of zero length")
        return tracks.pose(cameras.quaternion_to_rotation([w, x, y, z]), t)
    seq = data.get("sequence", "ZYX")
    if not (isinstance(seq, str) and len(seq) == 3 and set(seq) <= set("XYZ")):
        raise tracks.bad(path, f"{where}.sequence", f"expected three axes such as 'ZYX', got {seq!r}")
    return tracks.pose(_euler(tracks.number_list(data.get("euler_angles"), 3, path, f"{where}.euler_angles"), seq), t)


def _cuboid_box(c, path, where: str) -> tuple:
    """(box_to_cs (4, 4), our size [w, l, h], coordinate system or None) of a cuboid."""
    if not isinstance(c, dict):
        raise tracks.bad(path, where, "expected a cuboid object")
    v = tracks.number_list(c.get("val"), (9, 10), path, f"{where}.val")
    if len(v) == 10:
        if np.linalg.norm(v[3:7]) < 1e-9:
            raise tracks.bad(path, f"{where}.val", "a quaternion of zero length")
        R = cameras.quaternion_to_rotation([v[6], v[3], v[4], v[5]])
    else:
        R = _euler([v[5], v[4], v[3]])
    sx, sy, sz = v[-3:]
    size = tracks.check_size([sy, sx, sz], path, f"{where}.val (sx, sy, sz)")
    return tracks.object_box(tracks.pose(R, v[:3])), size, c.get("coordinate_system")


def _first_cuboid(object_data) -> dict | None:
    cub = object_data.get("cuboid") if isinstance(object_data, dict) else None
    return cub[0] if isinstance(cub, list) and cub else None


def read(path: str, data: dict | None = None, camera: str = "") -> tracks.Recording:
    """The tracks of OpenLABEL file ``path`` (``data``: its JSON when already read) in camera system ``camera``."""
    d = files.read_json(path) if data is None else data
    ol = d.get("openlabel") if isinstance(d, dict) else None
    if not isinstance(ol, dict):
        raise tracks.bad(path, "openlabel", "expected the OpenLABEL root object")
    systems = ol.get("coordinate_systems") or {}
    if not isinstance(systems, dict):
        raise tracks.bad(path, "openlabel.coordinate_systems", "expected an object of coordinate systems")
    if camera and camera not in systems:
        raise tracks.bad(path, "openlabel.coordinate_systems", f"no coordinate system {camera!r}; the file has "
                                                               f"{sorted(systems)}")
    if not camera:
        sensors = [k for k, s in systems.items() if isinstance(s, dict) and s.get("type") == "sensor_cs"]
        camera = "camera" if "camera" in systems else (sensors[0] if len(sensors) == 1 else "")
        if not camera:
            raise tracks.bad(path, "openlabel.coordinate_systems", f"which coordinate system is the camera is not "
                                                                   f"clear (systems {sorted(systems)})",
                             hint="name it (--objects-camera)")
    frames = ol.get("frames") or {}
    if not isinstance(frames, dict):
        raise tracks.bad(path, "openlabel.frames", "expected an object of frames")
    bad_keys = [k for k in frames if not str(k).isdigit()]
    if bad_keys:
        raise tracks.bad(path, f"openlabel.frames[{bad_keys[0]!r}]", "expected a frame number as the key")
    numbers = sorted(int(k) for k in frames)
    intervals = ol.get("frame_intervals") or []
    if intervals:
        first = min(int(i["frame_start"]) for i in intervals)
        num_frames = max(int(i["frame_end"]) for i in intervals) - first + 1
    else:
        first, num_frames = 0, (numbers[-1] + 1 if numbers else 0)
    if num_frames < 1:
        raise tracks.bad(path, "openlabel.frames", "the file has no frames")

    def to_root(cs: str, frame) -> np.ndarray:
        """cs_to_root (4, 4) in ``frame`` (its transforms first, then the static poses)."""
        M, seen = np.eye(4), set()
        moves = ((frame or {}).get("frame_properties") or {}).get("transforms") or {}
        while cs and cs not in seen:
            seen.add(cs)
            s = systems.get(cs)
            if not isinstance(s, dict):
                raise tracks.bad(path, "coordinate_system", f"unknown coordinate system {cs!r}; the file has "
                                                            f"{sorted(systems)}")
            parent = s.get("parent", ROOT_PARENT)
            if not parent:
                return M
            step = None
            for name, tr in moves.items():
                if isinstance(tr, dict) and (tr.get("src"), tr.get("dst")) in ((cs, parent), (parent, cs)):
                    T = transform(tr.get("transform_src_to_dst"), path, f"frame_properties.transforms.{name}")
                    step = T if tr["src"] == cs else cameras.rigid_inverse(T)
            if step is None:
                if "pose_wrt_parent" not in s:
                    raise tracks.bad(path, f"openlabel.coordinate_systems.{cs}.pose_wrt_parent",
                                     f"no pose of {cs!r} in its parent {parent!r}")
                step = transform(s["pose_wrt_parent"], path, f"openlabel.coordinate_systems.{cs}.pose_wrt_parent")
            M, cs = step @ M, parent
        raise tracks.bad(path, "openlabel.coordinate_systems", f"the parents of {cs!r} form a loop")

    world_to_camera = [None] * num_frames
    objects = ol.get("objects") or {}
    seen = {}
    for key in numbers:
        f = tracks.check_frame(key - first, num_frames, path, f"openlabel.frames[{str(key)!r}]")
        frame = frames[str(key)]
        cam_to_root = to_root(camera, frame)
        world_to_camera[f] = cameras.rigid_inverse(cam_to_root)
        for uid, entry in ((frame or {}).get("objects") or {}).items():
            where = f"openlabel.frames[{str(key)!r}].objects[{uid!r}]"
            obj = objects.get(uid)
            if not isinstance(obj, dict):
                raise tracks.bad(path, where, f"object {uid!r} is not in openlabel.objects")
            c = _first_cuboid((entry or {}).get("object_data")) or _first_cuboid(obj.get("object_data"))
            if c is not None:
                seen.setdefault(uid, {})[f] = (c, f"{where}.object_data.cuboid[0]", frame)
    out = []
    for uid, obj in objects.items():
        where = f"openlabel.objects[{uid!r}]"
        if not isinstance(obj, dict):
            raise tracks.bad(path, where, "expected an object")
        static = _first_cuboid(obj.get("object_data"))
        per_frame = seen.get(uid, {})
        if static is not None:  # in every frame of its intervals (else of the recording) with no cuboid of its own
            spans = obj.get("frame_intervals") or [{"frame_start": first, "frame_end": first + num_frames - 1}]
            for span in spans:
                for key in range(int(span["frame_start"]), int(span["frame_end"]) + 1):
                    f = tracks.check_frame(key - first, num_frames, path, f"{where}.frame_intervals")
                    per_frame.setdefault(f, (static, f"{where}.object_data.cuboid[0]", frames.get(str(key))))
        if not per_frame:
            continue   # a 2D-only object: no box to import
        name = obj.get("type")
        ignore = name == categories.IGNORE
        cls = "misc" if ignore else tracks.category(str(name), _class, path, f"{where}.type", "name")
        sizes, boxes = [], {}
        for f, (c, cwhere, frame) in sorted(per_frame.items()):
            box, size, cs = _cuboid_box(c, path, cwhere)
            cs = cs or obj.get("coordinate_system") or next((k for k, s in systems.items()
                                                             if not (s or {}).get("parent")), camera)
            cam_to_root = to_root(camera, frame) if frame is not None else to_root(camera, None)
            boxes[f] = cameras.rigid_inverse(cam_to_root) @ to_root(cs, frame) @ box
            sizes.append(size)
        out.append(tracks.track(uid, cls, sizes, boxes, ignore))
    known = [m for m in world_to_camera if m is not None]
    w2c = np.stack(world_to_camera) if len(known) == num_frames else None
    return tracks.Recording(path, "openlabel", num_frames, out, w2c)
