"""The labelled preview (``conditions/labelled_NNNNNN.png``): the condition image with a frame's labels drawn on it,
for people to check the labels at a glance (docs/design.md §15).

Per object not removed and in view: its projected 3D box (edges cut at the near plane, so boxes reaching behind the
camera draw correctly), its amodal 2D box thin, its visible 2D box, and ``#track class visible%``; inserted cars in
a colour per track, recorded objects in white. A banner gives the frame, its timestamp, its coverage and its flags
(red when it has any). Drawn with OpenCV's primitives (antialiased lines, Hershey text).
"""

from __future__ import annotations

import numpy as np

from scpainter_blender.core import labels as labels_mod
from scpainter_blender.core.geometry import boxes

from .. import png

RECORDED_COLOUR = (255, 255, 255)


def track_colour(track_id: int) -> tuple:
    """A saturated RGB colour per track id (golden-ratio hues from orange: neighbours differ)."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((0.1 + (track_id - 1) * 0.618033988749895) % 1.0, 0.85, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def _box_to(labelled_box: dict) -> tuple:
    """(box_to_frame (4, 4), size (width, length, height)) of a label's box (center, size l w h, quaternion)."""
    from scpainter_blender.core.geometry import cameras

    T = np.eye(4)
    T[:3, :3] = cameras.quaternion_to_rotation(np.asarray(labelled_box["quaternion"])) @ boxes.OBJECT_TO_BOX.T
    T[:3, 3] = labelled_box["center"]
    l, w, h = labelled_box["size"]
    return T, np.array([w, l, h])


def draw(rgb, labels: dict) -> np.ndarray:
    """(H, W, 3) uint8: ``rgb`` (float [0, 1] or uint8) with ``labels`` (``core.labels``) drawn on it."""
    import cv2

    img = rgb if rgb.dtype == np.uint8 else (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    img = np.ascontiguousarray(img.copy())
    H, W = img.shape[:2]
    K = np.asarray(labels["camera"]["K"], np.float64)
    scale = max(0.4, min(W, H) / 600.0)   # OpenCV's font scale: ~0.4 keeps 10 px letters legible at 518 x 294
    for o in labels["objects"]:
        if o["removed"] or not o["in_view"]:
            continue
        colour = track_colour(o["track_id"]) if o["synthetic"] else RECORDED_COLOUR
        T, size = _box_to(o["box_camera"])
        c = boxes.corners(T, size)
        for i, j in boxes.EDGES:
            a, b = c[i], c[j]
            if a[2] < labels_mod.NEAR and b[2] < labels_mod.NEAR:
                continue
            if a[2] < labels_mod.NEAR or b[2] < labels_mod.NEAR:  # cut the edge at the near plane
                t = (labels_mod.NEAR - a[2]) / (b[2] - a[2])
                p = a + t * (b - a)
                a, b = (p, b) if a[2] < labels_mod.NEAR else (a, p)
            pa, pb = (K @ a)[:2] / a[2], (K @ b)[:2] / b[2]
            if np.all(np.isfinite([pa, pb])) and np.abs(np.concatenate([pa, pb])).max() < 1e6:
                cv2.line(img, tuple(int(round(v)) for v in pa), tuple(int(round(v)) for v in pb), colour, 1,
                         cv2.LINE_AA)
        if o["bbox_visible"] is not None:
            x0, y0, x1, y1 = (int(round(v)) for v in o["bbox_visible"])
            cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
        x0, y0 = (int(round(v)) for v in o["bbox_amodal"][:2])
        vis = "" if o["visible_fraction"] is None else f" {o['visible_fraction']:.0%}"
        _text(img, f"#{o['track_id']} {o['class']}{vis}", (max(x0, 0), y0), colour, scale)
    flags = labels["flags"]
    banner = (f"frame {labels['frame']}  t={labels['timestamp_s']:.2f}s  coverage {labels['coverage']:.0%}"
              + (f"  {', '.join(flags)}" if flags else ""))
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
