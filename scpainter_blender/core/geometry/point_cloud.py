"""A clip's coloured points: VGGT's depth (or point head) unprojected, filtered by confidence as VGGT's demo does,
and placed in the output world by ``vggt_to_world``; pixels on depth edges ("flying pixels") left out on request;
and the points likely on the road, for the ground plane.

Outputs are float64 positions in the requested world (Blender's: Z up, metres, when a ``vggt_to_world``
similarity from ``core.geometry.metric_scale`` is given) and sRGB-encoded colours as the images hold them.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from . import fits, similarity, unproject
from ..vggt import predictions as vggt

if TYPE_CHECKING:
    from collections.abc import Iterable

#: The confidence percentile when none is given, the one place it is written: VGGT's demo drops the less
#: confident half of the pixels. The import's, the job's and the training and evaluation default.
CONFIDENCE_PERCENTILE = 50.0


@dataclass
class FramePoints:
    """Coloured points, grouped by the frame they came from.

    ``positions`` (N, 3) float64 in the output world; ``colors`` (N, 3) float32 sRGB-encoded [0, 1];
    ``frame`` (N,) int32 source frame; frame i's points are ``positions[offsets[i]:offsets[i + 1]]``;
    ``depth_edge_points``: how many pixels that passed the other tests the depth-edge test left out.
    """

    positions: np.ndarray
    colors: np.ndarray
    frame: np.ndarray
    offsets: np.ndarray
    threshold: float = field(default=-np.inf)
    depth_edge_points: int = 0

    def __len__(self):
        return len(self.positions)

    def frame_slice(self, i: int) -> slice:
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))


def point_cloud(pred: vggt.VGGTPredictions, confidence_percentile: float = CONFIDENCE_PERCENTILE, source: str = "depth",
                vggt_to_world: np.ndarray | None = None, frames: Iterable[int] | None = None,
                depth_edge_ratio: float | None = None) -> FramePoints:
    """Coloured points of the clip, filtered by confidence percentile (VGGT demo semantics), per frame.

    ``source`` is "depth" (unproject depth with each frame's K and extrinsic; VGGT's recommended branch) or
    "world_points" (VGGT's point head, filtered by ``world_points_conf``). Points with depth <= 0 are dropped.
    ``vggt_to_world`` (4x4 similarity) maps them into the output world, in float64. ``depth_edge_ratio`` (None:
    off) also drops the pixels ``depth_edges`` finds on each frame's depth map (either source: the depth map is
    where a network's smear across an edge shows); the confidence threshold is the clip's as without it.

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
    masks, edge_points = [], 0
    for i in frames:
        m = (conf[i] > 1e-5) & (pred.depth[i] > 0)
        if np.isfinite(thr):
            m &= conf[i] >= thr
        if valid is not None:
            m &= valid[i]
        if depth_edge_ratio is not None:
            edges = depth_edges(pred.depth[i], depth_edge_ratio, None if pred.valid is None else pred.valid[i])
            edge_points += int((m & edges).sum())
            m &= ~edges
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
    return FramePoints(pos, col, fid, offsets, thr, edge_points)


def scene_cloud(pred: vggt.VGGTPredictions, confidence_percentile: float, vggt_to_world: np.ndarray | None,
                depth_edge_ratio: float | None = None, removal_boxes: Iterable[object] = ()) -> tuple:
    """A job's scene points before outlier removal: (``point_cloud`` of every frame with the depth-edge test,
    keep (N,) bool: False for the points inside a removal box, any object with ``box_to_world`` and ``size``). The
    renderer (``backend.render.cleaning.clean_cloud``, which then removes outliers) and a variation run's road
    both take their points from here."""
    cloud = point_cloud(pred, confidence_percentile, vggt_to_world=vggt_to_world, depth_edge_ratio=depth_edge_ratio)
    keep = np.ones(len(cloud), bool)
    for box in removal_boxes:
        keep &= ~fits.points_in_box(cloud.positions, box.box_to_world, box.size)
    return cloud, keep


#: The 8 neighbours (row, column offsets) the depth-edge test compares a pixel with.
NEIGHBOURS_8 = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def depth_edges(depth: np.ndarray, ratio: float, valid: np.ndarray | None = None) -> np.ndarray:
    """Pixels on a depth edge (H, W) bool: where a network's depth smears across a discontinuity ("flying pixels").

    ``depth`` (H, W) camera z (any unit: the rule is a ratio); ``valid`` (H, W) bool or None. A pixel has depth
    when d > 0, finite and valid. The rule, for a pixel p with depth d_p and its 8 neighbours q inside the image
    that have depth:

        edge(p)  ⇔  max_q |d_p − d_q| > ratio · d_p

    Pixels without depth are never edges; neighbours without depth are not compared (a hole is not an edge).
    The jump is relative to the pixel's own depth, so one rule holds near and far; both sides of a true
    discontinuity are edges (the near side by |Δ|/d_near, the far side once |Δ|/d_far > ratio), and every pixel a
    blur put in between. A surface seen at a grazing angle changes by about d/(f·h) per pixel row (the road at
    depth d from a camera at height h with focal length f px), so ``ratio`` must stay above that for the road's
    far pixels to survive (bench/clean_points.py measures the trade). Vectorised: each of the 4 neighbour
    directions' differences once, given to both pixels of the pair."""
    d = np.asarray(depth, np.float64)
    ok = np.isfinite(d) & (d > 0)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    H, W = d.shape
    dp = np.where(ok, d, np.nan)
    jump = np.zeros((H, W))
    # each neighbour pair once (right, down, down-right, down-left), its |Δ| given to both pixels; NaN where either
    # has no depth, which fmax ignores
    pairs = (((slice(None), slice(0, W - 1)), (slice(None), slice(1, W))),
             ((slice(0, H - 1), slice(None)), (slice(1, H), slice(None))),
             ((slice(0, H - 1), slice(0, W - 1)), (slice(1, H), slice(1, W))),
             ((slice(0, H - 1), slice(1, W)), (slice(1, H), slice(0, W - 1))))
    with np.errstate(invalid="ignore"):
        for a, b in pairs:
            diff = np.abs(dp[a] - dp[b])
            np.fmax(jump[a], diff, out=jump[a])
            np.fmax(jump[b], diff, out=jump[b])
        return ok & (jump > ratio * np.where(ok, d, 0.0))


def depth_edges_reference(depth: np.ndarray, ratio: float, valid: np.ndarray | None = None) -> np.ndarray:
    """``depth_edges`` pixel by pixel, as the rule reads (tests compare the two)."""
    d = np.asarray(depth, np.float64)
    H, W = d.shape
    has = lambda r, c: np.isfinite(d[r, c]) and d[r, c] > 0 and (valid is None or bool(valid[r, c]))  # noqa: E731
    out = np.zeros((H, W), bool)
    for r in range(H):
        for c in range(W):
            if not has(r, c):
                continue
            jumps = [abs(d[r, c] - d[r + dr, c + dc]) for dr, dc in NEIGHBOURS_8
                     if 0 <= r + dr < H and 0 <= c + dc < W and has(r + dr, c + dc)]
            out[r, c] = bool(jumps) and max(jumps) > ratio * d[r, c]
    return out


def ground_candidates(pred: vggt.VGGTPredictions, confidence_percentile: float = CONFIDENCE_PERCENTILE,
                      lower_fraction: float = 0.4,
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
