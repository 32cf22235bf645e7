"""The ground-truth street: parameters, cache, and the files it is made of (no bpy here).

A procedural street (``build.py``, ``materials.py``) rendered by Cycles on the CPU (``render.py``) gives every
test and the demo data with exact answers: a recorded forward drive written in VGGT's predictions layout
(``predictions.py``: scale-normalised, first camera as origin, depth with a confidence map), the metric scale and
poses beside it, and ground-truth renders of the same drive shifted left/right. Everything is seeded and
deterministic, and cached under a key of the parameters and ``GENERATOR_VERSION``, so a second call returns at
once.

Layout of a street folder::

    predictions.npz        VGGT demo layout (images, depth, depth_conf, extrinsic, intrinsic, world_points, ...)
    metric.npz             world_to_camera (S,4,4) metric Blender world, K (S,3,3) ours, vggt_to_world (4,4),
                           metres_per_unit, depth (S,H,W) metres (inf = sky), instance (S,H,W) uint8 (0 = none),
                           world_to_camera_<view> for every shifted view
    street.json            parameters, views, parked cars (box_to_world, size, instance id), timings
    street.blend           the procedural scene itself
    <view>/frame_NNNNNN.png  renders: "recorded" and each shifted view ("left_2m", "right_3m", ...)

``write_objects`` writes the parked cars as a recording's tracked boxes (``core.recording.plain``,
``scpainter.objects/1`` in the street's world with the recorded cameras' poses): the ground truth the demo imports
as recorded objects. It is written where asked, never into the street folder (the cache key is the parameters').
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..core import outputs
from ..core.recording import plain

GENERATOR_VERSION = 2  # 2: a_to_b names (vggt_to_world) in the files it writes
HERE = os.path.dirname(os.path.abspath(__file__))
REPO_ROOT = os.path.dirname(os.path.dirname(HERE))


@dataclass(frozen=True)
class StreetParams:
    """What the street and the drive look like. Lengths in metres; the road runs along +Y, Z up."""

    seed: int = 0
    num_frames: int = 16
    width: int = 518                 # VGGT's working width
    height: int = 294                # a multiple of 14, as VGGT resizes
    focal_px: float = 300.0          # fx = fy, principal point at the image centre
    frame_spacing_m: float = 1.0     # distance driven between frames
    camera_height_m: float = 1.6
    lane_x_m: float = 0.0            # the ego lane's centre
    curve_m: float = 0.6             # lateral drift of the path after 20 m (a gentle bend)
    pitch_deg: float = -2.0          # camera pitch (negative: looking slightly down)
    shifts_m: tuple = (2.0, -2.0, 3.0, -3.0)   # ground-truth views: + left, - right
    samples: int = 8                 # Cycles samples per pixel for the colour renders (no denoiser)
    num_parked_cars: int = 5


def view_name(shift_m: float) -> str:
    return f"{'left' if shift_m > 0 else 'right'}_{abs(shift_m):g}m"


def cache_root() -> str:
    return os.environ.get("SCPAINTER_CACHE_DIR") or os.path.join(REPO_ROOT, ".cache")


def cache_key(params: StreetParams) -> str:
    """Hash of the parameters and ``GENERATOR_VERSION``.

    The generator's source is deliberately not hashed: moving code between modules (or renaming a helper) must not
    re-render the street for minutes. Bump ``GENERATOR_VERSION`` whenever a change alters what the street writes
    (files, keys, pixels). A clean checkout (CI) has no cache and always builds from the current code."""
    h = hashlib.sha256(json.dumps(dataclasses.asdict(params), sort_keys=True).encode())
    h.update(str(GENERATOR_VERSION).encode())
    return h.hexdigest()[:16]


@dataclass
class Street:
    """A generated street folder, with its files loaded on demand."""

    root: str
    params: StreetParams
    info: dict = field(default_factory=dict)

    @property
    def predictions_path(self) -> str:
        return os.path.join(self.root, "predictions.npz")

    @property
    def blend_path(self) -> str:
        return os.path.join(self.root, "street.blend")

    def metric(self) -> dict:
        with np.load(os.path.join(self.root, "metric.npz"), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def frame_path(self, view: str, i: int) -> str:
        return os.path.join(self.root, view, f"frame_{i:06d}.png")

    def write_objects(self, path: str) -> str:
        """The parked cars (``street.json`` ``cars``: box_to_world and size [w, l, h] in the street's world) as a
        ``scpainter.objects/1`` file at ``path`` (written atomically), in every recorded frame, with the recorded
        cameras' world_to_camera (``metric.npz``); track ids ``street_car_<instance>``. Returns ``path``."""
        w2c = self.metric()["world_to_camera"]
        n = len(w2c)
        cars = [{"id": f"street_car_{c['instance']}", "class": "car", "size": c["size"],
                 "boxes": {f: np.asarray(c["box_to_world"], np.float64) for f in range(n)}}
                for c in self.info["cars"]]
        outputs.write_json(path, plain.document(n, cars, w2c))
        return path

    @property
    def views(self) -> list:
        return ["recorded"] + [view_name(s) for s in self.params.shifts_m]


def load_street(root: str) -> Street:
    with open(os.path.join(root, "street.json")) as f:
        info = json.load(f)
    p = dict(info["params"])
    p["shifts_m"] = tuple(p["shifts_m"])
    return Street(root, StreetParams(**p), info)


def street_folder(params: StreetParams | None = None, cache_dir: str | None = None) -> str:
    """Where the street for ``params`` lies in the cache (whether or not it has been generated)."""
    return os.path.join(cache_dir or cache_root(), f"street-{cache_key(params or StreetParams())}")


def cached_street(params: StreetParams | None = None, cache_dir: str | None = None) -> Street | None:
    """The street for ``params`` if the cache holds it complete, else None (nothing is generated: no bpy needed)."""
    root = street_folder(params, cache_dir)
    return load_street(root) if os.path.isfile(os.path.join(root, "street.json")) else None


def ensure_street(params: StreetParams | None = None, cache_dir: str | None = None, log=None,
                  timeout: float = 1800) -> Street:
    """The street for ``params``, from the cache or generated now (in a subprocess that owns its own bpy).

    Generation writes into a temporary folder that is renamed into place when complete, so an interrupted run
    never leaves a half-written street behind.
    """
    params = params or StreetParams()
    cached = cached_street(params, cache_dir)
    if cached is not None:
        return cached
    root = street_folder(params, cache_dir)
    os.makedirs(os.path.dirname(root), exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = REPO_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    t0 = time.perf_counter()
    # another process finishing first: theirs is kept
    with outputs.atomic_folder(root, keep_existing=True) as tmp:
        cmd = [sys.executable, "-m", "scpainter_blender.street", "--out", tmp,
               "--params", json.dumps(dataclasses.asdict(params))]
        proc = subprocess.run(cmd, env=env, cwd=REPO_ROOT, capture_output=True, text=True, timeout=timeout)
        if proc.returncode != 0:
            raise RuntimeError(f"street generation failed (exit {proc.returncode}):\n{proc.stderr[-4000:]}")
        if log:
            log(proc.stderr.strip())
    street = load_street(root)
    street.info["generated_in_s"] = time.perf_counter() - t0
    return street
