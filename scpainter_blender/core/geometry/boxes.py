"""3D boxes of objects: estimated from points, placed in the world, projected into a camera, described as label
formats want them.

Conventions (docs/design.md §15):

- **Box frame** (the job's: removal boxes, asset boxes, the clip format's cars): a rigid ``box_to_x`` from the box
  frame (centre at the origin; x across the width, y along the length with +y the front, z up) and ``size`` =
  full extents (width, length, height) along x, y, z.
- **Object frame** of labels (ISO 8855, nuScenes, Waymo, OpenLABEL): x forward (the box's +y), y left (the box's
  −x), z up; ``OBJECT_TO_BOX`` maps it into the box frame, and label sizes are (length, width, height).
- **Camera**: OpenCV (x right, y down, z forward), ``K`` with pixel centres at +0.5 (docs/design.md §3).
- Quaternions are (w, x, y, z), unit, w ≥ 0. ``yaw`` is the heading of the object's forward axis about the
  frame's z (world: from +x towards +y).

numpy only (Blender's import estimates boxes too).
"""

from __future__ import annotations

import numpy as np

from . import cameras

#: Object frame (x forward, y left, z up) -> box frame (x width, y length/front, z up): a rotation about z.
OBJECT_TO_BOX = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

#: Points beyond a gap of this fraction of the body's robust extent, along any box axis, are floaters.
GAP_FRACTION = 0.05
#: The robust extent that scales the gap: the range between these quantiles.
BODY_QUANTILES = (0.02, 0.98)
#: At most this many points drive the heading search (a fixed subsample: the estimate is deterministic).
SEARCH_POINTS = 20_000

_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)])
#: The 12 edges of a box as pairs of ``corners`` indices (corners differing in one sign).
EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                   if np.count_nonzero(_CORNER_SIGNS[i] != _CORNER_SIGNS[j]) == 1])  # (12, 2)


# -- estimating a box --------------------------------------------------------------------------------------------

def body_range(x: np.ndarray) -> tuple:
    """(low, high) of the body of 1-D coordinates ``x``: starting from the median, the range grows outwards
    through the sorted values until a gap wider than ``GAP_FRACTION`` of the robust extent (``BODY_QUANTILES``).
    A clean object gives its exact min and max; isolated floaters beyond a gap are left out, however far."""
    x = np.sort(np.asarray(x, np.float64))
    lo_q, hi_q = np.quantile(x, BODY_QUANTILES)
    gap = max(GAP_FRACTION * (hi_q - lo_q), 1e-9 * (1.0 + abs(hi_q)))
    mid = len(x) // 2
    d = np.diff(x)
    big = np.flatnonzero(d > gap)
    below, above = big[big < mid], big[big >= mid]
    lo = x[below[-1] + 1] if len(below) else x[0]
    hi = x[above[0]] if len(above) else x[-1]
    return float(lo), float(hi)


