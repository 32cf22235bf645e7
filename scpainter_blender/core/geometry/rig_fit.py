"""The rig of a multi-camera recording: each sensor's mounting pose (camera_to_ego) from the reconstruction, robustly.

Inputs: per VGGT frame its sensor and timestamp (``core.vggt.sensors.Sensors``) and its camera_to_world (4, 4) in the
import's world (Z up, metres; OpenCV camera axes), its K (ours). Output: a ``core.rig.Rig`` named ``"recording"``
(one camera per sensor, in the order of their first frames; no LiDAR) and per sensor how well the frames agree
with it (``SensorFit``).

**The ego path** (docs/design.md §4.5, §17). Ego frame per ``core.rig``: x forward, y left, z up, metres.

* When the sidecar gives the reference sensor's camera_to_ego (nuScenes' calibration), ego_to_world at each
  reference frame is camera_to_world · camera_to_ego⁻¹, exactly (``rig.ego_path``'s rule).
* Else it is built from the reference camera's motion. The ego z axis is the world's up (a level road) and its
  origin is on the world plane z = 0, the ground: the levelled road in camera-height mode; in the other scale modes
  that plane is whatever z = 0 is (the metric trajectory's, or the first camera's height in factor mode), so the
  mounting heights are relative to it. The heading is the camera's yaw minus a fixed mounting yaw δ, and the origin
  lies L metres behind the camera along the heading (its lateral offset is not observable: taken 0). δ and L come
  from the rule of a car's rear axle, which moves only along the heading (no side slip): the camera's horizontal
  velocity u and the yaw rate ω satisfy u · left(yaw − δ) = ω L at every frame; solved by least squares (linearised
  about the circular median of yaw − direction of travel, three passes, residuals beyond 3 robust sigmas left out).
  L needs turns: with less than ``MIN_TURN_DEG`` of yaw change, or a standard error above ``MAX_AXLE_STD_M``, L is 0
  (the origin below the reference camera) and the report says so.
* Between reference frames the ego pose is interpolated along the screw motion from one to the next (exact for a
  car on an arc), and extrapolated so up to half the median reference interval beyond the first and last one
  (with one reference frame, frames within ``ONE_FRAME_REACH_S`` take its pose); frames further out are not used.

**The estimate per sensor**: at each of its frames camera_to_ego = ego_to_world(t)⁻¹ · camera_to_world; the
translation's per-axis median and the rotations' chordal median (Weiszfeld on the 3×3 matrices, projected on SO(3))
start; frames deviating by more than 3 robust sigmas (1.4826 · the median deviation, at least
``TRANSLATION_FLOOR_M`` / ``ROTATION_FLOOR_DEG``) in either are outliers; the result is the inliers' mean
translation and chordal mean rotation. The spread is the inliers' deviation from it (median and 95th percentile,
metres and degrees). A sensor whose camera_to_ego the sidecar gives keeps it; its spread then measures how far the
reconstruction is from that calibration. K: the median of the sensor's frames' K (entry by entry), its spread the
largest |K_frame − K| of fx, fy, cx, cy (px); the resolution the predictions' (or the sidecar's, K scaled per axis).

No bpy, no torch: numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import rig as rig_mod
from ..errors import InputError
from ..vggt.sensors import Sensors
from . import cameras

#: A rig fitted from a recording is called so (``core.rig.Rig.name``; the preset name *Add Camera Rig* offers).
RIG_NAME = "recording"
TRANSLATION_FLOOR_M = 0.05
ROTATION_FLOOR_DEG = 0.5
OUTLIER_SIGMAS = 3.0
#: Yaw change of the reference camera below which the rear-axle offset L is not estimated (degrees).
MIN_TURN_DEG = 5.0
#: L's standard error above which it is not trusted (metres).
MAX_AXLE_STD_M = 0.25
#: With one reference frame, the other sensors' frames this close in time (s) share its ego pose (nuScenes' six
#: cameras of one sample fire within about 50 ms).
ONE_FRAME_REACH_S = 0.1
_MAD = 1.4826


@dataclass
class SensorFit:
    """How one sensor's frames agree with its rig camera: ``source`` ("sidecar": the sidecar's camera_to_ego, or
    "estimated"), ``frames`` (its VGGT frames), ``used`` (those with an ego pose), ``outliers`` (VGGT frame indices
    left out), ``translation_m`` and ``rotation_deg`` (median, 95th percentile) of the inliers' deviation,
    ``K_spread_px`` (median, max) of the frames' largest |K − median K| entry."""
    name: str
    source: str
    frames: int
    used: int
    outliers: list
    translation_m: tuple
    rotation_deg: tuple
    K_spread_px: tuple

    def to_json(self) -> dict:
        return {"source": self.source, "frames": self.frames, "used": self.used, "outliers": list(self.outliers),
                "translation_m": {"median": self.translation_m[0], "p95": self.translation_m[1]},
                "rotation_deg": {"median": self.rotation_deg[0], "p95": self.rotation_deg[1]},
                "K_spread_px": {"median": self.K_spread_px[0], "max": self.K_spread_px[1]}}

    def sentence(self) -> str:
        """One line for the import report."""
        out = f", {len(self.outliers)} outlier frames left out" if self.outliers else ""
        return (f"{self.name}: camera_to_ego {self.source} from {self.used} of {self.frames} frames{out}; spread "
                f"{self.translation_m[0]:.3g} m / {self.rotation_deg[0]:.3g}° median, {self.translation_m[1]:.3g} m / "
                f"{self.rotation_deg[1]:.3g}° p95; K within {self.K_spread_px[1]:.3g} px")


