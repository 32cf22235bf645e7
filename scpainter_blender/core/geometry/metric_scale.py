"""Metric scale: ``vggt_to_world``, the similarity from VGGT's world (first camera's OpenCV frame, VGGT units) to
Blender's (Z up, metres), found one of three ways (docs/design.md §3):

(a) ``vggt_to_world_by_factor``: a given metres-per-unit factor, the first camera at the origin looking along +Y;
(b) ``vggt_to_world_by_trajectory``: VGGT's camera path laid onto a metric one (``load_metric_trajectory`` reads
    it from .npz, x y z text or TUM text);
(c) ``vggt_to_world_by_camera_height``: a known camera height over a ground plane found in VGGT's world, the
    world levelled so the road is z = 0; ``camera_height_fit`` finds that plane in a clip's predictions first
    (``fits.fit_ground_plane`` on ``point_cloud.ground_candidates``).

Files and data that cannot give a scale raise ``vggt.PredictionsError`` naming the file and key (``camera_height_fit``
its ``GroundPlaneError``, with a hint); arguments out of range (a negative factor or height) raise ValueError. No
bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import cameras, fits, point_cloud, similarity
from .. import errors, files, outputs
from ..vggt import predictions as vggt
from ..vggt.predictions import PredictionsError


#: Blender world axes from VGGT's (first camera's OpenCV) axes: x stays right, camera forward (z) becomes +Y,
#: camera down (y) becomes -Z. A camera with no pitch or roll then stands upright looking along +Y.
OPENCV_TO_BLENDER_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass
class MetricFit:
    """A ``vggt_to_world`` similarity (4x4) with how it was found and how well it fits.

    ``residual_m``: RMS error in metres of what the fit matched (trajectory centres, or per-frame camera heights);
    ``max_error_m`` its maximum; ``details`` method-specific figures (plane inlier RMS, rotation residual, ...).
    """

    vggt_to_world: np.ndarray
    method: str
    scale: float
    residual_m: float = 0.0
    max_error_m: float = 0.0
    details: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"vggt_to_world": self.vggt_to_world.tolist(), "method": self.method, "scale": self.scale,
                "residual_m": self.residual_m, "max_error_m": self.max_error_m, "details": self.details}


def vggt_to_world_by_factor(scale: float) -> MetricFit:
    """(a) A given metres-per-VGGT-unit factor; the first camera sits at the origin looking along +Y. ValueError
    for a factor that is not a positive number (an argument: every user interface bounds it)."""
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"metric scale factor must be a positive number, got {scale}")
    M = similarity.similarity_matrix(scale, OPENCV_TO_BLENDER_AXES, np.zeros(3))
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
            a = vggt.numeric(arrays[key], path, key)
            if a.ndim != 3 or a.shape[1:] not in ((3, 4), (4, 4)):
                raise PredictionsError(path, key, f"expected (N, 4, 4) or (N, 3, 4), got {a.shape}")
            w2c = cameras.as_matrix4(a)
            centres = None
        elif "camera_centers" in arrays:
            key = "camera_centers"
            centres = np.asarray(vggt.numeric(arrays[key], path, key), np.float64)
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
        problem = cameras.rigid_problem(w2c, name="pose", what="pose")
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


def save_metric_trajectory(path, world_to_camera: np.ndarray) -> None:
    """Write a metric camera path as ``load_metric_trajectory`` reads it: ``.npz`` with ``world_to_camera``
    (N, 4, 4) float64, atomically."""
    with outputs.atomic_write(path) as f:
        np.savez(f, world_to_camera=np.asarray(world_to_camera, np.float64))


def _trajectory_error(path, key, message):
    return PredictionsError(path, key, "trajectory file not found" if message == "not found" else message)


def _npz_keys(path) -> list:
    """The member names of an .npz that read_npz has just opened, for a message ([] if it cannot be listed)."""
    import zipfile

    try:
        with files.open_regular(path) as fh, zipfile.ZipFile(fh) as zf:
            return sorted(n[:-4] if n.endswith(".npy") else n for n in zf.namelist())
    except (errors.InputError, zipfile.BadZipFile, OSError, ValueError, EOFError):
        return []


def vggt_to_world_by_trajectory(vggt_world_to_camera, metric_world_to_camera=None, metric_centers=None, *,
                                path="<trajectory>") -> MetricFit:
    """(b) The similarity that lays VGGT's camera path onto a metric one (Umeyama).

    With metric orientations the fit uses them as well (a straight drive then still fixes the roll); with centres
    alone it is Umeyama on centres and needs a path that is not a straight line. A path that cannot fix the
    similarity (a straight line of centres, one shared centre, a path driven backwards) is a PredictionsError
    naming ``path``, the metric trajectory's file.
    """
    A = cameras.orthonormalize(vggt_world_to_camera)
    try:
        if metric_world_to_camera is not None:
            key = "world_to_camera"
            fit = similarity.fit_similarity_to_cameras(A, metric_world_to_camera)
        else:
            key = "camera_centers"
            fit = similarity.umeyama(cameras.camera_centers(A), metric_centers)
    except ValueError as e:  # the arrays were checked on load: what is left is what the path itself cannot fix
        raise PredictionsError(path, key, f"cannot give the metric scale: {e}") from None
    details = {} if fit.rotation_rms_deg is None else {"rotation_rms_deg": fit.rotation_rms_deg}
    return MetricFit(fit.matrix(), "trajectory", fit.scale, fit.rms, fit.max_error, details)


def vggt_to_world_by_camera_height(plane, vggt_world_to_camera, camera_height: float,
                                   plane_inlier_rms: float | None = None, *, path="<predictions>") -> MetricFit:
    """(c) Scale from a known camera height over a ground plane found in VGGT's world.

    ``plane`` = (a, b, c, d) with a x + b y + c z + d = 0 in VGGT units. The scale is camera_height divided by the
    median camera-to-plane distance; the world is levelled so the plane is z = 0 with +Z towards the cameras, and
    the first camera stands at x = y = 0 with its forward axis projected on the ground along +Y. Residual: RMS of
    (scaled per-frame height - camera_height), in metres.

    ValueError for arguments out of range (height, plane); PredictionsError naming ``path`` (the predictions file
    the plane was found in) when its cameras cannot stand over that plane.
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
        raise PredictionsError(path, None, "the cameras lie on the ground plane found in the depth: it is not the "
                                           "ground under them; give the scale as a factor or a metric trajectory")
    s = camera_height / med
    fwd = T[0, 2, :3]  # camera 0's +z in VGGT world
    fwd = fwd - (fwd @ n) * n
    if np.linalg.norm(fwd) < 1e-6:
        raise PredictionsError(path, "extrinsic", "frame 0 looks straight down at the ground plane: the heading "
                                                  "is undefined; give the scale as a factor or a metric trajectory")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, n)
    R = np.stack([right, fwd, n])  # rows: world x, y, z expressed in VGGT axes
    # x, y: the first camera stands over the origin; z = s · (signed distance to the plane), so t_z = s d.
    t = -s * (R @ c[0])
    t[2] = s * d
    M = similarity.similarity_matrix(s, R, t)
    err = s * dist - camera_height
    details = {"plane_vggt": [*n.tolist(), float(d)], "camera_distance_vggt_median": med}
    if plane_inlier_rms is not None:
        details["plane_inlier_rms_m"] = float(plane_inlier_rms * s)
    return MetricFit(M, "camera_height", float(s), float(np.sqrt(np.mean(err ** 2))), float(np.abs(err).max()),
                     details)


