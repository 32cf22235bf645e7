"""A drive seen by a known rig, for the rig-fit and multi-camera import tests: the ego (its rear axle) drives
straight along +x, then turns left on an arc (the heading is the path's tangent, as a car's rear axle moves), the
ground at z = 0 of a Z-up world; each rig camera takes a frame a few ms after the previous one in every sample."""

import numpy as np

from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.vggt import sensors as S


def ego_at(t, speed=8.0, radius=25.0, straight_s=1.0):
    """ego_to_world (4, 4) at time ``t`` s: straight for ``straight_s`` s, then a left arc of ``radius`` m."""
    s = speed * t
    ds = s - speed * straight_s
    if ds <= 0:
        x, y, th = s, 0.0, 0.0
    else:
        th = ds / radius
        x, y = speed * straight_s + radius * np.sin(th), radius * (1 - np.cos(th))
    E = np.eye(4)
    E[:3, :3] = [[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]]
    E[:3, 3] = [x, y, 0.0]
    return E


def recording(rig, samples=8, period_s=0.5, stagger_s=0.008, noise_m=0.0, noise_deg=0.0, outliers=(), seed=0):
    """(Sensors, camera_to_world (S, 4, 4)) of ``rig``'s cameras at ``samples`` samples, frames sample-major in rig
    order; poses perturbed by ``noise_m`` / ``noise_deg`` (Gaussian), frames ``outliers`` moved by (1, −0.5, 0.3) m."""
    rng = np.random.default_rng(seed)
    names, stamps, c2w = [], [], []
    for i in range(samples):
        for k, cam in enumerate(rig.cameras):
            t = period_s * i + stagger_s * k
            T = ego_at(t) @ cam.camera_to_ego
            axis = rng.normal(size=3)
            angle = np.radians(rng.normal(0.0, noise_deg)) if noise_deg else 0.0
            q = np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis / np.linalg.norm(axis)]
            T = T.copy()
            T[:3, :3] = T[:3, :3] @ cameras.quaternion_to_rotation(q)
            T[:3, 3] += rng.normal(0.0, noise_m, 3) if noise_m else 0.0
            names.append(cam.name)
            stamps.append(int(round(1_000_000 + t * 1e6)))
            c2w.append(T)
    c2w = np.array(c2w)
    for j in outliers:
        c2w[j, :3, 3] += [1.0, -0.5, 0.3]
    return S.Sensors(names, np.array(stamps, np.int64), {}, "recording.sensors.json"), c2w


#: Blender's world from VGGT's in factor mode at 1 m per unit (``metric_scale.vggt_to_world_by_factor(1)``).
VGGT_TO_WORLD = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


def small_rig(W=16, H=12, names=("CAM_FRONT", "CAM_BACK")):
    """nuScenes' mounts of the cameras ``names`` (default CAM_FRONT and CAM_BACK) with a small camera (fx = W · 0.75,
    centred) each."""
    from scpainter_blender.core import rig as R

    K = np.array([[0.75 * W, 0.0, W / 2], [0.0, 0.75 * W, H / 2], [0.0, 0.0, 1.0]])
    ns = R.preset("nuscenes")
    return R.Rig("small", [R.RigCamera(n, (W, H), K.copy(), ns.camera(n).camera_to_ego) for n in names])


def predictions(rig, samples=4, seed=0):
    """(arrays for ``vggt.npz.save_predictions``, Sensors, camera_to_world (S, 4, 4) in Blender's world) of
    ``rig``'s cameras along ``recording``'s drive, as a factor-mode import at 1 m per unit reads them back."""
    from scpainter_blender.core.vggt import predictions as V

    sensors, c2w = recording(rig, samples=samples)
    rng = np.random.default_rng(seed)
    W, H = rig.cameras[0].resolution
    S = len(c2w)
    w2c_vggt = cameras.rigid_inverse(c2w) @ VGGT_TO_WORLD
    K = V.ours_K_to_vggt(np.stack([rig.camera(n).K for n in sensors.sensor]))
    arrays = dict(images=rng.random((S, H, W, 3), dtype=np.float32),
                  depth=rng.uniform(2.0, 6.0, (S, H, W)).astype(np.float32),
                  depth_conf=(1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32),
                  extrinsic=w2c_vggt, intrinsic_vggt=K)
    return arrays, sensors, c2w
