"""The 13 nuScenes tables of rendered clips (nuscenes-devkit 1.2.0 ``schema.md``): what ``backend/export/nuscenes.py``
writes as JSON under ``<dataroot>/<version>/``, built here from each clip's labels, rig and ego path.

A **clip** (``Clip``) is one job: its output frames (times from the job's frame ticks / fps, the labels'
``timestamp_s``), the ego pose per frame (``ego_to_world``), per camera the channel name, its mounting pose
(``camera_to_ego``), each frame's labels (``core.labels``) and image, and the LiDAR (``core.rig.RigLidar``) with
each frame's sweep file (``.pcd.bin``: rows of 5 float32 x, y, z, intensity, ring in the sensor frame) when the rig
has one. Each clip is one ``log``, one ``scene``, one ``map``.

Conventions (the devkit's): timestamps in µs (``EPOCH_US`` + ``Clip.start_us`` + the frame's time), quaternions [w, x, y, z], sizes
[w, l, h] metres, box rotation object_to_global with the object frame x forward, y left, z up (ours: labels'
``box_world``), ``translation`` the box centre. ``camera_intrinsic`` is our K in the devkit's pixel convention
(pixel centres at integers: cx, cy − 0.5, ``common.opencv_K``). **Global frame**: the job's world translated by
(ox, oy, 0) so that the clip's map raster (``MAP_RESOLUTION_M`` per pixel, its lower-left corner the global origin,
as nuScenes' maps are) holds every ego position ``MAP_MARGIN_M`` from its edges; the translation is the log's
``world_to_global`` (extra field). Tokens are the first 32 hex digits of the SHA-256 of ``<seed>/<table>/<key>``, the
seed the scene's name and its job's identity (``Clip.seed``): the same job gives the same tables, two jobs never
share a token. Visibility tokens are nuScenes' own "1".."4".

Keyframes (``sample``): the first frame, then each first frame at least 1 / ``keyframe_hz`` s after the last
keyframe. Every frame has a ``sample_data`` per camera (``samples/<CH>/`` on keyframes, ``sweeps/<CH>/`` else) and
one for the LiDAR where its sweep exists (a keyframe's must: mmdetection3d's converter opens it); a non-keyframe's
``sample_token`` is the next keyframe's (the last one after the last keyframe), the one the devkit interpolates
boxes towards. One ``ego_pose`` per frame, shared by its sensors (rendered synchronously).

``sample_annotation``: per keyframe each object of the labels (any camera's: ``box_world`` is the world's) that has a
box, is not removed and not ``ignore`` (the object's own), unless every camera that sees it calls it
``points_missing`` (a camera seeing a sliver of a car whose points are cut is no reason to drop the car another
camera labels) — recorded and inserted alike; ignore regions are not annotations (nuScenes has none): they are left out, and counted. ``num_lidar_pts``:
the keyframe's sweep points inside the box by the devkit's ``points_in_box`` rule (faces included), the sweep taken
to global by lidar_to_ego and the ego pose; 0 without a LiDAR; ``num_radar_pts`` 0. ``visibility_token``: the
visible share of the object's pixels over all cameras (Σ visible / Σ amodal pixels) in nuScenes' bins 0-40, 40-60,
60-80, 80-100 % (no amodal pixel: "1"). Attributes from the labels' velocity (``attributes``). Extra fields:
``synthetic`` (an inserted object), ``track_id`` (the labels').

numpy and ``core`` only: no bpy, no torch.
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field

import numpy as np

from scpainter_blender.core import categories, errors, files, labels
from scpainter_blender.core.geometry import cameras

from ..lidar import sweep as sweep_mod
from . import common

#: The devkit's tables, in its loading order (``NuScenes.table_names``).
TABLE_NAMES = ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose", "log",
               "scene", "sample", "sample_data", "sample_annotation", "map")
#: nuScenes' eight attributes.
ATTRIBUTES = ("vehicle.moving", "vehicle.stopped", "vehicle.parked", "cycle.with_rider", "cycle.without_rider",
              "pedestrian.sitting_lying_down", "pedestrian.standing", "pedestrian.moving")
#: nuScenes' visibility bins: (token, level, upper bound of the visible share).
VISIBILITY = (("1", "v0-40", 0.4), ("2", "v40-60", 0.6), ("3", "v60-80", 0.8), ("4", "v80-100", 1.0))
#: An object faster than this (m/s, the labels' velocity's norm) is moving: slower than a walk (~1.4 m/s), faster
#: than the jitter of a recorded box between frames.
MOVING_SPEED = 0.5
#: Timestamps: µs since the Unix epoch of a clip's first frame (2020-09-13), so they look like nuScenes' own.
EPOCH_US = 1_600_000_000_000_000
DATE_CAPTURED = "2020-09-13"
#: The map raster: metres per pixel (the devkit's ``MapMask`` native resolution) and the margin around the ego
#: path (more than the 40·√2 m the devkit's ``render_ego_centric_map`` crops around the ego).
MAP_RESOLUTION_M = 0.1
MAP_MARGIN_M = 60.0
#: The map marks as drivable (255) the strip the ego drove on, this far either side of its path; the rest is 0
#: (unknown, not known to be undrivable).
DRIVEN_HALF_WIDTH_M = 2.0


def token(*parts) -> str:
    """A record's token: 32 hex digits of the SHA-256 of its parts joined by "/"."""
    return hashlib.sha256("/".join(map(str, parts)).encode("utf-8")).hexdigest()[:32]


