"""VGGT predictions: load them as VGGT's demo writes them, unproject, filter, and give them metric scale.

VGGT's conventions (facebookresearch/vggt), which this module converts from:

* World frame = the first camera's OpenCV frame (x right, y down, z forward), scale normalised (not metric).
* ``extrinsic`` (S, 3, 4) world-to-camera; ``intrinsic`` (S, 3, 3) with the principal point at the image centre
  and pixel (u, v) unprojected at *integer* coordinates: x = (u - cx) d / fx. Our pixel convention puts pixel
  centres at u + 0.5 (DESIGN §3), so our K is VGGT's with cx + 0.5, cy + 0.5 and both unproject identically.
* ``depth`` (S, H, W, 1) camera z; ``depth_conf`` (S, H, W) = 1 + exp(x) >= 1; ``images`` (S, 3, H, W) in [0, 1]
  (sRGB-encoded display values); optional ``world_points`` (S, H, W, 3) and ``world_points_conf``.
* The demo squeezes a batch axis of 1 before saving; files with it are accepted too.

Outputs are float64 positions in the requested world (Blender's: Z up, metres, when a ``world_from_vggt``
similarity is given). Files are read with ``allow_pickle=False`` and only the numeric keys named above are
touched (newer demo files also hold ``pose_enc_list = None``, an object array that would need pickle).

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field

import numpy as np

from . import cameras

REQUIRED_KEYS = ("images", "depth", "depth_conf", "extrinsic", "intrinsic")
OPTIONAL_KEYS = ("world_points", "world_points_conf")

#: Blender world axes from VGGT's (first camera's OpenCV) axes: x stays right, camera forward (z) becomes +Y,
#: camera down (y) becomes -Z. A camera with no pitch or roll then stands upright looking along +Y.
BLENDER_FROM_OPENCV_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


class PredictionsError(ValueError):
    """A predictions file that cannot be used; the message names the file and the key."""

    def __init__(self, path, key, message):
        self.path, self.key = str(path), key
        where = f"{os.path.basename(self.path)}" + (f": '{key}'" if key else "")
        super().__init__(f"{where}: {message} ({self.path})")


@dataclass
class VGGTPredictions:
    """Validated VGGT predictions for S frames of H x W pixels (batch axis removed)."""

    path: str
    images: np.ndarray            # (S, H, W, 3) float32, sRGB-encoded, [0, 1]
    depth: np.ndarray             # (S, H, W) float32, camera z in VGGT units
    depth_conf: np.ndarray        # (S, H, W) float32
    world_to_camera: np.ndarray   # (S, 4, 4) float64, VGGT world -> OpenCV camera, as stored (float32 rotations
    #                               are orthonormal to ~1e-7 only: unprojection uses them as VGGT does, camera
    #                               placement goes through cameras.orthonormalize)
    intrinsic_vggt: np.ndarray    # (S, 3, 3) float64, VGGT's pixel convention
    world_points: np.ndarray | None = None        # (S, H, W, 3) float32, VGGT world
    world_points_conf: np.ndarray | None = None   # (S, H, W) float32

    @property
    def num_frames(self) -> int:
        return self.depth.shape[0]

    @property
    def height(self) -> int:
        return self.depth.shape[1]

    @property
    def width(self) -> int:
        return self.depth.shape[2]

    @property
    def K(self) -> np.ndarray:
        """Intrinsics (S, 3, 3) in our convention (pixel centres at +0.5): VGGT's with cx + 0.5, cy + 0.5."""
        return vggt_K_to_ours(self.intrinsic_vggt)


def vggt_K_to_ours(K) -> np.ndarray:
    K = np.array(K, dtype=np.float64, copy=True)
    K[..., 0, 2] += 0.5
    K[..., 1, 2] += 0.5
    return K


def ours_K_to_vggt(K) -> np.ndarray:
    K = np.array(K, dtype=np.float64, copy=True)
    K[..., 0, 2] -= 0.5
    K[..., 1, 2] -= 0.5
    return K


