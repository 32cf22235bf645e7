"""A clip's coloured points: VGGT's depth (or point head) unprojected, filtered by confidence as VGGT's demo does,
and placed in the output world by ``vggt_to_world``; and the points likely on the road, for the ground plane.

Outputs are float64 positions in the requested world (Blender's: Z up, metres, when a ``vggt_to_world``
similarity from ``core.metric_scale`` is given) and sRGB-encoded colours as the images hold them.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import similarity, unproject, vggt


@dataclass
class FramePoints:
    """Coloured points, grouped by the frame they came from.

    ``positions`` (N, 3) float64 in the output world; ``colors`` (N, 3) float32 sRGB-encoded [0, 1];
    ``frame`` (N,) int32 source frame; frame i's points are ``positions[offsets[i]:offsets[i + 1]]``.
    """

    positions: np.ndarray
    colors: np.ndarray
    frame: np.ndarray
    offsets: np.ndarray
    threshold: float = field(default=-np.inf)

    def __len__(self):
        return len(self.positions)

    def frame_slice(self, i: int) -> slice:
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))


def point_cloud(pred: vggt.VGGTPredictions, confidence_percentile: float = 50.0, source: str = "depth",
                vggt_to_world=None, frames=None) -> FramePoints:
    """Coloured points of the clip, filtered by confidence percentile (VGGT demo semantics), per frame.

    ``source`` is "depth" (unproject depth with each frame's K and extrinsic; VGGT's recommended branch) or
    "world_points" (VGGT's point head, filtered by ``world_points_conf``). Points with depth <= 0 are dropped.
    ``vggt_to_world`` (4x4 similarity) maps them into the output world, in float64.

    Vectorised per frame with no per-point Python: the camera-to-world step and ``vggt_to_world`` are fused
    into one affine map per frame, x_world = A (d · ray) + b, written straight into preallocated outputs.
    """
    if source == "depth":
        conf, valid = pred.depth_conf, pred.valid
    elif source == "world_points":
        if pred.world_points is None:
            raise vggt.PredictionsError(pred.path, "world_points",
                                        "requested as point source but absent from the file")
        conf = pred.world_points_conf if pred.world_points_conf is not None else pred.depth_conf
        valid = pred.world_points_valid
        if pred.world_points_conf is None and pred.valid is not None:
            valid = pred.valid if valid is None else valid & pred.valid
    else:
        raise ValueError(f"source must be 'depth' or 'world_points', got {source!r}")
    # pixels with NaN/inf values (zeroed on load) are not part of the clip's confidence distribution
    thr = unproject.confidence_threshold(conf if valid is None else conf[valid], confidence_percentile)
    frames = list(range(pred.num_frames) if frames is None else frames)
    s, Rw, tw = (1.0, np.eye(3), np.zeros(3)) if vggt_to_world is None else \
        similarity.decompose_similarity(vggt_to_world)
    masks = []
    for i in frames:
        m = (conf[i] > 1e-5) & (pred.depth[i] > 0)
        if np.isfinite(thr):
            m &= conf[i] >= thr
        if valid is not None:
            m &= valid[i]
        masks.append(m)
    counts = [int(m.sum()) for m in masks]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    N = int(offsets[-1])
    pos = np.empty((N, 3), np.float64)
    col = np.empty((N, 3), np.float32)
    fid = np.empty(N, np.int32)
    W = pred.width
    K = pred.K
    for k, i in enumerate(frames):
        sl = slice(offsets[k], offsets[k + 1])
        flat = np.flatnonzero(masks[k])  # once per frame; every array below is gathered with it
        if source == "depth":
            T = pred.world_to_camera[i]
            A = s * Rw @ T[:3, :3].T          # camera -> VGGT world (R^T) -> output world (s Rw)
            b = tw - A @ T[:3, 3]
            d = pred.depth[i].reshape(-1).take(flat).astype(np.float64)
            rows, cols = np.divmod(flat, W)
            cam = np.empty((len(flat), 3))
            cam[:, 0] = (cols + 0.5 - K[i, 0, 2]) / K[i, 0, 0] * d   # pixel centres at +0.5 (our K)
            cam[:, 1] = (rows + 0.5 - K[i, 1, 2]) / K[i, 1, 1] * d
            cam[:, 2] = d
        else:
            A, b = s * Rw, tw
            cam = pred.world_points[i].reshape(-1, 3).take(flat, axis=0).astype(np.float64)
        np.matmul(cam, A.T, out=pos[sl])
        pos[sl] += b
        img = pred.images[i]
        for c in range(3):  # one channel plane at a time: contiguous when the file is CHW, as VGGT writes it
            col[sl, c] = img[..., c].reshape(-1).take(flat)
        fid[sl] = i
    return FramePoints(pos, col, fid, offsets, thr)


def ground_candidates(pred: vggt.VGGTPredictions, confidence_percentile: float = 50.0, lower_fraction: float = 0.4,
                      max_points: int = 200_000, seed: int = 0) -> np.ndarray:
    """Points likely on the road, in VGGT's world: confident pixels from the lower part of each image.

    A forward-looking car camera sees the road in the bottom rows; a random, seeded subset keeps the plane fit
    fast on long clips.
    """
    H = pred.height
    conf = pred.depth_conf
    thr = unproject.confidence_threshold(conf if pred.valid is None else conf[pred.valid], confidence_percentile)
    start = int(np.floor(H * (1.0 - lower_fraction)))
    K = pred.K
    pts = []
    for i in range(pred.num_frames):
        keep = (conf[i, start:] >= thr) & (conf[i, start:] > 1e-5) & (pred.depth[i, start:] > 0)
        if pred.valid is not None:
            keep &= pred.valid[i, start:]
        rows, cols = np.nonzero(keep)
        pts.append(unproject.unproject_pixels(pred.depth[i], K[i], pred.world_to_camera[i], rows + start, cols))
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(seed).choice(len(pts), max_points, replace=False)]
    return pts