@dataclass
class CameraClip:
    """One camera of a clip: ``name`` (the channel), ``camera_to_ego`` (4, 4) rigid (OpenCV axes to ego),
    ``labels`` (``core.labels`` dict per frame) and ``images`` (PNG per frame), both in the clip's frame order."""
    name: str
    camera_to_ego: np.ndarray
    labels: list
    images: list


@dataclass
class Clip:
    """One job as a nuScenes scene: ``name`` (unique in a dataroot: file names and tokens), ``description``,
    ``vehicle`` (the rig's name), ``frames`` (scene frame numbers), ``times_s`` (seconds from the first frame),
    ``ego_to_world`` (N, 4, 4), ``cameras`` ([CameraClip]), ``lidar`` (``core.rig.RigLidar`` or None) and ``sweeps``
    (per frame a ``.pcd.bin`` path or None); ``identity`` (``nuscenes.job_identity``: the job's; "" none)."""
    name: str
    description: str
    vehicle: str
    frames: list
    times_s: list
    ego_to_world: np.ndarray
    cameras: list
    lidar: object = None
    sweeps: list = field(default_factory=list)
    identity: str = ""

    @property
    def seed(self) -> str:
        """What the clip's tokens are derived from: its name, and its job's ``identity`` when it has one (so two
        jobs' tables never share a token, and a job exported again keeps its own)."""
        return f"{self.name}/{self.identity}" if self.identity else self.name

    @property
    def start_us(self) -> int:
        """µs from ``EPOCH_US`` to the clip's first frame: 0 without an identity, else whole seconds within
        ``DATE_CAPTURED``'s day drawn from it (two jobs' scenes do not start at one instant; a job keeps its own)."""
        return int(token(self.identity), 16) % 86_400 * 1_000_000 if self.identity else 0


def keyframes(times_s, keyframe_hz: float) -> list:
    """Indices of the keyframes of frames at ``times_s`` (ascending seconds): the first, then each first frame at
    least 1 / keyframe_hz (less a µs) after the last keyframe."""
    step, out = 1.0 / float(keyframe_hz), []
    for i, t in enumerate(times_s):
        if not out or t - times_s[out[-1]] >= step - 1e-6:
            out.append(i)
    return out


