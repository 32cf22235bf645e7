"""Similarity transforms between worlds (x_new = s R x_old + t): 4x4 matrices, fits, and their action on cameras.

``vggt_to_world`` (VGGT's world in VGGT units -> Blender's world in metres) is one of these. Fits: Umeyama on
point sets, and a camera-path fit that uses orientations as well as centres (a straight drive then still fixes
the roll). Everything is float64 and centred before it is multiplied, so 1e5 m coordinates fit to ~1e-10.

Argument errors (shapes, collinear points, opposite paths) raise ValueError: callers that fit user data (a
trajectory file) turn them into an InputError naming the file (``core.geometry.metric_scale``).

No bpy, no torch: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import cameras


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

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points, np.float64) @ self.rotation.T + self.translation


def similarity_matrix(scale: float, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 matrix of x -> scale · R x + t."""
    M = np.eye(4)
    M[:3, :3] = scale * np.asarray(rotation, np.float64)
    M[:3, 3] = translation
    return M


def decompose_similarity(M: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(scale, R, t) of a 4x4 similarity; raises if it is not one (shear, reflection, non-uniform scale)."""
    M = cameras.as_matrix4(M, "similarity")
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


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> SimilarityFit:
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


def fit_similarity_to_cameras(src_world_to_camera: np.ndarray, dst_world_to_camera: np.ndarray) -> SimilarityFit:
    """Similarity taking the world of one camera path onto another's, using orientations as well as centres.

    Centres alone cannot fix the roll about a straight drive, so the rotation maximises the agreement of the
    camera orientations (Σ R_dst_i R_src_i^T, a chordal rotation average) plus the normalised centre covariance;
    the scale and translation then follow from the centres with that rotation. The camera frames must be the same rigid
    frames (for example OpenCV in both). The residual is over centres (dst units) and orientations (degrees).
    """
    A = cameras.as_matrix4(src_world_to_camera, "src world_to_camera")
    B = cameras.as_matrix4(dst_world_to_camera, "dst world_to_camera")
    if A.shape != B.shape or A.ndim != 3:
        raise ValueError(f"camera paths must both be (N, 4, 4), got {A.shape} and {B.shape}")
    if len(A) < 1:
        raise ValueError("need at least one camera")
    x, y = cameras.camera_centers(A), cameras.camera_centers(B)
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


def transform_world_to_camera(world_to_camera: np.ndarray, old_to_world: np.ndarray) -> np.ndarray:
    """Re-express cameras of an old world in a new one, given ``old_to_world`` (a similarity, 4x4).

    With x_new = s R x_old + t, metric camera coordinates are s · (old camera coordinates), so the rigid
    world_to_camera in the new world is [R_c R^T | s t_c - R_c R^T t]. Works on (..., 4, 4).
    """
    T = cameras.as_matrix4(world_to_camera, "world_to_camera")
    s, R, t = decompose_similarity(old_to_world)
    Rc = T[..., :3, :3] @ R.T
    out = np.zeros_like(T)
    out[..., :3, :3] = Rc
    out[..., :3, 3] = s * T[..., :3, 3] - np.einsum("...ij,j->...i", Rc, t)
    out[..., 3, 3] = 1.0
    return out
