"""Recorded camera frames: lens undistortion (OpenCV's distortion model or the fisheye one), frames decoded from a
video file as players show them (its display rotation applied), and the frames' aspect against the predictions'.

Conventions (docs/design.md §3): ``K`` is ours, pixel centres at (u + 0.5, v + 0.5); OpenCV puts them at (u, v), so
OpenCV's K is ours with cx − 0.5, cy − 0.5 (``to_opencv``), and an OpenCV remap map holds OpenCV pixel coordinates.
Images are (H, W, 3) uint8 RGB. Two distortion models (``distortion_model``), both acting on normalised camera
coordinates (x, y) = (X/Z, Y/Z) before K:

- ``opencv``: OpenCV's coefficients, in its order ``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tau_x,
  tau_y]]]]`` (radial, tangential, rational, thin prism, tilt);
- ``fisheye``: Kannala–Brandt ``k1, k2, k3, k4`` as ``cv2.fisheye`` takes them: θ = atan(r), r = |(x, y)|, the
  distorted point is (x, y) · θ_d / r with θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸).

No torch here: numpy, OpenCV (cv2: numpy arrays in and out), Pillow, and PyAV for videos (imported when needed).

(Over 400 lines: two lens models, video decoding with display matrices and image orientation share the
undistortion maps and their checks: one module is where a frame becomes the pinhole image training sees.)
"""

from __future__ import annotations

import math
from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core import errors, files

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    import av
    from PIL import Image

#: The lens models a clip's ``distortion_model`` names: OpenCV's (pinhole with polynomial distortion) and the fisheye
#: one (Kannala–Brandt, ``cv2.fisheye``)
OPENCV, FISHEYE = "opencv", "fisheye"
DISTORTION_MODELS = (OPENCV, FISHEYE)
#: The coefficient counts each model takes: OpenCV's ``distCoeffs`` of 4, 5, 8, 12 or 14 elements; fisheye k1..k4
DISTORTION_LENGTHS = {OPENCV: (4, 5, 8, 12, 14), FISHEYE: (4,)}
#: What each model's coefficients are, for error messages
DISTORTION_ORDER = {OPENCV: "OpenCV's [k1, k2, p1, p2, k3, ...]", FISHEYE: "Kannala–Brandt [k1, k2, k3, k4]"}
#: No coefficient of a real lens comes near this (rational-model fits stay within tens); beyond it a value is a
#: units or order mistake, and the model's polynomials would lose float precision
COEFFICIENT_BOUND = 1000.0
#: The undistorted frame may zoom by at most this (alpha 0 crops to the valid pixels): a stronger zoom keeps less
#: than half of the recorded frame's width or height — coefficients of another model, or (zooming out) a fisheye
#: too wide for a pinhole frame: its edges stretch out towards 90° off axis
MAX_ZOOM = 2.0
#: Half of VGGT's patch (14 px): VGGT's preprocessing rounds the resized height to a multiple of the patch, so a
#: side of the predictions is off the frames' aspect by up to this many of its pixels
ASPECT_ROUNDING_PX = 7.0
#: Undistortion maps kept per ``Undistorter`` (one per distinct K and image size; 20 MB each at 1920 x 1280)
MAPS_KEPT = 4


def distortion_model(value: object, path: str, field: str,
                     error: Callable[..., Exception] = errors.InputError) -> str | None:
    """The clip's ``distortion_model`` field: ``"opencv"`` or ``"fisheye"``; None when absent (not stated).
    ``error(path, field, message, hint)`` otherwise."""
    if value is None:
        return None
    if not isinstance(value, str) or value not in DISTORTION_MODELS:
        raise error(path, field, f"expected 'opencv' (OpenCV's 4 to 14 coefficients) or 'fisheye' (Kannala–Brandt "
                                 f"k1..k4, cv2.fisheye), got {value!r}"[:300],
                    "name the model the frames' calibration was made with")
    return value


