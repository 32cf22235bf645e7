"""Recorded camera frames: lens undistortion (OpenCV's distortion model) and frames decoded from a video file.

Conventions (docs/design.md §3): ``K`` is ours, pixel centres at (u + 0.5, v + 0.5); OpenCV puts them at (u, v), so
OpenCV's K is ours with cx − 0.5, cy − 0.5 (``to_opencv``), and an OpenCV remap map holds OpenCV pixel coordinates.
Images are (H, W, 3) uint8 RGB. Distortion coefficients are OpenCV's, in its order:
``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tau_x, tau_y]]]]`` (radial, tangential, rational, thin prism,
tilt), acting on normalised camera coordinates (x, y) = (X/Z, Y/Z) before K.

No torch here: numpy, OpenCV (cv2: numpy arrays in and out), Pillow, and PyAV for videos (imported when needed).
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from scpainter_blender.core import errors, files

#: The coefficient counts OpenCV accepts (``distCoeffs`` of 4, 5, 8, 12 or 14 elements)
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
#: No coefficient of a real lens comes near this (rational-model fits stay within tens); beyond it a value is a
#: units or order mistake, and the model's polynomials would lose float precision
COEFFICIENT_BOUND = 1000.0
#: The undistorted frame may zoom by at most this (alpha 0 crops to the valid pixels): a stronger zoom keeps less
#: than half of the recorded frame's width or height — a fisheye lens or coefficients of another model
MAX_ZOOM = 2.0
#: Undistortion maps kept per ``Undistorter`` (one per distinct K and image size; 20 MB each at 1920 x 1280)
MAPS_KEPT = 4


def distortion_coefficients(value, path, field, error=errors.InputError) -> np.ndarray | None:
    """The clip's ``distortion`` field: a list of 4, 5, 8, 12 or 14 finite numbers within ±COEFFICIENT_BOUND, as
    float64; None when absent or all zero (a pinhole camera: frames are used as they are). ``error(path, field,
    message)`` otherwise."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) not in DISTORTION_LENGTHS or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        got = f"a list of {len(value)}" if isinstance(value, list) else f"{type(value).__name__}"
        raise error(path, field, "expected OpenCV's distortion coefficients: a list of 4, 5, 8, 12 or 14 numbers "
                                 f"[k1, k2, p1, p2, k3, ...], got {got}", "give the coefficients of the frames' calibration, "
                                 "in OpenCV's order")
    d = np.array(value, np.float64)
    if not np.all(np.isfinite(d)) or np.any(np.abs(d) > COEFFICIENT_BOUND):
        raise error(path, field, f"coefficients must be finite and within ±{COEFFICIENT_BOUND:g}, got "
                                 f"{[float(v) for v in d]}")
    return None if not np.any(d) else d


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


def scale_K(K: np.ndarray, size, to_size) -> np.ndarray:
    """K (ours) for an image of ``size`` (W, H) resized to ``to_size``: rows 0 and 1 scaled (pixel centres +0.5)."""
    return np.diag([to_size[0] / size[0], to_size[1] / size[1], 1.0]) @ K


def distort_reference(x: np.ndarray, y: np.ndarray, dist: np.ndarray):
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


def undistorted_K(K: np.ndarray, dist: np.ndarray, size) -> np.ndarray:
    """The K (ours, (3, 3)) of the undistorted frame of size (W, H), for the recorded frame's K (ours, no skew)
    and ``dist``.

    ``cv2.getOptimalNewCameraMatrix`` with alpha 0 gives the largest rectangle of the undistorted image plane that
    holds only recorded pixels (no black borders: they would be training targets). It scales x and y separately
    (Waymo's front camera: 1913 against 1994 px, a 4 % stretch), so the frame's pixel aspect fx/fy is kept
    instead: both focal lengths take the larger zoom, and the frame is centred on that rectangle."""
    import cv2

    W, H = size
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


def undistortion_maps_reference(K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size):
    """(map_x, map_y) float64 (H, W): for each pixel of the undistorted frame (K_new, ours), the OpenCV pixel
    coordinates of the recorded frame (K, ours) it shows. Plain numpy; ``undistortion_maps`` is the fast path."""
    W, H = size
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x, y = (u - K_new[0, 2]) / K_new[0, 0], (v - K_new[1, 2]) / K_new[1, 1]
    xd, yd = distort_reference(x, y, dist)
    return K[0, 0] * xd + K[0, 2] - 0.5, K[1, 1] * yd + K[1, 2] - 0.5


def undistortion_maps(K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size):
    """``undistortion_maps_reference`` by ``cv2.initUndistortRectifyMap``: float32 maps (H, W) (not OpenCV's
    16-bit fixed point, which rounds to 1/32 px)."""
    import cv2

    return cv2.initUndistortRectifyMap(to_opencv(K), dist, None, to_opencv(K_new), tuple(size), cv2.CV_32FC1)


def distortion_problem(K: np.ndarray, dist: np.ndarray, K_new: np.ndarray, size) -> str | None:
    """Why the lens model (K, dist) cannot undistort a (W, H) frame to K_new, or None. Refused: a zoom beyond
    MAX_ZOOM; a model that folds over (two undistorted pixels showing one recorded one: coefficients in another
    order or of another model) or sends the undistorted frame outside the recorded one — both checked on a
    65 x 65 grid of the undistorted frame's pixel centres."""
    W, H = size
    if not np.all(np.isfinite(K_new)) or K_new[0, 0] <= 0 or K_new[1, 1] <= 0:
        return "OpenCV finds no undistorted frame for these coefficients"
    zoom = K_new[0, 0] / K[0, 0]
    if not 1 / MAX_ZOOM <= zoom <= MAX_ZOOM:
        return (f"undistorting would zoom by {zoom:.2f} (more than {MAX_ZOOM:g}): not a lens this model fits "
                f"(a fisheye?), or coefficients in another order")
    u, v = np.meshgrid(np.linspace(0.5, W - 0.5, 65), np.linspace(0.5, H - 0.5, 65))
    x, y = (u - K_new[0, 2]) / K_new[0, 0], (v - K_new[1, 2]) / K_new[1, 1]
    with np.errstate(all="ignore"):
        xd, yd = distort_reference(x, y, dist)
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


