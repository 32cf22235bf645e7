"""The labelled preview (``conditions/labelled_NNNNNN.png``): the condition image with a frame's labels drawn on it,
for people to check the labels at a glance (docs/design.md §15).

Per object not removed and in view: its projected 3D box (edges cut at the near plane, so boxes reaching behind the
camera draw correctly), its visible 2D box, and ``#track class visible%``; inserted cars in a colour per track,
recorded objects in white. Ignore regions (``core.labels.ignore_region``: objects marked ignore, and recorded
objects whose points are missing) are greyed and hatched instead, their box and text grey, the text ending
``ignore`` or ``no points``. A banner gives the frame, its timestamp, its coverage, the share of unlabelled pixels
when there are any, and its flags (red when it has any). Drawn with OpenCV's primitives (antialiased lines, Hershey
text) and numpy (the hatching).
"""

from __future__ import annotations

import numpy as np

from scpainter_blender.core import labels as labels_mod
from scpainter_blender.core.geometry import boxes

from .. import png

RECORDED_COLOUR = (255, 255, 255)
#: Ignore regions: their boxes and text, and the hatching's lines (every ``HATCH_PERIOD`` px along a diagonal).
IGNORE_COLOUR, HATCH_COLOUR, HATCH_PERIOD = (170, 170, 170), (60, 60, 60), 6