def distortion_coefficients(value: object, path: str, field: str, error: Callable[..., Exception] = errors.InputError,
                            model: str | None = None, model_field: str = "distortion_model") -> np.ndarray | None:
    """The clip's ``distortion`` field for ``model`` (``distortion_model``'s value; None: not stated, read as
    OpenCV's): a list of ``DISTORTION_LENGTHS[model]`` finite numbers within ±COEFFICIENT_BOUND, as float64; None
    when absent or, for OpenCV's model, all zero (a pinhole camera: frames are used as they are; the fisheye's
    zeros are the equidistant lens). Four numbers without a stated model are refused naming ``model_field``:
    OpenCV's k1 k2 p1 p2 and the fisheye's k1..k4 are both four numbers, and taking a fisheye's for OpenCV's moves
    most undistorted pixels (an 82° lens at 518 x 294: 60 % more than 0.1 px, up to 56 px; the issue's: 19 px).
    ``error(path, field, message, hint)`` otherwise."""
    if value is None:
        return None
    lengths = DISTORTION_LENGTHS[model or OPENCV]
    if not isinstance(value, list) or len(value) not in lengths or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        others = sorted({type(v).__name__ for v in value if not isinstance(v, (int, float)) or isinstance(v, bool)}
                        ) if isinstance(value, list) else ()
        got = (f"a list of {len(value)}{' holding ' + ', '.join(others) if others else ''}"
               if isinstance(value, list) else f"{type(value).__name__}")
        count = ", ".join(map(str, lengths[:-1])) + " or " + str(lengths[-1]) if len(lengths) > 1 else str(lengths[0])
        raise error(path, field, f"expected {DISTORTION_ORDER[model or OPENCV]} distortion coefficients: a list of "
                                 f"{count} numbers, got {got}", "give the coefficients of the frames' calibration, "
                                 "in the model's order")
    d = np.array(value, np.float64)
    if not np.all(np.isfinite(d)) or np.any(np.abs(d) > COEFFICIENT_BOUND):
        raise error(path, field, f"coefficients must be finite and within ±{COEFFICIENT_BOUND:g}, got "
                                 f"{[float(v) for v in d]}")
    if model is None and len(d) == 4:  # even all zeros: no distortion to OpenCV, the equidistant lens to fisheye
        raise error(path, model_field, f"missing, and {field} holds four numbers: OpenCV's k1, k2, p1, p2 or a "
                                       f"fisheye's (Kannala–Brandt) k1, k2, k3, k4?",
                    f'state "{model_field}": "{OPENCV}" for a pinhole calibration k1, k2, p1, p2 '
                    f'(cv2.calibrateCamera), '
                    f'or "{FISHEYE}" for a fisheye one k1..k4 (cv2.fisheye.calibrate, Kalibr\'s equidistant)')
    if not np.any(d) and model != FISHEYE:  # fisheye zeros are the equidistant lens, no pinhole
        return None
    return d


def to_opencv(K: np.ndarray) -> np.ndarray:
    """(…, 3, 3) ours -> OpenCV's K (pixel centres at integers): cx − 0.5, cy − 0.5."""
    K = np.array(K, np.float64)
    K[..., 0, 2] -= 0.5
    K[..., 1, 2] -= 0.5
    return K


def from_opencv(K: np.ndarray) -> np.ndarray:
    """(…, 3, 3) OpenCV's K -> ours: cx + 0.5, cy + 0.5."""
    K = np.array(K, np.float64)
    K[..., 0, 2] += 0.5
    K[..., 1, 2] += 0.5
    return K


def scale_K(K: np.ndarray, size: tuple[int, int], to_size: tuple[int, int]) -> np.ndarray:
    """K (ours) for an image of ``size`` (W, H) resized to ``to_size``: rows 0 and 1 scaled (pixel centres +0.5)."""
    return np.diag([to_size[0] / size[0], to_size[1] / size[1], 1.0]) @ K