# --------------------------------------------------------------------------------------------------------------
# Loading and validation
# --------------------------------------------------------------------------------------------------------------

def _fit_shape(arr, path, key, target, what):
    """Reshape ``arr`` to ``target`` by dropping a leading batch axis of 1 and/or a trailing axis of 1."""
    shape = tuple(arr.shape)
    candidates = [shape]
    if len(shape) >= 1 and shape[0] == 1:
        candidates.append(shape[1:])
    for c in list(candidates):
        if len(c) >= 1 and c[-1] == 1:
            candidates.append(c[:-1])
    for c in candidates:
        if c == tuple(target):
            return arr.reshape(target)
    raise PredictionsError(path, key, f"expected shape {what} = {tuple(target)} (a batch axis of 1 allowed), "
                                      f"got {shape}")


def _images_to_hwc(arr, path):
    a = arr
    if a.ndim == 5:
        if a.shape[0] != 1:
            raise PredictionsError(path, "images", f"a batch of {a.shape[0]} clips is not supported; "
                                                   f"save one clip per file (shape {a.shape})")
        a = a[0]
    if a.ndim == 3:  # one frame without the frame axis
        a = a[None]
    if a.ndim != 4:
        raise PredictionsError(path, "images", f"expected (S, 3, H, W) or (S, H, W, 3), got shape {arr.shape}")
    if a.shape[-1] == 3:
        hwc = a
    elif a.shape[1] == 3:
        hwc = np.moveaxis(a, 1, -1)
    else:
        raise PredictionsError(path, "images", f"expected 3 colour channels, got shape {arr.shape}")
    if hwc.dtype == np.uint8:
        return hwc.astype(np.float32) / np.float32(255.0)
    if not np.issubdtype(hwc.dtype, np.floating):
        raise PredictionsError(path, "images", f"expected float in [0, 1] or uint8, got dtype {hwc.dtype}")
    hwc = hwc.astype(np.float32, copy=False)
    lo, hi = float(hwc.min()), float(hwc.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise PredictionsError(path, "images", f"{int((~np.isfinite(hwc)).sum())} values are NaN or inf")
    if lo < -1e-3 or hi > 1.0 + 1e-3:
        raise PredictionsError(path, "images", f"float values must lie in [0, 1], found [{lo:g}, {hi:g}] "
                                               "(uint8 images are accepted as they are)")
    return np.clip(hwc, 0.0, 1.0) if lo < 0.0 or hi > 1.0 else hwc


def _check_finite(a, path, key):
    if np.isfinite(a.min()) and np.isfinite(a.max()):  # NaN propagates through min/max: one cheap pass each
        return
    bad = ~np.isfinite(a)
    if bad.any():
        frames = np.unique(np.nonzero(bad.reshape(bad.shape[0], -1))[0])
        raise PredictionsError(path, key, f"{int(bad.sum())} values are NaN or inf "
                                          f"(first in frame {int(frames[0])}; frames {frames[:8].tolist()})")


def _numeric(npz, path, key):
    try:
        a = npz[key]
    except ValueError as e:  # object arrays need pickle: refuse them
        raise PredictionsError(path, key, f"is not a numeric array ({e})") from None
    except (zipfile.BadZipFile, EOFError, OSError) as e:
        raise PredictionsError(path, key, f"cannot be read; the file is truncated or corrupt ({e})") from None
    if a.dtype.kind not in "fiub":
        raise PredictionsError(path, key, f"is not a numeric array (dtype {a.dtype})")
    return a


def load_predictions(path, world_points: bool = True) -> VGGTPredictions:
    """Load and validate a VGGT ``predictions.npz``; raises PredictionsError naming the file and key.

    ``world_points=False`` skips the optional point-map arrays (half the file) when they will not be used.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise PredictionsError(path, None, "file not found")
    try:
        npz = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        raise PredictionsError(path, None, f"not a readable .npz file (truncated or corrupt?): {e}") from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise PredictionsError(path, None, "expected an .npz archive of named arrays, got a single array")
    with npz:
        missing = [k for k in REQUIRED_KEYS if k not in npz.files]
        if missing:
            raise PredictionsError(path, missing[0], f"missing key(s) {missing}; the file has {sorted(npz.files)}")
        wanted = REQUIRED_KEYS + (OPTIONAL_KEYS if world_points else ())
        arrays = {k: _numeric(npz, path, k) for k in wanted if k in npz.files}
    return predictions_from_arrays(arrays, path)


def predictions_from_arrays(arrays, path="<arrays>") -> VGGTPredictions:
    """Validate a mapping of VGGT arrays (as in the .npz) into VGGTPredictions."""
    images = _images_to_hwc(np.asarray(arrays["images"]), path)
    S, H, W, _ = images.shape
    depth = _fit_shape(np.asarray(arrays["depth"]), path, "depth", (S, H, W), "(S, H, W[, 1])").astype(np.float32)
    _check_finite(depth, path, "depth")
    conf = _fit_shape(np.asarray(arrays["depth_conf"]), path, "depth_conf", (S, H, W), "(S, H, W)")
    conf = conf.astype(np.float32)
    _check_finite(conf, path, "depth_conf")

    ext = np.asarray(arrays["extrinsic"], dtype=np.float64)
    if ext.ndim == 4 and ext.shape[0] == 1:
        ext = ext[0]
    if ext.ndim != 3 or ext.shape[0] != S or ext.shape[1:] not in ((3, 4), (4, 4)):
        raise PredictionsError(path, "extrinsic", f"expected ({S}, 3, 4) or ({S}, 4, 4), got {np.shape(arrays['extrinsic'])}")
    _check_finite(ext, path, "extrinsic")
    ext = cameras.as_matrix4(ext)
    R = ext[:, :3, :3]
    orth = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    if orth.max() > 1e-3 or np.any(np.linalg.det(R) < 0):
        bad = int(np.argmax(orth))
        raise PredictionsError(path, "extrinsic", f"frame {bad} is not a rotation + translation "
                                                  f"(|R^T R - I| = {orth[bad]:.2e})")
    if np.any(ext[:, 3] != [0, 0, 0, 1]):
        raise PredictionsError(path, "extrinsic", "the last row of a 4x4 extrinsic must be [0, 0, 0, 1]")

    intr = np.asarray(arrays["intrinsic"], dtype=np.float64)
    if intr.ndim == 4 and intr.shape[0] == 1:
        intr = intr[0]
    if intr.shape != (S, 3, 3):
        raise PredictionsError(path, "intrinsic", f"expected ({S}, 3, 3), got {np.shape(arrays['intrinsic'])}")
    _check_finite(intr, path, "intrinsic")
    if np.any(intr[:, 0, 0] <= 0) or np.any(intr[:, 1, 1] <= 0):
        raise PredictionsError(path, "intrinsic", "focal lengths must be positive")

    wp = wpc = None
    if "world_points" in arrays:
        wp = _fit_shape(np.asarray(arrays["world_points"]), path, "world_points", (S, H, W, 3), "(S, H, W, 3)")
        wp = wp.astype(np.float32)
        _check_finite(wp, path, "world_points")
    if "world_points_conf" in arrays:
        wpc = _fit_shape(np.asarray(arrays["world_points_conf"]), path, "world_points_conf", (S, H, W),
                         "(S, H, W)").astype(np.float32)
        _check_finite(wpc, path, "world_points_conf")
    return VGGTPredictions(path=str(path), images=images, depth=depth, depth_conf=conf, world_to_camera=ext,
                           intrinsic_vggt=intr, world_points=wp, world_points_conf=wpc)


# --------------------------------------------------------------------------------------------------------------
# Unprojection and confidence filtering
# --------------------------------------------------------------------------------------------------------------

def confidence_threshold(conf, percentile: float) -> float:
    """VGGT demo semantics: the ``percentile``-th percentile of *all* confidences of the clip."""
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f"confidence percentile must be in [0, 100], got {percentile}")
    if percentile == 0.0:
        return -np.inf
    return float(np.percentile(conf, percentile))


def confidence_mask(conf, percentile: float) -> np.ndarray:
    """Keep ``conf >= percentile(conf, p)`` and ``conf > 1e-5``, exactly as VGGT's demo filters."""
    conf = np.asarray(conf)
    return (conf >= confidence_threshold(conf, percentile)) & (conf > 1e-5)


def unproject_pixels(depth, K, world_to_camera, rows, cols) -> np.ndarray:
    """World points (N, 3) float64 of pixels (rows, cols) of one frame; pixel centres at (col + .5, row + .5).

    x_cam = d · K^-1 [u + 0.5, v + 0.5, 1]^T, then x_world = R^T (x_cam - t).
    """
    K = np.asarray(K, np.float64)
    T = cameras.as_matrix4(world_to_camera)
    d = np.asarray(depth, np.float64)[rows, cols]
    x = (cols + 0.5 - K[0, 2]) / K[0, 0] * d
    y = (rows + 0.5 - K[1, 2]) / K[1, 1] * d
    cam = np.stack([x, y, d], axis=1) - T[:3, 3]
    return cam @ T[:3, :3]  # R^T applied to row vectors


def unproject_depth(depth, K, world_to_camera) -> np.ndarray:
    """Dense unprojection of depth maps (S, H, W) with our K (S, 3, 3): world points (S, H, W, 3) float64."""
    depth = np.asarray(depth)
    S, H, W = depth.shape
    rows, cols = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    return np.stack([unproject_pixels(depth[i], K[i], world_to_camera[i], rows, cols).reshape(H, W, 3)
                     for i in range(S)])


@dataclass
class FramePoints:
    """Coloured points, grouped by the frame they came from.

    ``positions`` (N, 3) float64 in the output world; ``colors`` (N, 3) float32 sRGB-encoded [0, 1];
    ``frame`` (N,) int32 source frame; frame i's points are ``positions[offsets[i]:offsets[i + 1]]``.
    """

    positions: np.ndarray
    colors: np.ndarray
    frame: np.ndarray
    offsets: np.ndarray
    threshold: float = field(default=-np.inf)

    def __len__(self):
        return len(self.positions)

    def frame_slice(self, i: int) -> slice:
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))


