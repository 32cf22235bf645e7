"""VGGT predictions: load them as VGGT's demo writes them, unproject, filter, and give them metric scale.

VGGT's conventions (facebookresearch/vggt), which this module converts from:

* World frame = the first camera's OpenCV frame (x right, y down, z forward), scale normalised (not metric).
* ``extrinsic`` (S, 3, 4) world-to-camera; ``intrinsic`` (S, 3, 3) with the principal point at the image centre
  and pixel (u, v) unprojected at *integer* coordinates: x = (u - cx) d / fx. Our pixel convention puts pixel
  centres at u + 0.5 (DESIGN §3), so our K is VGGT's with cx + 0.5, cy + 0.5 and both unproject identically.
* ``depth`` (S, H, W, 1) camera z; ``depth_conf`` (S, H, W) = 1 + exp(x) >= 1; ``images`` (S, 3, H, W) in [0, 1]
  (sRGB-encoded display values); optional ``world_points`` (S, H, W, 3) and ``world_points_conf``.
* The demo squeezes a batch axis of 1 before saving; files with it are accepted too, and so are one-frame files
  saved with every size-1 axis squeezed (depth (H, W), extrinsic (3, 4), intrinsic (3, 3), images (3, H, W)).

What other tools write around VGGT, and what loading does about it (``load_predictions`` options, ``LoadReport``):

* ``extrinsic`` holding camera-to-world poses (a common mix-up): ``extrinsic_convention="auto"`` checks each
  frame's depth unprojection against ``world_points`` and refuses such a file, saying how to re-import;
  "camera_to_world" inverts on load.
* VGGT's "pad" preprocessing adds white borders to make the images square: ``crop="auto"`` finds and removes
  them (or give the pixels), moving the principal point with the crop.
* NaN/inf depth, confidence or world-point pixels are dropped (``valid`` masks) and counted; a frame without a
  finite pixel, or a non-finite pose or intrinsic, is refused naming the frame.

Outputs are float64 positions in the requested world (Blender's: Z up, metres, when a ``world_from_vggt``
similarity is given). Files are read with ``allow_pickle=False`` and only the numeric keys named above are
touched (newer demo files also hold ``pose_enc_list = None``, an object array that would need pickle).

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import cameras, files

REQUIRED_KEYS = ("images", "depth", "depth_conf", "extrinsic", "intrinsic")
OPTIONAL_KEYS = ("world_points", "world_points_conf")

#: Blender world axes from VGGT's (first camera's OpenCV) axes: x stays right, camera forward (z) becomes +Y,
#: camera down (y) becomes -Z. A camera with no pitch or roll then stands upright looking along +Y.
BLENDER_FROM_OPENCV_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


class PredictionsError(files.InputError):
    """A predictions (or trajectory) file that cannot be used; the message names the file and the key (``key``,
    also ``field``; None / "(file)" for the file as a whole)."""

    def __init__(self, path, key, message, hint=None):
        key = None if key == "(file)" else key  # files' callbacks name the whole file so
        files.InputError.__init__(self, path, key, message, hint)
        self.key = key
        where = f"{os.path.basename(self.path)}" + (f": '{key}'" if key else "")
        self.args = (f"{where}: {message} ({self.path})",)  # the text it has always had


def _npz_error(path, key, message):
    """``files.read_npz``'s error callback."""
    return PredictionsError(path, key, "file not found" if message == "not found" else message)


#: Per-pixel arrays hold measurements: VGGT saves them as float32. An integer depth map (millimetres, as depth
#: cameras write) or a boolean mask under these names would be read as VGGT units without a word: refused.
_FLOAT_KEYS = ("depth", "depth_conf", "world_points", "world_points_conf")


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
    valid: np.ndarray | None = None               # (S, H, W) bool: finite depth and depth_conf (None: all are)
    world_points_valid: np.ndarray | None = None  # (S, H, W) bool: finite world point and its confidence
    report: LoadReport = field(default_factory=lambda: LoadReport())  # what loading decided and dropped

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

#: What ``extrinsic`` holds: VGGT's own world-to-camera, or camera-to-world as some tools around VGGT save it
#: (facebookresearch/vggt issues 275, 370). ``"auto"`` (load_predictions only) checks against ``world_points``.
EXTRINSIC_CONVENTIONS = ("world_to_camera", "camera_to_world")

#: A reading of ``extrinsic`` agrees with the file's ``world_points`` in a frame when the depth it unprojects
#: lands within this fraction of the frame's median depth of the point head (median over confident pixels).
#: VGGT's depth and point heads are independent estimates that differ by a few percent of the depth; reading
#: camera-to-world poses as world-to-camera misses by twice the camera's offset plus twice its rotation angle
#: times the depth, far beyond this once the camera has moved.
CONVENTION_TOLERANCE = 0.25

#: Within that tolerance, a reading still loses a frame to the other one when the other lands at most half as far
#: and at least this fraction of the depth nearer: a camera-to-world file of a slow drive misses by only ~10-20 %
#: of the depth in its later frames, yet its inverse fits exactly. Frames where the camera barely moved give both
#: readings the same distance and decide nothing.
CONVENTION_MARGIN = 0.02

