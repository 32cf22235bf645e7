"""Camera conventions: rigid transforms and poses, OpenCV pinhole <-> Blender camera and render settings.

Camera paths (heading, lateral shifts) are in ``core.geometry.trajectory``; similarity transforms and their fits in
``core.geometry.similarity``.

Conventions (docs/design.md §3), stated once here and assumed by every module that
takes cameras:

* World: Blender's, right-handed, Z up, metres.
* OpenCV camera: x right, y down, z forward. ``world_to_camera`` is a 4x4 rigid transform taking world
  points to camera coordinates. ``K`` is 3x3 in pixels for a stated resolution (W, H).
* Pixels: pixel (u, v) covers [u, u+1) x [v, v+1); its centre is (u + 0.5, v + 0.5) in the coordinates ``K``
  maps to, so a centred principal point is (W/2, H/2). Rows go down.
* Blender camera object: looks down its local -Z with +Y up, so
  ``matrix_world = inverse(world_to_camera) @ diag(1, -1, -1, 1)``.
* All math is float64. Rigid inverses are taken in closed form (R^T, -R^T t), which keeps round trips exact to
  ~1e-12 relative even 1e5 m from the origin.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Maps OpenCV camera axes to Blender camera axes (and back: it is its own inverse).
OPENCV_TO_BLENDER_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])
#: p_zup = Y_UP_TO_Z_UP @ p for Y-up files (glTF, OBJ): (x, y, z) -> (x, -z, y), a +90° turn about x, what Blender's
#: glTF importer does; the mesh-car import and the glTF splat reader both stand files up with it.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


#: A camera's intrinsics K (``intrinsics_problem``): every entry at most this in size (pixels). Checked against an
#: image's size (a training clip's poses.npz, whose frames are resized for training up to MAX_SIDE): focal lengths
#: at most MAX_FOCAL_RATIO image sizes (a field of view of 0.06°: no camera), the principal point at most
#: PRINCIPAL_POINT_MARGIN image sizes outside the image; so a K resized to any job size stays within MAX_K.
MAX_K = 1e8
MAX_FOCAL_RATIO = 1000.0
#: the focal length's lower bound, as a share of the image size: fx = W / 1000 is a 179.9° field of view
MIN_FOCAL_RATIO = 1.0 / MAX_FOCAL_RATIO
PRINCIPAL_POINT_MARGIN = 1.0

def intrinsics_problem(K: np.ndarray, size: tuple[int, int] | None = None) -> str | None:
    """Why ``K`` (3, 3) is not usable intrinsics — ours: [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in pixels, finite,
    fx, fy > 0, every entry at most ``MAX_K`` in size — or None. With the image's ``size`` (W, H) also fx between
    ``MIN_FOCAL_RATIO`` W and ``MAX_FOCAL_RATIO`` W, fy between as many H, and (cx, cy) at most ``PRINCIPAL_POINT_MARGIN`` image sizes
    outside the image. A job's ``frames[i].K``, a rig camera's K (``core.rig``) and a training clip's ``poses.npz`` K are checked by
    it."""
    K = np.asarray(K, np.float64)
    shape = f"expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 (pixels, at most {MAX_K:g})"
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or not (K[0, 0] > 0 and K[1, 1] > 0) or \
            np.any(K[2] != [0, 0, 1]) or K[1, 0] != 0 or np.abs(K).max() > MAX_K:
        return shape
    if size is None:
        return None
    W, H = float(size[0]), float(size[1])
    if K[0, 0] > MAX_FOCAL_RATIO * W or K[1, 1] > MAX_FOCAL_RATIO * H:
        return (f"fx, fy = {K[0, 0]:g}, {K[1, 1]:g} px: more than {MAX_FOCAL_RATIO:g} times the image's "
                f"{W:g} x {H:g} px (a field of view no camera has)")
    if K[0, 0] < MIN_FOCAL_RATIO * W or K[1, 1] < MIN_FOCAL_RATIO * H:
        return (f"fx, fy = {K[0, 0]:g}, {K[1, 1]:g} px: less than 1/{MAX_FOCAL_RATIO:g} of the image's "
                f"{W:g} x {H:g} px (a field of view of 180° or more, which no pinhole camera has)")
    m = PRINCIPAL_POINT_MARGIN
    if not (-m * W <= K[0, 2] <= (1 + m) * W and -m * H <= K[1, 2] <= (1 + m) * H):
        return (f"the principal point (cx, cy) = ({K[0, 2]:g}, {K[1, 2]:g}) px lies more than {m:g} image size "
                f"outside the {W:g} x {H:g} px image (fx = {K[0, 0]:g})")
    return None


# --------------------------------------------------------------------------------------------------------------
# Rigid transforms and camera poses
# --------------------------------------------------------------------------------------------------------------

def as_matrix4(m: np.ndarray, name: str = "matrix") -> np.ndarray:
    """Return ``m`` as float64 (..., 4, 4); a (..., 3, 4) matrix gets the row [0, 0, 0, 1] appended."""
    m = np.asarray(m, dtype=np.float64)
    if m.ndim < 2 or m.shape[-1] != 4 or m.shape[-2] not in (3, 4):
        raise ValueError(f"{name}: expected shape (..., 3, 4) or (..., 4, 4), got {m.shape}")
    if m.shape[-2] == 3:
        bottom = np.zeros(m.shape[:-2] + (1, 4))
        bottom[..., 0, 3] = 1.0
        m = np.concatenate([m, bottom], axis=-2)
    return m


def rigid_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4) in closed form: [R t]^-1 = [R^T, -R^T t]."""
    T = as_matrix4(T)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def rigid_problem(T: np.ndarray, tolerance: float = 1e-3, name: str = "extrinsic", what: str = "frame") -> tuple[int,
                  str] | None:
    """(index, sentence) of the first finite matrix of ``T`` (N, 4, 4) that is not a rotation + translation
    (|R^T R - I| > ``tolerance``, a reflection, or a last row other than [0, 0, 0, 1]); None if all are. The
    sentence calls the matrices ``what`` ("frame 3 is not ...") and the array ``name``. Camera placement inverts
    these matrices, so readers of pose files refuse a singular one with this sentence (naming their file and
    key) rather than fail in a solver."""
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


def orthonormalize(world_to_camera: np.ndarray) -> np.ndarray:
    """Replace each rotation block by the nearest rotation (SVD), keeping the camera *centre* where it was.

    Rotations stored in float32 (VGGT's) are orthonormal only to ~1e-7; with translations of 1e5 m that is
    centimetres of error in every closed-form inverse. Projecting onto SO(3) once, in float64, makes all later
    math exact. The centre -R^-1 t is preserved, which is what a camera path means.
    """
    T = as_matrix4(world_to_camera).copy()
    R = T[..., :3, :3]
    centre = -np.einsum("...ij,...j->...i", np.linalg.inv(R), T[..., :3, 3])
    U, _, Vt = np.linalg.svd(R)
    fix = np.ones(R.shape[:-2] + (3,))
    fix[..., 2] = np.sign(np.linalg.det(U @ Vt))
    Rn = (U * fix[..., None, :]) @ Vt
    T[..., :3, :3] = Rn
    T[..., :3, 3] = -np.einsum("...ij,...j->...i", Rn, centre)
    return T


def camera_centers(world_to_camera: np.ndarray) -> np.ndarray:
    """Camera centres in world coordinates, (..., 3): c = -R^T t."""
    T = as_matrix4(world_to_camera)
    return -np.einsum("...ji,...j->...i", T[..., :3, :3], T[..., :3, 3])


def blender_matrix_world(world_to_camera: np.ndarray) -> np.ndarray:
    """Blender camera ``matrix_world`` (..., 4, 4) for OpenCV ``world_to_camera`` (..., 4, 4)."""
    return rigid_inverse(world_to_camera) @ OPENCV_TO_BLENDER_CAMERA


def world_to_camera_from_blender(matrix_world: np.ndarray) -> np.ndarray:
    """OpenCV ``world_to_camera`` for a Blender camera's ``matrix_world`` (unit scale, no shear)."""
    M = as_matrix4(matrix_world, "matrix_world")
    R = M[..., :3, :3]
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() if R.size else 0.0
    if err > 1e-5:
        raise ValueError(f"matrix_world is not a rigid transform (|R^T R - I| = {err:.2e}); "
                         "apply the camera's scale before exporting")
    return OPENCV_TO_BLENDER_CAMERA @ rigid_inverse(M)


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), (..., 4), of rotation matrices (..., 3, 3); w >= 0.

    Shepperd's method: picks the largest of 4w², 4x², 4y², 4z² as the pivot so no branch divides by a small
    number (exact to ~1e-16 for any rotation, including 180° turns).
    """
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    pivot = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for k in range(4):
        sel = pivot == k
        if not sel.any():
            continue
        a = m[sel]
        if k == 0:
            s = np.sqrt(1.0 + tr[sel]) * 2.0
            q[sel] = np.stack([0.25 * s, (a[:, 2, 1] - a[:, 1, 2]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s,
                               (a[:, 1, 0] - a[:, 0, 1]) / s], axis=1)
        elif k == 1:
            s = np.sqrt(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2]) * 2.0
            q[sel] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, 0.25 * s, (a[:, 0, 1] + a[:, 1, 0]) / s,
                               (a[:, 0, 2] + a[:, 2, 0]) / s], axis=1)
        elif k == 2:
            s = np.sqrt(1.0 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2]) * 2.0
            q[sel] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 0, 1] + a[:, 1, 0]) / s, 0.25 * s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s], axis=1)
        else:
            s = np.sqrt(1.0 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1]) * 2.0
            q[sel] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(R.shape[:-2] + (4,))


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (w, x, y, z), (..., 4); normalised first."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("quaternion of zero length")
    w, x, y, z = np.moveaxis(q / n, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 so consecutive quaternions have a non-negative dot product.

    q and -q are the same rotation, but interpolating keyframes between them turns the long way round; a camera
    path keyed with continuous signs never flips between frames.
    """
    q = np.array(q, dtype=np.float64, copy=True)
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0.0:
            q[i] = -q[i]
    return q