def point_cloud(pred: VGGTPredictions, confidence_percentile: float = 50.0, source: str = "depth",
                world_from_vggt=None, frames=None) -> FramePoints:
    """Coloured points of the clip, filtered by confidence percentile (VGGT demo semantics), per frame.

    ``source`` is "depth" (unproject depth with each frame's K and extrinsic; VGGT's recommended branch) or
    "world_points" (VGGT's point head, filtered by ``world_points_conf``). Points with depth <= 0 are dropped.
    ``world_from_vggt`` (4x4 similarity) maps them into the output world, in float64.

    Vectorised per frame with no per-point Python: the camera-to-world step and ``world_from_vggt`` are fused
    into one affine map per frame, x_world = A (d · ray) + b, written straight into preallocated outputs.
    """
    if source == "depth":
        conf = pred.depth_conf
    elif source == "world_points":
        if pred.world_points is None:
            raise PredictionsError(pred.path, "world_points", "requested as point source but absent from the file")
        conf = pred.world_points_conf if pred.world_points_conf is not None else pred.depth_conf
    else:
        raise ValueError(f"source must be 'depth' or 'world_points', got {source!r}")
    thr = confidence_threshold(conf, confidence_percentile)
    frames = list(range(pred.num_frames) if frames is None else frames)
    s, Rw, tw = (1.0, np.eye(3), np.zeros(3)) if world_from_vggt is None else \
        cameras.decompose_similarity(world_from_vggt)
    masks = []
    for i in frames:
        m = (conf[i] > 1e-5) & (pred.depth[i] > 0)
        if np.isfinite(thr):
            m &= conf[i] >= thr
        masks.append(m)
    counts = [int(m.sum()) for m in masks]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    N = int(offsets[-1])
    pos = np.empty((N, 3), np.float64)
    col = np.empty((N, 3), np.float32)
    fid = np.empty(N, np.int32)
    W = pred.width
    K = pred.K
    for k, i in enumerate(frames):
        sl = slice(offsets[k], offsets[k + 1])
        flat = np.flatnonzero(masks[k])  # once per frame; every array below is gathered with it
        if source == "depth":
            T = pred.world_to_camera[i]
            A = s * Rw @ T[:3, :3].T          # camera -> VGGT world (R^T) -> output world (s Rw)
            b = tw - A @ T[:3, 3]
            d = pred.depth[i].reshape(-1).take(flat).astype(np.float64)
            rows, cols = np.divmod(flat, W)
            cam = np.empty((len(flat), 3))
            cam[:, 0] = (cols + 0.5 - K[i, 0, 2]) / K[i, 0, 0] * d   # pixel centres at +0.5 (our K)
            cam[:, 1] = (rows + 0.5 - K[i, 1, 2]) / K[i, 1, 1] * d
            cam[:, 2] = d
        else:
            A, b = s * Rw, tw
            cam = pred.world_points[i].reshape(-1, 3).take(flat, axis=0).astype(np.float64)
        np.matmul(cam, A.T, out=pos[sl])
        pos[sl] += b
        img = pred.images[i]
        for c in range(3):  # one channel plane at a time: contiguous when the file is CHW, as VGGT writes it
            col[sl, c] = img[..., c].reshape(-1).take(flat)
        fid[sl] = i
    return FramePoints(pos, col, fid, offsets, thr)


