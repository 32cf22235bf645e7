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
