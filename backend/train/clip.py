"""Training clips: one folder per recorded clip, described by ``clip.json`` (schema ``scpainter.clip/1``).

Layout (paths in ``clip.json`` are relative to it; docs/training.md has the full description)::

    clip.json         {"schema": "scpainter.clip/1",
                       "predictions": "predictions.npz",           VGGT demo layout, S frames (required)
                       "frames": "frames/frame_{:06d}.png",        the real frames: a pattern, a list of S paths,
                                                                   or a video file ("drive.mp4": no {} field)
                       "distortion": [k1, k2, p1, p2, k3],         optional lens distortion (needs poses)
                       "distortion_model": "opencv",               its model: "opencv" | "fisheye" (k1..k4)
                       "poses": "poses.npz",                       optional metric poses (below)
                       "cars": [{"id": "car 3", "size": [w, l, h],  optional tracked cars: box size in metres,
                                 "boxes": {"0": 4x4, ...},          per-frame box_to_world (frames the car is in),
                                 "asset": "assets/car_3.ply",       optional Gaussian asset (Amodal3R/TRELLIS PLY)
                                 "asset_to_box": 4x4}],             optional; default: fitted (see Car)
                       "views": {"2": "views/left_2m/frame_{:06d}.png"},   optional ground truth of the drive
                       "fps": 10}                                           shifted left by 2 m (evaluation only)
    predictions.npz   images (S,3,h,w), depth, depth_conf, extrinsic, intrinsic (VGGT's demo output)
    poses.npz         world_to_camera (S,4,4) OpenCV, metric world; K (S,3,3) ours, for the frame images' size
                      (with ``distortion``: the calibrated K of the recorded, distorted frames);
                      vggt_to_world (4,4) similarity taking VGGT's world to the metric one
    frames/           the real frames (any size; the targets of training, resized to the training resolution)

World: the metric world of ``poses.npz`` when given; otherwise VGGT's own world (first camera = origin, scale
normalised), with VGGT's cameras, and box sizes/asset alignment then in VGGT units. Boxes follow the job's
convention: ``box_to_world`` maps the box frame (centre at the origin, axes along the box's width x, length y,
height z, Z up) to the world; ``size`` is the box's full extent along those axes.

Camera frames (``Clip.load_frames``): with ``distortion`` (OpenCV's coefficients, 4 to 14, or with
``distortion_model`` "fisheye" Kannala–Brandt k1..k4; four numbers need the model stated), every frame and
ground-truth view is undistorted at its own size to ``Clip.K`` — the pinhole K that ``undistorted_K`` chooses
(alpha 0: no black borders; the frame's pixel aspect kept) — and then resized with Lanczos; ``Clip.K_recorded``
keeps the calibrated K. ``K``, ``K_for``, training pairs and evaluation jobs all project with the undistorted K.
Without distortion the frames are only resized, as always. A video's frames are taken as players show them (its
display rotation applied), and frames whose aspect differs from the predictions' beyond a resize's rounding are
refused (``camera_frames.aspect_problem``).

No torch here: numpy, Pillow, OpenCV and PyAV (``camera_frames``). Every error names the file and the field.
(Just over 400 lines: ``load`` checks every field of clip.json in one pass, in the file's order, so its errors read
top to bottom; the camera and video code lives in ``camera_frames``.)
"""

from __future__ import annotations

import math
import os
import re
import string
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core.geometry import cameras
from scpainter_blender.core import errors, files, outputs
from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io
from scpainter_blender.core import fields as fields_mod
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.job import JobError

from . import camera_frames

if TYPE_CHECKING:
    from collections.abc import Sequence

SCHEMA = "scpainter.clip/1"