#: Pixels compared per frame by the convention check (a regular grid; more adds nothing to a median).
CONVENTION_CHECK_PIXELS = 20_000


@dataclass
class ConventionCheck:
    """Depth unprojected with each reading of ``extrinsic`` against the file's ``world_points``, per frame.

    ``frames``: the frames checked (frames without enough confident pixels are left out); ``relative[c]``: per
    checked frame, the median distance between the two point estimates divided by the median depth, for
    convention ``c``; ``distance[c]``: that median distance in VGGT units; ``pixels``: pixels compared per frame.
    """

    frames: np.ndarray
    relative: dict
    distance: dict
    pixels: np.ndarray
    tolerance: float = CONVENTION_TOLERANCE

    def agrees(self, convention: str) -> bool:
        """Every checked frame within the tolerance, and in none does the other reading fit decisively better."""
        this = self.relative[convention]
        other = next(v for k, v in self.relative.items() if k != convention)
        beaten = (other <= 0.5 * this) & (this - other >= CONVENTION_MARGIN)
        return bool(len(self.frames)) and bool(np.all(this <= self.tolerance)) and not bool(np.any(beaten))

    def worst(self, convention: str) -> int:
        """Index (into ``frames``) of the frame where ``convention`` disagrees most."""
        return int(np.argmax(self.relative[convention]))

    def to_json(self) -> dict:
        return {"frames": self.frames.tolist(), "tolerance": self.tolerance, "pixels": self.pixels.tolist(),
                "relative": {k: v.tolist() for k, v in self.relative.items()},
                "distance_vggt": {k: v.tolist() for k, v in self.distance.items()}}


@dataclass
class LoadReport:
    """What loading decided and dropped: the extrinsic convention (and whether it was checked), the crop, and the
    pixels with NaN/inf values. ``info`` and ``warnings`` are sentences for the import report."""

    extrinsic_convention: str = "world_to_camera"  # resolved: never "auto"
    convention_requested: str = "world_to_camera"
    convention_checked: bool = False
    check: ConventionCheck | None = None
    crop: tuple = (0, 0, 0, 0)                     # (left, top, right, bottom) pixels removed
    crop_requested: str = "none"                   # "none", "auto" or "explicit"
    original_size: tuple = (0, 0)                  # (W, H) before the crop
    nonfinite: dict = field(default_factory=dict)  # key -> per-frame counts of NaN/inf pixels (keys with any)
    dropped_pixels: list = field(default_factory=list)  # per frame: pixels dropped from depth points (NaN/inf)
    info: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    def to_json(self) -> dict:
        return {"extrinsic_convention": self.extrinsic_convention,
                "extrinsic_convention_requested": self.convention_requested,
                "extrinsic_convention_checked": self.convention_checked,
                "convention_check": None if self.check is None else self.check.to_json(),
                "crop": list(self.crop), "crop_requested": self.crop_requested,
                "original_size": list(self.original_size),
                "nonfinite_pixels": {k: list(v) for k, v in self.nonfinite.items()},
                "dropped_pixels": int(sum(self.dropped_pixels)), "info": list(self.info),
                "warnings": list(self.warnings)}


def _fit_shape(arr, path, key, target, what):
    """Reshape ``arr`` to ``target`` by dropping a leading batch axis of 1 and/or a trailing axis of 1, or (one
    frame) adding the frame axis that a squeeze of every size-1 axis removed."""
    shape = tuple(arr.shape)
    candidates = [shape]
    if len(shape) >= 1 and shape[0] == 1:
        candidates.append(shape[1:])
    for c in list(candidates):
        if len(c) >= 1 and c[-1] == 1:
            candidates.append(c[:-1])
    if target[0] == 1:
        candidates += [(1,) + c for c in list(candidates)]
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
    if hwc.shape[0] == 0:  # every later step needs a frame: refuse here, naming the key, not in a reduction
        raise PredictionsError(path, "images", f"holds no frames (shape {arr.shape}): VGGT writes at least one")
    if hwc.shape[1] == 0 or hwc.shape[2] == 0:
        raise PredictionsError(path, "images", f"has images of {hwc.shape[2]} x {hwc.shape[1]} pixels (shape "
                                               f"{arr.shape}): nothing to place")
    if hwc.dtype == np.uint8:
        return hwc.astype(np.float32) / np.float32(255.0)
    if not np.issubdtype(hwc.dtype, np.floating):
        raise PredictionsError(path, "images", f"expected float in [0, 1] or uint8, got dtype {hwc.dtype}")
    hwc = hwc.astype(np.float32, copy=False)
    lo, hi = float(hwc.min()), float(hwc.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):  # colours have no stand-in: refuse, naming where
        bad = ~np.isfinite(hwc)
        frames = np.unique(np.nonzero(bad.reshape(len(bad), -1))[0])
        raise PredictionsError(path, "images", f"{int(bad.sum())} colour values are NaN or inf (frames "
                                               f"{frames[:8].tolist()}): the images VGGT saw are finite, so the "
                                               "file was damaged after VGGT; export it again")
    if lo < -1e-3 or hi > 1.0 + 1e-3:
        raise PredictionsError(path, "images", f"float values must lie in [0, 1], found [{lo:g}, {hi:g}] "
                                               "(uint8 images are accepted as they are)")
    return np.clip(hwc, 0.0, 1.0) if lo < 0.0 or hi > 1.0 else hwc