# --------------------------------------------------------------------------------------------------------------
# Intrinsics <-> Blender camera data
# --------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BlenderCamera:
    """The Blender camera and render settings that reproduce one pinhole ``K`` exactly.

    ``lens`` and the sensor sizes are in millimetres; shifts are fractions of the sensor-fit side in pixels
    (Blender's own definition); ``pixel_aspect_*`` are the scene's render pixel aspect (both >= 1).
    """

    lens: float
    sensor_width: float
    sensor_height: float
    sensor_fit: str
    shift_x: float
    shift_y: float
    resolution_x: int
    resolution_y: int
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0


def _fit_geometry(sensor_fit: str, width: int, height: int, aspx: float, aspy: float,
                  sensor_width: float, sensor_height: float):
    """Blender's view-plane rule: (resolved fit, sensor size in mm, pixels across the sensor side, ycor).

    Mirrors ``BKE_camera_params_compute_viewplane``: AUTO picks HORIZONTAL when aspx·W >= aspy·H, but the sensor
    *size* used is the width unless the fit setting itself is VERTICAL; ``viewfac`` is W for a horizontal fit and
    ycor·H for a vertical one, where ycor = aspy / aspx.
    """
    if sensor_fit not in SENSOR_FITS:
        raise ValueError(f"sensor_fit must be one of {SENSOR_FITS}, got {sensor_fit!r}")
    ycor = aspy / aspx
    resolved = sensor_fit
    if sensor_fit == "AUTO":
        resolved = "HORIZONTAL" if aspx * width >= aspy * height else "VERTICAL"
    sensor = sensor_height if sensor_fit == "VERTICAL" else sensor_width
    viewfac = float(width) if resolved == "HORIZONTAL" else ycor * float(height)
    return resolved, sensor, viewfac, ycor


