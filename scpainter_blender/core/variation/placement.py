"""Placing cars in a variant: footprints on the ground plane, the rejection rules, parked and moving cars.

Frames: world metres, Z up. A car's pose is its box (``core.geometry.boxes``' convention: x width, y length with
+y the front, z up); its **footprint** is the box's rectangle on the ground, (4, 2) corners in order. Headings are
unit horizontal vectors (the direction of travel, ``core.geometry.trajectory``); *left* = up × heading.

The rules a car must pass, each named in the manifest when it rejects a try (``RULES``):

- ``off_road``, ``recorded_object``: the road's (``road.Road.check_footprint``: not on road tiles or on a
  kerb/sidewalk; points of something standing there);
- ``recorded_box``: overlaps a removal box, a recorded object's box at that frame, or a car the base job already
  holds, grown by the gap;
- ``car_overlap``: overlaps a car placed before it in the variant, at any frame, grown by the gap;
- ``ego_path``: a parked car touches the swept footprint of the variant's camera path (the ego vehicle's
  rectangle around each camera, grown by its margin, over every frame); a moving car touches, at some frame, the
  ego's rectangles of that frame and of the frames of the next ``headway`` (the road the ego covers in that
  time: a car driving ahead in its lane keeps a gap; one it never meets may cross where it drove).

A car's pose along the drive is ``drive``'s (the scenario command's moving and parked cars, and *Drive Along
Lane* in Blender). A moving car is checked at every frame; a parked one once (and against every frame of the
others). Before any car, the variant's camera path itself must stay on the road and clear of what the base holds
(``CAMERA_RULES``): a shift plus a lane change can otherwise drive the camera into a parked car or onto the
sidewalk.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.boxes import cross2

if TYPE_CHECKING:
    from collections.abc import Sequence
    from .road import Road


RULES = ("off_road", "recorded_object", "recorded_box", "car_overlap", "ego_path")
#: The rules a variant's camera path must pass first (``variants.Variation.check_camera``).
CAMERA_RULES = ("camera_off_road", "camera_blocked")
UP = np.array([0.0, 0.0, 1.0])


def rectangle(centre_xy: np.ndarray, heading_xy: np.ndarray, length: float, width: float) -> np.ndarray:
    """(4, 2) corners, in order, of a rectangle of ``length`` along the unit ``heading_xy`` and ``width`` across,
    centred at ``centre_xy``."""
    h = np.asarray(heading_xy, np.float64)
    left = np.array([-h[1], h[0]])
    c = np.asarray(centre_xy, np.float64)
    hl, hw = 0.5 * length * h, 0.5 * width * left
    return np.stack([c - hl - hw, c + hl - hw, c + hl + hw, c - hl + hw])


def box_footprint(box_to_world: np.ndarray, size: np.ndarray, grow: float = 0.0) -> np.ndarray:
    """(4, 2) footprint of a box (its x-y rectangle, the box assumed upright), grown by ``grow`` on every side."""
    T = np.asarray(box_to_world, np.float64)
    y = T[:2, 1] / max(np.linalg.norm(T[:2, 1]), 1e-12)
    return rectangle(T[:2, 3], y, float(size[1]) + 2 * grow, float(size[0]) + 2 * grow)


def rectangles_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether convex quadrilaterals overlap (touching counts), by the separating axis theorem: ``a`` (..., 4, 2),
    ``b`` (..., 4, 2), broadcast; returns a bool array of the broadcast shape."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    overlap = np.ones(a.shape[:-2], bool)
    for poly in (a, b):
        for k in range(2):                       # a rectangle has two edge directions
            e = poly[..., k + 1, :] - poly[..., k, :]
            n = np.stack([-e[..., 1], e[..., 0]], axis=-1)[..., None, :]
            pa, pb = (a * n).sum(-1), (b * n).sum(-1)
            overlap &= (pa.max(-1) >= pb.min(-1)) & (pb.max(-1) >= pa.min(-1))
    return overlap


def overlaps_any(rect: np.ndarray, rects: np.ndarray) -> bool:
    """Whether the quadrilateral ``rect`` (4, 2) overlaps any of ``rects`` (K, 4, 2), K ≥ 0."""
    return len(rects) > 0 and bool(rectangles_overlap(rect, rects).any())


def rectangles_overlap_reference(a: np.ndarray, b: np.ndarray) -> bool:
    """The plain version of ``rectangles_overlap`` for one pair: some corner of one inside the other, or two edges
    crossing (tests compare the two)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)

    def inside(p, poly):
        s = [cross2(poly[(i + 1) % 4] - poly[i], p - poly[i]) for i in range(4)]
        return all(v >= 0 for v in s) or all(v <= 0 for v in s)

    def cross(p1, p2, q1, q2):
        d = lambda o, x, y: cross2(x - o, y - o)  # noqa: E731
        return d(p1, p2, q1) * d(p1, p2, q2) <= 0 and d(q1, q2, p1) * d(q1, q2, p2) <= 0

    if any(inside(p, b) for p in a) or any(inside(p, a) for p in b):
        return True
    return any(cross(a[i], a[(i + 1) % 4], b[j], b[(j + 1) % 4]) for i in range(4) for j in range(4))