class ClipError(JobError, errors.InputError):
    """A clip folder that cannot be used; ``str()`` is "<file name>: <field>: <message>". A JobError (a clip's
    fields are checked by the job's validators, ``core.fields``) and an InputError (bad input: exit code 2,
    ``field`` in the error event)."""

    def __init__(self, path: str | os.PathLike, field: str, message: str, hint: str | None = None) -> None:
        errors.InputError.__init__(self, path, field, message, hint)


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
    frame_paths: list | None       # the S frame image files; None when the frames are a video
    image_size: tuple              # (W, H) of the real frames
    world_to_camera: np.ndarray    # (S, 4, 4) OpenCV, clip world
    K: np.ndarray                  # (S, 3, 3) ours, for image_size; of the undistorted frames when distortion is set
    vggt_to_world: np.ndarray    # (4, 4)
    cars: list = field(default_factory=list)
    fps: float = 10.0
    metric: bool = False
    views: dict = field(default_factory=dict)   # lateral shift (m, + left) -> S ground-truth frame paths
    video: str | None = None       # the video file holding the S frames (frame_paths is None then)
    distortion: np.ndarray | None = None   # lens coefficients of the recorded frames and views; None: pinhole
    distortion_model: str = camera_frames.OPENCV   # the model of ``distortion``: "opencv" | "fisheye"
    K_recorded: np.ndarray | None = None   # (S, 3, 3) ours, for image_size: the recorded frames' calibrated K
    _undistort: camera_frames.Undistorter = field(default_factory=camera_frames.Undistorter, repr=False,
                                                  compare=False)

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

    def load_frames(self, width: int, height: int, indices: Sequence[int] | None = None,
                    view: float | None = None) -> np.ndarray:
        """(N, height, width, 3) uint8 RGB: the recorded frames ``indices`` (default all S, in the order given), or
        those of the ground-truth view ``view`` (a lateral shift, a key of ``views``), as the model sees them —
        with ``distortion``: undistorted at their own size to ``K``, then resized with Lanczos; without:
        only resized with Lanczos (bit-identical to ``pairs.load_resized``). Their intrinsics are
        ``K_for(width, height)``. A video is decoded once, up to the last frame asked for, and only the
        resized frames are kept. ClipError naming clip.json and ``frames[t]`` / ``views.<shift>[t]`` for a
        frame file that cannot be read."""
        S = self.num_frames
        indices = list(range(S)) if indices is None else [int(t) for t in indices]
        if any(not 0 <= t < S for t in indices):
            raise IndexError(f"frame indices {indices} outside the clip's 0..{S - 1}")
        out = np.empty((len(indices), height, width, 3), np.uint8)
        if view is None and self.video is not None:
            at: dict = {}
            for i, t in enumerate(indices):
                at.setdefault(t, []).append(i)
            for t, rgb in camera_frames.decode_video(self.video, max(indices, default=-1) + 1,
                                                     lambda m: ClipError(self.path, "frames", m)):
                if t in at:
                    if (rgb.shape[1], rgb.shape[0]) != tuple(self.image_size):
                        raise ClipError(self.path, "frames", f"frame {t} of the video {self.video} is "
                                                             f"{rgb.shape[1]}x{rgb.shape[0]}, not {self.image_size}")
                    out[at[t]] = self._camera_frame(rgb, t, width, height)
            return out
        paths, where = (self.frame_paths, "frames") if view is None else (self.views[view], f"views.{view:g}")
        for i, t in enumerate(indices):
            image = camera_frames.read_image(paths[t], lambda m: ClipError(self.path, f"{where}[{t}]", m))
            out[i] = self._camera_frame(image, t, width, height)
        return out

    def load_frame(self, t: int, width: int, height: int, view: float | None = None) -> np.ndarray:
        """(height, width, 3) uint8 RGB: frame t, as ``load_frames`` gives it (for a video, ``load_frames`` of
        all the frames needed at once decodes it once)."""
        return self.load_frames(width, height, [t], view)[0]

    def _camera_frame(self, image, t: int, width: int, height: int) -> np.ndarray:
        """A recorded image of frame t (PIL RGB or (h, w, 3) uint8, any size) -> (height, width, 3) uint8."""
        if self.distortion is None:
            return camera_frames.resized(image, width, height)
        rgb = np.asarray(image)
        size = (rgb.shape[1], rgb.shape[0])  # a view may have another size than the frames: K scales with it
        K = camera_frames.scale_K(self.K_recorded[t], self.image_size, size)
        K_new = camera_frames.scale_K(self.K[t], self.image_size, size)
        undistorted = self._undistort(rgb, K, self.distortion, K_new, out_size=(width, height),
                                      model=self.distortion_model)
        return camera_frames.resized(undistorted, width, height)


