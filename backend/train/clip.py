"""Training clips: one folder per recorded clip, described by ``clip.json`` (schema ``scpainter.clip/1``).

Layout (paths in ``clip.json`` are relative to it; docs/training.md has the full description)::

    clip.json         {"schema": "scpainter.clip/1",
                       "predictions": "predictions.npz",           VGGT demo layout, S frames (required)
                       "frames": "frames/frame_{:06d}.png",        the real frames, a pattern or a list of S paths
                       "poses": "poses.npz",                       optional metric poses (below)
                       "cars": [{"id": "car 3", "size": [w, l, h],  optional tracked cars: box size in metres,
                                 "boxes": {"0": 4x4, ...},          per-frame box_to_world (frames the car is in),
                                 "asset": "assets/car_3.ply",       optional Gaussian asset (Amodal3R/TRELLIS PLY)
                                 "asset_to_box": 4x4}],             optional; default: fitted (see Car)
                       "views": {"2": "views/left_2m/frame_{:06d}.png"},   optional ground truth of the drive
                       "fps": 10}                                           shifted left by 2 m (evaluation only)
    predictions.npz   images (S,3,h,w), depth, depth_conf, extrinsic, intrinsic (VGGT's demo output)
    poses.npz         world_to_camera (S,4,4) OpenCV, metric world; K (S,3,3) ours, for the frame images' size;
                      vggt_to_world (4,4) similarity taking VGGT's world to the metric one
    frames/           the real frames (any size; the targets of training, resized to the training resolution)

World: the metric world of ``poses.npz`` when given; otherwise VGGT's own world (first camera = origin, scale
normalised), with VGGT's cameras, and box sizes/asset alignment then in VGGT units. Boxes follow the job's
convention: ``box_to_world`` maps the box frame (centre at the origin, axes along the box's width x, length y,
height z, Z up) to the world; ``size`` is the box's full extent along those axes.

No torch here: numpy, Pillow for the frames. Every error names the file and the field.
"""

from __future__ import annotations

import math
import os
import re
import string
from dataclasses import dataclass, field

import numpy as np

from scpainter_blender.core import cameras, files, outputs, vggt, vggt_io
from scpainter_blender.core import fields as fields_mod
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.job import JobError

SCHEMA = "scpainter.clip/1"


class ClipError(JobError, files.InputError):
    """A clip folder that cannot be used; ``str()`` is "<file name>: <field>: <message>". A JobError (a clip's
    fields are checked by the job's validators, ``core.fields``) and an InputError (bad input: exit code 2,
    ``field`` in the error event)."""

    def __init__(self, path, field, message, hint=None):
        files.InputError.__init__(self, path, field, message, hint)


@dataclass
class Car:
    """A tracked car. ``boxes``: frame -> box_to_world (4x4). ``asset_to_box`` maps the asset's file coordinates
    into the box frame; when the clip gives none, the asset's bounding-box centre goes to the box centre and its
    largest extent is scaled to the box's largest extent (assets in Z-up, front along +Y, as ours are)."""

    id: str
    size: np.ndarray
    boxes: dict
    asset: str | None = None
    asset_to_box: np.ndarray | None = None


@dataclass
class Clip:
    path: str                      # the clip.json
    predictions: vggt.VGGTPredictions
    frame_paths: list
    image_size: tuple              # (W, H) of the real frames
    world_to_camera: np.ndarray    # (S, 4, 4) OpenCV, clip world
    K: np.ndarray                  # (S, 3, 3) ours, for image_size
    vggt_to_world: np.ndarray    # (4, 4)
    cars: list = field(default_factory=list)
    fps: float = 10.0
    metric: bool = False
    views: dict = field(default_factory=dict)   # lateral shift (m, + left) -> S ground-truth frame paths

    @property
    def num_frames(self) -> int:
        return self.predictions.num_frames

    @property
    def folder(self) -> str:
        return os.path.dirname(os.path.abspath(self.path))

    def K_for(self, width: int, height: int) -> np.ndarray:
        """(S, 3, 3) intrinsics for the frames resized to width x height (pixel centres at +0.5, so a resize is a
        plain scale of rows 0 and 1)."""
        sx, sy = width / self.image_size[0], height / self.image_size[1]
        return np.diag([sx, sy, 1.0]) @ self.K