def _check_finite(a, path, key):
    if not _all_finite(a):
        bad = ~np.isfinite(a)
        frames = np.unique(np.nonzero(bad.reshape(bad.shape[0], -1))[0])
        raise PredictionsError(path, key, f"{int(bad.sum())} values are NaN or inf (first in frame "
                                          f"{int(frames[0])}; frames {frames[:8].tolist()}): those frames "
                                          "cannot be placed; re-run VGGT on the clip or remove those frames from "
                                          "the file")


def _all_finite(a) -> bool:
    return bool(np.isfinite(a.min()) and np.isfinite(a.max()))  # NaN propagates through min/max: one cheap pass


def _check_convention(value) -> None:
    if value not in ("auto",) + EXTRINSIC_CONVENTIONS:
        raise ValueError(f"extrinsic_convention must be 'auto', 'world_to_camera' or 'camera_to_world', "
                         f"got {value!r}")


def _per_frame(counts) -> str:
    """"frame 3: 12, frame 7: 1" for the frames with a non-zero count (the first 8, then "...")."""
    frames = [f"frame {i}: {int(n)}" for i, n in enumerate(counts) if n]
    return ", ".join(frames[:8]) + (", ..." if len(frames) > 8 else "")


def _numeric(arr, path, key):
    """``arr`` as a numpy array of numbers: floats (and, but for per-pixel measurements, integers); booleans,
    objects, strings, complex numbers refused naming the key."""
    a = np.asarray(arr)
    if a.dtype.kind == "b" or a.dtype.kind not in "fiu":
        raise PredictionsError(path, key, f"is not an array of numbers (dtype {a.dtype}); VGGT saves float32")
    if key in _FLOAT_KEYS and a.dtype.kind != "f":
        raise PredictionsError(path, key, f"holds integers (dtype {a.dtype}), VGGT saves float32: convert it to "
                                          "VGGT's units as floats (an integer depth map in millimetres would "
                                          "otherwise be read as units)")
    return a


def rigid_problem(T, tolerance: float = 1e-3, name: str = "extrinsic", what: str = "frame"):
    """(index, sentence) of the first finite matrix of ``T`` (N, 4, 4) that is not a rotation + translation
    (|R^T R - I| > ``tolerance``, a reflection, or a last row other than [0, 0, 0, 1]); None if all are. The
    sentence calls the matrices ``what`` ("frame 3 is not ...") and the array ``name``. Camera placement inverts
    these matrices, so a singular one must be refused here, not fail in a solver."""
    R = T[:, :3, :3]
    orth = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    bad = (orth > tolerance) | (np.linalg.det(R) < 0)
    if bad.any():
        i = int(np.argmax(bad))
        return i, f"{what} {i} is not a rotation + translation (|R^T R - I| = {orth[i]:.2e})"
    rows = np.any(T[:, 3] != [0, 0, 0, 1], axis=1)
    if rows.any():
        i = int(np.argmax(rows))
        return i, f"the last row of a 4x4 {name} must be [0, 0, 0, 1] ({what} {i})"
    return None


def parse_crop(value):
    """The crop option: ``"auto"``, ``"none"`` (also None, ``""``) or four pixel counts ``left top right
    bottom`` (a sequence, or a string of four integers separated by spaces or commas). Returns "auto", "none" or
    a tuple of 4 ints >= 0; raises ValueError saying what is accepted."""
    given = value
    if value is None:
        return "none"
    if isinstance(value, str):
        s = value.strip().lower()
        if s in ("", "none"):
            return "none"
        if s == "auto":
            return "auto"
        value = s.replace(",", " ").split()
    try:
        px = tuple(int(v) for v in value)
        ok = len(px) == 4 and all(p >= 0 and float(v) == p for p, v in zip(px, value))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"crop {given!r}: expected 'auto', 'none' or four pixel counts 'left top right bottom' "
                         "(integers >= 0)")
    return px


def white_borders(images) -> tuple:
    """(left, top, right, bottom): how many border columns/rows are exactly white (1.0 in every channel) in every
    pixel of every frame, symmetric or not. ``images`` (S, H, W, 3)."""
    images = np.asarray(images)
    S, H, W, _ = images.shape
    white = np.ones((H, W), bool)
    for i in range(S):  # one frame at a time: no (S, H, W, 3) temporary
        white &= np.all(images[i] == 1.0, axis=-1)
        if not (white[0].any() or white[-1].any() or white[:, 0].any() or white[:, -1].any()):
            return (0, 0, 0, 0)
    rows, cols = white.all(axis=1), white.all(axis=0)
    lead = lambda x: len(x) if x.all() else int(np.argmin(x))  # noqa: E731  (leading True count)
    return lead(cols), lead(rows), lead(cols[::-1]), lead(rows[::-1])