def _basis(up) -> np.ndarray:
    """(3, 3) rows e1, e2, u: the frame's x, y, z turned by the smallest rotation that takes +z to ``up`` (so a
    Z-up frame keeps its axes, and TRELLIS's file frame, up = −y, gets e2 = +z: the direction its cars face)."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    c = float(u @ z)
    if c < -1.0 + 1e-12:                  # up = −z: half a turn about x
        R = np.diag([1.0, -1.0, -1.0])
    else:                                 # Rodrigues' formula for the rotation z -> u
        v = np.cross(z, u)
        V = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        R = np.eye(3) + V + V @ V / (1.0 + c)
    return R.T                            # rows: R x, R y, R z = u


def _footprint_area(q: np.ndarray, theta: float) -> float:
    c, s = np.cos(theta), np.sin(theta)
    a, b = body_range(q @ [c, s]), body_range(q @ [-s, c])
    return (a[1] - a[0]) * (b[1] - b[0])


def estimate_box(points, up=(0.0, 0.0, 1.0)):
    """The upright box of an object's points (N, 3) in their own frame: (box_to_frame (4, 4) rigid, size (3,)
    width, length, height in the points' units).

    Upright: the box's z is ``up`` (a direction in the points' frame). Its heading minimises the footprint's area (a
    search over 0–90° in 1° steps, refined to 0.02°, on at most ``SEARCH_POINTS`` points); along each box axis the
    extent is ``body_range``'s, so floaters beyond a gap are left out (first along the frame's axes, keeping the points
    inside all three ranges, up to three times: a floater far out on one axis leaves the others). The length (y) is the
    longer horizontal extent, its front (+y) the one closer to the frame's +y turned with its up (``_basis``: the axis
    the procedural cars and TRELLIS/Amodal3R's face); the user may flip it. Rows with NaN/inf are ignored. ValueError
    when fewer than 4 finite points."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    P = P[np.isfinite(P).all(1)]
    if len(P) < 4:
        raise ValueError(f"a box needs at least 4 finite points, got {len(P)}")
    B = _basis(up)
    origin = np.median(P, axis=0)
    local = (P - origin) @ B.T            # e1, e2, up coordinates, relative to the median (large coordinates)
    for _ in range(3):                    # a floater far out on one axis may sit inside another's range: a point
        ranges = [body_range(local[:, k]) for k in range(3)]  # counts only inside all three
        inside = np.all([(local[:, k] >= lo) & (local[:, k] <= hi) for k, (lo, hi) in enumerate(ranges)], axis=0)
        if inside.all() or inside.sum() < 4:
            break
        local = local[inside]
    q = local[:, :2]
    sample = q if len(q) <= SEARCH_POINTS else q[np.random.default_rng(0).choice(len(q), SEARCH_POINTS, False)]
    angles = np.radians(np.arange(0.0, 90.0, 1.0))
    best = angles[int(np.argmin([_footprint_area(sample, a) for a in angles]))]
    fine = best + np.radians(np.arange(-1.0, 1.0001, 0.02))
    theta = float(fine[int(np.argmin([_footprint_area(sample, a) for a in fine]))])
    c, s = np.cos(theta), np.sin(theta)
    axes2 = np.array([[c, s], [-s, c]])
    ranges = [body_range(q @ a) for a in axes2] + [body_range(local[:, 2])]
    extent = np.array([hi - lo for lo, hi in ranges])
    centre_local = np.array([(lo + hi) / 2 for lo, hi in ranges])
    if extent[0] > extent[1]:             # the length is the longer horizontal axis: y
        axes2 = np.array([axes2[1], -axes2[0]])
        extent[[0, 1]] = extent[[1, 0]]
        centre_local[[0, 1]] = centre_local[[1, 0]] * [1.0, -1.0]
    y_dir = axes2[1] @ B[:2]
    if y_dir @ B[1] < 0 or (abs(y_dir @ B[1]) < 1e-12 and y_dir @ B[0] < 0):   # front towards the frame's +y
        axes2 = -axes2
        centre_local[:2] = -centre_local[:2]
    x_dir, y_dir = axes2[0] @ B[:2], axes2[1] @ B[:2]
    R = np.stack([x_dir, y_dir, B[2]], axis=1)          # columns: box x, y, z in the points' frame
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = origin + R @ centre_local
    return T, extent


# -- placing and describing a box --------------------------------------------------------------------------------

