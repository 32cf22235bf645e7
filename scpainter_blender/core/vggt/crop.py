"""Crops of VGGT predictions: VGGT's white "pad" borders found, or pixels given, cut from every per-pixel array.

VGGT's ``load_and_preprocess_images(mode="pad")`` pads the shorter side of each image with pure white (1.0) to a
square, half on each side (the second half one pixel larger when the total is odd); its predictions there mean
nothing. ``crop="auto"`` finds those borders (``detect_padding``), or the caller gives (left, top, right, bottom)
pixels; the principal point moves with the crop, so the cropped file unprojects exactly like the unpadded one.

A crop that is not one, or that leaves nothing of the images, raises CropError (an InputError naming the file and
the field "crop"). No bpy, no torch: numpy only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from . import predictions as vggt

if TYPE_CHECKING:
    import os
    from collections.abc import Sequence


class CropError(vggt.PredictionsError):
    """A crop that is not four pixel counts, or leaves nothing of the file's images. ``field`` is "crop" (the
    option, not a key of the file); the text reads "<file name>: crop ...: <what is wrong> (<path>)"."""

    def __init__(self, path: str | os.PathLike, message: str, hint: str | None = None) -> None:
        vggt.PredictionsError.__init__(self, path, None, message, hint)
        self.field = "crop"


def parse_crop(value: str | Sequence[int] | None, path: str | os.PathLike = "<crop option>") -> str | tuple[int, int,
               int, int]:
    """The crop option: ``"auto"``, ``"none"`` (also None, ``""``) or four pixel counts ``left top right
    bottom`` (a sequence, or a string of four integers separated by spaces or commas). Returns "auto", "none" or
    a tuple of 4 ints >= 0; CropError (naming ``path``, the file it is for) saying what is accepted."""
    given = value
    if value is None:
        return "none"
    if isinstance(value, str):
        s = value.strip().lower()
        if s in ("", "none"):
            return "none"
        if s == "auto":
            return "auto"
        value = s.replace(",", " ").split()
    try:
        px = tuple(int(v) for v in value)
        ok = len(px) == 4 and all(p >= 0 and float(v) == p for p, v in zip(px, value))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise CropError(path, f"crop {given!r}: expected 'auto', 'none' or four pixel counts 'left top right "
                              "bottom' (integers >= 0)")
    return px


def white_borders(images: np.ndarray) -> tuple:
    """(left, top, right, bottom): how many border columns/rows are exactly white (1.0 in every channel) in every
    pixel of every frame, symmetric or not. ``images`` (S, H, W, 3)."""
    images = np.asarray(images)
    S, H, W, _ = images.shape
    white = np.ones((H, W), bool)
    for i in range(S):  # one frame at a time: no (S, H, W, 3) temporary
        white &= np.all(images[i] == 1.0, axis=-1)
        if not (white[0].any() or white[-1].any() or white[:, 0].any() or white[:, -1].any()):
            return (0, 0, 0, 0)
    rows, cols = white.all(axis=1), white.all(axis=0)
    lead = lambda x: len(x) if x.all() else int(np.argmin(x))  # noqa: E731  (leading True count)
    return lead(cols), lead(rows), lead(cols[::-1]), lead(rows[::-1])


def detect_padding(images: np.ndarray) -> tuple:
    """(left, top, right, bottom) of the white borders VGGT's "pad" preprocessing adds, or zeros.

    ``load_and_preprocess_images(mode="pad")`` pads the shorter side with pure white (1.0) to a square, half on
    each side (the second half one pixel larger when the total is odd). A border counts only when it is exactly
    1.0 in every channel of every pixel of every frame *and* the opposite border of the same axis is too, with
    the two differing by at most one pixel: a white sky at the top alone, or a sky band wider than the bottom one,
    is not cropped; nor is an image that is white all over.
    """
    left, top, right, bottom = white_borders(images)
    H, W = np.shape(images)[1:3]
    if top >= H or left >= W:
        return (0, 0, 0, 0)

    def symmetric(a, b):
        return (a, b) if a + b >= 2 and abs(a - b) <= 1 else (0, 0)

    top, bottom = symmetric(top, bottom)
    left, right = symmetric(left, right)
    return (left, top, right, bottom)


def apply_crop(crop: str | tuple[int, int, int, int], per_pixel: dict, intrinsic: np.ndarray, report: vggt.LoadReport,
               path: str | os.PathLike) -> dict:
    """Cut ``crop`` from every per-pixel array and move the principal point with it.

    ``crop``: "auto", "none" or (left, top, right, bottom) as parse_crop returns it; ``per_pixel``: key -> array
    (S, H, W, ...), "images" (S, H, W, 3) among them; ``intrinsic`` (S, 3, 3) is shifted by (-left, -top) in
    place. The crop used and what "auto" decided go to ``report`` (a vggt.LoadReport). Returns the cropped arrays
    (contiguous copies; the same dict when nothing is cut). CropError when the crop leaves nothing.
    """
    images = per_pixel["images"]
    _, H, W, _ = images.shape
    report.original_size = (W, H)
    if crop == "auto":
        report.crop_requested = "auto"
        crop = detect_padding(images)
        bands = white_borders(images) if not any(crop) else (0, 0, 0, 0)
        if any(bands) and bands[1] < H:
            report.info.append(f"white borders (left {bands[0]}, top {bands[1]}, right {bands[2]}, bottom "
                               f"{bands[3]} px) are not the symmetric bands VGGT's padding makes: not cropped "
                               "(give the crop in pixels to remove them)")
    elif crop == "none":
        crop = (0, 0, 0, 0)
    else:
        report.crop_requested = "explicit"
    report.crop = tuple(int(c) for c in crop)
    if not any(crop):
        return per_pixel
    left, top, right, bottom = crop
    if left + right >= W or top + bottom >= H:
        raise CropError(path, f"crop left {left} top {top} right {right} bottom {bottom} leaves nothing of the "
                              f"{W} x {H} images: give fewer pixels (or crop 'none')")
    out = {k: np.ascontiguousarray(v[:, top:H - bottom, left:W - right]) for k, v in per_pixel.items()}
    intrinsic[:, 0, 2] -= left
    intrinsic[:, 1, 2] -= top
    how = "VGGT's white padding detected" if report.crop_requested == "auto" else "as given"
    report.info.append(f"cropped left {left}, top {top}, right {right}, bottom {bottom} px ({how}): {W} x {H} -> "
                       f"{W - left - right} x {H - top - bottom}, principal point moved with the crop")
    return out