@dataclass
class RigFit:
    """``rig`` (``Rig`` "recording"), ``reference`` (the sensor of the ego path), ``ego_to_world`` (n, 4, 4) at the
    reference frames, ``sensors`` {name: SensorFit} in rig order, ``yaw_offset_deg`` / ``rear_axle_m`` /
    ``rear_axle_std_m`` (the estimated ego path's δ, L and L's standard error; None when the sidecar gave the
    reference's pose, or L was not estimated), ``notes`` (sentences)."""
    rig: rig_mod.Rig
    reference: str
    ego_to_world: np.ndarray
    sensors: dict
    yaw_offset_deg: float | None = None
    rear_axle_m: float | None = None
    rear_axle_std_m: float | None = None
    notes: list = field(default_factory=list)

    def to_json(self) -> dict:
        return {"name": self.rig.name, "reference": self.reference, "yaw_offset_deg": self.yaw_offset_deg,
                "rear_axle_m": self.rear_axle_m, "rear_axle_std_m": self.rear_axle_std_m, "notes": list(self.notes),
                "sensors": {n: s.to_json() for n, s in self.sensors.items()}}


def _rz(theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(np.shape(theta) + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _derivative(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """d x / d t per sample (central differences, one-sided at the ends); x (n, ...) , t (n,) seconds."""
    if len(x) < 2:
        return np.zeros_like(x)
    i = np.arange(len(x))
    a, b = np.maximum(i - 1, 0), np.minimum(i + 1, len(x) - 1)
    dt = (t[b] - t[a]).reshape((-1,) + (1,) * (x.ndim - 1))
    return (x[b] - x[a]) / dt


def _robust_lstsq(A: np.ndarray, b: np.ndarray) -> tuple:
    """(x, kept rows, residual sigma): least squares with rows beyond 3 robust sigmas left out (two passes)."""
    keep = np.ones(len(b), bool)
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    for _ in range(2):
        r = A @ x - b
        sigma = _MAD * np.median(np.abs(r[keep])) if keep.any() else 0.0
        keep = np.abs(r) <= max(OUTLIER_SIGMAS * sigma, 1e-12 + 1e-9 * np.abs(b).max(initial=0.0))
        if keep.sum() < A.shape[1]:
            keep[:] = True
        x = np.linalg.lstsq(A[keep], b[keep], rcond=None)[0]
    r = A[keep] @ x - b[keep]
    dof = max(int(keep.sum()) - A.shape[1], 1)
    return x, keep, float(np.sqrt(r @ r / dof))


def ego_path_from_camera(camera_to_world: np.ndarray, t_s: np.ndarray, ground_z: float = 0.0) -> tuple:
    """(ego_to_world (n, 4, 4), δ radians, L metres or None, L's standard error m or None, notes) of a reference camera's poses ``camera_to_world``
    (n, 4, 4) at times ``t_s`` (n,) seconds: the module's rule (x = heading = camera yaw − δ, z up, origin on
    z = ``ground_z`` L metres behind the camera)."""
    T = np.asarray(camera_to_world, np.float64)
    n = len(T)
    c = T[:, :3, 3]
    fwd = T[:, :3, 2]
    psi = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
    notes = []
    if np.linalg.norm(fwd[:, :2], axis=1).min() < 0.1:
        notes.append("the reference camera looks almost straight up or down: its yaw, and the ego heading, are "
                     "poorly defined")
    u = _derivative(c[:, :2], t_s)
    omega = _derivative(psi, t_s)
    speed = np.linalg.norm(u, axis=1)
    moving = speed > 0.2 * np.median(speed) if n > 1 and np.median(speed) > 0 else np.zeros(n, bool)
    delta, L, L_std = 0.0, None, None
    if moving.sum() >= 2:
        phi = np.arctan2(u[:, 1], u[:, 0])
        d = _wrap(psi - phi)[moving]
        d0 = np.arctan2(np.sin(d).mean(), np.cos(d).mean())
        delta = float(d0 + np.median(_wrap(d - d0)))   # the circular median's start
        um, om, pm = u[moving], omega[moving], psi[moving]
        turn = np.degrees(np.ptp(psi))
        for _ in range(3):
            th = pm - delta
            x_hat = np.stack([np.cos(th), np.sin(th)], 1)
            y_hat = np.stack([-np.sin(th), np.cos(th)], 1)
            along, across = (um * x_hat).sum(1), (um * y_hat).sum(1)
            with_axle = turn >= MIN_TURN_DEG and len(um) >= 4
            A = np.stack([along, -om], 1) if with_axle else along[:, None]
            x, keep, sigma = _robust_lstsq(A, -across)
            delta += float(x[0])
        L = None
        if with_axle:
            cov = sigma ** 2 * np.linalg.pinv(A[keep].T @ A[keep])
            std = float(np.sqrt(max(cov[1, 1], 0.0)))
            if std <= MAX_AXLE_STD_M:
                L, L_std = float(x[1]), std
            else:
                notes.append(f"the rear axle's offset behind the reference camera is uncertain (±{std:.2g} m): the "
                             "ego origin is taken below the reference camera")
        else:
            notes.append(f"the drive turns by {turn:.3g}° only (the rear axle needs ≥ {MIN_TURN_DEG:g}°): the ego "
                         "origin is taken below the reference camera")
        if L is None:   # δ alone, as a straight drive determines it
            th = pm - delta
            along = (um * np.stack([np.cos(th), np.sin(th)], 1)).sum(1)
            across = (um * np.stack([-np.sin(th), np.cos(th)], 1)).sum(1)
            delta += float(_robust_lstsq(along[:, None], -across)[0][0])
    else:
        notes.append("the reference camera does not move: the ego heading is its own yaw and the ego origin lies "
                     "below it")
    theta = psi - delta
    E = np.tile(np.eye(4), (n, 1, 1))
    E[:, :3, :3] = _rz(theta)
    E[:, 0, 3] = c[:, 0] - (L or 0.0) * np.cos(theta)
    E[:, 1, 3] = c[:, 1] - (L or 0.0) * np.sin(theta)
    E[:, 2, 3] = ground_z
    return E, float(_wrap(delta)), L, L_std, notes


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _screw(T0: np.ndarray, T1: np.ndarray, a: float) -> np.ndarray:
    """The pose a fraction ``a`` (any real: < 0 and > 1 extrapolate) along the screw motion from rigid ``T0`` to
    ``T1``: T0 · exp(a · log(T0⁻¹ T1)). A car on an arc (constant curvature and speed) moves exactly so; linear
    interpolation would cut the arc's chord (8 cm in the middle of a 4 m step on a 25 m radius)."""
    rel = cameras.rigid_inverse(T0) @ T1
    R, t = rel[:3, :3], rel[:3, 3]
    theta = float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    out = np.eye(4)
    if theta < 1e-9:
        out[:3, 3] = a * t
        return T0 @ out
    # the unit axis from the skew part (theta < pi: a vehicle turns far less between two frames)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * np.sin(theta))
    Kx = _skew(axis / np.linalg.norm(axis))
    V1 = np.eye(3) + (1 - np.cos(theta)) / theta * Kx + (theta - np.sin(theta)) / theta * Kx @ Kx
    u = np.linalg.solve(V1, t)
    at = a * theta
    out[:3, :3] = np.eye(3) + np.sin(at) * Kx + (1 - np.cos(at)) * Kx @ Kx
    out[:3, 3] = (a * np.eye(3) + (1 - np.cos(at)) / theta * Kx + (at - np.sin(at)) / theta * Kx @ Kx) @ u
    return T0 @ out


def interpolate_poses(T: np.ndarray, t_ref: np.ndarray, t: np.ndarray, reach: float) -> tuple:
    """(poses (m, 4, 4), inside (m,) bool): rigid poses ``T`` (n, 4, 4) at increasing times ``t_ref`` interpolated
    at ``t`` along the screw motion between the two around it (``_screw``), extrapolated from the end intervals up
    to ``reach`` beyond them; ``inside`` False (identity) further out."""
    T = np.asarray(T, np.float64)
    t_ref, t = np.asarray(t_ref, np.float64), np.asarray(t, np.float64)
    out = np.tile(np.eye(4), (len(t), 1, 1))
    inside = (t >= t_ref[0] - reach) & (t <= t_ref[-1] + reach)
    if len(t_ref) == 1:
        out[inside] = T[0]
        return out, inside
    k = np.searchsorted(t_ref, t).clip(1, len(t_ref) - 1)
    a = (t - t_ref[k - 1]) / (t_ref[k] - t_ref[k - 1])
    for j in np.flatnonzero(inside):
        out[j] = _screw(T[k[j] - 1], T[k[j]], float(a[j]))
    return out, inside


def _project_rotation(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _chordal_median(R: np.ndarray, iterations: int = 30) -> np.ndarray:
    """The rotation nearest the chordal (Frobenius) geometric median of rotations ``R`` (n, 3, 3): Weiszfeld."""
    x = R.mean(0)
    for _ in range(iterations):
        d = np.linalg.norm((R - x).reshape(len(R), 9), axis=1)
        w = 1.0 / np.maximum(d, 1e-12)
        x = (w[:, None, None] * R).sum(0) / w.sum()
    return _project_rotation(x)


def _deviations(T: np.ndarray, t0: np.ndarray, R0: np.ndarray) -> tuple:
    dt = np.linalg.norm(T[:, :3, 3] - t0, axis=1)
    cos = (np.einsum("ij,nij->n", R0, T[:, :3, :3]) - 1.0) / 2.0   # trace(R0ᵀ R) = 1 + 2 cos(angle)
    return dt, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def robust_pose_mean(T: np.ndarray) -> tuple:
    """(mean (4, 4), inliers (n,) bool, translation deviations m, rotation deviations deg) of rigid poses ``T``
    (n, 4, 4): the module's estimate (median start, 3-sigma outliers out, inliers' mean; deviations of every pose
    from the result)."""
    T = np.asarray(T, np.float64)
    t0, R0 = np.median(T[:, :3, 3], axis=0), _chordal_median(T[:, :3, :3])
    dt, dr = _deviations(T, t0, R0)
    keep = (dt <= max(OUTLIER_SIGMAS * _MAD * np.median(dt), TRANSLATION_FLOOR_M)) & \
           (dr <= max(OUTLIER_SIGMAS * _MAD * np.median(dr), ROTATION_FLOOR_DEG))
    if not keep.any():
        keep[:] = True
    M = np.eye(4)
    M[:3, :3] = _project_rotation(T[keep, :3, :3].sum(0))
    M[:3, 3] = T[keep, :3, 3].mean(0)
    dt, dr = _deviations(T, M[:3, 3], M[:3, :3])
    return M, keep, dt, dr


def _stats(v: np.ndarray) -> tuple:
    return (float(np.median(v)), float(np.percentile(v, 95))) if len(v) else (0.0, 0.0)


def fit(sensors: Sensors, camera_to_world: np.ndarray, K: np.ndarray, size: tuple) -> RigFit:
    """The recording's rig from ``sensors`` (S frames), ``camera_to_world`` (S, 4, 4) (the import's world, OpenCV
    axes), ``K`` (S, 3, 3) ours at the predictions' ``size`` (width, height). InputError (naming the sidecar) for a
    sensor that has no frame within reach of the reference's frames and no camera_to_ego of its own."""
    c2w = np.asarray(camera_to_world, np.float64)
    K = np.asarray(K, np.float64)
    t_s = sensors.timestamp_us.astype(np.float64) * 1e-6
    ref = sensors.reference
    ref_idx = sensors.frames_of(ref)
    given_ref = sensors.info.get(ref)
    delta = L = L_std = None
    notes = []
    if given_ref is not None and given_ref.camera_to_ego is not None:
        ego = c2w[ref_idx] @ cameras.rigid_inverse(given_ref.camera_to_ego)
        notes.append(f"ego path from {ref} and the sidecar's camera_to_ego")
    else:
        ego, delta, L, L_std, notes = ego_path_from_camera(c2w[ref_idx], t_s[ref_idx])
        delta = float(np.degrees(delta))
    if len(ref_idx) > 1:
        reach = 0.5 * float(np.median(np.diff(t_s[ref_idx])))
    else:   # one sample of every camera (one moment): the vehicle's motion between their shutters is not known
        reach = ONE_FRAME_REACH_S
        notes.append(f"one {ref} frame: the other sensors' frames within {ONE_FRAME_REACH_S:g} s of it are taken at "
                     "its ego pose (the motion between their shutters is ignored)")
    cams, fits = [], {}
    for name in sensors.names:
        idx = sensors.frames_of(name)
        at, inside = interpolate_poses(ego, t_s[ref_idx], t_s[idx], reach)
        per_frame = cameras.rigid_inverse(at[inside]) @ c2w[idx[inside]]
        info = sensors.info.get(name)
        given = info is not None and info.camera_to_ego is not None
        if not inside.any() and not given:
            raise InputError(sensors.path, "frames", f"no {name} frame is within {reach:.3g} s of the reference "
                                                     f"sensor {ref}'s frames: its mounting pose cannot be estimated",
                             hint=f"give {name}'s camera_to_ego in the sidecar's sensors, or its frames at the "
                                  f"{ref} frames' times")
        if given:
            E = np.asarray(info.camera_to_ego, np.float64)
            dt, dr = _deviations(per_frame, E[:3, 3], E[:3, :3]) if len(per_frame) else (np.zeros(0),) * 2
            keep = np.ones(len(per_frame), bool)
        else:
            E, keep, dt, dr = robust_pose_mean(per_frame)
        Ks = K[idx]
        K_med = np.median(Ks, axis=0)
        K_dev = np.abs(Ks - K_med)[:, [0, 1, 0, 1], [0, 1, 2, 2]].max(1)
        W, H = size
        if info is not None and info.resolution is not None:
            W2, H2 = info.resolution
            K_med = np.diag([W2 / W, H2 / H, 1.0]) @ K_med
            W, H = W2, H2
        cams.append(rig_mod.RigCamera(name, (int(W), int(H)), K_med, E))
        fits[name] = SensorFit(name, "sidecar" if given else "estimated", len(idx), int(inside.sum()),
                               [int(j) for j in idx[inside][~keep]], _stats(dt[keep]), _stats(dr[keep]),
                               (float(np.median(K_dev)), float(K_dev.max())))
    rig = rig_mod.Rig(RIG_NAME, cams)
    # the rig file's own checks (K fits its resolution, rigid mounts): what Add Camera Rig will read back
    rig = rig_mod.Rig.from_dict(rig.to_dict(), sensors.path, "recording rig")
    return RigFit(rig, ref, ego, fits, delta, L, L_std, notes)
