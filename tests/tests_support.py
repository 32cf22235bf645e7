"""Helpers shared by the tests (data they make themselves; nothing is downloaded)."""

import numpy as np

from scpainter_blender.core import cameras as C


def synthetic_predictions(S=3, H=14, W=21, seed=0):
    """Synthetic predictions shaped exactly as VGGT's demo saves them (float32, no batch axis)."""
    rng = np.random.default_rng(seed)
    ext = np.zeros((S, 3, 4), np.float32)
    for i in range(S):
        R = C.quaternion_to_rotation(np.array([1.0, *rng.normal(0, 0.05, 3)]))
        ext[i, :, :3] = R
        ext[i, :, 3] = rng.normal(0, 0.2, 3)
    ext[0] = np.eye(3, 4)
    intr = np.zeros((S, 3, 3), np.float32)
    intr[:, 0, 0] = intr[:, 1, 1] = 20.0
    intr[:, 0, 2], intr[:, 1, 2], intr[:, 2, 2] = W / 2, H / 2, 1.0
    return {
        "images": rng.random((S, 3, H, W), dtype=np.float32),
        "depth": rng.uniform(0.5, 3.0, (S, H, W, 1)).astype(np.float32),
        "depth_conf": (1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32),
        "extrinsic": ext,
        "intrinsic": intr,
        "world_points": rng.normal(0, 1, (S, H, W, 3)).astype(np.float32),
        "world_points_conf": (1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32),
    }