def detect_padding(images) -> tuple:
    """(left, top, right, bottom) of the white borders VGGT's "pad" preprocessing adds, or zeros.

    ``load_and_preprocess_images(mode="pad")`` pads the shorter side with pure white (1.0) to a square, half on
    each side (the second half one pixel larger when the total is odd). A border counts only when it is exactly
    1.0 in every channel of every pixel of every frame *and* the opposite border of the same axis is too, with
    the two differing by at most one pixel: a white sky at the top alone, or a sky band wider than the bottom one,
    is not cropped; nor is an image that is white all over.
    """
    left, top, right, bottom = white_borders(images)
    H, W = np.shape(images)[1:3]
    if top >= H or left >= W:
        return (0, 0, 0, 0)

    def symmetric(a, b):
        return (a, b) if a + b >= 2 and abs(a - b) <= 1 else (0, 0)

    top, bottom = symmetric(top, bottom)
    left, right = symmetric(left, right)
    return (left, top, right, bottom)


def load_predictions(path, world_points: bool = True, *, extrinsic_convention: str = "world_to_camera",
                     crop="none", metres_per_unit: float | None = None) -> VGGTPredictions:
    """Load and validate a VGGT ``predictions.npz``; raises PredictionsError naming the file and key.

    ``world_points=False`` skips the optional point-map arrays (half the file) when they will not be used.
    ``extrinsic_convention``: what ``extrinsic`` holds, "world_to_camera" (VGGT's, the default), "camera_to_world"
    (inverted on load), or "auto": check each frame's depth unprojection against ``world_points`` (read for the
    check even with ``world_points=False``) and refuse a file whose poses are camera-to-world or do not fit at all
    (see check_extrinsic_convention). ``crop``: "none", "auto" (VGGT's white pad borders, see detect_padding) or
    (left, top, right, bottom) pixels cut from every per-pixel array, the principal point moved with them.
    ``metres_per_unit`` (when known) only turns disagreements in refusals into metres.
    Pixels with NaN/inf depth, confidence or world point are dropped (``valid`` masks), counted in ``report``.
    """
    path = os.fspath(path)
    _check_convention(extrinsic_convention)
    try:
        crop = parse_crop(crop)
    except ValueError as e:
        raise PredictionsError(path, None, str(e)) from None
    read_wp = world_points or extrinsic_convention == "auto"
    # only the named keys are read (newer demo files also hold pose_enc_list = None, a pickle: never touched);
    # read_npz refuses FIFOs and directories, pickles, broken headers and corrupt members, naming file and key
    arrays = files.read_npz(path, REQUIRED_KEYS, OPTIONAL_KEYS if read_wp else (), error=_npz_error)
    return predictions_from_arrays(arrays, path, extrinsic_convention=extrinsic_convention, crop=crop,
                                   metres_per_unit=metres_per_unit, keep_world_points=world_points)


def _per_frame_matrices(arr, path, key, S, shapes):
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim == 4 and a.shape[0] == 1:
        a = a[0]
    if a.ndim == 2 and S == 1:  # one frame saved with every size-1 axis squeezed
        a = a[None]
    if a.ndim != 3 or a.shape[0] != S or a.shape[1:] not in shapes:
        want = " or ".join(f"({S}, {r}, {c})" for r, c in shapes)
        raise PredictionsError(path, key, f"expected {want}, got {np.shape(arr)}")
    return a


def _drop_nonfinite(report, path, values, confs, keys, S, what, hint):
    """Valid-pixel mask (S, H, W) or None when every pixel is finite; zeroes the bad pixels in place, counts them
    per frame in ``report`` and refuses a frame left without any finite pixel."""
    if all(_all_finite(a) for a in (values, confs) if a is not None):
        return None
    bad_v = ~np.isfinite(values)
    if bad_v.ndim == 4:
        bad_v = bad_v.any(axis=-1)
    bad_c = ~np.isfinite(confs) if confs is not None else np.zeros_like(bad_v)
    bad = bad_v | bad_c
    for key, b in zip(keys, (bad_v, bad_c)):
        counts = b.reshape(S, -1).sum(axis=1)
        if counts.any():
            report.nonfinite[key] = [int(c) for c in counts]
    n_px = bad[0].size
    for i in range(S):
        if bad[i].all():
            key = keys[0] if bad_v[i].all() or not bad_c[i].all() else keys[1]
            raise PredictionsError(path, key, f"frame {i} has no pixel with a finite {what} ({int(bad_v[i].sum())} "
                                              f"of its {n_px} {keys[0]} pixels and {int(bad_c[i].sum())} "
                                              f"{keys[1]} values are NaN or inf): {hint.format(i=i)}")
    values[bad] = 0.0
    if confs is not None:
        confs[bad] = 0.0
    return ~bad


