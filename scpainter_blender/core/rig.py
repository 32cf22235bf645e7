"""Camera rigs: several cameras (and a LiDAR) with fixed mounting poses on the ego vehicle (docs/design.md §4.2, §17).

A rig job (``core.job``) renders every camera of its rig along one ego path instead of one camera along a camera
path. Conventions:

* **Ego frame** (nuScenes, ISO 8855): x forward, y left, z up, metres, the origin on the ground under the rear axle.
  ``ego_to_world`` (4, 4) rigid is where the vehicle is at a frame; the world is the import's (Z up, metres).
* **Camera**: OpenCV axes (x right, y down, z forward); ``camera_to_ego`` (4, 4) rigid is its mounting pose; ``K``
  is ours (pixel centres at +0.5, ``core.geometry.cameras``) for the camera's own ``resolution`` (width, height).
* **LiDAR**: its sensor frame is nuScenes' ``LIDAR_TOP`` one (x right, y forward, z up); ``lidar_to_ego`` (4, 4)
  rigid; ``model`` names a spinning sensor of ``core.lidar_model.MODELS``.
* Quaternions, where a file holds them (nuScenes' ``calibrated_sensor``), are (w, x, y, z).

Presets (``PRESETS``): ``front`` (nuScenes' front camera alone) and ``nuscenes`` (its six cameras and its top
LiDAR), from the ``calibrated_sensor`` records of one nuScenes log (n015, Singapore Holland Village) as the devkit's
v1.0-mini tables hold them: 1600 × 900 images, intrinsics shifted by +0.5 px into our pixel convention. A rig read
from a file or a job is checked (``Rig.from_dict``): at least one camera, sensor names unique, each K usable at its
resolution with its principal point in the middle half of the image (``PRINCIPAL_POINT_CENTRE_SHARE``: a K for
another resolution is refused), every mounting pose rigid.

No bpy, no torch: numpy.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from . import fields
from .errors import ArgumentError, InputError, did_you_mean
from .geometry import cameras
from .output_layout import OutputLayout

RIG_SCHEMA = "scpainter.rig/1"
#: A sensor's name: what nuScenes calls a channel (a folder name in every export, so no path characters).
NAME_PATTERN = re.compile(r"[A-Za-z0-9_]{1,64}")
#: The six camera channels in nuScenes' (and mmdetection3d's info converter's) order.
NUSCENES_CAMERAS = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_FRONT_LEFT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_BACK_RIGHT")
NUSCENES_LIDAR = OutputLayout.LIDAR  # "LIDAR_TOP": its sweeps' folder is named by the channel
MAX_CAMERAS = 32

#: nuScenes' calibrated sensors of log n015 (v1.0-mini): channel -> (translation m, rotation (w, x, y, z), (fx, cx,
#: cy) px in the devkit's pixel convention, pixel centres at integers; fy = fx). Images 1600 × 900.
_NUSCENES_CALIBRATION = {
    "CAM_FRONT": ((1.70079118954, 0.0159456324149, 1.51095763913),
                  (0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755),
                  (1266.417203046554, 816.2670197447984, 491.50706579294757)),
    "CAM_FRONT_RIGHT": ((1.5508477543, -0.493404796419, 1.49574800619),
                        (0.2060347966337182, -0.2026940577919598, 0.6824507824531167, -0.6713610884174485),
                        (1260.8474446004698, 807.968244525554, 495.3344268742088)),
    "CAM_FRONT_LEFT": ((1.52387798135, 0.494631336551, 1.50932822144),
                       (0.6757265034669446, -0.6736266522251881, 0.21214015046209478, -0.21122827103904068),
                       (1272.5979470598488, 826.6154927353808, 479.75165386361925)),
    "CAM_BACK": ((0.0283260309358, 0.00345136761476, 1.57910346144),
                 (0.5037872666382278, -0.49740249788611096, -0.4941850223835201, 0.5045496097725578),
                 (809.2209905677063, 829.2196003259838, 481.77842384512485)),
    "CAM_BACK_LEFT": ((1.03569100218, 0.484795032713, 1.59097014818),
                      (0.6924185592174665, -0.7031619420114925, -0.11648342771943819, 0.11203317912370753),
                      (1256.7414812095406, 792.1125740759628, 492.7757465151356)),
    "CAM_BACK_RIGHT": ((1.0148780988, -0.480568219723, 1.56239545128),
                       (0.12280980120078765, -0.132400842670559, -0.7004305821388234, 0.690496031265798),
                       (1259.5137405846733, 807.2529053838625, 501.19579884916527)),
}
_NUSCENES_LIDAR_MOUNT = ((0.943713, 0.0, 1.84023),
                         (0.7077955119163518, -0.006492242056004365, 0.010646214713995808, -0.7063073142877817))
NUSCENES_RESOLUTION = (1600, 900)
NUSCENES_LIDAR_MODEL = "nuscenes-32"


@dataclass(eq=False)
class RigCamera:
    """One camera of a rig: ``name`` (a channel, ``NAME_PATTERN``), ``resolution`` (width, height) px, ``K`` (3, 3)
    ours for that resolution, ``camera_to_ego`` (4, 4) rigid, OpenCV camera axes to the ego frame, metres."""
    name: str
    resolution: tuple
    K: np.ndarray
    camera_to_ego: np.ndarray

    def to_dict(self) -> dict:
        return {"name": self.name, "resolution": [int(v) for v in self.resolution],
                "K": np.asarray(self.K, np.float64).tolist(),
                "camera_to_ego": np.asarray(self.camera_to_ego, np.float64).tolist()}


@dataclass(eq=False)
class RigLidar:
    """A rig's spinning LiDAR: ``name`` (a channel, ``LIDAR_TOP``), ``model`` (a key of
    ``core.lidar_model.MODELS``), ``lidar_to_ego`` (4, 4) rigid, sensor frame (x right, y forward, z up) to ego."""
    name: str
    model: str
    lidar_to_ego: np.ndarray

    def to_dict(self) -> dict:
        return {"name": self.name, "model": self.model,
                "lidar_to_ego": np.asarray(self.lidar_to_ego, np.float64).tolist()}


@dataclass(eq=False)
class Rig:
    """``name`` (a preset's, or what the user calls it), ``cameras`` ([RigCamera], ≥ 1, in their output order),
    ``lidar`` (RigLidar or None)."""
    name: str
    cameras: list
    lidar: RigLidar | None = None

    def camera(self, name: str) -> RigCamera:
        """The camera called ``name``; KeyError listing the names otherwise."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise KeyError(f"no camera {name!r} in rig {self.name!r} (it has {[c.name for c in self.cameras]})")

    @property
    def sensor_names(self) -> list:
        return [c.name for c in self.cameras] + ([self.lidar.name] if self.lidar is not None else [])

    def scaled(self, factor: float) -> Rig:
        """Every camera's resolution × ``factor`` (rounded, at least 1 px) with K scaled to the same field of view:
        with pixel centres at +0.5, K's first two rows scale by the size ratios exactly."""
        cams = []
        for c in self.cameras:
            W, H = (max(1, int(round(v * factor))) for v in c.resolution)
            S = np.diag([W / c.resolution[0], H / c.resolution[1], 1.0])
            cams.append(replace(c, resolution=(W, H), K=S @ np.asarray(c.K, np.float64)))
        return replace(self, cameras=cams)

    def to_dict(self) -> dict:
        d = {"name": self.name, "cameras": [c.to_dict() for c in self.cameras]}
        if self.lidar is not None:
            d["lidar"] = self.lidar.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: object, path: str | os.PathLike, where: str = "rig",
                  error: Callable[..., Exception] = InputError) -> Rig:
        """A rig from its JSON content (``to_dict``'s); ``error(path, field, message, hint)`` names the field
        (``rig.cameras[2].K``) for anything that is not a usable rig."""
        path = os.fspath(path)
        top = f"{where}." if where else ""   # a rig file's fields are its top level: "cameras[2].K"
        if not isinstance(d, dict):
            raise error(path, where or "(top level)", f"expected an object, got {fields.short(d)}")
        _known(d, path, where, ("name", "cameras", "lidar"), error)
        name = fields.string(d.get("name", "custom"), path, f"{top}name", error)
        cams_in = d.get("cameras")
        if not isinstance(cams_in, list) or not cams_in:
            raise error(path, f"{top}cameras", "expected a non-empty list of cameras")
        if len(cams_in) > MAX_CAMERAS:
            raise error(path, f"{top}cameras", f"{len(cams_in)} cameras: at most {MAX_CAMERAS} in one rig")
        seen: dict = {}
        cams = []
        for i, c in enumerate(cams_in):
            at = f"{top}cameras[{i}]"
            if not isinstance(c, dict):
                raise error(path, at, f"expected an object, got {fields.short(c)}")
            _known(c, path, at, ("name", "resolution", "K", "camera_to_ego"), error)
            cname = _sensor_name(c.get("name"), path, f"{at}.name", seen, error)
            res = c.get("resolution")
            if not isinstance(res, list) or len(res) != 2:
                raise error(path, f"{at}.resolution", f"expected [width, height], got {fields.short(res)}")
            W, H = (fields.integer(v, path, f"{at}.resolution[{k}]", 1, 16384, error) for k, v in enumerate(res))
            K = fields.matrix(c.get("K"), path, f"{at}.K", (3, 3), error)
            problem = cameras.intrinsics_problem(K, (W, H))
            if problem is not None:
                raise error(path, f"{at}.K", f"does not fit the camera's {W} x {H} resolution: {problem}",
                            "give K in pixels of this camera's own resolution (scale K with it)")
            off = _principal_point_off_centre(K, (W, H))
            if off is not None:
                raise error(path, f"{at}.K", f"does not fit the camera's {W} x {H} resolution: {off}",
                            "K is for another resolution? scale it with the image (Rig.scaled / --scale)")
            T = fields.rigid(c.get("camera_to_ego"), path, f"{at}.camera_to_ego", error)
            cams.append(RigCamera(cname, (W, H), K, T))
        lidar = None
        if d.get("lidar") is not None:
            at = f"{top}lidar"
            ld = d["lidar"]
            if not isinstance(ld, dict):
                raise error(path, at, f"expected an object, got {fields.short(ld)}")
            _known(ld, path, at, ("name", "model", "lidar_to_ego"), error)
            lname = _sensor_name(ld.get("name", NUSCENES_LIDAR), path, f"{at}.name", seen, error)
            model = fields.string(ld.get("model"), path, f"{at}.model", error)
            problem = lidar_model_problem(model)
            if problem is not None:
                raise error(path, f"{at}.model", problem)
            lidar = RigLidar(lname, model, fields.rigid(ld.get("lidar_to_ego"), path, f"{at}.lidar_to_ego", error))
        return cls(name, cams, lidar)