def _check_resolution(width, height):
    if int(width) != width or int(height) != height or width < 1 or height < 1:
        raise ValueError(f"resolution must be positive integers, got ({width}, {height})")


def blender_camera_from_K(K: np.ndarray, width: int, height: int, sensor_width: float = 36.0,
                          sensor_fit: str = "HORIZONTAL", sensor_height: float | None = None) -> BlenderCamera:
    """Blender camera settings for pinhole ``K`` (pixels, our pixel-centre convention) at ``width`` x ``height``.

    fx != fy is expressed with the render pixel aspect (Blender's only way), so it is exact too. Raises
    ValueError for skewed, non-finite or non-positive intrinsics.
    """
    _check_resolution(width, height)
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K must be a finite 3x3 matrix, got shape {K.shape}")
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    if fx <= 0 or fy <= 0:
        raise ValueError(f"K must have positive focal lengths, got fx={fx}, fy={fy}")
    if abs(skew) > 1e-9 * fx or K[1, 0] != 0 or np.any(K[2] != [0.0, 0.0, 1.0]):
        raise ValueError("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (Blender cameras have no skew)")
    if sensor_height is None:
        sensor_height = sensor_width * height / width
    ratio = fx / fy  # = ycor = aspy / aspx
    aspx, aspy = (1.0, ratio) if ratio >= 1.0 else (1.0 / ratio, 1.0)
    _, sensor, viewfac, ycor = _fit_geometry(sensor_fit, width, height, aspx, aspy, sensor_width, sensor_height)
    lens = fx * sensor / viewfac
    shift_x = (width / 2.0 - cx) / viewfac
    shift_y = (cy - height / 2.0) * ycor / viewfac
    return BlenderCamera(lens=lens, sensor_width=float(sensor_width), sensor_height=float(sensor_height),
                         sensor_fit=sensor_fit, shift_x=shift_x, shift_y=shift_y, resolution_x=int(width),
                         resolution_y=int(height), pixel_aspect_x=aspx, pixel_aspect_y=aspy)