@dataclass
class Path:
    """A camera path on the ground: centres (F, 3) world, per-frame unit headings (F, 2), arc length (F,)."""
    centres: np.ndarray
    headings: np.ndarray
    arc: np.ndarray

    @classmethod
    def of(cls, centres: np.ndarray, headings: np.ndarray) -> "Path":
        c = np.asarray(centres, np.float64)
        step = np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1)
        return cls(c, np.asarray(headings, np.float64)[:, :2], np.concatenate([[0.0], np.cumsum(step)]))

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    def at(self, s: np.ndarray | float) -> tuple:
        """(xy (..., 2), heading (..., 2)) at arc lengths ``s`` (...): interpolated along the path, continued in a
        straight line beyond its ends."""
        s = np.asarray(s, np.float64)
        arc, c, h = self.arc, self.centres[:, :2], self.headings
        if len(arc) == 1 or arc[-1] <= 0:
            return c[0] + s[..., None] * h[0], np.broadcast_to(h[0], s.shape + (2,)).copy()
        i = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(arc) - 2)
        seg = np.maximum(arc[i + 1] - arc[i], 1e-12)
        t = (s - arc[i]) / seg
        before, after = s < 0, s > arc[-1]
        t = np.where(before, 0.0, np.where(after, 1.0, t))
        xy = c[i] + t[..., None] * (c[i + 1] - c[i])
        xy = np.where(before[..., None], c[0] + s[..., None] * h[0], xy)
        xy = np.where(after[..., None], c[-1] + (s - arc[-1])[..., None] * h[-1], xy)
        head = h[i] + t[..., None] * (h[i + 1] - h[i])
        head /= np.maximum(np.linalg.norm(head, axis=-1, keepdims=True), 1e-12)
        return xy, head

    def project(self, xy: np.ndarray) -> tuple:
        """(arc length, offset left of the path), metres, of the world point ``xy`` (2,): the point of the path
        nearest it (the path continued straight beyond its ends, as ``at``) and how far to its left it lies."""
        p = np.asarray(xy, np.float64)[:2]
        c, arc = self.centres[:, :2], self.arc
        d = np.diff(c, axis=0)
        L2 = (d * d).sum(1)
        u = np.clip(((p - c[:-1]) * d).sum(1) / np.maximum(L2, 1e-24), 0.0, 1.0)
        # candidates: the nearest point of each segment, and of the straight continuations before and after
        s = np.concatenate([[min(0.0, float((p - c[0]) @ self.headings[0]))], arc[:-1] + u * np.sqrt(L2),
                            [arc[-1] + max(0.0, float((p - c[-1]) @ self.headings[-1]))]])
        at, head = self.at(s)
        k = int(np.argmin(np.linalg.norm(at - p, axis=1)))
        return float(s[k]), float((p - at[k]) @ np.array([-head[k, 1], head[k, 0]]))


@dataclass
class Car:
    """A car placed in a variant: per output frame its rigid ``box_to_world`` and footprint; ``size`` (3,)
    metres (width, length, height)."""
    size: np.ndarray
    box_to_world: dict                 # {frame: (4, 4)}
    footprints: dict                   # {frame: (4, 2)}
    moving: bool = False
    details: dict = field(default_factory=dict)


