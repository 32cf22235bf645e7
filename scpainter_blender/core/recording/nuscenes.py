"""A nuScenes scene's annotations: the devkit's JSON tables (nuscenes-devkit ``schema.md``) of one ``scene``.

Read from the folder holding the tables (``<dataroot>/v1.0-mini/``): ``scene`` (the scene by ``name`` or ``token``),
``sample`` (its keyframes, in order from ``first_sample_token`` along ``next``), ``sample_data`` (per keyframe the
camera's image: ``is_key_frame``, its ``ego_pose_token`` and ``calibrated_sensor_token``), ``calibrated_sensor`` and
``sensor`` (which channel a calibration is: ``CAM_FRONT`` by default), ``ego_pose``, ``sample_annotation`` (a box per
sample: ``translation`` and ``rotation`` quaternion [w, x, y, z] in the global frame, ``size`` [w, l, h] metres),
``instance`` (the track: its ``category_token``) and ``category`` (``name``). Poses are sensor-to-ego
(calibrated_sensor) and ego-to-global (ego_pose), with the camera in OpenCV axes, as the devkit uses them; a box's own
frame is x forward, y left, z up (the devkit's ``Box``).

The recording's frames are the scene's keyframes, so the reconstruction must be made from that camera's keyframe
images in order (``samples/CAM_FRONT/...``); a box at a keyframe goes into that keyframe's camera: camera_to_ego⁻¹ ·
ego_to_global⁻¹ · box_to_global. Classes map through ``core.categories.from_nuscenes``; the devkit's classes the
table does not label (``NOT_LABELLED``: animals, pushable objects, bicycle racks) become ignore regions, any other
unknown name is an error naming ``category.json``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .. import categories, files
from .. import rig as rig_mod
from ..geometry import cameras
from ..vggt import sensors as sensors_mod
from . import tracks

TABLES = ("scene", "sample", "sample_data", "calibrated_sensor", "sensor", "ego_pose", "sample_annotation",
          "instance", "category")
DEFAULT_CAMERA = "CAM_FRONT"
#: The devkit's categories that are not objects to label: imported as ignore regions (class ``misc``).
NOT_LABELLED = ("animal", "movable_object.pushable_pullable", "static_object.bicycle_rack")
NOT_LABELLED_CLASS = "misc"


def is_tables_folder(path: str) -> bool:
    """Whether ``path`` is a folder holding nuScenes tables (``scene.json`` and ``sample_annotation.json``)."""
    return os.path.isdir(path) and all(os.path.isfile(os.path.join(path, f"{t}.json"))
                                       for t in ("scene", "sample_annotation"))


def _table(folder: str, name: str) -> tuple:
    path = os.path.join(folder, f"{name}.json")
    if not os.path.isfile(path):
        raise tracks.bad(path, "(file)", f"the nuScenes table {name!r} is missing",
                         hint=f"give the folder holding the devkit's tables: {', '.join(TABLES)}")
    rows = files.read_json(path, max_bytes=2 ** 31)
    if not isinstance(rows, list) or not all(isinstance(r, dict) and "token" in r for r in rows):
        raise tracks.bad(path, "(file)", "expected a list of records, each with a token")
    return path, {r["token"]: r for r in rows}


def _get(table: tuple, token, where: str, field: str):
    path, rows = table
    if token not in rows:
        raise tracks.bad(path, field, f"no record {token!r} (named by {where})")
    return rows[token]


def _pose(record: dict, path, where: str) -> np.ndarray:
    q = tracks.number_list(record.get("rotation"), 4, path, f"{where}.rotation")
    t = tracks.number_list(record.get("translation"), 3, path, f"{where}.translation")
    if np.linalg.norm(q) < 1e-9:
        raise tracks.bad(path, f"{where}.rotation", "a quaternion of zero length")
    return tracks.pose(cameras.quaternion_to_rotation(q), t)


def _scene_samples(t: dict, scene: str, option: str = "--objects-scene") -> tuple:
    """(the scene record, its samples in order along ``next`` from the first) of scene ``scene`` (name or token; may
    be empty when the tables hold one scene), from the tables ``t`` (name -> ``_table``); ``option``: the command
    line's option that names the scene (in the hint of a scene not found)."""
    scenes_path, scenes = t["scene"]
    chosen = [s for s in scenes.values() if scene in (s.get("name"), s["token"])] if scene else list(scenes.values())
    if len(chosen) != 1:
        names = sorted(str(s.get("name")) for s in scenes.values())
        raise tracks.bad(scenes_path, "name", (f"no scene {scene!r}" if scene else f"{len(chosen)} scenes") +
                         f" among {names[:10]}{' …' if len(names) > 10 else ''}",
                         hint=f"name the scene (its name or token: {option})")
    sc = chosen[0]
    # the keyframes in order, along next from the first
    samples, token = [], sc.get("first_sample_token")
    while token:
        s = _get(t["sample"], token, f"scene {sc.get('name')!r}", "token")
        if len(samples) > len(t["sample"][1]) or s.get("scene_token") != sc["token"]:
            raise tracks.bad(t["sample"][0], "next", f"the samples of scene {sc.get('name')!r} do not form one chain")
        samples.append(s)
        token = s.get("next") or None
    stamps = [s.get("timestamp", 0) for s in samples]
    if any(b <= a for a, b in zip(stamps, stamps[1:])):
        raise tracks.bad(t["sample"][0], "timestamp", f"the samples of scene {sc.get('name')!r} are not in time order")
    return sc, samples