def K_from_blender_camera(cam: BlenderCamera) -> np.ndarray:
    """Pinhole ``K`` (pixels, pixel centres at +0.5) of Blender camera settings; inverse of blender_camera_from_K."""
    W, H = cam.resolution_x, cam.resolution_y
    _check_resolution(W, H)
    _, sensor, viewfac, ycor = _fit_geometry(cam.sensor_fit, W, H, cam.pixel_aspect_x, cam.pixel_aspect_y,
                                            cam.sensor_width, cam.sensor_height)
    fx = cam.lens * viewfac / sensor
    fy = fx / ycor
    cx = W / 2.0 - cam.shift_x * viewfac
    cy = H / 2.0 + cam.shift_y * viewfac / ycor
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def project(K: np.ndarray, world_to_camera: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (N, 3) to pixel coordinates (N, 2) and camera depth z (N,), all float64.

    The world->camera step is done in float64 before anything else (large coordinates stay exact). Points at or
    behind the camera get depth <= 0 and non-finite or meaningless pixel coordinates: callers mask on depth.
    """
    T = as_matrix4(world_to_camera, "world_to_camera")
    X = np.asarray(points, dtype=np.float64)
    cam = X @ T[:3, :3].T + T[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam[:, :2] / z[:, None]) @ np.asarray(K, np.float64)[:2, :2].T + np.asarray(K, np.float64)[:2, 2]
    return uv, z