def distort_reference(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's distortion model, written plainly: normalised undistorted (x, y) -> normalised distorted (x_d, y_d)
    (arrays of any one shape). The reference for ``cv2.initUndistortRectifyMap`` / ``cv2.projectPoints``."""
    d = np.zeros(14)
    d[:len(dist)] = dist
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y = d
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
    if tau_x == 0 and tau_y == 0:
        return xd, yd
    # tilted sensor (OpenCV's computeTiltProjectionMatrix): rotate the image plane, project back onto z = 1
    cx_, sx_, cy_, sy_ = math.cos(tau_x), math.sin(tau_x), math.cos(tau_y), math.sin(tau_y)
    rot_x = np.array([[1, 0, 0], [0, cx_, sx_], [0, -sx_, cx_]])
    rot_y = np.array([[cy_, 0, -sy_], [0, 1, 0], [sy_, 0, cy_]])
    R = rot_y @ rot_x
    proj_z = np.array([[R[2, 2], 0, -R[0, 2]], [0, R[2, 2], -R[1, 2]], [0, 0, 1]])
    T = proj_z @ R
    v = T @ np.stack([xd.ravel(), yd.ravel(), np.ones(xd.size)])
    return (v[0] / v[2]).reshape(xd.shape), (v[1] / v[2]).reshape(xd.shape)


def distort_fisheye_reference(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fisheye (Kannala–Brandt) model, written plainly: normalised undistorted (x, y) -> normalised distorted
    (x_d, y_d), ``dist`` = k1..k4. The reference for ``cv2.fisheye.initUndistortRectifyMap`` / ``projectPoints``."""
    k1, k2, k3, k4 = dist
    r = np.hypot(x, y)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > 1e-12, theta_d / r, 1.0)  # θ_d / r -> 1 on the axis
    return x * scale, y * scale


def distort(x: np.ndarray, y: np.ndarray, dist: np.ndarray, model: str = OPENCV) -> tuple[np.ndarray, np.ndarray]:
    """``model``'s reference: ``distort_reference`` (opencv) or ``distort_fisheye_reference`` (fisheye)."""
    return (distort_fisheye_reference if model == FISHEYE else distort_reference)(x, y, dist)


def _fisheye_inner_rectangle(K: np.ndarray, dist: np.ndarray, size):
    """(x0, y0, x1, y1): the largest axis-aligned rectangle of the undistorted (normalised) plane inside the
    fisheye frame's edges, between the pixel centres of its first and last rows and columns — as
    ``cv2.getOptimalNewCameraMatrix`` with alpha 0 finds it for OpenCV's model (which has no fisheye version:
    ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` looks at the edges' midpoints only). Every
    edge pixel centre is undistorted (``cv2.fisheye.undistortPoints``) and checked by distorting it back: NaN when
    one is not found (a lens seeing 90° or more off axis within the frame, which no pinhole frame holds)."""
    import cv2

    W, H = size
    xs, ys = np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64)  # OpenCV pixel coordinates
    edges = [np.stack([xs, np.zeros(W)], -1), np.stack([xs, np.full(W, H - 1.0)], -1),
             np.stack([np.zeros(H), ys], -1), np.stack([np.full(H, W - 1.0), ys], -1)]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    K_cv = to_opencv(K)
    found = []
    for e in edges:
        xy = cv2.fisheye.undistortPoints(e.reshape(-1, 1, 2), K_cv, dist, criteria=criteria)[:, 0]
        with np.errstate(all="ignore"):
            xd, yd = distort_fisheye_reference(xy[:, 0], xy[:, 1], dist)
            off = np.hypot(K[0, 0] * xd + K_cv[0, 2] - e[:, 0], K[1, 1] * yd + K_cv[1, 2] - e[:, 1])
        if not np.all(off < 0.01):  # beyond 90° OpenCV returns points ~1e16 away, whose θ_d is not the pixel's
            return (math.nan,) * 4
        found.append(xy)
    top, bottom, left, right = found
    return left[:, 0].max(), top[:, 1].max(), right[:, 0].min(), bottom[:, 1].min()


