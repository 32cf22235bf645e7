"""Camera conventions: OpenCV pinhole <-> Blender camera, trajectories, similarity fits.

Conventions (DESIGN §3), stated once here and assumed by every function below:

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

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


# --------------------------------------------------------------------------------------------------------------
# Rigid transforms and camera poses
# --------------------------------------------------------------------------------------------------------------

def as_matrix4(m, name: str = "matrix") -> np.ndarray:
    """Return ``m`` as float64 (..., 4, 4); a (..., 3, 4) matrix gets the row [0, 0, 0, 1] appended."""
    m = np.asarray(m, dtype=np.float64)
    if m.ndim < 2 or m.shape[-1] != 4 or m.shape[-2] not in (3, 4):
        raise ValueError(f"{name}: expected shape (..., 3, 4) or (..., 4, 4), got {m.shape}")
    if m.shape[-2] == 3:
        bottom = np.zeros(m.shape[:-2] + (1, 4))
        bottom[..., 0, 3] = 1.0
        m = np.concatenate([m, bottom], axis=-2)
    return m


def rigid_inverse(T) -> np.ndarray:
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


def orthonormalize(world_to_camera) -> np.ndarray:
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


def camera_centers(world_to_camera) -> np.ndarray:
    """Camera centres in world coordinates, (..., 3): c = -R^T t."""
    T = as_matrix4(world_to_camera)
    return -np.einsum("...ji,...j->...i", T[..., :3, :3], T[..., :3, 3])


def blender_matrix_world(world_to_camera) -> np.ndarray:
    """Blender camera ``matrix_world`` (..., 4, 4) for OpenCV ``world_to_camera`` (..., 4, 4)."""
    return rigid_inverse(world_to_camera) @ OPENCV_TO_BLENDER_CAMERA


def world_to_camera_from_blender(matrix_world) -> np.ndarray:
    """OpenCV ``world_to_camera`` for a Blender camera's ``matrix_world`` (unit scale, no shear)."""
    M = as_matrix4(matrix_world, "matrix_world")
    R = M[..., :3, :3]
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() if R.size else 0.0
    if err > 1e-5:
        raise ValueError(f"matrix_world is not a rigid transform (|R^T R - I| = {err:.2e}); "
                         "apply the camera's scale before exporting")
    return OPENCV_TO_BLENDER_CAMERA @ rigid_inverse(M)


def rotation_to_quaternion(R) -> np.ndarray:
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


def quaternion_to_rotation(q) -> np.ndarray:
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


def continuous_quaternions(q) -> np.ndarray:
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