# --------------------------------------------------------------------------------------------------------------
# Metric scale: world_from_vggt
# --------------------------------------------------------------------------------------------------------------

@dataclass
class MetricFit:
    """A ``world_from_vggt`` similarity (4x4) with how it was found and how well it fits.

    ``residual_m``: RMS error in metres of what the fit matched (trajectory centres, or per-frame camera heights);
    ``max_error_m`` its maximum; ``details`` method-specific figures (plane inlier RMS, rotation residual, ...).
    """

    world_from_vggt: np.ndarray
    method: str
    scale: float
    residual_m: float = 0.0
    max_error_m: float = 0.0
    details: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"world_from_vggt": self.world_from_vggt.tolist(), "method": self.method, "scale": self.scale,
                "residual_m": self.residual_m, "max_error_m": self.max_error_m, "details": self.details}


def world_from_vggt_by_factor(scale: float) -> MetricFit:
    """(a) A given metres-per-VGGT-unit factor; the first camera sits at the origin looking along +Y."""
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"metric scale factor must be a positive number, got {scale}")
    M = cameras.similarity_matrix(scale, BLENDER_FROM_OPENCV_AXES, np.zeros(3))
    return MetricFit(M, "factor", float(scale))


def load_metric_trajectory(path, num_frames: int | None = None):
    """A metric camera path in world metres: returns (world_to_camera (N, 4, 4) or None, centres (N, 3)).

    Accepted: ``.npz`` with ``world_to_camera`` ((N, 4, 4) or (N, 3, 4), OpenCV cameras) or ``camera_centers``
    (N, 3); text (``.txt``/``.csv``, ``#`` comments) with 3 columns x y z, or 8 columns in TUM order
    ``t x y z qx qy qz qw`` (camera-to-world, OpenCV camera axes).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise PredictionsError(path, None, "trajectory file not found")
    w2c = None
    if path.lower().endswith(".npz"):
        try:
            with np.load(path, allow_pickle=False) as z:
                if "world_to_camera" in z.files:
                    w2c = cameras.as_matrix4(_numeric(z, path, "world_to_camera"), "world_to_camera")
                    if w2c.ndim != 3:
                        raise PredictionsError(path, "world_to_camera", f"expected (N, 4, 4), got {w2c.shape}")
                    centres = cameras.camera_centers(w2c)
                elif "camera_centers" in z.files:
                    centres = np.asarray(_numeric(z, path, "camera_centers"), np.float64)
                else:
                    raise PredictionsError(path, "world_to_camera",
                                           f"missing; expected 'world_to_camera' or 'camera_centers', has {z.files}")
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
            if isinstance(e, PredictionsError):
                raise
            raise PredictionsError(path, None, f"not a readable .npz file: {e}") from None
    else:
        try:
            rows = np.loadtxt(path, comments="#", delimiter="," if path.lower().endswith(".csv") else None,
                              ndmin=2, dtype=np.float64)
        except ValueError as e:
            raise PredictionsError(path, None, f"not a numeric table: {e}") from None
        if rows.shape[1] == 3:
            centres = rows
        elif rows.shape[1] == 8:
            centres = rows[:, 1:4]
            q = rows[:, [7, 4, 5, 6]]  # TUM's qx qy qz qw -> (w, x, y, z)
            try:
                Rc2w = cameras.quaternion_to_rotation(q)
            except ValueError as e:
                raise PredictionsError(path, "quaternion", str(e)) from None
            c2w = np.tile(np.eye(4), (len(rows), 1, 1))
            c2w[:, :3, :3], c2w[:, :3, 3] = Rc2w, centres
            w2c = cameras.rigid_inverse(c2w)
        else:
            raise PredictionsError(path, None, f"expected 3 columns (x y z) or 8 (TUM), got {rows.shape[1]}")
    if centres.ndim != 2 or centres.shape[1] != 3:
        raise PredictionsError(path, "camera_centers", f"expected (N, 3), got {centres.shape}")
    if not np.all(np.isfinite(centres)) or (w2c is not None and not np.all(np.isfinite(w2c))):
        raise PredictionsError(path, None, "trajectory contains NaN or inf")
    if w2c is not None:
        w2c = cameras.orthonormalize(w2c)
    if num_frames is not None and len(centres) != num_frames:
        raise PredictionsError(path, None, f"has {len(centres)} poses but the clip has {num_frames} frames")
    return w2c, centres


def world_from_vggt_by_trajectory(vggt_world_to_camera, metric_world_to_camera=None,
                                  metric_centers=None) -> MetricFit:
    """(b) The similarity that lays VGGT's camera path onto a metric one (Umeyama).

    With metric orientations the fit uses them as well (a straight drive then still fixes the roll); with centres
    alone it is Umeyama on centres and needs a path that is not a straight line.
    """
    A = cameras.orthonormalize(vggt_world_to_camera)
    if metric_world_to_camera is not None:
        fit = cameras.fit_similarity_to_cameras(A, metric_world_to_camera)
    else:
        fit = cameras.umeyama(cameras.camera_centers(A), metric_centers)
    details = {} if fit.rotation_rms_deg is None else {"rotation_rms_deg": fit.rotation_rms_deg}
    return MetricFit(fit.matrix(), "trajectory", fit.scale, fit.rms, fit.max_error, details)


def world_from_vggt_by_camera_height(plane, vggt_world_to_camera, camera_height: float,
                                     plane_inlier_rms: float | None = None) -> MetricFit:
    """(c) Scale from a known camera height over a ground plane found in VGGT's world.

    ``plane`` = (a, b, c, d) with a x + b y + c z + d = 0 in VGGT units. The scale is camera_height divided by the
    median camera-to-plane distance; the world is levelled so the plane is z = 0 with +Z towards the cameras, and
    the first camera stands at x = y = 0 with its forward axis projected on the ground along +Y. Residual: RMS of
    (scaled per-frame height - camera_height), in metres.
    """
    if not np.isfinite(camera_height) or camera_height <= 0:
        raise ValueError(f"camera height must be a positive number of metres, got {camera_height}")
    p = np.asarray(plane, np.float64)
    if p.shape != (4,) or not np.all(np.isfinite(p)):
        raise ValueError(f"plane must be 4 finite numbers (a, b, c, d), got {p}")
    n = p[:3]
    norm = np.linalg.norm(n)
    if norm < 1e-12:
        raise ValueError("plane normal has zero length")
    n, d = n / norm, p[3] / norm
    T = cameras.as_matrix4(vggt_world_to_camera)
    c = cameras.camera_centers(T)
    dist = c @ n + d
    if np.median(dist) < 0:  # orient the normal towards the cameras
        n, d, dist = -n, -d, -dist
    med = float(np.median(dist))
    if med <= 1e-9:
        raise ValueError("the cameras lie on the fitted plane: it is not the ground under them")
    s = camera_height / med
    fwd = T[0, 2, :3]  # camera 0's +z in VGGT world
    fwd = fwd - (fwd @ n) * n
    if np.linalg.norm(fwd) < 1e-6:
        raise ValueError("the first camera looks straight down at the plane: heading undefined")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, n)
    R = np.stack([right, fwd, n])  # rows: world x, y, z expressed in VGGT axes
    # x, y: the first camera stands over the origin; z = s · (signed distance to the plane), so t_z = s d.
    t = -s * (R @ c[0])
    t[2] = s * d
    M = cameras.similarity_matrix(s, R, t)
    err = s * dist - camera_height
    details = {"plane_vggt": [*n.tolist(), float(d)], "camera_distance_vggt_median": med}
    if plane_inlier_rms is not None:
        details["plane_inlier_rms_m"] = float(plane_inlier_rms * s)
    return MetricFit(M, "camera_height", float(s), float(np.sqrt(np.mean(err ** 2))), float(np.abs(err).max()),
                     details)


def ground_candidates(pred: VGGTPredictions, confidence_percentile: float = 50.0, lower_fraction: float = 0.4,
                      max_points: int = 200_000, seed: int = 0) -> np.ndarray:
    """Points likely on the road, in VGGT's world: confident pixels from the lower part of each image.

    A forward-looking car camera sees the road in the bottom rows; a random, seeded subset keeps the plane fit
    fast on long clips.
    """
    H = pred.height
    conf = pred.depth_conf
    thr = confidence_threshold(conf, confidence_percentile)
    start = int(np.floor(H * (1.0 - lower_fraction)))
    K = pred.K
    pts = []
    for i in range(pred.num_frames):
        keep = (conf[i, start:] >= thr) & (conf[i, start:] > 1e-5) & (pred.depth[i, start:] > 0)
        rows, cols = np.nonzero(keep)
        pts.append(unproject_pixels(pred.depth[i], K[i], pred.world_to_camera[i], rows + start, cols))
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(seed).choice(len(pts), max_points, replace=False)]
    return pts


def save_predictions(path, images, depth, depth_conf, extrinsic, intrinsic_vggt, world_points=None,
                     world_points_conf=None) -> None:
    """Write predictions exactly as VGGT's demo does (``np.savez``, float32, no batch axis), atomically.

    ``images`` (S, 3, H, W) or (S, H, W, 3) in [0, 1]; ``depth`` (S, H, W) is saved as (S, H, W, 1);
    ``extrinsic`` (S, 3, 4) world-to-camera; ``intrinsic_vggt`` in VGGT's pixel convention (see ours_K_to_vggt).
    """
    images = np.asarray(images, np.float32)
    if images.shape[-1] == 3 and images.shape[1] != 3:
        images = np.moveaxis(images, -1, 1)
    depth = np.asarray(depth, np.float32)
    if depth.ndim == 3:
        depth = depth[..., None]
    arrays = {"images": images, "depth": depth, "depth_conf": np.asarray(depth_conf, np.float32),
              "extrinsic": cameras.as_matrix4(extrinsic)[:, :3, :].astype(np.float32),
              "intrinsic": np.asarray(intrinsic_vggt, np.float32)}
    if world_points is not None:
        arrays["world_points"] = np.asarray(world_points, np.float32)
    if world_points_conf is not None:
        arrays["world_points_conf"] = np.asarray(world_points_conf, np.float32)
    path = os.fspath(path)
    tmp = path + ".tmp.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