def _image_size(path: str, where: str, clip_path: str) -> tuple:
    from PIL import Image

    def error(p, f, message):
        if message == "not found":
            return ClipError(clip_path, where, f"frame file not found: {path}")
        return ClipError(clip_path, where, f"{path} {message}")

    with files.open_regular(path, error) as fh:  # PIL opens by name too: a FIFO would block it
        try:
            with Image.open(fh) as im:
                return camera_frames.displayed_size(im)
        except Exception as e:  # noqa: BLE001  PIL raises OSError, SyntaxError, DecompressionBombError, ...
            raise ClipError(clip_path, where, f"cannot read the image {path} ({type(e).__name__}: "
                                              f"{str(e)[:200]})") from None


#: A frame pattern's only replacement field: the frame index, optionally zero-padded (``{:06d}``, ``{}``, ``{0}``).
_INDEX_FIELD = re.compile(r"(0?[1-9]\d?)?d?")


def _has_field(text: str) -> bool:
    """Whether ``text`` holds a replacement field ({...}): a frame pattern does, a video file's path does not."""
    try:
        return any(name is not None for _, name, _, _ in string.Formatter().parse(text))
    except ValueError:
        return True  # a broken pattern: _pattern says why


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
    try:  # "{}{}" asks for two indices, "{}{0}" mixes automatic and manual numbering: str.format refuses both
        return [job_mod.resolve(clip_path, pattern.format(i)) for i in range(S)]
    except (IndexError, ValueError) as e:
        raise ClipError(clip_path, where, f"expected a pattern like 'frames/frame_{{:06d}}.png' with one frame index "
                                          f"field, got {pattern!r} ({e})") from None


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


def _read_poses(poses_path: str, clip_path: str, S: int, size):
    """world_to_camera (S, 4, 4) rigid, K (S, 3, 3) our intrinsics within a job's bounds for frames of ``size``
    (W, H) (``core.job.intrinsics_problem``), vggt_to_world (4, 4) a similarity, from ``poses.npz``; ClipError
    naming the file and key (``K[t]`` for one frame's K) for anything else."""
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
    for t in range(S):  # a job's bounds (and the frames' size): every job made from the clip passes them
        problem = job_mod.intrinsics_problem(K[t], size)
        if problem is not None:
            raise ClipError(poses_path, f"K[{t}]", problem, f"give each frame's calibrated intrinsics for the frame "
                                                            f"images' {size[0]} x {size[1]} px")
    M = _float_array(arrays["vggt_to_world"], poses_path, "vggt_to_world", (4, 4))
    s = np.cbrt(np.linalg.det(M[:3, :3]))
    if not s > 0 or np.abs(M[:3, :3].T @ M[:3, :3] / (s * s) - np.eye(3)).max() > 1e-3 or \
            np.any(M[3] != [0, 0, 0, 1]):
        raise ClipError(poses_path, "vggt_to_world", "expected a similarity (scale > 0 x rotation, translation, "
                                                       "last row [0, 0, 0, 1])")
    return w2c, K, M


#: A poses.npz K whose focal lengths differ from VGGT's estimate (scaled to the frames' size) by more than this
#: factor, or whose principal point lies further than ``POSES_K_CENTRE_AGREEMENT`` of the image size from VGGT's,
#: is refused: it was made for another image size (a K for VGGT's 518 px frames beside 1920 px frames gives fx 0.27
#: times VGGT's and a principal point in the top-left quarter; one for half-size frames 0.5 and a quarter image
#: off), and nothing else would notice. VGGT's focal estimate is within ~20 % on real clips and a calibrated
#: principal point within a few % of the image centre, which VGGT assumes: the bounds leave room for both.
POSES_K_FOCAL_AGREEMENT = 1.5
POSES_K_CENTRE_AGREEMENT = 0.2