def _image_size(path: str, where: str, clip_path: str) -> tuple:
    from PIL import Image

    def error(p, f, message):
        if message == "not found":
            return ClipError(clip_path, where, f"frame file not found: {path}")
        return ClipError(clip_path, where, f"{path} {message}")

    with files.open_regular(path, error) as fh:  # PIL opens by name too: a FIFO would block it
        try:
            with Image.open(fh) as im:
                return im.size
        except Exception as e:  # noqa: BLE001  PIL raises OSError, SyntaxError, DecompressionBombError, ...
            raise ClipError(clip_path, where, f"cannot read the image {path} ({type(e).__name__}: "
                                              f"{str(e)[:200]})") from None


#: A frame pattern's only replacement field: the frame index, optionally zero-padded (``{:06d}``, ``{}``, ``{0}``).
_INDEX_FIELD = re.compile(r"(0?[1-9]\d?)?d?")


def _pattern(value, clip_path: str, where: str, S: int) -> list:
    """The S paths of a frame pattern such as ``frames/frame_{:06d}.png``. Only the index may be formatted: a
    pattern is a path, and ``str.format`` could otherwise read attributes or pad to a gigabyte."""
    pattern = fields_mod.string(value, clip_path, where, error=ClipError)
    try:
        fields_ = [(name, spec, conv) for _, name, spec, conv in string.Formatter().parse(pattern) if name is not None]
    except ValueError as e:
        raise ClipError(clip_path, where, f"expected a pattern like 'frames/frame_{{:06d}}.png' ({e})") from None
    for name, spec, conv in fields_:
        if name not in ("", "0") or conv is not None or not _INDEX_FIELD.fullmatch(spec or ""):
            raise ClipError(clip_path, where, f"expected a pattern like 'frames/frame_{{:06d}}.png': only the frame "
                                              f"index may be formatted, got {{{name}{'!' + conv if conv else ''}"
                                              f"{':' + spec if spec else ''}}}")
    return [job_mod.resolve(clip_path, pattern.format(i)) for i in range(S)]


def _float_array(a, path: str, key: str, shape) -> np.ndarray:
    """A poses.npz array of ``shape``, finite, as float64; ClipError naming the file and key otherwise."""
    if a.dtype.kind == "b":
        raise ClipError(path, key, f"holds booleans (dtype {a.dtype}), expected numbers")
    if a.shape != shape:
        raise ClipError(path, key, f"expected finite {shape}, got shape {a.shape}")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise ClipError(path, key, f"expected finite {shape}, got shape {a.shape}, non-finite")
    return a