def nearest_rotation(M) -> np.ndarray:
    """The rotation nearest to a 3x3 matrix (polar decomposition through the SVD; det +1)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def place_box(box_to_file, size, object_to_world) -> tuple:
    """An asset's box in the world: (box_to_world (4, 4) rigid, size (3,) metres) from its box in file coordinates
    and the asset's ``object_to_world`` (any affine). The box's axes are mapped by the affine's linear part: sizes
    scale by the lengths of the mapped axes, the rotation is the nearest one to the mapped axes (exact for
    similarities; for a shear, the nearest box)."""
    A = np.asarray(object_to_world, np.float64) @ np.asarray(box_to_file, np.float64)
    lengths = np.linalg.norm(A[:3, :3], axis=0)
    T = np.eye(4)
    T[:3, :3] = nearest_rotation(A[:3, :3] / np.where(lengths > 0, lengths, 1.0))
    T[:3, 3] = A[:3, 3]
    return T, np.asarray(size, np.float64) * lengths


def rigid_box(M) -> tuple:
    """(box_to_x (4, 4) rigid, size (3,)) of an affine ``M`` that maps the unit cube [−0.5, 0.5]³ onto a box (a
    Blender cube empty of display size 0.5 has that matrix_world)."""
    return place_box(np.eye(4), np.ones(3), M)


def corners(box_to_world, size) -> np.ndarray:
    """(8, 3) corners of a box; corner i has sign bits (x: bit 2, y: bit 1, z: bit 0) of ``_CORNER_SIGNS``. Of N
    boxes at once: ``box_to_world`` (N, 4, 4), ``size`` (N, 3) give (N, 8, 3)."""
    T = np.asarray(box_to_world, np.float64)
    return ((_CORNER_SIGNS * np.asarray(size, np.float64)[..., None, :]) @ np.swapaxes(T[..., :3, :3], -1, -2)
            + T[..., None, :3, 3])


def contains(box_to_world, size, point, margin: float = 0.0) -> bool:
    """Whether ``point`` (3,) lies inside the box grown by ``margin`` on every side."""
    T = np.asarray(box_to_world, np.float64)
    local = (np.asarray(point, np.float64) - T[:3, 3]) @ T[:3, :3]
    return bool(np.all(np.abs(local) <= np.asarray(size, np.float64) / 2 + margin))


def object_pose(box_to_x, size) -> dict:
    """A box as labels describe it in frame x: ``center`` (3,), ``size`` (length, width, height), ``rotation`` the
    object_to_x rotation (3, 3) of the object frame (x forward, y left, z up), its ``quaternion`` (w, x, y, z)
    and ``yaw`` = atan2 of the forward axis' y and x components in frame x (radians, −π..π). Also of N boxes at
    once: ``box_to_x`` (N, 4, 4), ``size`` (N, 3) give each entry a leading N axis (``yaw`` an array)."""
    T = np.asarray(box_to_x, np.float64)
    R = T[..., :3, :3] @ OBJECT_TO_BOX
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return {"center": T[..., :3, 3].copy(), "size": np.asarray(size, np.float64)[..., [1, 0, 2]], "rotation": R,
            "quaternion": cameras.rotation_to_quaternion(R), "yaw": float(yaw) if yaw.ndim == 0 else yaw}


def rotation_y(object_to_camera_rotation) -> float:
    """KITTI's ``rotation_y`` of an object in OpenCV camera axes: the angle about the camera's y axis such that
    the object's forward axis, projected on the camera's x–z plane, points along (cos ry, 0, −sin ry)."""
    f = np.asarray(object_to_camera_rotation, np.float64)[:, 0]
    return float(np.arctan2(-f[2], f[0]))


# -- projecting a box --------------------------------------------------------------------------------------------

def _clipped_vertices(corners_cam: np.ndarray, near: float) -> np.ndarray:
    """The vertices of a box (8 corners in camera axes) cut by the plane z = near, keeping z >= near: the corners
    in front and the points where the 12 edges cross the plane. (M, 3); empty when the box lies wholly behind."""
    keep = [corners_cam[corners_cam[:, 2] >= near]]
    a, b = corners_cam[EDGES[:, 0]], corners_cam[EDGES[:, 1]]
    cross = (a[:, 2] < near) != (b[:, 2] < near)
    if cross.any():
        a, b = a[cross], b[cross]
        t = (near - a[:, 2]) / (b[:, 2] - a[:, 2])
        keep.append(a + t[:, None] * (b - a))
    return np.concatenate(keep)


def unseen_projection() -> dict:
    """``project_box``'s answer for a box no camera pixel shows (wholly behind the near plane; the defaults the
    others start from): no polygon, no bbox, truncation 1, no depth range. A new dict each call."""
    return {"polygon": np.zeros((0, 2)), "bbox": None, "truncation": 1.0, "depth_range": None}


def project_box(box_to_world, size, K, world_to_camera, width: int, height: int, near: float = 0.05) -> dict:
    """A box seen by a camera: ``polygon`` (M, 2) pixel coordinates of the convex hull of the projected box (cut at
    z = ``near`` first, so boxes reaching behind the camera project correctly; empty when wholly behind),
    ``bbox`` [x0, y0, x1, y1] its bounding rectangle clipped to the image [0, width] x [0, height] (continuous
    pixel coordinates; None when it misses the image), ``truncation`` = 1 − area(clipped) / area(unclipped)
    (0: inside the image; 1: outside or behind), and ``depth_range`` (z min, z max) of the cut box."""
    w2c = np.asarray(world_to_camera, np.float64)
    cam = corners(box_to_world, size) @ w2c[:3, :3].T + w2c[:3, 3]
    V = _clipped_vertices(cam, near)
    out = unseen_projection()
    if len(V) == 0:
        return out
    K = np.asarray(K, np.float64)
    uv = (V @ K.T)[:, :2] / V[:, 2:3]
    out["polygon"] = convex_hull(uv)
    out["depth_range"] = (float(V[:, 2].min()), float(V[:, 2].max()))
    out.update(_image_rect(*uv.min(0), *uv.max(0), width, height))
    return out


def _image_rect(x0, y0, x1, y1, width: int, height: int) -> dict:
    """``project_box``'s ``bbox`` and ``truncation`` of projected points spanning [x0, x1] x [y0, y1]; {} when
    they miss the image (or their area overflows): the box's defaults stand."""
    cx0, cy0, cx1, cy1 = max(x0, 0.0), max(y0, 0.0), min(x1, float(width)), min(y1, float(height))
    area = (x1 - x0) * (y1 - y0)
    if cx1 <= cx0 or cy1 <= cy0 or not np.isfinite(area):
        return {}
    return {"bbox": [float(cx0), float(cy0), float(cx1), float(cy1)],
            "truncation": float(np.clip(1.0 - (cx1 - cx0) * (cy1 - cy0) / area, 0.0, 1.0)) if area > 0 else 0.0}