def undistorted_Ks(K_recorded: np.ndarray, dist: np.ndarray, size, error) -> np.ndarray:
    """(S, 3, 3): the undistorted frames' K (``undistorted_K``) for each frame's calibrated K (S, 3, 3), computed
    once per distinct K. ``error(message)`` -> the exception for a model that cannot undistort the frames
    (``distortion_problem``)."""
    K = np.empty_like(K_recorded)
    done: dict = {}
    for i, Ki in enumerate(K_recorded):
        key = Ki.tobytes()
        if key not in done:
            K_new = undistorted_K(Ki, dist, size)
            problem = distortion_problem(Ki, dist, K_new, size)
            if problem is not None:
                raise error(f"{problem} (with frame {i}'s K for {size[0]}x{size[1]})")
            done[key] = K_new
        K[i] = done[key]
    return K


class Undistorter:
    """Undistorts frames, keeping the maps of the last ``MAPS_KEPT`` distinct (K, dist, K_new, size)."""

    def __init__(self, kept: int = MAPS_KEPT):
        self.kept = kept
        self._maps: OrderedDict = OrderedDict()

    def maps(self, K, dist, K_new, size):
        key = (np.asarray(K, np.float64).tobytes(), np.asarray(dist, np.float64).tobytes(),
               np.asarray(K_new, np.float64).tobytes(), tuple(size))
        if key not in self._maps:
            self._maps[key] = undistortion_maps(K, dist, K_new, size)
            while len(self._maps) > self.kept:
                self._maps.popitem(last=False)
        self._maps.move_to_end(key)
        return self._maps[key]

    def __call__(self, image: np.ndarray, K, dist, K_new, out_size=None) -> np.ndarray:
        """(H, W, 3) uint8 recorded with (K, dist) -> the same size, pinhole with K_new; edge pixels replicated
        into the sub-pixel spill. ``out_size`` (W, H): the size the caller resizes it to next (None: kept).

        Interpolation: Lanczos (8 x 8) when the frame is kept or shrunk by less than 2 — the sharpest, and the most
        exact (blob centroids within 0.02 px; OpenCV's bicubic, a = −0.75, shifts them 0.05 px); bilinear when it is
        shrunk by 2 or more: the antialiased resize then removes what bilinear would soften (measured: ≥ 51.9 dB
        against Lanczos after the resize), at 1/15 of the cost (1920 x 1280: 25 ms against 360 ms here)."""
        import cv2

        H, W = image.shape[:2]
        map_x, map_y = self.maps(K, dist, K_new, (W, H))
        shrunk = out_size is not None and (2 * out_size[0] <= W and 2 * out_size[1] <= H)
        interpolation = cv2.INTER_LINEAR if shrunk else cv2.INTER_LANCZOS4
        return cv2.remap(image, map_x, map_y, interpolation, borderMode=cv2.BORDER_REPLICATE)

    def __getstate__(self):  # DataLoader workers get a clip without the (large, rebuildable) maps
        return {"kept": self.kept, "_maps": OrderedDict()}


def read_image(path: str, error):
    """A PIL image of the file, as RGB (opened as a regular file: a FIFO is refused, not waited on).
    ``error(message)`` -> the exception to raise for a file that is missing or cannot be read."""
    from PIL import Image

    try:
        with files.open_regular(path, lambda p, f, m: error(f"{path} {m}" if m != "not found" else
                                                            f"frame file not found: {path}")) as fh:
            with Image.open(fh) as im:
                return im.convert("RGB")  # convert loads the pixels: the file can be closed
    except (OSError, Image.DecompressionBombError, SyntaxError) as e:
        raise error(f"cannot read the image {path} ({type(e).__name__}: {str(e)[:200]})") from None


def resized(image, width: int, height: int) -> np.ndarray:
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


def probe_video(path: str, error) -> tuple:
    """(frame count, (W, H)) of the first video stream of a video file. The count is the stream's packets (one
    per frame; no header's estimate), read without decoding; the size is the first decoded frame's.
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
                    count += packet.size > 0  # the last packet, empty, flushes the decoder
                    if size is None:  # decoders may hold the first frames back for a few packets
                        for frame in packet.decode():
                            size = (frame.width, frame.height)
                            break
        except (av.error.FFmpegError, OSError, ValueError, IndexError) as e:
            raise _video_error(path, error, e) from None
    if stream is None:
        raise error(f"{path} holds no video stream")
    if size is None:
        raise error(f"{path}: no frame of its video stream could be decoded")
    return count, size


def decode_video(path: str, stop: int, error):
    """Yields (t, (H, W, 3) uint8 RGB) for frames t = 0 .. stop − 1 of the video, decoding each once and
    stopping there. ``error(message)`` -> the exception for a file that cannot be read or decoded, or that ends
    before ``stop``."""
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
                    yield t, frame.to_ndarray(format="rgb24")
                    t += 1
        except (av.error.FFmpegError, OSError, ValueError, IndexError) as e:
            raise _video_error(path, error, e) from None
    if t < stop:
        raise error(f"the video {path} ends after {t} decoded frames, {stop} were needed")