def hatch(img: np.ndarray, regions: list) -> None:
    """Grey out and hatch ``regions`` ([x0, y0, x1, y1] continuous pixel boxes) of (H, W, 3) uint8 ``img`` in place:
    the pixels whose centres they hold, each once however many regions cover it."""
    if not regions:  # nothing to grey: no full-image mask and diagonal pattern
        return
    H, W = img.shape[:2]
    mask = np.zeros((H, W), bool)
    for x0, y0, x1, y1 in regions:
        mask[max(int(np.ceil(y0 - 0.5)), 0):max(int(np.ceil(y1 - 0.5)), 0),
             max(int(np.ceil(x0 - 0.5)), 0):max(int(np.ceil(x1 - 0.5)), 0)] = True
    img[mask] = (img[mask] // 2 + 64).astype(np.uint8)                       # halfway to mid grey
    lines = mask & (np.add.outer(np.arange(H), np.arange(W)) % HATCH_PERIOD == 0)
    img[lines] = HATCH_COLOUR


def track_colour(track_id: int) -> tuple:
    """A saturated RGB colour per track id (golden-ratio hues from orange: neighbours differ)."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((0.1 + (track_id - 1) * 0.618033988749895) % 1.0, 0.85, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def _box_to(labelled_boxes: list) -> tuple:
    """(box_to_frame (N, 4, 4), size (N, 3) width, length, height) of labels' boxes (center, size l w h,
    quaternion), all at once (the same numbers as one at a time)."""
    from scpainter_blender.core.geometry import cameras

    T = np.tile(np.eye(4), (len(labelled_boxes), 1, 1))
    if not labelled_boxes:
        return T, np.zeros((0, 3))
    q = np.array([b["quaternion"] for b in labelled_boxes], np.float64)
    T[:, :3, :3] = cameras.quaternion_to_rotation(q) @ boxes.OBJECT_TO_BOX.T
    T[:, :3, 3] = [b["center"] for b in labelled_boxes]
    lwh = np.array([b["size"] for b in labelled_boxes], np.float64)
    return T, lwh[:, [1, 0, 2]]


def _edges(c, K) -> list:
    """((x, y), (x, y)) integer pixel end points of the 12 edges of a box with corners ``c`` (8, 3) in camera axes,
    each cut at the near plane (an edge wholly behind it left out, as is one whose projection is not finite or
    reaches 1e6 px): all 12 at once, one numpy pass per box rather than per edge."""
    near = labels_mod.NEAR
    a, b = c[boxes.EDGES[:, 0]], c[boxes.EDGES[:, 1]]
    a_in, b_in = ~(a[:, 2] < near), ~(b[:, 2] < near)
    with np.errstate(all="ignore"):  # the cut's t of an edge parallel to the plane is used by no kept edge
        t = (near - a[:, 2]) / (b[:, 2] - a[:, 2])
        p = a + t[:, None] * (b - a)
        a = np.where((~a_in & b_in)[:, None], p, a)
        b = np.where((a_in & ~b_in)[:, None], p, b)
        # K @ point as a stack of matrix-vector products: the same rounding as one point at a time (a @ K.T is
        # not, and a pixel's rounding would move)
        pa = (K @ a[:, :, None])[:, :2, 0] / a[:, 2:3]
        pb = (K @ b[:, :, None])[:, :2, 0] / b[:, 2:3]
    ends = np.concatenate([pa, pb], 1)
    keep = (a_in | b_in) & np.isfinite(ends).all(1) & (np.abs(ends).max(1, initial=0.0) < 1e6)
    return [((round(x0), round(y0)), (round(x1), round(y1))) for x0, y0, x1, y1 in ends[keep].tolist()]


def draw(rgb, labels: dict) -> np.ndarray:
    """(H, W, 3) uint8: ``rgb`` (float [0, 1] or uint8) with ``labels`` (``core.labels``) drawn on it."""
    import cv2

    img = np.ascontiguousarray(png.eight_bit(rgb).copy())
    H, W = img.shape[:2]
    K = np.asarray(labels["camera"]["K"], np.float64)
    scale = max(0.4, min(W, H) / 600.0)   # OpenCV's font scale: ~0.4 keeps 10 px letters legible at 518 x 294
    shown = [o for o in labels["objects"] if not o["removed"] and o["in_view"]]
    regions = [labels_mod.ignore_region(o) for o in shown]
    hatch(img, [r for r in regions if r is not None])
    for o, region, T, size in zip(shown, regions, *_box_to([o["box_camera"] for o in shown])):
        colour = track_colour(o["track_id"]) if o["synthetic"] else RECORDED_COLOUR
        if region is not None:
            colour = IGNORE_COLOUR
        for pa, pb in _edges(boxes.corners(T, size), K):
            cv2.line(img, pa, pb, colour, 1, cv2.LINE_AA)
        if o["bbox_visible"] is not None and region is None:
            x0, y0, x1, y1 = (int(round(v)) for v in o["bbox_visible"])
            cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
        x0, y0 = (int(round(v)) for v in o["bbox_amodal"][:2])
        if region is not None:
            what = " no points" if o["points_missing"] else " ignore"
        else:
            what = "" if o["visible_fraction"] is None else f" {o['visible_fraction']:.0%}"
        _text(img, f"#{o['track_id']} {o['class']}{what}", (max(x0, 0), y0), colour, scale)
    flags = labels["flags"]
    unlabelled = labels["unlabelled_fraction"]
    banner = (f"frame {labels['frame']}  t={labels['timestamp_s']:.2f}s  coverage {labels['coverage']:.0%}"
              + (f"  unlabelled {unlabelled:.1%}" if unlabelled else "") + (f"  {', '.join(flags)}" if flags else ""))
    _text(img, banner, (0, H), (255, 90, 90) if flags else (255, 255, 255), scale)
    return img


def _text(img, text: str, corner, colour, scale: float) -> None:
    """``text`` on a dark box whose lower-left corner is ``corner`` (kept inside the image, the text no wider)."""
    import cv2

    H, W = img.shape[:2]
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    if w > W - 4:  # a small image: the text shrinks to its width rather than losing its end (the flags)
        scale *= (W - 4) / w
        (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    x = int(min(max(corner[0], 0), max(W - w - 4, 0)))
    y = int(min(max(corner[1], h + base + 4), H))
    cv2.rectangle(img, (x, y - h - base - 4), (x + w + 4, y), (0, 0, 0), -1)
    cv2.putText(img, text, (x + 2, y - base - 2), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def write(path: str, rgb, labels: dict) -> None:
    """``draw`` written as an 8-bit PNG, atomically."""
    png.write_png(path, draw(rgb, labels))