class GroundPlaneError(vggt.PredictionsError):
    """Camera-height scale impossible for this predictions file: too few confident points in the lower image rows,
    or only collinear ones (``field`` "depth"); no level plane among them holding enough of them, or a plane the
    cameras do not stand over (``field`` "(camera height)"). The hint says what to do instead."""


#: What to do instead, for each way the camera-height fit fails.
_GROUND_HINTS = {
    "depth": "the ground is found among the confident pixels of the lower 40 % of each image: lower the "
             "Confidence Percentile, or give the scale as a factor or a metric trajectory",
    "(camera height)": "the road must be visible in the lower part of the images, under cameras looking ahead; "
                       "otherwise give the scale as a factor or a metric trajectory",
}


def camera_height_fit(pred: vggt.VGGTPredictions, camera_height: float,
                      confidence_percentile: float = point_cloud.CONFIDENCE_PERCENTILE, seed: int = 0) -> MetricFit:
    """(c) in full: metric ``vggt_to_world`` from a known camera height (metres) over the road of ``pred``.

    Ground candidates (``point_cloud.ground_candidates``: confident pixels of the lower 40 % of each image, at most
    200,000, seeded) → ``fits.fit_ground_plane`` (seeded RANSAC within 30° of the cameras' up axis, inliers
    closer than 1 % of the median candidate distance, refined by least squares) → ``vggt_to_world_by_camera_height``
    (scale = height / median camera-to-plane distance; the road becomes z = 0). ``details`` adds the plane fit's
    ``inliers``, ``candidates``, ``nonfinite_candidates``, ``inlier_rms_vggt``, ``tilt_deg``, ``threshold_vggt``
    (VGGT units) to the fit's own (``plane_inlier_rms_m`` among them). Raises ``GroundPlaneError`` naming
    ``pred.path``.
    """
    if not (np.isfinite(camera_height) and camera_height > 0):
        raise GroundPlaneError(pred.path, "(camera height)", f"the camera height must be a positive number of "
                                                             f"metres, got {camera_height}",
                               hint="give the camera's height over the road in metres, such as 1.6")
    pts = point_cloud.ground_candidates(pred, confidence_percentile, seed=seed)
    try:
        g = fits.fit_ground_plane(pts, pred.world_to_camera, seed=seed)
    except fits.PlaneFitError as e:
        key = "depth" if e.reason in ("too_few", "degenerate") else "(camera height)"
        raise GroundPlaneError(pred.path, key, f"no road plane for the camera-height scale: {e}",
                               hint=_GROUND_HINTS[key]) from None
    try:
        fit = vggt_to_world_by_camera_height(g.plane, pred.world_to_camera, camera_height,
                                             plane_inlier_rms=g.inlier_rms, path=pred.path)
    except errors.InputError as e:  # cameras on the plane or looking straight down at it: same error type here
        key = "(camera height)" if e.field == "(file)" else e.field
        raise GroundPlaneError(pred.path, key, e.message, hint=e.hint or _GROUND_HINTS["(camera height)"]) \
            from None
    fit.details.update({"inliers": g.num_inliers, "candidates": g.candidates, "nonfinite_candidates": g.nonfinite,
                        "inlier_rms_vggt": g.inlier_rms, "tilt_deg": g.tilt_deg, "threshold_vggt": g.threshold})
    return fit