def visibility_token(visible: int, amodal: int) -> str:
    """nuScenes' visibility token of a visible share ``visible / amodal`` (pixels over all cameras)."""
    share = visible / amodal if amodal > 0 else 0.0
    return next(tok for tok, _, upper in VISIBILITY if share <= upper or upper == 1.0)


def attributes(nuscenes_name: str, our_class: str, speed: float | None, track_moves: bool) -> list:
    """The attribute names of an object: vehicles ``vehicle.moving`` above ``MOVING_SPEED``, else
    ``vehicle.stopped`` when its track moves at another keyframe, else ``vehicle.parked``; bicycles and
    motorcycles ``cycle.with_rider`` when moving or of our class ``cyclist``, else ``cycle.without_rider``;
    pedestrians ``pedestrian.moving`` / ``pedestrian.standing``; other classes none. ``speed`` None (one frame):
    not moving."""
    moving = speed is not None and speed > MOVING_SPEED
    if nuscenes_name in ("vehicle.bicycle", "vehicle.motorcycle"):
        return ["cycle.with_rider" if moving or our_class == "cyclist" else "cycle.without_rider"]
    if nuscenes_name.startswith("vehicle."):
        return ["vehicle.moving" if moving else "vehicle.stopped" if track_moves else "vehicle.parked"]
    if nuscenes_name.startswith("human.pedestrian."):
        return ["pedestrian.moving" if moving else "pedestrian.standing"]
    return []


def points_in_boxes(points: np.ndarray, centres, sizes_wlh, rotations_wxyz) -> np.ndarray:
    """(K,) how many of ``points`` (R, 3) lie in each box (global centre, size [w, l, h], rotation [w, x, y, z];
    object frame x along l, y along w): the devkit's ``points_in_box`` rule, faces included."""
    out = np.zeros(len(centres), np.int64)
    for k, (c, s, q) in enumerate(zip(centres, sizes_wlh, rotations_wxyz)):
        local = (points - np.asarray(c, np.float64)) @ cameras.quaternion_to_rotation(np.asarray(q, np.float64))
        half = np.array([s[1], s[0], s[2]], np.float64) / 2.0
        out[k] = int(np.count_nonzero(np.all(np.abs(local) <= half, axis=1)))
    return out