def project_boxes(box_to_world, size, K, world_to_camera, width: int, height: int, near: float = 0.05) -> list:
    """``project_box`` of N boxes at once (``box_to_world`` (N, 4, 4), ``size`` (N, 3)), the same numbers as one at
    a time. The boxes wholly behind the near plane, and those wholly in front whose corners project to finite
    pixels (below 1e150), take one numpy pass, then a hull each for those in the image only: one of them that
    misses the image gets an empty ``polygon`` (its hull would be finite, and nothing of it is rasterised). A
    box the plane cuts, or whose projection overflows, takes ``project_box``."""
    T, S = np.asarray(box_to_world, np.float64), np.asarray(size, np.float64)
    w2c = np.asarray(world_to_camera, np.float64)
    cam = corners(T, S) @ w2c[:3, :3].T + w2c[:3, 3]   # (N, 8, 3), as project_box has them
    with np.errstate(all="ignore"):  # corners at or behind the camera divide by z <= 0: those boxes are not used
        uv = (cam @ np.asarray(K, np.float64).T)[..., :2] / cam[..., 2:3]
        behind = (cam[..., 2] < near).all(1)
        front = (cam[..., 2] >= near).all(1) & (np.abs(uv) < 1e150).all((1, 2))
    lo, hi, z = uv.min(1).tolist(), uv.max(1).tolist(), cam[..., 2]
    out = []
    for n in range(len(T)):
        if behind[n]:
            out.append(unseen_projection())
        elif front[n]:
            p = {**unseen_projection(), "depth_range": (float(z[n].min()), float(z[n].max())),
                 **_image_rect(*lo[n], *hi[n], width, height)}
            if p["bbox"] is not None:
                p["polygon"] = convex_hull(uv[n])
            out.append(p)
        else:
            out.append(project_box(T[n], S[n], K, w2c, width, height, near))
    return out