def _keyframe_data(t: dict, sample_of: dict):
    """(sample index, sample_data, its calibrated_sensor, its channel) of each keyframe ``sample_data`` record of the
    samples ``sample_of`` ({sample token: index}); a dangling token is an error naming the record."""
    for sd in t["sample_data"][1].values():
        i = sample_of.get(sd.get("sample_token"))
        if i is None or not sd.get("is_key_frame"):
            continue
        cs = _get(t["calibrated_sensor"], sd.get("calibrated_sensor_token"), f"sample_data {sd['token']!r}", "token")
        sensor = _get(t["sensor"], cs.get("sensor_token"), f"calibrated_sensor {cs['token']!r}", "token")
        yield i, sd, cs, sensor.get("channel")


def read(folder: str, scene: str = "", camera: str = "") -> tracks.Recording:
    """The tracks of nuScenes scene ``scene`` (name or token; may be empty when the tables hold one scene) seen from
    channel ``camera`` (default ``CAM_FRONT``), from the tables in ``folder`` (or the folder of a table file)."""
    folder = folder if os.path.isdir(folder) else os.path.dirname(folder)
    camera = camera or DEFAULT_CAMERA
    t = {name: _table(folder, name) for name in TABLES}
    sc, samples = _scene_samples(t, scene)
    frame_of = {s["token"]: i for i, s in enumerate(samples)}
    # per keyframe the camera's sample_data: global -> camera
    sd_path = t["sample_data"][0]
    w2c = [None] * len(samples)
    for i, sd, cs, channel in _keyframe_data(t, frame_of):
        if channel != camera:
            continue
        where = f"sample_data {sd['token']!r}"
        ego = _get(t["ego_pose"], sd.get("ego_pose_token"), where, "token")
        camera_to_global = _pose(ego, t["ego_pose"][0], f"ego_pose {ego['token']!r}") @ \
            _pose(cs, t["calibrated_sensor"][0], f"calibrated_sensor {cs['token']!r}")
        w2c[i] = cameras.rigid_inverse(camera_to_global)
    missing = [i for i, m in enumerate(w2c) if m is None]
    if missing:
        raise tracks.bad(sd_path, "is_key_frame", f"no {camera} keyframe image for samples {missing[:5]} of scene "
                                                  f"{sc.get('name')!r}", hint="choose the camera: --objects-camera")
    ann_path, anns = t["sample_annotation"]
    seen = {}  # instance token -> (class, ignore, sizes, boxes)
    for a in anns.values():
        i = frame_of.get(a.get("sample_token"))
        if i is None:
            continue   # another scene's
        where = f"sample_annotation {a['token']!r}"
        inst = _get(t["instance"], a.get("instance_token"), where, "token")
        cat = _get(t["category"], inst.get("category_token"), f"instance {inst['token']!r}", "token")
        name = cat.get("name")
        ignore = name in NOT_LABELLED
        cls = NOT_LABELLED_CLASS if ignore else tracks.category(
            name, categories.from_nuscenes, t["category"][0], f"category {cat['token']!r}.name", "nuscenes")
        size = tracks.check_size(tracks.number_list(a.get("size"), 3, ann_path, f"{where}.size"), ann_path,
                                 f"{where}.size")
        box_to_global = tracks.object_box(_pose(a, ann_path, where))
        entry = seen.setdefault(inst["token"], (cls, ignore, [], {}))
        if i in entry[3]:
            raise tracks.bad(ann_path, f"{where}.sample_token", f"instance {inst['token']!r} has two boxes in "
                                                                f"sample {a['sample_token']!r}")
        entry[2].append(size)
        entry[3][i] = w2c[i] @ box_to_global
    out = [tracks.track(tok, cls, sizes, b, ig) for tok, (cls, ig, sizes, b) in sorted(seen.items())]
    return tracks.Recording(folder, "nuscenes", len(samples), out, np.stack(w2c))