def undistorted_K(K: np.ndarray, dist: np.ndarray, size: tuple[int, int], model: str = OPENCV) -> np.ndarray:
    """The K (ours, (3, 3)) of the undistorted frame of size (W, H), for the recorded frame's K (ours, no skew)
    and ``dist``.

    ``cv2.getOptimalNewCameraMatrix`` with alpha 0 gives the largest rectangle of the undistorted image plane that
    holds only recorded pixels (no black borders: they would be training targets). It scales x and y separately
    (Waymo's front camera: 1913 against 1994 px, a 4 % stretch), so the frame's pixel aspect fx/fy is kept
    instead: both focal lengths take the larger zoom, and the frame is centred on that rectangle. The fisheye model
    (``model`` "fisheye") gets the same rectangle from ``_fisheye_inner_rectangle``."""
    import cv2

    W, H = size
    if model == FISHEYE:
        x0, y0, x1, y1 = _fisheye_inner_rectangle(K, dist, size)
        with np.errstate(all="ignore"):
            zoom = max((W - 1) / (x1 - x0) / K[0, 0], (H - 1) / (y1 - y0) / K[1, 1])
    else:
        cv_new, _ = cv2.getOptimalNewCameraMatrix(to_opencv(K), dist, (W, H), 0, (W, H))
        # the rectangle, in normalised coordinates, between the centres of the first and last pixels (OpenCV: pixel
        # 0 at inner.x, pixel W-1 at inner.x + inner.width, fx = (W-1) / inner.width)
        x0, y0 = -cv_new[0, 2] / cv_new[0, 0], -cv_new[1, 2] / cv_new[1, 1]
        x1, y1 = x0 + (W - 1) / cv_new[0, 0], y0 + (H - 1) / cv_new[1, 1]
        zoom = max(cv_new[0, 0] / K[0, 0], cv_new[1, 1] / K[1, 1])
    fx, fy = zoom * K[0, 0], zoom * K[1, 1]
    return np.array([[fx, 0.0, W / 2 - fx * (x0 + x1) / 2],
                     [0.0, fy, H / 2 - fy * (y0 + y1) / 2],
                     [0.0, 0.0, 1.0]])


def undistortion_maps_reference(K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size: tuple[int, int],
                                model: str = OPENCV) -> tuple[np.ndarray, np.ndarray]:
    """(map_x, map_y) float64 (H, W): for each pixel of the undistorted frame (K_new, ours), the OpenCV pixel
    coordinates of the recorded frame (K, ours) it shows. Plain numpy; ``undistortion_maps`` is the fast path."""
    W, H = size
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x, y = (u - K_new[0, 2]) / K_new[0, 0], (v - K_new[1, 2]) / K_new[1, 1]
    xd, yd = distort(x, y, dist, model)
    return K[0, 0] * xd + K[0, 2] - 0.5, K[1, 1] * yd + K[1, 2] - 0.5


def undistortion_maps(K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size: tuple[int, int],
                      model: str = OPENCV) -> tuple[np.ndarray, np.ndarray]:
    """``undistortion_maps_reference`` by ``cv2.initUndistortRectifyMap`` (``cv2.fisheye``'s for the fisheye
    model): float32 maps (H, W) (not OpenCV's 16-bit fixed point, which rounds to 1/32 px)."""
    import cv2

    if model == FISHEYE:
        return cv2.fisheye.initUndistortRectifyMap(to_opencv(K), dist, np.eye(3), to_opencv(K_new), tuple(size),
                                                   cv2.CV_32FC1)
    return cv2.initUndistortRectifyMap(to_opencv(K), dist, None, to_opencv(K_new), tuple(size), cv2.CV_32FC1)


