"""The rendered drive as files: ``predictions.npz`` in VGGT's layout and ``metric.npz`` with the exact answers.

VGGT's layout (``core.vggt.predictions``): the first camera's OpenCV frame is the world, lengths are normalised so the
mean distance of all valid points from the first camera is 1 (``metres_per_unit``), depth comes with a VGGT-like
confidence, and ``world_points`` are the depth unprojected. ``metric.npz`` keeps the metric Blender world (see
``dataset.py`` for its keys). Sky pixels (no hit, depth inf) get a far depth and the lowest confidence.

No bpy: numpy only, so it runs (and is tested) outside Blender.
"""

from __future__ import annotations

import os

import numpy as np

from ..core.geometry import cameras, unproject
from ..core.vggt import predictions as vggt, npz as vggt_io


def metres_per_unit(depth, K, w2c) -> float:
    """VGGT's normalisation: the mean distance of all valid points from the first camera becomes 1.

    ``depth`` (S, H, W) metres, inf where nothing was hit; ``K`` (3, 3) ours; ``w2c`` (S, 4, 4) metric OpenCV."""
    hits = np.isfinite(depth)
    pts = []
    for i in range(len(depth)):
        rows, cols = np.nonzero(hits[i])
        pts.append(unproject.unproject_pixels(depth[i], K, w2c[i], rows, cols))
    P = np.concatenate(pts)
    c0 = cameras.camera_centers(w2c[0])
    return float(np.linalg.norm(P - c0, axis=1).mean())


def vggt_to_world(w2c, metres_per_unit) -> np.ndarray:
    """VGGT world = first camera's OpenCV frame in VGGT units: x_world = c2w_0 (m x_vggt), a 4x4 similarity."""
    M = cameras.rigid_inverse(w2c[0])
    M[:3, :3] *= metres_per_unit
    return M


def write_predictions(path, images, depth, K, w2c, metres_per_unit):
    """The recorded drive in VGGT's layout: first camera at the origin, scale normalised, depth + confidence.

    ``images`` (S, H, W, 3) in [0, 1]; ``depth`` (S, H, W) metres (inf: sky); ``K`` (3, 3) ours; ``w2c`` (S, 4, 4)
    metric world-to-camera."""
    m = metres_per_unit
    first = cameras.rigid_inverse(w2c[0])
    ext = w2c @ first  # camera i from the first camera's frame, still metric
    ext[0] = np.eye(4)  # exactly, not to rounding
    ext[:, :3, 3] /= m
    hit = np.isfinite(depth)
    far = float(depth[hit].max()) * 1.5 if hit.any() else 100.0
    d = np.where(hit, depth, far) / m
    # VGGT-like confidence (1 + exp(x) >= 1): high near, falling with distance, minimal on the sky
    conf = np.where(hit, 1.0 + 30.0 * np.exp(-np.where(hit, depth, 0) / 20.0), 1.0 + 1e-3).astype(np.float32)
    Ks = np.tile(K, (len(depth), 1, 1))
    wp = unproject.unproject_depth(d, Ks, ext).astype(np.float32)
    vggt_io.save_predictions(path, images, d, conf, ext, vggt.ours_K_to_vggt(Ks), world_points=wp,
                             world_points_conf=conf)


def write_drive(out_dir, images, depth, instance, K, views: dict, camera_height_m: float) -> float:
    """``predictions.npz`` and ``metric.npz`` of a rendered drive into ``out_dir``; returns metres per VGGT unit.

    ``views``: name -> world_to_camera (S, 4, 4), "recorded" first (the drive the predictions are of);
    ``instance`` (S, H, W) uint8 object ids (0: none)."""
    w2c = views["recorded"]
    m = metres_per_unit(depth, K, w2c)
    write_predictions(os.path.join(out_dir, "predictions.npz"), images, depth, K, w2c, m)
    np.savez(os.path.join(out_dir, "metric.npz"), world_to_camera=w2c, K=np.tile(K, (len(w2c), 1, 1)), depth=depth,
             instance=instance, camera_height_m=camera_height_m, vggt_to_world=vggt_to_world(w2c, m),
             metres_per_unit=m, **{f"world_to_camera_{k}": v for k, v in views.items() if k != "recorded"})
    return m