def _crop_arrays(arrays: dict, crop, path, W, H):
    l, t, r, b = crop
    if l + r >= W or t + b >= H:
        raise PredictionsError(path, None, f"crop left {l} top {t} right {r} bottom {b} leaves nothing of the "
                                           f"{W} x {H} images: give fewer pixels (or crop 'none')")
    return {k: np.ascontiguousarray(v[:, t:H - b, l:W - r]) for k, v in arrays.items()}


def predictions_from_arrays(arrays, path="<arrays>", *, extrinsic_convention: str = "world_to_camera",
                            crop="none", metres_per_unit: float | None = None,
                            keep_world_points: bool = True) -> VGGTPredictions:
    """Validate a mapping of VGGT arrays (as in the .npz) into VGGTPredictions (see load_predictions)."""
    _check_convention(extrinsic_convention)
    crop = parse_crop(crop)
    report = LoadReport(convention_requested=extrinsic_convention)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise PredictionsError(path, missing[0], f"missing key(s) {missing}; the arrays are {sorted(arrays)}")
    arrays = {k: _numeric(v, path, k) for k, v in arrays.items() if k in REQUIRED_KEYS + OPTIONAL_KEYS}
    images = _images_to_hwc(arrays["images"], path)
    S, H, W, _ = images.shape
    depth = _fit_shape(arrays["depth"], path, "depth", (S, H, W), "(S, H, W[, 1])").astype(np.float32)
    conf = _fit_shape(arrays["depth_conf"], path, "depth_conf", (S, H, W), "(S, H, W)")
    conf = conf.astype(np.float32)

    ext = _per_frame_matrices(arrays["extrinsic"], path, "extrinsic", S, ((3, 4), (4, 4)))
    _check_finite(ext, path, "extrinsic")
    ext = cameras.as_matrix4(ext)
    problem = rigid_problem(ext)
    if problem is not None:
        raise PredictionsError(path, "extrinsic", problem[1])

    intr = _per_frame_matrices(arrays["intrinsic"], path, "intrinsic", S, ((3, 3),)).copy()
    _check_finite(intr, path, "intrinsic")
    if np.any(intr[:, 0, 0] <= 0) or np.any(intr[:, 1, 1] <= 0):
        raise PredictionsError(path, "intrinsic", "focal lengths must be positive")

    wp = wpc = None
    if "world_points" in arrays:
        wp = _fit_shape(arrays["world_points"], path, "world_points", (S, H, W, 3), "(S, H, W, 3)")
        wp = wp.astype(np.float32)
    if "world_points_conf" in arrays:
        wpc = _fit_shape(arrays["world_points_conf"], path, "world_points_conf", (S, H, W),
                         "(S, H, W)").astype(np.float32)

    # crop: every per-pixel array, and the principal point with them
    report.original_size = (W, H)
    if crop == "auto":
        report.crop_requested = "auto"
        crop = detect_padding(images)
        bands = white_borders(images) if not any(crop) else (0, 0, 0, 0)
        if any(bands) and bands[1] < H:
            report.info.append(f"white borders (left {bands[0]}, top {bands[1]}, right {bands[2]}, bottom "
                               f"{bands[3]} px) are not the symmetric bands VGGT's padding makes: not cropped "
                               "(give the crop in pixels to remove them)")
    elif crop == "none":
        crop = (0, 0, 0, 0)
    else:
        report.crop_requested = "explicit"
    if any(crop):
        per_pixel = {"images": images, "depth": depth, "depth_conf": conf}
        if wp is not None:
            per_pixel["world_points"] = wp
        if wpc is not None:
            per_pixel["world_points_conf"] = wpc
        per_pixel = _crop_arrays(per_pixel, crop, path, W, H)
        images, depth, conf = per_pixel["images"], per_pixel["depth"], per_pixel["depth_conf"]
        wp, wpc = per_pixel.get("world_points"), per_pixel.get("world_points_conf")
        intr[:, 0, 2] -= crop[0]
        intr[:, 1, 2] -= crop[1]
        H, W = depth.shape[1:]
        how = "VGGT's white padding detected" if report.crop_requested == "auto" else "as given"
        report.info.append(f"cropped left {crop[0]}, top {crop[1]}, right {crop[2]}, bottom {crop[3]} px "
                           f"({how}): {report.original_size[0]} x {report.original_size[1]} -> {W} x {H}, "
                           "principal point moved with the crop")
    report.crop = tuple(int(c) for c in crop)

    # NaN/inf pixels: dropped (zeroed and masked), counted; a frame without any finite pixel is refused
    valid = _drop_nonfinite(report, path, depth, conf, ("depth", "depth_conf"), S, "depth and confidence",
                            "re-run VGGT on the clip or remove frame {i} from the file")
    wp_valid = None
    if wp is not None:
        wp_valid = _drop_nonfinite(
            report, path, wp, wpc, ("world_points", "world_points_conf"), S, "world point",
            "re-run VGGT on the clip or remove frame {i} from the file; or import with points from depth and an "
            "explicit extrinsic convention, which do not read the point map")
    if valid is not None:
        report.dropped_pixels = [int(n) for n in (~valid).reshape(S, -1).sum(axis=1)]
        report.warnings.append(f"dropped {sum(report.dropped_pixels)} pixels with NaN/inf depth or confidence "
                               f"({_per_frame(report.dropped_pixels)})")
    else:
        report.dropped_pixels = [0] * S
    if wp_valid is not None:
        n = (~wp_valid).reshape(S, -1).sum(axis=1)
        report.warnings.append(f"{int(n.sum())} world_points pixels are NaN/inf: left out of the point map and the "
                               f"convention check ({_per_frame(n)})")

    pred = VGGTPredictions(path=str(path), images=images, depth=depth, depth_conf=conf, world_to_camera=ext,
                           intrinsic_vggt=intr, world_points=wp, world_points_conf=wpc, valid=valid,
                           world_points_valid=wp_valid, report=report)
    _resolve_convention(pred, extrinsic_convention, metres_per_unit)
    if not keep_world_points:
        pred.world_points = pred.world_points_conf = pred.world_points_valid = None
    return pred