def distortion_problem(K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size: tuple[int, int],
                       model: str = OPENCV) -> str | None:
    """Why the lens model (K, dist) cannot undistort a (W, H) frame to K_new, or None. Refused: a zoom beyond
    MAX_ZOOM; a model that folds over (two undistorted pixels showing one recorded one: coefficients in another
    order or of another model) or sends the undistorted frame outside the recorded one — both checked on a
    65 x 65 grid of the undistorted frame's pixel centres."""
    W, H = size
    if not np.all(np.isfinite(K_new)) or K_new[0, 0] <= 0 or K_new[1, 1] <= 0:
        if model == FISHEYE:
            return ("the lens sees 90° or more off axis within the frame: too wide for a pinhole frame (crop the "
                    "frames to their middle), or coefficients in another order")
        return "OpenCV finds no undistorted frame for these coefficients"
    zoom = K_new[0, 0] / K[0, 0]
    if not 1 / MAX_ZOOM <= zoom <= MAX_ZOOM:
        lens = ("a lens too wide for a pinhole frame (crop the frames to their middle)" if model == FISHEYE else
                "not a lens this model fits (a fisheye? then distortion_model 'fisheye')")
        return (f"undistorting would zoom by {zoom:.2f} (beyond {1 / MAX_ZOOM:g}..{MAX_ZOOM:g}): {lens}, or "
                f"coefficients in another order")
    u, v = np.meshgrid(np.linspace(0.5, W - 0.5, 65), np.linspace(0.5, H - 0.5, 65))
    x, y = (u - K_new[0, 2]) / K_new[0, 0], (v - K_new[1, 2]) / K_new[1, 1]
    with np.errstate(all="ignore"):
        xd, yd = distort(x, y, dist, model)
        ud, vd = K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]
    if not (np.all(np.isfinite(ud)) and np.all(np.isfinite(vd))):
        return "the model is not finite over the frame"
    if np.any(np.diff(ud, axis=1) <= 0) or np.any(np.diff(vd, axis=0) <= 0):
        return ("the model folds over within the frame (not invertible): coefficients in another order or of "
                "another model?")
    # alpha 0 keeps the undistorted frame inside the recorded one's pixel centres; OpenCV finds its rectangle from
    # a 9 x 9 grid, so a little spill is expected (measured at 1920 x 1280: ≤ 0.13 px) and is filled by
    # replicating the edge pixels
    spill = max(0.5 - ud.min(), 0.5 - vd.min(), ud.max() - (W - 0.5), vd.max() - (H - 0.5))
    if spill > 1.0:
        return f"the undistorted frame reaches {spill:.1f} px beyond the recorded one's edge pixels"
    return None


def undistorted_Ks(K_recorded: np.ndarray, dist: np.ndarray, size: tuple[int, int], error: Callable[[str], Exception],
                   model: str = OPENCV) -> np.ndarray:
    """(S, 3, 3): the undistorted frames' K (``undistorted_K``) for each frame's calibrated K (S, 3, 3), computed
    once per distinct K. ``error(message)`` -> the exception for a model that cannot undistort the frames
    (``distortion_problem``)."""
    K = np.empty_like(K_recorded)
    done: dict = {}
    for i, Ki in enumerate(K_recorded):
        key = Ki.tobytes()
        if key not in done:
            K_new = undistorted_K(Ki, dist, size, model)
            problem = distortion_problem(Ki, dist, K_new, size, model)
            if problem is not None:
                raise error(f"{problem} (with frame {i}'s K for {size[0]}x{size[1]})")
            done[key] = K_new
        K[i] = done[key]
    return K


