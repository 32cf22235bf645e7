"""Pixels to points: depth unprojected with our K and a camera's pose, and VGGT's confidence filter.

Pixel centres are at (col + 0.5, row + 0.5) in the coordinates our K maps to (``core.geometry.cameras``); VGGT's K
(``core.vggt.predictions``) unprojects integer coordinates, and ``vggt.vggt_K_to_ours`` makes the two agree exactly.
Depth is camera z; world points come back float64 in the world ``world_to_camera`` maps from.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import numpy as np

from . import cameras


def confidence_threshold(conf: np.ndarray, percentile: float) -> float:
    """VGGT demo semantics: the ``percentile``-th percentile of *all* confidences of the clip."""
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f"confidence percentile must be in [0, 100], got {percentile}")
    if percentile == 0.0:
        return -np.inf
    return float(np.percentile(conf, percentile))


def confidence_mask(conf: np.ndarray, percentile: float) -> np.ndarray:
    """Keep ``conf >= percentile(conf, p)`` and ``conf > 1e-5``, exactly as VGGT's demo filters."""
    conf = np.asarray(conf)
    return (conf >= confidence_threshold(conf, percentile)) & (conf > 1e-5)


def unproject_pixels(depth: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, rows: np.ndarray,
                     cols: np.ndarray) -> np.ndarray:
    """World points (N, 3) float64 of pixels (rows, cols) of one frame; pixel centres at (col + .5, row + .5).

    x_cam = d · K^-1 [u + 0.5, v + 0.5, 1]^T, then x_world = R^T (x_cam - t).
    """
    K = np.asarray(K, np.float64)
    T = cameras.as_matrix4(world_to_camera)
    d = np.asarray(depth, np.float64)[rows, cols]
    x = (cols + 0.5 - K[0, 2]) / K[0, 0] * d
    y = (rows + 0.5 - K[1, 2]) / K[1, 1] * d
    cam = np.stack([x, y, d], axis=1) - T[:3, 3]
    return cam @ T[:3, :3]  # R^T applied to row vectors


def unproject_depth(depth: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray) -> np.ndarray:
    """Dense unprojection of depth maps (S, H, W) with our K (S, 3, 3): world points (S, H, W, 3) float64."""
    depth = np.asarray(depth)
    S, H, W = depth.shape
    rows, cols = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    return np.stack([unproject_pixels(depth[i], K[i], world_to_camera[i], rows, cols).reshape(H, W, 3)
                     for i in range(S)])