# --------------------------------------------------------------------------------------------------------------
# Extrinsic convention: world-to-camera (VGGT) or camera-to-world, checked against the point head
# --------------------------------------------------------------------------------------------------------------

def check_extrinsic_convention(pred: VGGTPredictions, tolerance: float = CONVENTION_TOLERANCE,
                               max_pixels: int = CONVENTION_CHECK_PIXELS) -> ConventionCheck | None:
    """Each frame's depth, unprojected with ``pred.world_to_camera`` as stored and with its inverse, against the
    file's ``world_points`` (None without them).

    Pixels: a regular grid of at most ``max_pixels`` per frame, with finite values, positive depth and both
    confidences at or above the frame's median (VGGT's point head is least reliable where it is unsure). Per frame
    and reading: median distance between the two estimates, and that divided by the median depth. A frame with
    fewer than 16 such pixels is left out.
    """
    if pred.world_points is None:
        return None
    S, H, W = pred.depth.shape
    step = max(1, int(np.ceil(np.sqrt(H * W / max_pixels))))
    rows, cols = np.mgrid[0:H:step, 0:W:step]
    rows, cols = rows.ravel(), cols.ravel()
    readings = {"world_to_camera": cameras.as_matrix4(pred.world_to_camera),
                "camera_to_world": cameras.rigid_inverse(pred.world_to_camera)}
    K = pred.K
    frames, pixels = [], []
    rel = {k: [] for k in readings}
    dist = {k: [] for k in readings}
    for i in range(S):
        d = pred.depth[i][rows, cols]
        c = pred.depth_conf[i][rows, cols]
        ok = (d > 0) & (c > 1e-5)
        if pred.valid is not None:
            ok &= pred.valid[i][rows, cols]
        if pred.world_points_valid is not None:
            ok &= pred.world_points_valid[i][rows, cols]
        if ok.sum() >= 16:
            ok &= c >= np.median(c[ok])
        if pred.world_points_conf is not None and ok.sum() >= 16:
            wc = pred.world_points_conf[i][rows, cols]
            ok &= wc >= np.median(wc[ok])
        if ok.sum() < 16:
            continue
        r, q = rows[ok], cols[ok]
        P = pred.world_points[i][r, q].astype(np.float64)
        scale = float(np.median(d[ok]))
        frames.append(i)
        pixels.append(int(ok.sum()))
        for name, T in readings.items():
            X = unproject_pixels(pred.depth[i], K[i], T[i], r, q)
            m = float(np.median(np.linalg.norm(X - P, axis=1)))
            dist[name].append(m)
            rel[name].append(m / scale)
    return ConventionCheck(np.array(frames, np.int64), {k: np.array(v) for k, v in rel.items()},
                           {k: np.array(v) for k, v in dist.items()}, np.array(pixels, np.int64), tolerance)


def _length(units: float, metres_per_unit: float | None) -> str:
    if metres_per_unit:
        return f"{units * metres_per_unit:.3g} m"
    return f"{units:.3g} VGGT units (the metric scale is not known before the import's fit)"