def _check_poses_K(K: np.ndarray, K_vggt: np.ndarray, size, poses_path: str, focal: bool = True) -> None:
    """Refuse poses.npz's K (S, 3, 3), ours for frames of ``size`` (W, H), when a frame's disagrees with VGGT's
    estimate ``K_vggt`` (S, 3, 3) scaled to that size beyond the bounds above, naming ``K[t]`` and both. ``focal``
    False (a clip with ``distortion``) compares the principal points only: VGGT fits a pinhole to the distorted
    frames, whose focal length differs from the lens' calibrated one (a fisheye's by up to ~2x), while the
    principal point stays where it is."""
    W, H = size
    ratio = np.stack([K[:, 0, 0] / K_vggt[:, 0, 0], K[:, 1, 1] / K_vggt[:, 1, 1]], axis=1)
    off = np.stack([np.abs(K[:, 0, 2] - K_vggt[:, 0, 2]) / W, np.abs(K[:, 1, 2] - K_vggt[:, 1, 2]) / H], axis=1)
    bad = (off > POSES_K_CENTRE_AGREEMENT).any(1)
    if focal:
        bad |= ~((ratio <= POSES_K_FOCAL_AGREEMENT) & (ratio >= 1 / POSES_K_FOCAL_AGREEMENT)).all(1)
    if not bad.any():
        return
    t = int(np.argmax(bad))
    r = float(np.sqrt(ratio[t, 0] * ratio[t, 1]))
    raise ClipError(poses_path, f"K[{t}]", f"fx {K[t, 0, 0]:.4g}, fy {K[t, 1, 1]:.4g}, principal point "
                                           f"({K[t, 0, 2]:.4g}, {K[t, 1, 2]:.4g}) for frames of {W} x {H} px, where "
                                           f"VGGT's estimate at that size is fx {K_vggt[t, 0, 0]:.4g}, fy "
                                           f"{K_vggt[t, 1, 1]:.4g}, principal point ({K_vggt[t, 0, 2]:.4g}, "
                                           f"{K_vggt[t, 1, 2]:.4g}): {r:.2g} times its focal length. It looks like a "
                                           f"K for images of about {W * r:.0f} x {H * r:.0f} px",
                    f"give each frame's K for the frame images' {W} x {H} px (scale a K calibrated at another size "
                    f"by the size ratio, pixel centres at +0.5)")


def json_path(path: str) -> str:
    """The clip.json of a clip folder (or the path itself when it names the file)."""
    path = os.fspath(path)
    return os.path.join(path, "clip.json") if os.path.isdir(path) or not path.endswith(".json") else path


