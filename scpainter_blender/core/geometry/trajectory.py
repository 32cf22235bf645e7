"""Camera paths: the direction of travel per frame, and paths shifted sideways, up or forward by metres.

World: Blender's (Z up, metres); cameras are OpenCV ``world_to_camera`` (``core.geometry.cameras``). The direction of
travel is measured along the path's *travelled distance*, so a stop or a parked camera keeps a sensible heading
(docs/design.md §3).

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import numpy as np

from . import cameras


def _unit(v, axis=-1):
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def heading_directions(centers, window_m: float = 1.0, up=(0.0, 0.0, 1.0), fallback=None) -> np.ndarray:
    """Unit direction of travel per frame, (N, 3), horizontal (perpendicular to ``up``).

    The heading at frame i is the chord between the positions half a window of *travelled distance* before and
    after it (arc length, not frame count). A vehicle that stops keeps the heading it had: its positions during
    the stop share one arc length, so the chord still spans the motion before and after. Where the whole path is
    shorter than a hair (a parked camera), ``fallback`` (N, 3) or (3,) is used, typically the camera's forward
    axis; without one a ValueError explains why.
    """
    c = np.asarray(centers, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0:
        raise ValueError(f"centers must be (N, 3), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("centers contain NaN or inf")
    up = _unit(np.asarray(up, dtype=np.float64))
    rel = c - c[0]  # relative to the first centre: differences of 1e5 m coordinates stay exact
    horiz = rel - np.outer(rel @ up, up)
    steps = np.linalg.norm(np.diff(horiz, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    total = s[-1]
    if total < 1e-6:
        if fallback is None:
            raise ValueError("the trajectory does not move, so it has no direction of travel; pass the camera "
                             "forward axis as fallback")
        f = np.broadcast_to(np.asarray(fallback, np.float64), c.shape)
        f = f - np.outer(f @ up, up)
        return _unit(f)
    half = min(window_m / 2.0, total / 2.0)
    ahead = np.searchsorted(s, s + half, side="left").clip(0, len(s) - 1)
    behind = (np.searchsorted(s, s - half, side="right") - 1).clip(0, len(s) - 1)
    chord = horiz[ahead] - horiz[behind]
    return _unit(chord)


def left_directions(headings, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Unit vectors pointing to the driver's left: up x heading (right-handed world)."""
    up = _unit(np.asarray(up, dtype=np.float64))
    return _unit(np.cross(np.broadcast_to(up, np.shape(headings)), headings))


def shift_trajectory(world_to_camera, left_m: float = 0.0, up_m: float = 0.0, forward_m: float = 0.0,
                     window_m: float = 1.0, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Move each camera of a path by metres relative to the direction of travel; orientation is kept.

    ``left_m`` > 0 moves left, < 0 right; ``forward_m`` along the heading; ``up_m`` along ``up``; each a number or
    one per frame (N,) (a lane change: a shift that grows over frames). Returns the new
    world_to_camera (N, 4, 4). Parked frames keep the heading they had (see heading_directions); a path that never
    moves uses the cameras' forward axes.
    """
    T = cameras.as_matrix4(world_to_camera, "world_to_camera")
    c = cameras.camera_centers(T)
    forward_axes = T[:, 2, :3]  # camera +z in world = third row of R
    h = heading_directions(c, window_m=window_m, up=up, fallback=forward_axes)
    upv = _unit(np.asarray(up, dtype=np.float64))
    per_frame = lambda v: np.asarray(v, np.float64)[..., None]  # noqa: E731  (N, 1) or (1,): broadcast over axes
    offset = per_frame(left_m) * left_directions(h, upv) + per_frame(forward_m) * h + per_frame(up_m) * upv
    new_c = c + offset
    out = T.copy()
    out[:, :3, 3] = -np.einsum("nij,nj->ni", T[:, :3, :3], new_c)
    return out

