"""The size of a car mesh for stage 1, as the ``mesh-asset`` command reports it.

Stage-1 size: an upright oriented box (yaw only, Z kept up): ``trimesh.bounds.oriented_bounds_2D`` of the
vertices' horizontal projection gives (length, width) and the yaw, the z range the height. The box follows the
project's box convention (length along the box's local +Y, docs/design.md §8): its length axis is
(-sin θ, cos θ, 0), θ in (-90°, 90°]. ``trimesh.bounds.oriented_bounds`` gives the full 3D box for the report.

No bpy, no torch.
"""

from __future__ import annotations

import math

import numpy as np


def upright_box(vertices) -> dict:
    """Upright oriented bounding box of points (N, 3), Z up: yaw only.

    Returns ``size`` [length, width, height] (length >= width, horizontal; height the z range), ``yaw_deg`` θ in
    (-90, 90] (the box's rotation about +Z; its length along the box's local +Y, so the length axis is
    (-sin θ, cos θ, 0)), ``center`` [x, y, z], and ``aabb_size`` [length, width, height] of the axis-aligned box for
    comparison. Non-finite points are ignored; degenerate footprints (a line, a point) fall back to PCA axes.
    """
    import trimesh

    v = np.asarray(vertices, np.float64)
    v = v[np.isfinite(v).all(axis=1)]
    if not len(v):
        raise ValueError("upright_box: no finite points")
    xy = v[:, :2]
    try:
        with np.errstate(all="ignore"):  # numpy's warnings inside trimesh (flat or tiny footprints) are not ours
            T2, rect = trimesh.bounds.oriented_bounds_2D(xy)
        d = T2[0, :2]                      # the box's long (x after trimesh's flip) axis, in world xy
        centre = -T2[:2, :2].T @ T2[:2, 2]
        length, width = float(rect[0]), float(rect[1])
    except Exception:  # qhull: fewer than 3 points or all on a line
        c = xy.mean(axis=0)
        _, _, vt = np.linalg.svd(xy - c, full_matrices=True)
        d = vt[0]
        proj = (xy - c) @ vt.T
        lo, hi = proj.min(axis=0), proj.max(axis=0)
        length, width = float(hi[0] - lo[0]), float(hi[1] - lo[1])
        centre = c + vt.T @ ((lo + hi) / 2)
    theta = math.degrees(math.atan2(-d[0], d[1]))   # Rz(θ) (0, 1) = (-sin θ, cos θ) = ±d
    theta = (theta + 90.0) % 180.0 - 90.0
    if theta == -90.0:
        theta = 90.0
    zlo, zhi = float(v[:, 2].min()), float(v[:, 2].max())
    ext = v.max(axis=0) - v.min(axis=0)
    return {"size": [length, width, zhi - zlo], "yaw_deg": theta,
            "center": [float(centre[0]), float(centre[1]), (zlo + zhi) / 2],
            "aabb_size": [float(max(ext[0], ext[1])), float(min(ext[0], ext[1])), float(ext[2])]}


def oriented_box_3d(vertices) -> list:
    """Extents (3,), largest first, of trimesh's minimum-volume-ish 3D oriented box (``oriented_bounds``)."""
    import trimesh

    v = np.asarray(vertices, np.float64)
    v = v[np.isfinite(v).all(axis=1)]
    try:
        with np.errstate(all="ignore"):  # a flat mesh: trimesh's hull divides by its zero volume
            _, ext = trimesh.bounds.oriented_bounds(v)
    except Exception:  # degenerate (fewer than 4 points, all on a line): the axis-aligned extents
        ext = v.max(axis=0) - v.min(axis=0)
    return sorted((float(e) for e in ext), reverse=True)