def load(path: str) -> Clip:
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
    video = None
    if isinstance(frames, str) and not _has_field(frames):  # a video file
        video = job_mod.resolve(path, fields_mod.string(frames, path, "frames", error=ClipError))
        count, size = camera_frames.probe_video(video, lambda m: ClipError(path, "frames", m))
        if count != S:
            raise ClipError(path, "frames", f"the video {video} has {count} frames, the predictions {S}: one frame "
                                            f"per VGGT frame", "cut the video to the frames VGGT was run on")
        frame_paths = None
    elif isinstance(frames, str):
        frame_paths = _pattern(frames, path, "frames", S)
    elif isinstance(frames, list) and len(frames) == S:
        frame_paths = [job_mod.resolve(path, fields_mod.string(p, path, f"frames[{i}]", error=ClipError))
                       for i, p in enumerate(frames)]
    else:
        raise ClipError(path, "frames", f"expected a path pattern, a list of {S} paths (one per VGGT frame) or a "
                                        f"video file")
    for i, frame in enumerate(frame_paths or ()):  # cheap stats: training opens every frame; a FIFO would block it
        _check_file(frame, path, f"frames[{i}]", "frame file")
    if frame_paths is not None:
        size = _image_size(frame_paths[0], "frames[0]", path)
        for i in (S // 2, S - 1):  # the ends and the middle: a wrong count or size fails here, not mid-training
            if _image_size(frame_paths[i], f"frames[{i}]", path) != size:
                raise ClipError(path, f"frames[{i}]", f"size differs from frames[0] {size}")
    problem = camera_frames.aspect_problem(size, (pred.width, pred.height))
    if problem is not None:  # without poses K would be stretched; with them, the points would not be the frames'
        raise ClipError(path, "frames", f"{problem} ({video or frame_paths[0]} against {pred_path})",
                        "give the frames VGGT was run on, as shown (upright), resized without cropping or padding")

    metric = "poses" in data
    K_vggt = np.diag([size[0] / pred.width, size[1] / pred.height, 1.0]) @ pred.K  # VGGT's estimate, frames' size
    if metric:
        poses_path = job_mod.resolve(path, fields_mod.string(data["poses"], path, "poses", error=ClipError))
        w2c, K, vggt_to_world = _read_poses(poses_path, path, S, size)
    else:
        w2c = cameras.orthonormalize(pred.world_to_camera)
        K = K_vggt
        vggt_to_world = np.eye(4)
    model = camera_frames.distortion_model(data.get("distortion_model"), path, "distortion_model", error=ClipError)
    if model is not None and data.get("distortion") is None:
        raise ClipError(path, "distortion_model", f"{model!r} is stated without distortion coefficients, so it has "
                                                  "no effect", "add the calibration's distortion (for a fisheye "
                                                  "k1..k4; [0, 0, 0, 0] is the equidistant lens), or remove "
                                                  "distortion_model")
    distortion = camera_frames.distortion_coefficients(data.get("distortion"), path, "distortion", error=ClipError,
                                                       model=model)
    model = model or camera_frames.OPENCV
    if metric:
        _check_poses_K(K, K_vggt, size, poses_path, focal=distortion is None)
    K_recorded = K
    if distortion is not None:
        if not metric:
            raise ClipError(path, "distortion", "needs poses: the coefficients go with the calibrated K of the "
                                                "recorded frames (poses.npz), not with VGGT's pinhole estimate")
        if np.any(K[:, 0, 1] != 0):
            raise ClipError(poses_path, "K", "has skew (K[0, 1] != 0): undistortion needs K without skew")
        K = camera_frames.undistorted_Ks(K_recorded, distortion, size, lambda m: ClipError(
            path, "distortion", m, f"give the frames' calibration: {camera_frames.DISTORTION_ORDER[model]} "
                                   f"coefficients that go with the K of poses.npz"), model)

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
    return Clip(path, pred, frame_paths, size, w2c, K, vggt_to_world, cars, fps, metric, views, video, distortion,
                model, K_recorded)


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def _check_file(file_path: str, clip_path: str, where: str, what: str = "file") -> None:
    """A file the clip names must be a regular file: ClipError naming the clip's field otherwise."""
    files.check_regular(file_path, lambda p, f, m: ClipError(
        clip_path, where, f"{what} not found: {file_path}" if m == "not found" else f"{file_path} {m}"))


def fit_asset_to_box(means: np.ndarray, box_size: np.ndarray) -> np.ndarray:
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
        from scpainter_blender.core.splats import reader as splats_io

        means = splats_io.load(car.asset).means
    return fit_asset_to_box(means, car.size)


def grown_box(box_to_world: np.ndarray, size: np.ndarray, grow_m: float, grow_ratio: float) -> tuple[np.ndarray,
              np.ndarray]:
    """The removal box of a car: its size scaled by (1 + grow_ratio) plus grow_m on every side (metres or clip
    units), same pose."""
    return np.asarray(box_to_world, np.float64), np.asarray(size, np.float64) * (1 + grow_ratio) + 2 * grow_m


def save(path: str | os.PathLike, data: dict) -> None:
    """Write a clip.json atomically (after checking it parses with ``load`` from the same folder is the caller's
    business: the files it names may not exist yet)."""
    path = os.fspath(path)
    if data.get("schema") != SCHEMA:
        raise ValueError(f"{path}: schema must be {SCHEMA!r}")
    outputs.write_json(path, data)  # atomic; NaN refused, as load would refuse it