def blender_camera_from_K(K, width: int, height: int, sensor_width: float = 36.0,
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


def project(K, world_to_camera, points):
    """Project world points (N, 3) to pixel coordinates (N, 2) and camera depth z (N,), all float64.

    The world->camera step is done in float64 before anything else (DESIGN §3, large coordinates). Points at or
    behind the camera get depth <= 0 and non-finite or meaningless pixel coordinates: callers mask on depth.
    """
    T = as_matrix4(world_to_camera, "world_to_camera")
    X = np.asarray(points, dtype=np.float64)
    cam = X @ T[:3, :3].T + T[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam[:, :2] / z[:, None]) @ np.asarray(K, np.float64)[:2, :2].T + np.asarray(K, np.float64)[:2, 2]
    return uv, z


# --------------------------------------------------------------------------------------------------------------
# Trajectories: heading and lateral shift
# --------------------------------------------------------------------------------------------------------------

def _unit(v, axis=-1):
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def heading_directions(centers, window_m: float = 1.0, up=(0.0, 0.0, 1.0), fallback=None) -> np.ndarray:
    """Unit direction of travel per frame, (N, 3), horizontal (perpendicular to ``up``).

    The heading at frame i is the chord between the positions half a window of *travelled distance* before and
    after it (arc length, not frame count). A vehicle that stops keeps the heading it had: its positions during
    the stop share one arc length, so the chord still spans the motion before and after. Where the whole path is
    shorter than a hair (a parked camera), ``fallback`` (N, 3) or (3,) is used, typically the camera's forward
    axis; without one a ValueError explains why.
    """
    c = np.asarray(centers, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0:
        raise ValueError(f"centers must be (N, 3), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("centers contain NaN or inf")
    up = _unit(np.asarray(up, dtype=np.float64))
    rel = c - c[0]  # relative to the first centre: differences of 1e5 m coordinates stay exact
    horiz = rel - np.outer(rel @ up, up)
    steps = np.linalg.norm(np.diff(horiz, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    total = s[-1]
    if total < 1e-6:
        if fallback is None:
            raise ValueError("the trajectory does not move, so it has no direction of travel; pass the camera "
                             "forward axis as fallback")
        f = np.broadcast_to(np.asarray(fallback, np.float64), c.shape)
        f = f - np.outer(f @ up, up)
        return _unit(f)
    half = min(window_m / 2.0, total / 2.0)
    ahead = np.searchsorted(s, s + half, side="left").clip(0, len(s) - 1)
    behind = (np.searchsorted(s, s - half, side="right") - 1).clip(0, len(s) - 1)
    chord = horiz[ahead] - horiz[behind]
    return _unit(chord)


def left_directions(headings, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Unit vectors pointing to the driver's left: up x heading (right-handed world)."""
    up = _unit(np.asarray(up, dtype=np.float64))
    return _unit(np.cross(np.broadcast_to(up, np.shape(headings)), headings))


def shift_trajectory(world_to_camera, left_m: float = 0.0, up_m: float = 0.0, forward_m: float = 0.0,
                     window_m: float = 1.0, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Move each camera of a path by metres relative to the direction of travel; orientation is kept.

    ``left_m`` > 0 moves left, < 0 right; ``forward_m`` along the heading; ``up_m`` along ``up``. Returns the new
    world_to_camera (N, 4, 4). Parked frames keep the heading they had (see heading_directions); a path that never
    moves uses the cameras' forward axes.
    """
    T = as_matrix4(world_to_camera, "world_to_camera")
    c = camera_centers(T)
    forward_axes = T[:, 2, :3]  # camera +z in world = third row of R
    h = heading_directions(c, window_m=window_m, up=up, fallback=forward_axes)
    upv = _unit(np.asarray(up, dtype=np.float64))
    offset = left_m * left_directions(h, upv) + forward_m * h + up_m * upv
    new_c = c + offset
    out = T.copy()
    out[:, :3, 3] = -np.einsum("nij,nj->ni", T[:, :3, :3], new_c)
    return out


# --------------------------------------------------------------------------------------------------------------
# Similarity fits
# --------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SimilarityFit:
    """dst ≈ scale · rotation @ src + translation, with the fit's RMS residual in dst units (metres)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    rms: float
    max_error: float
    rotation_rms_deg: float | None = None

    def matrix(self) -> np.ndarray:
        return similarity_matrix(self.scale, self.rotation, self.translation)

    def apply(self, points) -> np.ndarray:
        return self.scale * np.asarray(points, np.float64) @ self.rotation.T + self.translation


def similarity_matrix(scale: float, rotation, translation) -> np.ndarray:
    """4x4 matrix of x -> scale · R x + t."""
    M = np.eye(4)
    M[:3, :3] = scale * np.asarray(rotation, np.float64)
    M[:3, 3] = translation
    return M


def decompose_similarity(M):
    """(scale, R, t) of a 4x4 similarity; raises if it is not one (shear, reflection, non-uniform scale)."""
    M = as_matrix4(M, "similarity")
    A = M[:3, :3]
    s = np.cbrt(np.linalg.det(A))
    if not np.isfinite(s) or s <= 0:
        raise ValueError("similarity has a non-positive determinant (a reflection or a collapse)")
    R = A / s
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.any(M[3] != [0, 0, 0, 1]):
        raise ValueError("matrix is not a similarity (uniform scale · rotation + translation)")
    return float(s), R, M[:3, 3].copy()


def _rotation_from_covariance(H):
    """The rotation R maximising tr(R^T H) (Kabsch/Umeyama with the reflection guard)."""
    U, _, Vt = np.linalg.svd(H)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0
    return U @ D @ Vt


def umeyama(src, dst, with_scale: bool = True) -> SimilarityFit:
    """Least-squares similarity dst ≈ s R src + t (Umeyama 1991), for point sets (N, 3), N >= 3.

    Both sets are centred before the covariance is formed, so points 1e5 m from the origin fit to ~1e-10.
    Raises ValueError when the points are (nearly) collinear: the rotation about that line is undetermined.
    """
    x = np.asarray(src, np.float64)
    y = np.asarray(dst, np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"src and dst must both be (N, 3), got {x.shape} and {y.shape}")
    if len(x) < 3:
        raise ValueError(f"need at least 3 point pairs for a similarity fit, got {len(x)}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("point sets contain NaN or inf")
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    var_x = (xc ** 2).sum() / len(x)
    H = yc.T @ xc / len(x)
    sv = np.linalg.svd(xc, compute_uv=False)
    if var_x <= 0 or sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ValueError("points are (nearly) collinear or coincident: the rotation is undetermined "
                         "(give camera orientations too, or a path that turns)")
    R = _rotation_from_covariance(H)
    s = float(np.trace(R.T @ H) / var_x) if with_scale else 1.0
    t = my - s * R @ mx
    return _finish_fit(s, R, t, x, y)


def _finish_fit(s, R, t, x, y, rotation_rms_deg=None) -> SimilarityFit:
    err = np.linalg.norm(s * x @ R.T + t - y, axis=1)
    return SimilarityFit(scale=float(s), rotation=R, translation=t, rms=float(np.sqrt(np.mean(err ** 2))),
                         max_error=float(err.max()), rotation_rms_deg=rotation_rms_deg)


def fit_similarity_to_cameras(src_world_to_camera, dst_world_to_camera) -> SimilarityFit:
    """Similarity taking the world of one camera path onto another's, using orientations as well as centres.

    Centres alone cannot fix the roll about a straight drive, so the rotation maximises the agreement of the
    camera orientations (Σ R_dst_i R_src_i^T, a chordal rotation average) plus the normalised centre covariance; the scale and
    translation then follow from the centres with that rotation. The camera frames must be the same rigid frames
    (for example OpenCV in both). The residual is over centres (dst units) and orientations (degrees).
    """
    A = as_matrix4(src_world_to_camera, "src world_to_camera")
    B = as_matrix4(dst_world_to_camera, "dst world_to_camera")
    if A.shape != B.shape or A.ndim != 3:
        raise ValueError(f"camera paths must both be (N, 4, 4), got {A.shape} and {B.shape}")
    if len(A) < 1:
        raise ValueError("need at least one camera")
    x, y = camera_centers(A), camera_centers(B)
    # camera-to-world rotations: dst_c2w ≈ R · src_c2w  =>  H_rot = Σ dst_c2w src_c2w^T
    Ra = np.swapaxes(A[:, :3, :3], 1, 2)
    Rb = np.swapaxes(B[:, :3, :3], 1, 2)
    H = np.einsum("nij,nkj->ik", Rb, Ra) / len(A)
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    sx, sy = np.sqrt((xc ** 2).sum(1).mean()), np.sqrt((yc ** 2).sum(1).mean())
    if sx > 0 and sy > 0:
        H = H + (yc.T @ xc / len(x)) / (sx * sy)
    R = _rotation_from_covariance(H)
    if sx > 0:
        s = float(np.einsum("ni,ij,nj->", yc, R, xc) / (xc ** 2).sum())
    else:
        raise ValueError("all source cameras share one centre: the scale is undetermined")
    if s <= 0:
        raise ValueError("the two camera paths run in opposite directions (negative scale)")
    t = my - s * R @ mx
    rel = np.einsum("nji,jk,nkl->nil", Rb, R, Ra)  # Rb^T R Ra, identity for a perfect fit
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return _finish_fit(s, R, t, x, y, rotation_rms_deg=float(np.sqrt(np.mean(ang ** 2))))


def transform_world_to_camera(world_to_camera, world_from_old) -> np.ndarray:
    """Re-express cameras of an old world in a new one, given ``world_from_old`` (a similarity, 4x4).

    With x_new = s R x_old + t, metric camera coordinates are s · (old camera coordinates), so the rigid
    world_to_camera in the new world is [R_c R^T | s t_c - R_c R^T t]. Works on (..., 4, 4).
    """
    T = as_matrix4(world_to_camera, "world_to_camera")
    s, R, t = decompose_similarity(world_from_old)
    Rc = T[..., :3, :3] @ R.T
    out = np.zeros_like(T)
    out[..., :3, :3] = Rc
    out[..., :3, 3] = s * T[..., :3, 3] - np.einsum("...ij,j->...i", Rc, t)
    out[..., 3, 3] = 1.0
    return out