class Undistorter:
    """Undistorts frames, keeping the maps of the last ``MAPS_KEPT`` distinct (K, dist, K_new, size, model)."""

    def __init__(self, kept: int = MAPS_KEPT) -> None:
        self.kept = kept
        self._maps: OrderedDict = OrderedDict()

    def maps(self, K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size: tuple[int, int],
             model: str = OPENCV) -> tuple[np.ndarray, np.ndarray]:
        key = (np.asarray(K, np.float64).tobytes(), np.asarray(dist, np.float64).tobytes(),
               np.asarray(K_new, np.float64).tobytes(), tuple(size), model)
        if key not in self._maps:
            self._maps[key] = undistortion_maps(K, dist, K_new, size, model)
            while len(self._maps) > self.kept:
                self._maps.popitem(last=False)
        self._maps.move_to_end(key)
        return self._maps[key]

    def __call__(self, image: np.ndarray, K, dist, K_new, out_size=None, model: str = OPENCV) -> np.ndarray:
        """(H, W, 3) uint8 recorded with (K, dist) of ``model`` -> the same size, pinhole with K_new; edge pixels
        replicated into the sub-pixel spill. ``out_size`` (W, H): the size the caller resizes it to next (None:
        kept).

        Interpolation: Lanczos (8 x 8) when the frame is kept or shrunk by less than 2 — the sharpest, and the most
        exact (blob centroids within 0.02 px; OpenCV's bicubic, a = −0.75, shifts them 0.05 px); bilinear when it is
        shrunk by 2 or more: the antialiased resize then removes what bilinear would soften (measured: ≥ 51.9 dB
        against Lanczos after the resize), at 1/15 of the cost (1920 x 1280: 25 ms against 360 ms here)."""
        import cv2

        H, W = image.shape[:2]
        map_x, map_y = self.maps(K, dist, K_new, (W, H), model)
        shrunk = out_size is not None and (2 * out_size[0] <= W and 2 * out_size[1] <= H)
        interpolation = cv2.INTER_LINEAR if shrunk else cv2.INTER_LANCZOS4
        return cv2.remap(image, map_x, map_y, interpolation, borderMode=cv2.BORDER_REPLICATE)

    def __getstate__(self):  # DataLoader workers get a clip without the (large, rebuildable) maps
        return {"kept": self.kept, "_maps": OrderedDict()}


#: EXIF ``Orientation`` (tag 0x0112) values whose display turns the picture a quarter: width and height swap
_EXIF_ORIENTATION = 0x0112
_EXIF_QUARTER_TURNS = (5, 6, 7, 8)


def displayed_size(im: Image.Image) -> tuple:
    """(width, height) of an open PIL image as viewers show it: its EXIF ``Orientation`` (a phone photo taken
    upright is stored sideways with orientation 6 or 8) applied, as ``read_image`` applies it, without decoding."""
    width, height = im.size
    try:
        orientation = im.getexif().get(_EXIF_ORIENTATION, 1)
    except Exception:  # noqa: BLE001  a broken EXIF block: PIL's exif_transpose ignores it the same way
        orientation = 1
    return (height, width) if orientation in _EXIF_QUARTER_TURNS else (width, height)


def read_image(path: str, error: Callable[[str], Exception]) -> Image.Image:
    """A PIL image of the file, as RGB, turned as viewers show it (EXIF ``Orientation``, like a video's display
    matrix in ``display_orientation``), opened as a regular file: a FIFO is refused, not waited on.
    ``error(message)`` -> the exception to raise for a file that is missing or cannot be read."""
    from PIL import Image, ImageOps

    try:
        with files.open_regular(path, lambda p, f, m: error(f"{path} {m}" if m != "not found" else
                                                            f"frame file not found: {path}")) as fh:
            with Image.open(fh) as im:
                # exif_transpose loads the pixels (convert too): the file can be closed
                return ImageOps.exif_transpose(im).convert("RGB")
    except (OSError, Image.DecompressionBombError, SyntaxError) as e:
        raise error(f"cannot read the image {path} ({type(e).__name__}: {str(e)[:200]})") from None