#: The tables ``sensors`` reads.
SENSOR_TABLES = ("scene", "sample", "sample_data", "calibrated_sensor", "sensor", "ego_pose")


@dataclass
class SensorFrames:
    """What ``sensors`` reads of a scene's camera keyframes, per VGGT frame in order: ``sensors`` (the sidecar),
    ``images`` (``sample_data.filename``, relative to the dataroot), ``world_to_camera`` (S, 4, 4) in nuScenes'
    global frame (ego_pose · calibrated_sensor, inverted; metres, OpenCV camera axes)."""
    sensors: sensors_mod.Sensors
    images: list
    world_to_camera: np.ndarray


def sensors(folder: str, scene: str = "", channels: list | tuple = (), calibration: bool = True) -> SensorFrames:
    """The sensors sidecar (``core.vggt.sensors``) of the reconstruction VGGT made from nuScenes scene ``scene``'s
    keyframe images of camera ``channels``: frames in sample order (the scene's keyframes along ``next``), and within
    a sample in the order of ``channels`` (default: those of ``rig.NUSCENES_CAMERAS`` the scene has, in that order:
    CAM_FRONT, CAM_FRONT_RIGHT, CAM_FRONT_LEFT, CAM_BACK, CAM_BACK_LEFT, CAM_BACK_RIGHT), each with its
    ``sample_data`` timestamp (µs). With ``calibration`` every sensor gets its ``calibrated_sensor`` pose as
    ``camera_to_ego`` and its image ``width``/``height`` as ``resolution`` (the recording's rig is then nuScenes'
    own, not estimated). Returns the sidecar, the frames' images (give VGGT the images in exactly this order) and
    their camera poses (a metric trajectory for the import's trajectory scale mode)."""
    folder = folder if os.path.isdir(folder) else os.path.dirname(folder)
    t = {name: _table(folder, name) for name in SENSOR_TABLES}
    sc, samples = _scene_samples(t, scene, "--scene")   # the option of the sensors command, its one caller
    sample_of = {s["token"]: i for i, s in enumerate(samples)}
    found: dict = {}   # (sample index, channel) -> (timestamp, calibrated sensor, width, height)
    for i, sd, cs, channel in _keyframe_data(t, sample_of):
        found[(i, channel)] = (sd, cs)
    have = {ch for _, ch in found}
    channels = list(channels) or [c for c in rig_mod.NUSCENES_CAMERAS if c in have]
    if not channels:
        raise tracks.bad(t["sample_data"][0], "is_key_frame", f"no camera keyframe images in scene "
                                                              f"{sc.get('name')!r}")
    frames, stamps, images, w2c, info = [], [], [], [], {}
    for i in range(len(samples)):
        for ch in channels:
            if (i, ch) not in found:
                raise tracks.bad(t["sample_data"][0], "is_key_frame",
                                 f"no {ch} keyframe image for sample {samples[i]['token']!r} of scene "
                                 f"{sc.get('name')!r} (the scene has {sorted(have)})",
                                 hint="choose channels that every keyframe has (--channels)")
            sd, cs = found[(i, ch)]
            where = f"sample_data {sd['token']!r}"
            ts = sd.get("timestamp")
            if isinstance(ts, bool) or not isinstance(ts, int) or ts < 0:
                raise tracks.bad(t["sample_data"][0], f"{where}.timestamp", f"expected microseconds, got {ts!r}")
            frames.append(ch)
            stamps.append(ts)
            images.append(str(sd.get("filename", "")))
            ego = _get(t["ego_pose"], sd.get("ego_pose_token"), where, "token")
            w2c.append(cameras.rigid_inverse(
                _pose(ego, t["ego_pose"][0], f"ego_pose {ego['token']!r}") @
                _pose(cs, t["calibrated_sensor"][0], f"calibrated_sensor {cs['token']!r}")))
            if calibration and ch not in info:
                res = (sd.get("width"), sd.get("height"))
                ok = all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 16384 for v in res)
                info[ch] = sensors_mod.SensorInfo(
                    _pose(cs, t["calibrated_sensor"][0], f"calibrated_sensor {cs['token']!r}"),
                    tuple(res) if ok else None)
    out = sensors_mod.Sensors(frames, np.array(stamps, np.int64), info, os.path.join(folder, "sample_data.json"))
    # the sidecar's own checks (sensor names, each sensor's timestamps increasing), naming sample_data.json
    return SensorFrames(sensors_mod.from_dict(out.to_dict(), out.path), images, np.stack(w2c))
