"""VGGT predictions as other tools write them, for the core and import tests: a drive whose world_points agree
with its depth (as VGGT's independent point head does, to a few percent), and VGGT's "pad" preprocessing."""

import numpy as np

from scpainter_blender.core.geometry import unproject
from scpainter_blender.core.vggt import npz as vggt_io
from scpainter_blender.core.vggt import predictions as V


def drive(S=4, H=24, W=32, seed=0, noise=0.02):
    """A forward drive with a turn: world-to-camera poses, depth, and world_points that agree with the depth to
    ``noise`` (relative, per axis) as VGGT's independent point head does. Returns (arrays for save_predictions,
    the true world-to-camera (S, 4, 4), the intrinsic in VGGT's convention)."""
    rng = np.random.default_rng(seed)
    w2c = np.tile(np.eye(4), (S, 1, 1))
    for i in range(S):
        yaw = np.radians(6.0 * i)
        R = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
        c = np.array([0.1 * i, 0.02 * i, 0.8 * i])
        w2c[i, :3, :3], w2c[i, :3, 3] = R, -R @ c
    intr = np.tile(np.array([[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1]]), (S, 1, 1))
    depth = rng.uniform(1.0, 4.0, (S, H, W)).astype(np.float32)
    wp = unproject.unproject_depth(depth, V.vggt_K_to_ours(intr), w2c)
    wp += rng.normal(0.0, noise, wp.shape) * depth[..., None]
    arrays = dict(images=rng.random((S, H, W, 3), dtype=np.float32), depth=depth,
                  depth_conf=(1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32), extrinsic=w2c,
                  intrinsic_vggt=intr, world_points=wp.astype(np.float32),
                  world_points_conf=(1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32))
    return arrays, w2c, intr


def write(tmp_path, arrays, name="predictions.npz"):
    path = tmp_path / name
    vggt_io.save_predictions(path, **arrays)
    return str(path)


def pad(arrays, top, bottom, left=0, right=0, seed=5):
    """What VGGT's pad preprocessing gives: white borders on the images, its predictions there (depth and points
    that mean nothing, with VGGT's lowest confidences), and the principal point of the padded image."""
    rng = np.random.default_rng(seed)
    out = dict(arrays)
    widths = ((0, 0), (top, bottom), (left, right))
    out["images"] = np.pad(arrays["images"], widths + ((0, 0),), constant_values=1.0)
    for key in ("depth", "depth_conf", "world_points_conf", "world_points"):
        a = arrays[key]
        lo, hi = (1.0, 1.05) if key.endswith("conf") else (0.5, 9.0)
        filled = rng.uniform(lo, hi, (a.shape[0], a.shape[1] + top + bottom, a.shape[2] + left + right)
                             + a.shape[3:]).astype(np.float32)
        filled[:, top:top + a.shape[1], left:left + a.shape[2]] = a
        out[key] = filled
    K = arrays["intrinsic_vggt"].copy()
    K[:, 0, 2] += left
    K[:, 1, 2] += top
    out["intrinsic_vggt"] = K
    return out