def resized(image: Image.Image | np.ndarray, width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8 of a PIL image or an (H, W, 3) uint8 array: Lanczos (antialiased) when the size
    differs, as ``pairs.load_resized`` has always resized the frames."""
    from PIL import Image

    if isinstance(image, np.ndarray):
        if image.shape[:2] == (height, width):
            return image
        image = Image.fromarray(image)
    if image.size != (width, height):
        image = image.resize((width, height), Image.LANCZOS)
    return np.asarray(image)


def _video_error(path, error, e) -> Exception:
    return error(f"cannot decode the video {path} ({type(e).__name__}: {str(e)[:200]})")


#: FFmpeg's display matrix (libavutil/display.h): nine int32, row-major, a b c d in 16.16 fixed point
_FIXED_ONE = 65536.0


class OrientationError(Exception):
    """A display matrix no player shows the same way (not a ValueError: PyAV's errors are caught as those)."""


def display_orientation(frame: av.VideoFrame, path: str) -> tuple:
    """(transpose, flip_rows, flip_columns): how a decoded PyAV frame is turned to show as players show it, from
    its display matrix (frame side data DISPLAYMATRIX: the MP4/MOV track matrix a phone writes for a video filmed
    upright, FFmpeg attaches it to every frame). FFmpeg's matrix maps a pixel (p, q) (x right, y down) to
    (a p + c q, b p + d q) (+ a translation that only brings the picture back into view): the 8 orientations
    are the matrices whose 2 x 2 part is a signed permutation. (False, False, False) without a matrix. A matrix
    that is no quarter turn or flip (a 30° rotation, a shear) -> OrientationError: no player shows such video
    the same way. Where PyAV cannot list the frame's side data, ``frame.rotation`` (the matrix's angle alone).
    """
    import av

    try:
        side = frame.side_data.get(av.sidedata.sidedata.Type.DISPLAYMATRIX)
    except ValueError:  # PyAV (18.1) cannot list side data of a type it has no name for: the angle alone, then
        quarter = frame.rotation / 90  # counter-clockwise, as FFmpeg's av_display_rotation_get (flips not seen)
        if quarter != round(quarter):
            raise OrientationError(f"the video {path} has a display rotation of {frame.rotation}°, no quarter turn: "
                                   f"re-encode it upright (ffmpeg applies it)") from None
        return {0: (False, False, False), 1: (True, True, False), 2: (False, True, True),
                3: (True, False, True)}[round(quarter) % 4]
    if side is None:
        return False, False, False
    m = np.frombuffer(bytes(side), np.int32)
    a, b, c, d = (m[[0, 1, 3, 4]] / _FIXED_ONE) if m.size == 9 else (1.0, 0.0, 0.0, 1.0)
    scale = math.sqrt(abs(a * d - b * c))
    L = np.array([[a, c], [b, d]]) / (scale if scale > 0 else 1.0)
    R = np.round(L)
    if scale == 0 or np.abs(L - R).max() > 1e-3 or np.abs(np.abs(R).sum(axis=0) - 1).max() > 0:
        raise OrientationError(f"the video {path} has a display matrix that is no quarter-turn rotation or flip "
                               f"({[round(float(v), 4) for v in (a, b, c, d)]}): re-encode it upright (ffmpeg "
                               f"applies it)")
    if R[0, 0] != 0:  # p' = a p, q' = d q
        return False, R[1, 1] < 0, R[0, 0] < 0
    return True, R[1, 0] < 0, R[0, 1] < 0  # p' = c q, q' = b p: transposed, then rows follow b, columns c


def displayed(rgb: np.ndarray, orientation: tuple[bool, bool, bool]) -> np.ndarray:
    """An (H, W, 3) decoded frame turned as ``display_orientation`` says (contiguous; the array itself when it
    says nothing)."""
    transpose, flip_rows, flip_columns = orientation
    if not (transpose or flip_rows or flip_columns):
        return rgb
    if transpose:
        rgb = rgb.transpose(1, 0, 2)
    if flip_rows:
        rgb = rgb[::-1]
    if flip_columns:
        rgb = rgb[:, ::-1]
    return np.ascontiguousarray(rgb)


def probe_video(path: str, error: Callable[[str], Exception]) -> tuple:
    """(frame count, (W, H)) of the first video stream of a video file. The count is the stream's packets (one
    per frame; no header's estimate) that players show, read without decoding: an MP4/MOV edit list (what
    ``ffmpeg -ss … -t … -c copy`` and phone trimming write: the file keeps the packets from the key frame before
    the cut, the edit list says which presentation times play) is applied by FFmpeg's demuxer, which marks the
    packets whose presentation time lies outside the edited timeline as discarded, and the decoder drops their
    frames (``decode_video`` yields the shown frames only, their pts from 0), so those packets are not counted.
    The size is the first decoded frame's, as shown (``display_orientation``: a phone video filmed upright is
    W x H as players show it, not as coded).
    ``error(message)`` -> the exception for a file that is missing, not regular, or not a decodable video."""
    import av

    with files.open_regular(path, lambda p, f, m: error(f"{path} {m}" if m != "not found" else
                                                        f"video file not found: {path}")) as fh:
        try:
            with av.open(fh, mode="r") as container:
                count, size = 0, None
                streams = container.streams.video
                stream = streams[0] if streams else None
                for packet in container.demux(stream) if stream is not None else ():
                    # the last packet, empty, flushes the decoder; a discarded one is outside the edit list
                    count += packet.size > 0 and not packet.is_discard
                    if size is None:  # decoders may hold the first frames back for a few packets
                        for frame in packet.decode():
                            transpose = display_orientation(frame, path)[0]
                            size = (frame.height, frame.width) if transpose else (frame.width, frame.height)
                            break
        except OrientationError as e:
            raise error(str(e)) from None
        except (av.error.FFmpegError, OSError, ValueError, IndexError) as e:
            raise _video_error(path, error, e) from None
    if stream is None:
        raise error(f"{path} holds no video stream")
    if size is None:
        raise error(f"{path}: no frame of its video stream could be decoded")
    return count, size


def decode_video(path: str, stop: int, error: Callable[[str], Exception]) -> Iterator[tuple[int, np.ndarray]]:
    """Yields (t, (H, W, 3) uint8 RGB) for frames t = 0 .. stop − 1 of the video, as players show them (each
    frame's display matrix applied: ``display_orientation``; an edit list's cut frames left out, as
    ``probe_video`` says), decoding each once and stopping there.
    ``error(message)`` -> the exception for a file that cannot be read or decoded, or that ends before ``stop``."""
    import av

    t = 0
    with files.open_regular(path, lambda p, f, m: error(f"{path} {m}" if m != "not found" else
                                                        f"video file not found: {path}")) as fh:
        try:
            with av.open(fh, mode="r") as container:
                stream = container.streams.video[0]
                stream.thread_type = "AUTO"  # frame threads: several frames decoded at once
                for frame in container.decode(stream):
                    if t >= stop:
                        break
                    yield t, displayed(frame.to_ndarray(format="rgb24"), display_orientation(frame, path))
                    t += 1
        except OrientationError as e:
            raise error(str(e)) from None
        except (av.error.FFmpegError, OSError, ValueError, IndexError) as e:
            raise _video_error(path, error, e) from None
    if t < stop:
        raise error(f"the video {path} ends after {t} decoded frames, {stop} were needed")


def aspect_problem(frames_size: tuple[int, int], predictions_size: tuple[int, int]) -> str | None:
    """Why frames of ``frames_size`` (W, H) cannot be the images VGGT's predictions of ``predictions_size`` (w, h)
    were made from, or None. Without poses the frames' K is VGGT's scaled by W / w and H / h, so frames of another
    aspect (a rotated video, a crop) would get a stretched K. Allowed: the rounding of a resize — VGGT's
    preprocessing rounds each side to a multiple of its 14 px patch (``ASPECT_ROUNDING_PX`` of a side), the frames
    to whole pixels (half a pixel a side) —, to first order a relative difference of the aspect ratios of
    7 / w + 7 / h + 0.5 / W + 0.5 / H (518 x 350 from 1920 x 1280: 3.4 %, where the rounding made 1.3 %)."""
    (W, H), (w, h) = frames_size, predictions_size
    tolerance = ASPECT_ROUNDING_PX / w + ASPECT_ROUNDING_PX / h + 0.5 / W + 0.5 / H
    difference = abs(math.log((W / H) / (w / h)))
    if difference <= tolerance:
        return None
    return (f"the frames are {W}x{H} (aspect {W / H:.3f}), the predictions {w}x{h} (aspect {w / h:.3f}): "
            f"{100 * (math.exp(difference) - 1):.0f} % apart, more than a resize's rounding "
            f"({100 * tolerance:.1f} %)")