def lidar_model_problem(model: str) -> str | None:
    """Why ``model`` names no LiDAR model of ``core.lidar_model.MODELS`` (the list in the message), or None."""
    from . import lidar_model  # the models' one home

    if model in lidar_model.MODELS:
        return None
    return (f"no LiDAR model {model!r}: expected one of {sorted(lidar_model.MODELS)}"
            f"{did_you_mean(str(model), lidar_model.MODELS)}")


def _known(d: dict, path, where, known, error) -> None:
    for k in d:
        if k not in known:
            raise error(path, f"{where}.{k}" if where else k, f"unknown field (expected {', '.join(known)})")


def _sensor_name(value, path, where, seen: dict, error) -> str:
    name = fields.string(value, path, where, error)
    if not NAME_PATTERN.fullmatch(name):
        raise error(path, where, f"{fields.short(name)} is not a sensor name (1-64 letters, digits or _)")
    if name in seen:
        raise error(path, where, f"{name!r} is also the name of {seen[name]}: two sensors with one name",
                    "give every camera and the LiDAR its own name")
    seen[name] = where.rsplit(".", 1)[0]
    return name


def pose(translation, rotation_wxyz) -> np.ndarray:
    """(4, 4) rigid from a translation (3,) and a quaternion (w, x, y, z) (nuScenes' record order)."""
    T = np.eye(4)
    T[:3, :3] = cameras.quaternion_to_rotation(np.asarray(rotation_wxyz, np.float64))
    T[:3, 3] = np.asarray(translation, np.float64)
    return T