def cross2(a, b):
    """The z of the cross product of 2-vectors ``a`` (..., 2) and ``b`` (..., 2): > 0 when b turns left of a.
    (``np.cross`` of 2-vectors is deprecated in numpy 2.)"""
    a, b = np.asarray(a), np.asarray(b)
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def convex_hull(xy) -> np.ndarray:
    """(M, 2) counter-clockwise (in pixel axes: clockwise on screen) hull of 2-D points (Andrew's monotone
    chain)."""
    P = np.asarray(xy, np.float64)
    # np.unique(P, axis=0) at a quarter of its cost: the rows in lexicographic order (NaN last), the first of
    # equal rows kept (np.unique's values; of 0.0 and -0.0 at one place it may keep the other, the same pixels)
    P = P[np.lexsort((P[:, 1], P[:, 0]))]
    first = np.ones(len(P), bool)
    first[1:] = (P[1:] != P[:-1]).any(1)
    P = P[first]
    if len(P) < 3:
        return P

    def half(points):
        # on Python floats (the same IEEE arithmetic as ``cross2`` on rows, without numpy's cost per small call)
        h = []
        for px, py in points:
            while len(h) >= 2 and ((h[-1][0] - h[-2][0]) * (py - h[-2][1])
                                   - (h[-1][1] - h[-2][1]) * (px - h[-2][0])) <= 0:
                h.pop()
            h.append((px, py))
        return h[:-1]

    rows = P.tolist()
    return np.array(half(rows) + half(rows[::-1]), np.float64)


def polygon_mask(polygon, width: int, height: int) -> np.ndarray:
    """(height, width) bool: the pixels whose centres (u + 0.5, v + 0.5) lie inside a convex polygon (M, 2)."""
    mask = np.zeros((height, width), bool)
    window = polygon_window(polygon, width, height)
    if window is not None:
        (x0, y0), inside = window
        mask[y0:y0 + inside.shape[0], x0:x0 + inside.shape[1]] = inside
    return mask


def polygon_window(polygon, width: int, height: int):
    """``polygon_mask`` within the image rectangle that holds the polygon: ((x0, y0) its top-left pixel,
    inside (h, w) bool), None when it covers no pixel of the image. Work in proportion to the polygon's size."""
    P = np.asarray(polygon, np.float64)
    if len(P) < 3:
        return None
    # clipped to the image (np.minimum of np.maximum: np.clip's numbers at a tenth of its cost on two values)
    x0, y0 = np.minimum(np.maximum(np.floor(P.min(0)).astype(np.int64), 0), [width, height])
    x1, y1 = np.minimum(np.maximum(np.ceil(P.max(0)).astype(np.int64) + 1, 0), [width, height])
    if x1 <= x0 or y1 <= y0:
        return None
    # every edge (a -> b) at once, (edges, rows, columns); pixel centres as a row (u) and a column (v): each
    # edge's two products are made once per column or row, the same numbers as on a full grid
    u, v = (np.arange(x0, x1) + 0.5)[None, None, :], (np.arange(y0, y1) + 0.5)[None, :, None]
    a, b = P[:, :, None, None], np.concatenate([P[1:], P[:1]])[:, :, None, None]
    orient = np.sign(cross2(P[1] - P[0], P[2] - P[0])) or 1.0
    inside = (orient * ((b[:, 0] - a[:, 0]) * (v - a[:, 1]) - (b[:, 1] - a[:, 1]) * (u - a[:, 0])) >= 0).all(0)
    return (int(x0), int(y0)), inside
