"""The sensors sidecar of a multi-camera reconstruction: which sensor (camera channel) took each VGGT frame, and when.

VGGT runs on the images of several cameras at once; its ``predictions.npz`` does not say which camera took which
frame. The sidecar does (docs/design.md §4.1), a JSON file beside the predictions (the import looks for
``<predictions stem>.sensors.json`` when none is named)::

    {"schema": "scpainter.sensors/1",
     "frames": [{"sensor": "CAM_FRONT", "timestamp_us": 1533151603512404},
                {"sensor": "CAM_FRONT_LEFT", "timestamp_us": 1533151603504799}, ...],
     "sensors": [{"name": "CAM_FRONT", "camera_to_ego": [[...4x4...]], "resolution": [1600, 900]}, ...]}

* ``frames``: one record per VGGT frame, in the predictions' frame order (as many as the predictions have):
  ``sensor`` a channel name (``core.rig.NAME_PATTERN``: 1-64 letters, digits or ``_``) and ``timestamp_us`` when
  the image was taken, integer microseconds (nuScenes' unit; any epoch). A sensor's timestamps increase strictly
  in frame order.
* ``sensors`` (optional): per sensor what is known of it: ``camera_to_ego`` (4, 4) rigid, OpenCV camera axes to the
  ego frame (x forward, y left, z up, metres: ``core.rig``), used as the recording's rig instead of the estimate
  (``core.geometry.rig_fit``); ``resolution`` [width, height] of the sensor's own images (the rig camera gets it,
  K scaled per axis from the predictions' size). Every sensor listed must have frames.

Unknown fields are refused (a misspelt ``camera_to_ego`` would silently become an estimate). Read with the bounded
JSON reader (``core.files.read_json``); every refusal is an ``InputError`` naming the file and the field
(``frames[3].timestamp_us``). ``write`` writes one (atomically). No bpy, no torch: numpy.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .. import fields, files, outputs
from .. import rig as rig_mod
from ..errors import InputError

SCHEMA = "scpainter.sensors/1"
#: The sidecar the import uses when none is named: ``<predictions stem>`` + this, beside the predictions.
SUFFIX = ".sensors.json"
#: The most frames a sidecar may list (VGGT runs on a few hundred images at most).
MAX_FRAMES = 100_000
#: The sensor whose frames carry the ego path and the scene frames when the recording has it (else the first).
PREFERRED_REFERENCE = rig_mod.NUSCENES_CAMERAS[0]


@dataclass
class SensorInfo:
    """What a sidecar says of one sensor beyond its frames: ``camera_to_ego`` (4, 4) or None (estimate it),
    ``resolution`` (width, height) px of its own images or None (the predictions')."""
    camera_to_ego: np.ndarray | None = None
    resolution: tuple | None = None


@dataclass
class Sensors:
    """A multi-camera recording's frames: ``sensor[i]`` and ``timestamp_us[i]`` of VGGT frame i; ``info`` per sensor
    name (only the sensors the sidecar describes); ``path`` the sidecar (for messages)."""
    sensor: list
    timestamp_us: np.ndarray        # (S,) int64 microseconds
    info: dict = field(default_factory=dict)
    path: str = ""

    @property
    def num_frames(self) -> int:
        return len(self.sensor)

    @property
    def names(self) -> list:
        """The sensors, in the order of their first frame."""
        return list(dict.fromkeys(self.sensor))

    def frames_of(self, name: str) -> np.ndarray:
        """(n,) the VGGT frame indices of sensor ``name``, in frame (and time) order."""
        return np.flatnonzero(np.asarray(self.sensor) == name)

    @property
    def reference(self) -> str:
        """The sensor whose frames make the ego path and the scene frames: ``reference_of(self.sensor)``."""
        return reference_of(self.sensor)

    def camera_frames(self) -> dict:
        """``camera_frames(self.sensor)``: {sensor: its VGGT frames}, the reference first."""
        return camera_frames(self.sensor)

    def check_frames(self, num_frames: int, predictions: str) -> Sensors:
        """``self`` if it has one record per frame of the predictions (``predictions`` the file, named in the
        message); InputError on ``frames`` otherwise."""
        if self.num_frames != num_frames:
            raise InputError(self.path, "frames", f"{self.num_frames} frames, but the predictions "
                                                  f"{os.path.basename(predictions)} hold {num_frames}",
                             hint="the sidecar needs one record per VGGT frame, in the order VGGT was given the "
                                  "images: make it for these predictions")
        return self

    def scene_frames(self) -> np.ndarray:
        """(S,) per VGGT frame its scene frame offset (0-based): scene frame k is the reference sensor's k-th frame
        (``reference``), and every other sensor's frame goes to the reference frame nearest in time (ties to the
        earlier). Several sensors share a scene frame; a sensor with two frames at one scene frame (a faster sensor
        than the reference) is an InputError on its second frame's ``timestamp_us``."""
        ref_frames = self.frames_of(self.reference)
        ref_t = self.timestamp_us[ref_frames]
        out = np.empty(self.num_frames, np.int64)
        for name in self.names:
            idx = self.frames_of(name)
            t = self.timestamp_us[idx]
            k = np.searchsorted(ref_t, t).clip(1, len(ref_t) - 1) if len(ref_t) > 1 else np.zeros(len(t), np.int64)
            if len(ref_t) > 1:
                k = np.where(np.abs(t - ref_t[k - 1]) <= np.abs(t - ref_t[k]), k - 1, k)
            dup = np.flatnonzero(np.diff(k) == 0)
            if len(dup):
                j = int(idx[dup[0] + 1])
                raise InputError(self.path, f"frames[{j}].timestamp_us",
                                 f"{name} has two frames nearest to the reference sensor {self.reference}'s frame "
                                 f"{int(k[dup[0]])}: one scene frame per reference frame holds one image per sensor",
                                 hint=f"give VGGT the {name} images at the {self.reference} frames' times only")
            out[idx] = k
        return out

    def to_dict(self) -> dict:
        d = {"schema": SCHEMA, "frames": [{"sensor": s, "timestamp_us": int(t)}
                                           for s, t in zip(self.sensor, self.timestamp_us)]}
        described = [n for n in self.names if n in self.info]
        if described:
            d["sensors"] = []
            for n in described:
                rec = {"name": n}
                inf = self.info[n]
                if inf.camera_to_ego is not None:
                    rec["camera_to_ego"] = np.asarray(inf.camera_to_ego, np.float64).tolist()
                if inf.resolution is not None:
                    rec["resolution"] = [int(v) for v in inf.resolution]
                d["sensors"].append(rec)
        return d


def reference_of(sensor: list) -> str:
    """The reference sensor of a recording whose VGGT frame i is sensor ``sensor[i]`` (non-empty): ``CAM_FRONT``
    when the recording has it, else the sensor of the first frame."""
    return PREFERRED_REFERENCE if PREFERRED_REFERENCE in sensor else sensor[0]


def camera_frames(sensor: list) -> dict:
    """{sensor name: (n,) int64 its VGGT frame indices in frame order} of a recording whose VGGT frame i is sensor
    ``sensor[i]``: one recorded camera each, the reference sensor (``reference_of``) first, then the others in the
    order of their first frame. The import makes its cameras in this order and *Import Recorded Objects* reads the
    stored sensors back through it (scene/recorded_objects.py)."""
    sensor = [str(s) for s in sensor]
    ref = reference_of(sensor)
    names = [ref] + [n for n in dict.fromkeys(sensor) if n != ref]
    arr = np.asarray(sensor)
    return {n: np.flatnonzero(arr == n) for n in names}


def default_path(predictions: str | os.PathLike) -> str:
    """``<predictions stem>.sensors.json`` beside the predictions: the sidecar the import uses when none is named."""
    p = os.fspath(predictions)
    return os.path.splitext(p)[0] + SUFFIX


def _known(d: dict, path, where, known) -> None:
    for k in d:
        if k not in known:
            raise InputError(path, f"{where}.{k}" if where else str(k), f"unknown field (expected {', '.join(known)})")


def from_dict(d: object, path: str | os.PathLike) -> Sensors:
    """A sidecar's content (``Sensors.to_dict``'s), checked; InputError naming ``path`` and the field."""
    path = os.fspath(path)
    if not isinstance(d, dict):
        raise InputError(path, "(file)", f"expected a JSON object, got {fields.short(d)}")
    if d.get("schema") != SCHEMA:
        raise InputError(path, "schema", f"expected {SCHEMA!r}, got {fields.short(d.get('schema'))}")
    _known(d, path, "", ("schema", "frames", "sensors"))
    frames = d.get("frames")
    if not isinstance(frames, list) or not frames:
        raise InputError(path, "frames", "expected a non-empty list of {sensor, timestamp_us} records, one per "
                                         "VGGT frame")
    if len(frames) > MAX_FRAMES:
        raise InputError(path, "frames", f"{len(frames)} frames: at most {MAX_FRAMES}")
    sensor, stamps = [], []
    last: dict = {}
    for i, f in enumerate(frames):
        at = f"frames[{i}]"
        if not isinstance(f, dict):
            raise InputError(path, at, f"expected an object, got {fields.short(f)}")
        _known(f, path, at, ("sensor", "timestamp_us"))
        name = fields.string(f.get("sensor"), path, f"{at}.sensor")
        if not rig_mod.NAME_PATTERN.fullmatch(name):
            raise InputError(path, f"{at}.sensor", f"{fields.short(name)} is not a sensor name (1-64 letters, digits "
                                                   "or _)")
        t = fields.integer(f.get("timestamp_us"), path, f"{at}.timestamp_us", 0)
        if name in last and t <= last[name][1]:
            raise InputError(path, f"{at}.timestamp_us", f"{t} is not after {name}'s previous frame "
                                                         f"(frames[{last[name][0]}], {last[name][1]}): a sensor's "
                                                         "timestamps must increase in frame order",
                             hint="list the frames in the order VGGT was given the images, each sensor's in time "
                                  "order")
        last[name] = (i, t)
        sensor.append(name)
        stamps.append(t)
    info = {}
    given = d.get("sensors", [])
    if not isinstance(given, list):
        raise InputError(path, "sensors", f"expected a list of sensors, got {fields.short(given)}")
    for i, s in enumerate(given):
        at = f"sensors[{i}]"
        if not isinstance(s, dict):
            raise InputError(path, at, f"expected an object, got {fields.short(s)}")
        _known(s, path, at, ("name", "camera_to_ego", "resolution"))
        name = fields.string(s.get("name"), path, f"{at}.name")
        if name not in last:
            raise InputError(path, f"{at}.name", f"{fields.short(name)} has no frame (the frames' sensors are "
                                                 f"{list(dict.fromkeys(sensor))})")
        if name in info:
            raise InputError(path, f"{at}.name", f"{name!r} is described twice")
        T = None if s.get("camera_to_ego") is None else fields.rigid(s["camera_to_ego"], path, f"{at}.camera_to_ego")
        res = s.get("resolution")
        if res is not None:
            if not isinstance(res, list) or len(res) != 2:
                raise InputError(path, f"{at}.resolution", f"expected [width, height], got {fields.short(res)}")
            res = tuple(fields.integer(v, path, f"{at}.resolution[{k}]", 1, 16384) for k, v in enumerate(res))
        info[name] = SensorInfo(T, res)
    return Sensors(sensor, np.array(stamps, np.int64), info, path)


def read(path: str | os.PathLike) -> Sensors:
    """The sidecar at ``path`` (bounded JSON, a regular file), checked: ``from_dict``."""
    path = os.fspath(path)
    return from_dict(files.read_json(path), path)


def write(path: str | os.PathLike, sensors: Sensors) -> None:
    """Write ``sensors`` as a sidecar (atomically)."""
    outputs.write_json(path, sensors.to_dict())