def box_on_ground(road: Road, xy: np.ndarray, heading: np.ndarray, size: np.ndarray) -> np.ndarray | None:
    """The rigid box_to_world (4, 4) of a box of ``size`` (width, length, height) standing on the road's plane at
    ``xy`` (2,), its +y along ``heading`` (2,) turned with the plane's normal (as *Snap to Ground* aligns an
    asset); None where no plane is known."""
    z, normal = road.ground(np.asarray(xy, np.float64))
    if not np.isfinite(z):
        return None
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    fwd = np.array([heading[0], heading[1], 0.0])
    fwd -= (fwd @ n) * n
    fwd /= np.linalg.norm(fwd)
    R = np.stack([np.cross(fwd, n), fwd, n], axis=1)   # columns: box x (width, right), y (front), z (up)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.array([xy[0], xy[1], z]) + n * (0.5 * float(size[2]))
    return T


def drive(road: Road, path: Path, size: np.ndarray, lane_m: float, speed_mps: float, start_m: float, t_s: np.ndarray,
          reach: tuple[float, float] | None = None) -> tuple:
    """A car driving along ``path`` (the drive's ground track, ``variants.reference_path``): (arc lengths (F,),
    per time its rigid box_to_world (4, 4), or None where the road knows no ground there).

    At time ``t_s`` (F,) seconds it is ``start_m + speed_mps · t`` metres along the path (``Path.at``: continued
    straight beyond its ends), held within ``reach`` (low, high) metres when given (the road's reach,
    ``Road.road_arc``: it stops at the end), ``lane_m`` metres left of it (``trajectory.shift_trajectory``'s
    sign); its box of ``size`` (width, length, height) stands on the road's local plane (``box_on_ground``), its
    front along the path's direction, or against it for a negative speed (oncoming). A parked car is a drive at
    speed 0 over one time. The one computation of a car's per-frame pose along the drive: the scenario command's
    moving and parked cars (``variants``) and *Drive Along Lane* (scene/drive_lane.py)."""
    arc = start_m + speed_mps * np.asarray(t_s, np.float64)
    if reach is not None:
        arc = np.clip(arc, *reach)
    xy, head = path.at(arc)
    xy = xy + lane_m * np.stack([-head[:, 1], head[:, 0]], axis=1)
    if speed_mps < 0:
        head = -head
    return arc, [box_on_ground(road, xy[i], head[i], size) for i in range(len(arc))]


class Rules:
    """The obstacles of one variant: the ego path's swept rectangles, the base job's boxes per frame, and the
    cars placed so far. ``frames`` are the variant's output frames."""

    def __init__(self, road: Road, frames: Sequence[int], ego_rects: dict, fixed_boxes: dict, gap_m: float,
                 headway_frames: int = 0) -> None:
        self.road, self.frames, self.gap = road, list(frames), float(gap_m)
        self.ego = np.stack([ego_rects[f] for f in self.frames])                       # (F, 4, 2)
        self.headway = int(headway_frames)
        self.fixed = {f: np.asarray(b, np.float64).reshape(-1, 4, 2) for f, b in fixed_boxes.items()}  # (K, 4, 2)
        self.placed: list = []

    def check(self, car: Car) -> str | None:
        """None when ``car`` may be placed, else the first rule it breaks (``RULES``' order)."""
        feet = car.footprints
        static = not car.moving
        for f in (self.frames[:1] if static else self.frames):
            reason = self.road.check_footprint(feet[f])
            if reason:
                return reason
        grown = {f: _grow(feet[f], self.gap) for f in self.frames}
        for f in self.frames:
            if overlaps_any(grown[f], self.fixed.get(f, ())):
                return "recorded_box"
        for other in self.placed:
            if any(rectangles_overlap(grown[f], other.footprints[f]) for f in self.frames):
                return "car_overlap"
        if static:
            if rectangles_overlap(feet[self.frames[0]], self.ego).any():
                return "ego_path"
            return None
        F = len(self.frames)
        for i, f in enumerate(self.frames):  # the ego now and over the headway ahead
            if rectangles_overlap(feet[f], self.ego[i:min(F, i + self.headway + 1)]).any():
                return "ego_path"
        return None


def _grow(rect, d: float) -> np.ndarray:
    """A rectangle (4, 2) grown by ``d`` on every side."""
    c = rect.mean(0)
    u, v = rect[1] - rect[0], rect[3] - rect[0]
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    return rectangle(c, u / max(lu, 1e-12), lu + 2 * d, lv + 2 * d)