def _resolve_convention(pred: VGGTPredictions, requested: str, metres_per_unit: float | None) -> None:
    """Apply the extrinsic convention to ``pred`` (in place), checking it first when ``requested`` is "auto"."""
    report = pred.report
    if requested == "camera_to_world":
        pred.world_to_camera = cameras.rigid_inverse(pred.world_to_camera)
        report.extrinsic_convention = "camera_to_world"
        report.info.append("extrinsic read as camera-to-world (as given) and inverted; not checked")
        return
    report.extrinsic_convention = "world_to_camera"
    if requested == "world_to_camera":
        report.info.append("extrinsic read as world-to-camera (VGGT's; as given), not checked")
        return
    check = check_extrinsic_convention(pred)
    report.check = check
    redo = ("re-import with the extrinsic convention set explicitly (the import's 'Extrinsic Convention' option, "
            "--extrinsic-convention on the command line)")
    if check is None or not len(check.frames):
        why = ("the file has no world_points" if check is None else
               "no frame has enough confident pixels with a finite point-map value")
        report.warnings.append(f"extrinsic convention not checked ({why}): read as world-to-camera, VGGT's; if "
                               f"the points look scattered and the camera path wrong, {redo}: camera_to_world")
        return
    report.convention_checked = True
    w2c, c2w = "world_to_camera", "camera_to_world"
    if check.agrees(w2c):
        k = check.worst(w2c)
        note = (f"extrinsic checked against world_points in {len(check.frames)} frames: world-to-camera agrees "
                f"(median {np.median(check.relative[w2c]):.1%} of the depth, at most {check.relative[w2c][k]:.1%} "
                f"in frame {int(check.frames[k])})")
        if check.agrees(c2w):
            note += "; the cameras barely move, so camera-to-world would fit as well"
        report.info.append(note)
        return
    k = check.worst(w2c)
    f = int(check.frames[k])
    if check.agrees(c2w):
        j = check.worst(c2w)
        raise PredictionsError(
            pred.path, "extrinsic",
            f"holds camera-to-world poses, not VGGT's world-to-camera: read as world-to-camera, the depth of frame "
            f"{f} lands {_length(check.distance[w2c][k], metres_per_unit)} from the file's world_points (median, "
            f"{check.relative[w2c][k]:.0%} of the depth; tolerance {check.tolerance:.0%}), while the inverted poses "
            f"agree in every frame (at most {check.relative[c2w][j]:.1%}). "
            f"{redo[0].upper() + redo[1:]}: camera_to_world")
    # neither reading fits: name the frame that neither explains
    worst = int(np.argmax(np.minimum(check.relative[w2c], check.relative[c2w])))
    f = int(check.frames[worst])
    raise PredictionsError(
        pred.path, "extrinsic",
        f"neither reading of the poses fits the file's world_points: in frame {f} the depth lands "
        f"{_length(check.distance[w2c][worst], metres_per_unit)} from them read as world-to-camera "
        f"({check.relative[w2c][worst]:.0%} of the depth) and {_length(check.distance[c2w][worst], metres_per_unit)} "
        f"read as camera-to-world ({check.relative[c2w][worst]:.0%}; tolerance {check.tolerance:.0%}). Check that "
        "extrinsic, intrinsic, depth and world_points come from the same VGGT run and were cropped or resized "
        f"together; to import the poses anyway, {redo}: world_to_camera or camera_to_world (no check)")


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
        conf, valid = pred.depth_conf, pred.valid
    elif source == "world_points":
        if pred.world_points is None:
            raise PredictionsError(pred.path, "world_points", "requested as point source but absent from the file")
        conf = pred.world_points_conf if pred.world_points_conf is not None else pred.depth_conf
        valid = pred.world_points_valid
        if pred.world_points_conf is None and pred.valid is not None:
            valid = pred.valid if valid is None else valid & pred.valid
    else:
        raise ValueError(f"source must be 'depth' or 'world_points', got {source!r}")
    # pixels with NaN/inf values (zeroed on load) are not part of the clip's confidence distribution
    thr = confidence_threshold(conf if valid is None else conf[valid], confidence_percentile)
    frames = list(range(pred.num_frames) if frames is None else frames)
    s, Rw, tw = (1.0, np.eye(3), np.zeros(3)) if world_from_vggt is None else \
        cameras.decompose_similarity(world_from_vggt)
    masks = []
    for i in frames:
        m = (conf[i] > 1e-5) & (pred.depth[i] > 0)
        if np.isfinite(thr):
            m &= conf[i] >= thr
        if valid is not None:
            m &= valid[i]
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


#: A TUM table of 100,000 poses is ~10 MB.
MAX_TRAJECTORY_TEXT_BYTES = 256 * 2 ** 20