#: A rig camera's principal point lies within this share of the image size from its centre (real cameras are within
#: a few %): stricter than ``cameras.intrinsics_problem`` so a K for another resolution (nuScenes' 1600 x 900 K at
#: 800 x 450 puts the principal point at the image's corner) is refused rather than rendering an almost black camera.
PRINCIPAL_POINT_CENTRE_SHARE = 0.25


def _principal_point_off_centre(K: np.ndarray, size: tuple[int, int]) -> str | None:
    """Why ``K``'s principal point is too far from the centre of a ``size`` (W, H) px image for a rig camera, or
    None: |cx - W/2| <= ``PRINCIPAL_POINT_CENTRE_SHARE`` W and the same for cy with H."""
    W, H = float(size[0]), float(size[1])
    cx, cy = float(K[0, 2]), float(K[1, 2])
    s = PRINCIPAL_POINT_CENTRE_SHARE
    if abs(cx - W / 2) <= s * W and abs(cy - H / 2) <= s * H:
        return None
    return (f"the principal point (cx, cy) = ({cx:g}, {cy:g}) px is outside the middle half of the image "
            f"(cx within {W / 2 - s * W:g}..{W / 2 + s * W:g}, cy within {H / 2 - s * H:g}..{H / 2 + s * H:g})")