def _read_poses(poses_path: str, clip_path: str, S: int):
    """world_to_camera (S, 4, 4) rigid, K (S, 3, 3) with positive focal lengths, vggt_to_world (4, 4) a
    similarity, from ``poses.npz``; ClipError naming the file and key for anything else."""
    def error(p, key, message):
        if key is None and message == "not found":
            return ClipError(clip_path, "poses", f"file not found: {poses_path}")
        return ClipError(p, key, message)

    arrays = files.read_npz(poses_path, ("world_to_camera", "K"), optional=("vggt_to_world", "world_from_vggt"),
                            error=error)
    if "vggt_to_world" not in arrays:  # the name before issue 15's a_to_b rule
        if "world_from_vggt" not in arrays:
            raise ClipError(poses_path, "vggt_to_world", "missing: the similarity from VGGT's world to metres")
        arrays["vggt_to_world"] = arrays.pop("world_from_vggt")
    w2c = _float_array(arrays["world_to_camera"], poses_path, "world_to_camera", (S, 4, 4))
    problem = cameras.rigid_problem(w2c, name="world_to_camera")
    if problem is not None:  # an inverse of it is taken for every rendered frame
        raise ClipError(poses_path, "world_to_camera", problem[1])
    K = _float_array(arrays["K"], poses_path, "K", (S, 3, 3))
    if np.any(K[:, 0, 0] <= 0) or np.any(K[:, 1, 1] <= 0) or np.any(K[:, 2] != [0, 0, 1]):
        raise ClipError(poses_path, "K", "expected intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    M = _float_array(arrays["vggt_to_world"], poses_path, "vggt_to_world", (4, 4))
    s = np.cbrt(np.linalg.det(M[:3, :3]))
    if not s > 0 or np.abs(M[:3, :3].T @ M[:3, :3] / (s * s) - np.eye(3)).max() > 1e-3 or \
            np.any(M[3] != [0, 0, 0, 1]):
        raise ClipError(poses_path, "vggt_to_world", "expected a similarity (scale > 0 x rotation, translation, "
                                                       "last row [0, 0, 0, 1])")
    return w2c, K, M


def json_path(path) -> str:
    """The clip.json of a clip folder (or the path itself when it names the file)."""
    path = os.fspath(path)
    return os.path.join(path, "clip.json") if os.path.isdir(path) or not path.endswith(".json") else path


def load(path) -> Clip:
    """Read and check a clip folder's ``clip.json`` (or the folder itself) and what it names."""
    path = json_path(path)
    # a regular file only (a FIFO is refused, not waited on), within size, depth and number limits
    data = files.read_json(path, error=ClipError)
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else data
        raise ClipError(path, "schema", f"expected {SCHEMA!r}, got {_short(got)}")
    pred_path = job_mod.resolve(path, fields_mod.string(data.get("predictions"), path, "predictions",
                                                        error=ClipError))
    files.check_regular(pred_path, lambda p, f, m: ClipError(
        path, "predictions", f"file not found: {pred_path}" if m == "not found" else f"{pred_path} {m}"))
    pred = vggt_io.load_predictions(pred_path, world_points=False)  # its errors name the file and key
    S = pred.num_frames

    frames = data.get("frames")
    if isinstance(frames, str):
        frame_paths = _pattern(frames, path, "frames", S)
    elif isinstance(frames, list) and len(frames) == S:
        frame_paths = [job_mod.resolve(path, fields_mod.string(p, path, f"frames[{i}]", error=ClipError))
                       for i, p in enumerate(frames)]
    else:
        raise ClipError(path, "frames", f"expected a path pattern or a list of {S} paths (one per VGGT frame)")
    for i, frame in enumerate(frame_paths):  # cheap stats: training opens every frame, and a FIFO would block it
        _check_file(frame, path, f"frames[{i}]", "frame file")
    size = _image_size(frame_paths[0], "frames[0]", path)
    for i in (S // 2, S - 1):  # the ends and the middle: a wrong count or size fails here, not mid-training
        if _image_size(frame_paths[i], f"frames[{i}]", path) != size:
            raise ClipError(path, f"frames[{i}]", f"size differs from frames[0] {size}")

    metric = "poses" in data
    if metric:
        poses_path = job_mod.resolve(path, fields_mod.string(data["poses"], path, "poses", error=ClipError))
        w2c, K, vggt_to_world = _read_poses(poses_path, path, S)
    else:
        w2c = cameras.orthonormalize(pred.world_to_camera)
        K = np.diag([size[0] / pred.width, size[1] / pred.height, 1.0]) @ pred.K
        vggt_to_world = np.eye(4)

    cars = []
    if not isinstance(data.get("cars", []), list):
        raise ClipError(path, "cars", f"expected a list of cars, got {_short(data.get('cars'))}")
    for i, c in enumerate(data.get("cars", [])):
        where = f"cars[{i}]"
        if not isinstance(c, dict):
            raise ClipError(path, where, "expected an object")
        size_ = c.get("size")
        car_size = None
        if isinstance(size_, list) and len(size_) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in size_):
            car_size = np.array(size_, np.float64)
        if car_size is None or not np.all(np.isfinite(car_size)) or not np.all(car_size > 0):
            raise ClipError(path, f"{where}.size", f"expected [width, length, height] > 0, got {_short(size_)}")
        car_id = c.get("id", i)
        if isinstance(car_id, bool) or not isinstance(car_id, (str, int)):
            raise ClipError(path, f"{where}.id", f"expected a name or a number, got {_short(car_id)}")
        boxes = {}
        if not isinstance(c.get("boxes"), dict) or not c["boxes"]:
            raise ClipError(path, f"{where}.boxes", "expected an object {frame: box_to_world 4x4}, non-empty")
        for k, m in c["boxes"].items():
            try:
                f = int(k)
            except ValueError:
                raise ClipError(path, f"{where}.boxes.{k}", "keys are frame indices") from None
            if not 0 <= f < S:
                raise ClipError(path, f"{where}.boxes.{k}", f"frame outside the clip's 0..{S - 1}")
            boxes[f] = fields_mod.rigid(m, path, f"{where}.boxes.{k}", error=ClipError)
        asset = c.get("asset")
        if asset is not None:
            asset = job_mod.resolve(path, fields_mod.string(asset, path, f"{where}.asset", error=ClipError))
            _check_file(asset, path, f"{where}.asset")
        a2b = c.get("asset_to_box")
        a2b = None if a2b is None else fields_mod.affine(a2b, path, f"{where}.asset_to_box", error=ClipError)
        cars.append(Car(str(car_id), car_size, boxes, asset, a2b))
    fps = fields_mod.number(data.get("fps", 10.0), path, "fps", lo=0.1, error=ClipError)
    views = {}
    if not isinstance(data.get("views", {}), dict):
        raise ClipError(path, "views", "expected an object {shift in metres: frame path pattern}")
    for k, pattern in data.get("views", {}).items():
        try:
            shift = float(k)
        except ValueError:
            shift = math.nan
        if not math.isfinite(shift):
            raise ClipError(path, f"views.{k}", "keys are lateral shifts in metres (+ left)")
        if shift in views:
            raise ClipError(path, f"views.{k}", f"a second entry for the shift {shift:g} m")
        views[shift] = _pattern(pattern, path, f"views.{k}", S)
        for frame in views[shift]:
            _check_file(frame, path, f"views.{k}", "frame file")
    return Clip(path, pred, frame_paths, size, w2c, K, vggt_to_world, cars, fps, metric, views)


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def _check_file(file_path: str, clip_path: str, where: str, what: str = "file") -> None:
    """A file the clip names must be a regular file: ClipError naming the clip's field otherwise."""
    files.check_regular(file_path, lambda p, f, m: ClipError(
        clip_path, where, f"{what} not found: {file_path}" if m == "not found" else f"{file_path} {m}"))


def fit_asset_to_box(means: np.ndarray, box_size) -> np.ndarray:
    """4x4 asset file -> box frame: bounding-box centre to the box centre, largest extent to the box's largest
    (uniform scale, no rotation: the asset is already Z up, front along +Y)."""
    lo, hi = means.min(axis=0).astype(np.float64), means.max(axis=0).astype(np.float64)
    s = float(np.max(box_size)) / max(float(np.max(hi - lo)), 1e-9)
    A = np.eye(4)
    A[:3, :3] *= s
    A[:3, 3] = -s * (lo + hi) / 2
    return A


def asset_to_box(car: Car, means: np.ndarray | None = None) -> np.ndarray:
    """The car's asset_to_box: the clip's when given, else fitted to the asset (fit_asset_to_box) — to ``means``
    when the caller has the asset loaded, else to the asset file read here."""
    if car.asset_to_box is not None:
        return car.asset_to_box
    if means is None:
        from scpainter_blender.core import splats_io

        means = splats_io.load(car.asset).means
    return fit_asset_to_box(means, car.size)


def grown_box(box_to_world, size, grow_m: float, grow_ratio: float):
    """The removal box of a car: its size scaled by (1 + grow_ratio) plus grow_m on every side (metres or clip
    units), same pose."""
    return np.asarray(box_to_world, np.float64), np.asarray(size, np.float64) * (1 + grow_ratio) + 2 * grow_m


def save(path, data: dict) -> None:
    """Write a clip.json atomically (after checking it parses with ``load`` from the same folder is the caller's
    business: the files it names may not exist yet)."""
    path = os.fspath(path)
    if data.get("schema") != SCHEMA:
        raise ValueError(f"{path}: schema must be {SCHEMA!r}")
    outputs.write_json(path, data)  # atomic; NaN refused, as load would refuse it