def map_raster(ego_xy: np.ndarray) -> np.ndarray:
    """(H, W) uint8 map of ego positions ``ego_xy`` (N, 2) in the map's metres (the global frame): 255 within
    ``DRIVEN_HALF_WIDTH_M`` of the path (sampled every half pixel between frames), 0 elsewhere; row 0 at the top
    (the devkit's ``MapMask``: global y grows upwards)."""
    extent = ego_xy.max(axis=0) + MAP_MARGIN_M
    W, H = (int(math.ceil(v / MAP_RESOLUTION_M)) for v in extent)
    out = np.zeros((H, W), np.uint8)
    samples = [ego_xy[:1]]
    for a, b in zip(ego_xy[:-1], ego_xy[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / (MAP_RESOLUTION_M / 2))))
        samples.append(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
    pts = np.concatenate(samples)
    r = int(math.ceil(DRIVEN_HALF_WIDTH_M / MAP_RESOLUTION_M))
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    disc = (dx ** 2 + dy ** 2) <= r * r
    dx, dy = dx[disc], dy[disc]
    cols = np.rint(pts[:, 0] / MAP_RESOLUTION_M).astype(np.int64)
    rows = H - np.rint(pts[:, 1] / MAP_RESOLUTION_M).astype(np.int64)
    for c, r0 in np.unique(np.stack([cols, rows], 1), axis=0):
        out[(r0 + dy).clip(0, H - 1), (c + dx).clip(0, W - 1)] = 255
    return out


def _pose_record(tok: str, T: np.ndarray, **extra) -> dict:
    T = np.asarray(T, np.float64)
    return {"token": tok, **extra, "translation": [float(v) for v in T[:3, 3]],
            "rotation": [float(v) for v in cameras.rotation_to_quaternion(T[:3, :3])]}


class Tables:
    """The tables of a dataroot being built: ``add`` each clip; ``records`` {table: [record]}; ``files`` the
    (source path, path relative to the dataroot, the clip's frame index) to copy; ``maps`` the (relative PNG path, (H, W) uint8 raster) to
    write; ``counts`` per clip."""

    def __init__(self, keyframe_hz: float = 2.0) -> None:
        self.keyframe_hz = float(keyframe_hz)
        self.records = {name: [] for name in TABLE_NAMES}
        self.files: list = []
        self.maps: list = []
        self._sensors: dict = {}
        self.records["category"] = [{"token": token("category", n), "name": n, "description": d}
                                    for n, d in categories.NUSCENES_CATEGORIES]
        self.records["attribute"] = [{"token": token("attribute", n), "name": n, "description": n}
                                     for n in ATTRIBUTES]
        lower = [0, *(int(u * 100) for _, _, u in VISIBILITY[:-1])]
        self.records["visibility"] = [
            {"token": t, "level": level, "description": f"visibility of whole object is between {lo} and "
                                                        f"{int(u * 100)} %"}
            for (t, level, u), lo in zip(VISIBILITY, lower)]

    def _sensor(self, channel: str, modality: str) -> str:
        if channel not in self._sensors:
            self._sensors[channel] = token("sensor", channel)
            self.records["sensor"].append({"token": self._sensors[channel], "channel": channel,
                                           "modality": modality})
        return self._sensors[channel]

    def add(self, clip: Clip) -> dict:
        """The clip's records; returns its counts {"frames", "samples", "objects", "ignore_regions",
        "inserted"} (annotations; ignore regions left out, per keyframe and camera)."""
        name, n = clip.name, len(clip.frames)
        R = self.records
        keys = keyframes(clip.times_s, self.keyframe_hz)   # a list: in order (membership tests are few)
        ego = np.asarray(clip.ego_to_world, np.float64)
        offset = MAP_MARGIN_M - ego[:, :2, 3].min(axis=0)
        world_to_global = np.eye(4)
        world_to_global[:2, 3] = offset
        ego_global = world_to_global @ ego
        stamps = [EPOCH_US + clip.start_us + int(round(t * 1e6)) for t in clip.times_s]
        seed = clip.seed
        log_tok, map_tok, scene_tok = token(seed, "log"), token(seed, "map"), token(seed, "scene")
        R["log"].append({"token": log_tok, "logfile": name, "vehicle": clip.vehicle, "date_captured": DATE_CAPTURED,
                         "location": "scpainter", "world_to_global": world_to_global.tolist()})
        map_file = f"maps/{map_tok}.png"
        self.maps.append((map_file, map_raster(ego_global[:, :2, 3])))
        R["map"].append({"token": map_tok, "log_tokens": [log_tok], "category": "semantic_prior",
                         "filename": map_file})
        pose_tok = [token(seed, "ego_pose", i) for i in range(n)]
        R["ego_pose"] += [_pose_record(pose_tok[i], ego_global[i], timestamp=stamps[i]) for i in range(n)]
        sample_tok = [token(seed, "sample", i) for i in keys]
        R["sample"] += [{"token": sample_tok[k], "timestamp": stamps[i], "scene_token": scene_tok,
                         "prev": sample_tok[k - 1] if k else "",
                         "next": sample_tok[k + 1] if k + 1 < len(keys) else ""} for k, i in enumerate(keys)]
        owner = [next((sample_tok[k] for k, j in enumerate(keys) if j >= i), sample_tok[-1]) for i in range(n)]
        for cam in clip.cameras:
            self._camera_data(clip, cam, keys, stamps, pose_tok, owner)
        if clip.lidar is not None:
            self._lidar_data(clip, keys, stamps, pose_tok, owner)
        R["scene"].append({"token": scene_tok, "name": name, "description": clip.description, "log_token": log_tok,
                           "nbr_samples": len(keys), "first_sample_token": sample_tok[0],
                           "last_sample_token": sample_tok[-1]})
        counts = self._annotations(clip, keys, sample_tok, world_to_global, ego_global)
        return {"frames": n, "samples": len(keys), **counts}

    def _chain(self, channel: str, rows: list) -> None:
        """prev/next links of one channel's sample_data ``rows`` (in time order), appended to the table."""
        for k, row in enumerate(rows):
            row["prev"] = rows[k - 1]["token"] if k else ""
            row["next"] = rows[k + 1]["token"] if k + 1 < len(rows) else ""
        self.records["sample_data"] += rows

    def _camera_data(self, clip: Clip, cam: CameraClip, keys, stamps, pose_tok, owner) -> None:
        sensor = self._sensor(cam.name, "camera")
        calibrations: dict = {}
        rows = []
        for i, (lab, image) in enumerate(zip(cam.labels, cam.images)):
            K = [[float(v) for v in row] for row in common.opencv_K(lab["camera"]["K"])]
            key = repr(K)
            if key not in calibrations:   # one per intrinsics the camera has (a rig camera: one)
                calibrations[key] = token(clip.seed, "calibrated_sensor", cam.name, len(calibrations))
                self.records["calibrated_sensor"].append(_pose_record(
                    calibrations[key], cam.camera_to_ego, sensor_token=sensor, camera_intrinsic=K))
            folder = "samples" if i in keys else "sweeps"
            rel = f"{folder}/{cam.name}/{clip.name}__{cam.name}__{stamps[i]}.png"
            self.files.append((image, rel, i))
            W, H = lab["image_size"]
            rows.append({"token": token(clip.seed, "sample_data", cam.name, i), "sample_token": owner[i],
                         "ego_pose_token": pose_tok[i], "calibrated_sensor_token": calibrations[key],
                         "filename": rel, "fileformat": "png", "width": int(W), "height": int(H),
                         "timestamp": stamps[i], "is_key_frame": i in keys})
        self._chain(cam.name, rows)

    def _lidar_data(self, clip: Clip, keys, stamps, pose_tok, owner) -> None:
        lid = clip.lidar
        cal = token(clip.seed, "calibrated_sensor", lid.name)
        self.records["calibrated_sensor"].append(_pose_record(cal, lid.lidar_to_ego,
                                                              sensor_token=self._sensor(lid.name, "lidar"),
                                                              camera_intrinsic=[]))
        rows = []
        for i, path in enumerate(clip.sweeps):
            if path is None or not os.path.isfile(path):
                if i in keys:
                    raise errors.InputError(path or f"(sweep of frame {clip.frames[i]})", "(file)",
                                            f"the {lid.name} sweep of keyframe {clip.frames[i]} is missing: nuScenes "
                                            "loaders need one per keyframe",
                                            hint="render again: python -m backend render JOB")
                continue
            folder = "samples" if i in keys else "sweeps"
            rel = f"{folder}/{lid.name}/{clip.name}__{lid.name}__{stamps[i]}.pcd.bin"
            self.files.append((path, rel, i))
            rows.append({"token": token(clip.seed, "sample_data", lid.name, i), "sample_token": owner[i],
                         "ego_pose_token": pose_tok[i], "calibrated_sensor_token": cal, "filename": rel,
                         "fileformat": "pcd", "width": 0, "height": 0, "timestamp": stamps[i],
                         "is_key_frame": i in keys})
        self._chain(lid.name, rows)

    def _objects(self, clip: Clip, i: int) -> tuple:
        """({track id: (object, Σ visible, Σ amodal)} of the objects annotated at frame ``i`` over every camera,
        the number of ignore regions)."""
        seen: dict = {}
        dropped, missing, labelled, regions = set(), set(), set(), 0
        for cam in clip.cameras:
            lab = cam.labels[i]
            for k, o in enumerate(lab["objects"]):
                tid = int(o["track_id"])
                if labels.ignore_region(o) is not None:
                    regions += 1
                if o["box_world"] is None or o["removed"] or o["ignore"]:   # the object's own: in every camera
                    dropped.add(tid)
                    continue
                if o["points_missing"]:      # this camera's view of it only: another may label it
                    missing.add(tid)
                elif o["in_view"]:
                    labelled.add(tid)
                common.category(lab, k)      # a class the table lacks: an InputError naming it
                prev = seen.get(tid, (o, 0, 0))
                seen[tid] = (prev[0], prev[1] + int(o["visible_pixels"]), prev[2] + int(o["amodal_pixels"]))
        dropped |= missing - labelled
        return {t: v for t, v in seen.items() if t not in dropped}, regions

    def _annotations(self, clip: Clip, keys, sample_tok, world_to_global, ego_global) -> dict:
        R = self.records
        per_key = [self._objects(clip, i) for i in keys]
        moves = {t for objs, _ in per_key for t, (o, _, _) in objs.items()
                 if o["velocity"] is not None and np.linalg.norm(o["velocity"]) > MOVING_SPEED}
        tracks: dict = {}
        for (objs, _), i, s_tok in zip(per_key, keys, sample_tok):
            rows = []
            for tid, (o, visible, amodal) in sorted(objs.items()):
                b = o["box_world"]
                l, w, h = b["size"]
                centre = world_to_global[:3, :3] @ np.asarray(b["center"], np.float64) + world_to_global[:3, 3]
                nus = categories.category(o["class"]).nuscenes
                speed = None if o["velocity"] is None else float(np.linalg.norm(o["velocity"]))
                rows.append({"token": token(clip.seed, "sample_annotation", tid, i), "sample_token": s_tok,
                             "instance_token": token(clip.seed, "instance", tid),
                             "attribute_tokens": [token("attribute", a)
                                                  for a in attributes(nus, o["class"], speed, tid in moves)],
                             "visibility_token": visibility_token(visible, amodal),
                             "translation": [float(v) for v in centre], "size": [float(w), float(l), float(h)],
                             "rotation": [float(v) for v in b["quaternion"]], "num_lidar_pts": 0,
                             "num_radar_pts": 0, "synthetic": bool(o["synthetic"]), "track_id": tid})
                tracks.setdefault(tid, (nus, o["name"], []))[2].append(rows[-1])
            if clip.lidar is not None and rows and clip.sweeps[i] is not None:
                pts = sweep_mod.read_pcd_bin(clip.sweeps[i])[:, :3].astype(np.float64)
                to_global = ego_global[i] @ np.asarray(clip.lidar.lidar_to_ego, np.float64)
                pts = pts @ to_global[:3, :3].T + to_global[:3, 3]
                counts = points_in_boxes(pts, [r["translation"] for r in rows], [r["size"] for r in rows],
                                         [r["rotation"] for r in rows])
                for r, c in zip(rows, counts):
                    r["num_lidar_pts"] = int(c)
            R["sample_annotation"] += rows
        for tid, (nus, obj_name, anns) in sorted(tracks.items()):
            for k, a in enumerate(anns):
                a["prev"] = anns[k - 1]["token"] if k else ""
                a["next"] = anns[k + 1]["token"] if k + 1 < len(anns) else ""
            R["instance"].append({"token": token(clip.seed, "instance", tid), "category_token": token("category", nus),
                                  "nbr_annotations": len(anns), "first_annotation_token": anns[0]["token"],
                                  "last_annotation_token": anns[-1]["token"], "track_id": tid, "name": obj_name})
        anns = [a for _, _, group in tracks.values() for a in group]
        return {"objects": len(anns), "inserted": sum(a["synthetic"] for a in anns),
                "ignore_regions": sum(r for _, r in per_key)}