def nuscenes_K(fx: float, cx: float, cy: float) -> np.ndarray:
    """Our K (pixel centres at +0.5) of a nuScenes ``camera_intrinsic`` (pixel centres at integers)."""
    return np.array([[fx, 0.0, cx + 0.5], [0.0, fx, cy + 0.5], [0.0, 0.0, 1.0]])


def _nuscenes(channels, lidar: bool) -> Rig:
    cams = [RigCamera(ch, NUSCENES_RESOLUTION, nuscenes_K(*_NUSCENES_CALIBRATION[ch][2]),
                      pose(*_NUSCENES_CALIBRATION[ch][:2])) for ch in channels]
    lid = RigLidar(NUSCENES_LIDAR, NUSCENES_LIDAR_MODEL, pose(*_NUSCENES_LIDAR_MOUNT)) if lidar else None
    return Rig("nuscenes" if len(channels) > 1 else "front", cams, lid)


#: Rig presets: name -> (description, maker(lidar: bool) -> Rig).
PRESETS = {
    "front": ("nuScenes' front camera alone (1600 x 900, 70°)", partial(_nuscenes, ("CAM_FRONT",))),
    "nuscenes": ("nuScenes' six cameras (1600 x 900; CAM_BACK 110°) and its 32-beam top LiDAR",
                 partial(_nuscenes, NUSCENES_CAMERAS)),
}


def preset(name: str, *, lidar: bool | None = None, scale: float = 1.0, field: str = "--rig") -> Rig:
    """Preset ``name`` (``PRESETS``) with its LiDAR (``lidar`` None: the preset's own, the top LiDAR for
    ``nuscenes`` and none for ``front``; True/False: with or without it), cameras scaled by ``scale``. An unknown
    name is an ``ArgumentError`` on ``field`` listing the presets."""
    if name not in PRESETS:
        raise ArgumentError(field, f"no rig preset {name!r}: expected one of {list(PRESETS)} or a rig file "
                            f"(.json){did_you_mean(name, PRESETS)}",
                            hint=f"give a preset ({', '.join(PRESETS)}) or the path of a rig file ending in .json "
                                 f"(schema {RIG_SCHEMA})")
    with_lidar = (name == "nuscenes") if lidar is None else bool(lidar)
    rig = PRESETS[name][1](with_lidar)
    return rig if scale == 1.0 else rig.scaled(scale)


def load(path: str | os.PathLike) -> Rig:
    """A rig file (``{"schema": "scpainter.rig/1", "name", "cameras", "lidar"}``, what ``save`` writes)."""
    from . import files  # bounded JSON, regular files only

    path = os.fspath(path)
    d = files.read_json(path)
    if not isinstance(d, dict) or d.get("schema") != RIG_SCHEMA:
        raise InputError(path, "schema", f"expected {RIG_SCHEMA!r}, got "
                                         f"{fields.short(d.get('schema') if isinstance(d, dict) else d)}")
    return Rig.from_dict({k: v for k, v in d.items() if k != "schema"}, path, "")


def save(path: str | os.PathLike, rig: Rig) -> None:
    """Write ``rig`` as a rig file (atomically)."""
    from . import outputs

    outputs.write_json(path, {"schema": RIG_SCHEMA, **rig.to_dict()})


def camera_to_world(ego_to_world: np.ndarray, camera_to_ego: np.ndarray) -> np.ndarray:
    """(…, 4, 4) camera_to_world = ego_to_world · camera_to_ego (float64)."""
    return np.asarray(ego_to_world, np.float64) @ np.asarray(camera_to_ego, np.float64)


def world_to_camera(ego_to_world: np.ndarray, camera_to_ego: np.ndarray) -> np.ndarray:
    """(…, 4, 4) OpenCV world_to_camera of a rig camera at ego pose(s) ``ego_to_world`` (closed-form inverse)."""
    return cameras.rigid_inverse(camera_to_world(ego_to_world, camera_to_ego))


def ego_path(camera_to_world_: np.ndarray, rig: Rig, follow: str) -> np.ndarray:
    """(N, 4, 4) ego_to_world of a camera path (``camera_to_world_`` (N, 4, 4), OpenCV axes) taken as the pose of
    rig camera ``follow``: ego_to_world = camera_to_world · camera_to_ego⁻¹."""
    T = cameras.rigid_inverse(np.asarray(rig.camera(follow).camera_to_ego, np.float64))
    return np.asarray(camera_to_world_, np.float64) @ T