def load_metric_trajectory(path, num_frames: int | None = None):
    """A metric camera path in world metres: returns (world_to_camera (N, 4, 4) or None, centres (N, 3)).

    Accepted: ``.npz`` with ``world_to_camera`` ((N, 4, 4) or (N, 3, 4), OpenCV cameras) or ``camera_centers``
    (N, 3); text (``.txt``/``.csv``, ``#`` comments) with 3 columns x y z, or 8 columns in TUM order
    ``t x y z qx qy qz qw`` (camera-to-world, OpenCV camera axes). PredictionsError naming the file and key for
    anything else (a FIFO or directory, an unreadable archive, no poses, wrong shapes, NaN, non-rigid poses).
    """
    path = os.fspath(path)
    w2c = None
    if path.lower().endswith(".npz"):
        arrays = files.read_npz(path, (), ("world_to_camera", "camera_centers"), error=_trajectory_error)
        if "world_to_camera" in arrays:
            key = "world_to_camera"
            a = _numeric(arrays[key], path, key)
            if a.ndim != 3 or a.shape[1:] not in ((3, 4), (4, 4)):
                raise PredictionsError(path, key, f"expected (N, 4, 4) or (N, 3, 4), got {a.shape}")
            w2c = cameras.as_matrix4(a)
            centres = None
        elif "camera_centers" in arrays:
            key = "camera_centers"
            centres = np.asarray(_numeric(arrays[key], path, key), np.float64)
        else:
            raise PredictionsError(path, "world_to_camera", "missing; expected 'world_to_camera' or "
                                                            f"'camera_centers', has {_npz_keys(path)}")
    else:
        key = None
        size = files.check_regular(path, _trajectory_error)  # np.loadtxt opens by name: a FIFO would block it
        if size > MAX_TRAJECTORY_TEXT_BYTES:  # loadtxt would take minutes and gigabytes before failing
            raise PredictionsError(path, None, f"is larger than {MAX_TRAJECTORY_TEXT_BYTES // 2 ** 20} MB ({size:,} "
                                               "bytes), far more than a camera path's table: not a trajectory file")
        try:
            with warnings.catch_warnings():  # "input contained no data": said below, as an error naming the file
                warnings.simplefilter("ignore", UserWarning)
                rows = np.loadtxt(path, comments="#", delimiter="," if path.lower().endswith(".csv") else None,
                                  ndmin=2, dtype=np.float64)
        except (ValueError, OSError) as e:  # a UnicodeDecodeError is a ValueError
            raise PredictionsError(path, None, f"not a numeric table: {str(e)[:300]}") from None
        if rows.size == 0:
            raise PredictionsError(path, None, "holds no poses (no numeric rows)")
        if rows.shape[1] == 3:
            centres = rows
        elif rows.shape[1] == 8:
            centres = rows[:, 1:4]
            q = rows[:, [7, 4, 5, 6]]  # TUM's qx qy qz qw -> (w, x, y, z)
            if not np.all(np.isfinite(q)):
                raise PredictionsError(path, "quaternion", "contains NaN or inf")
            try:
                Rc2w = cameras.quaternion_to_rotation(q)
            except ValueError as e:
                raise PredictionsError(path, "quaternion", str(e)) from None
            c2w = np.tile(np.eye(4), (len(rows), 1, 1))
            c2w[:, :3, :3], c2w[:, :3, 3] = Rc2w, centres
            w2c = cameras.rigid_inverse(c2w)
        else:
            raise PredictionsError(path, None, f"expected 3 columns (x y z) or 8 (TUM), got {rows.shape[1]}")
    if w2c is not None:
        if len(w2c) == 0:
            raise PredictionsError(path, key, f"holds no poses (shape {w2c.shape})")
        if not np.all(np.isfinite(w2c)):
            raise PredictionsError(path, key, "trajectory contains NaN or inf")
        problem = rigid_problem(w2c, name="pose", what="pose")
        if problem is not None:  # orthonormalize would invert a singular matrix
            raise PredictionsError(path, key, problem[1])
        centres = cameras.camera_centers(w2c)
    if centres.ndim != 2 or centres.shape[1] != 3:
        raise PredictionsError(path, "camera_centers", f"expected (N, 3), got {centres.shape}")
    if len(centres) == 0:
        raise PredictionsError(path, "camera_centers", f"holds no poses (shape {centres.shape})")
    if not np.all(np.isfinite(centres)):
        raise PredictionsError(path, None, "trajectory contains NaN or inf")
    if w2c is not None:
        w2c = cameras.orthonormalize(w2c)
    if num_frames is not None and len(centres) != num_frames:
        raise PredictionsError(path, None, f"has {len(centres)} poses but the clip has {num_frames} frames")
    return w2c, centres


def _trajectory_error(path, key, message):
    return PredictionsError(path, key, "trajectory file not found" if message == "not found" else message)


def _npz_keys(path) -> list:
    """The member names of an .npz that read_npz has just opened, for a message ([] if it cannot be listed)."""
    import zipfile

    try:
        with files.open_regular(path) as fh, zipfile.ZipFile(fh) as zf:
            return sorted(n[:-4] if n.endswith(".npy") else n for n in zf.namelist())
    except (files.InputError, zipfile.BadZipFile, OSError, ValueError, EOFError):
        return []


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
    thr = confidence_threshold(conf if pred.valid is None else conf[pred.valid], confidence_percentile)
    start = int(np.floor(H * (1.0 - lower_fraction)))
    K = pred.K
    pts = []
    for i in range(pred.num_frames):
        keep = (conf[i, start:] >= thr) & (conf[i, start:] > 1e-5) & (pred.depth[i, start:] > 0)
        if pred.valid is not None:
            keep &= pred.valid[i, start:]
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
    with files.atomic_write(os.fspath(path)) as f:  # a file object: np.savez would add .npz to a temporary name
        np.savez(f, **arrays)
