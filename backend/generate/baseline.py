"""The baseline generator: the condition image with its holes filled by OpenCV inpainting, no model and no weights.

It is the paper's "naive" comparison made watchable: ``generate`` uses it when no checkpoint is configured (or with
``--model baseline``), and ``evaluate`` scores it next to the model. It sees one frame at a time, so it knows
nothing of time, lighting or shadows: what it shows is how much of a new view the points and assets already cover.

Methods (``cv2.inpaint``):

* ``telea`` — A. Telea, "An Image Inpainting Technique Based on the Fast Marching Method", J. Graphics Tools 9(1),
  2004: each hole pixel, in order of distance from the hole's border, gets a weighted average of the known pixels
  within ``radius``, extrapolated along their gradients.
* ``navier-stokes`` — M. Bertalmio, A. L. Bertozzi, G. Sapiro, "Navier-Stokes, Fluid Dynamics, and Image and Video
  Inpainting", CVPR 2001: isophotes carried into the hole as the flow of an incompressible fluid.

Both run on 8-bit images (OpenCV inpaints 3-channel images only as 8 bits), so known pixels come back as the
condition image rounded to 8 bits, which is what the PNG and MP4 outputs hold anyway.
"""

from __future__ import annotations

import numpy as np

from scpainter_blender.core import job as job_mod

#: The OpenCV flag of each ``generate.inpaint`` value (``job.INPAINT_METHODS``; cv2's constants, resolved lazily).
METHODS = {"telea": "INPAINT_TELEA", "navier-stokes": "INPAINT_NS"}
NAMES = job_mod.INPAINT_NAMES
#: The defaults live with the job's other generation defaults (radius: the neighbourhood each hole pixel is filled
#: from, in pixels; OpenCV's documentation examples use 3).
DEFAULT_METHOD = job_mod.BASELINE_DEFAULTS["inpaint"]
DEFAULT_RADIUS = job_mod.BASELINE_DEFAULTS["inpaint_radius"]
#: A hole pixel is one whose hole mask M is above this (M is 0 or 1 from the renderer; a re-saved EXR may blur it).
HOLE_THRESHOLD = 0.5


def describe(method: str, radius: int) -> str:
    """One line for logs, events, the manifest and the MP4's metadata: what this video is and what it is not."""
    return (f"baseline: the condition image with its holes filled by OpenCV {NAMES[method]} inpainting "
            f"(radius {radius} px); no model")


def to_uint8(image: np.ndarray) -> np.ndarray:
    """(..., 3) float in [0, 1] -> uint8, rounded; NaN counts as 0 (the renderer never writes one: re-saved files)."""
    return (np.clip(np.nan_to_num(image, nan=0.0), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def inpaint_frame(image: np.ndarray, hole: np.ndarray, method: str = DEFAULT_METHOD,
                  radius: int = DEFAULT_RADIUS) -> np.ndarray:
    """One frame filled in.

    image: (H, W, 3) float in [0, 1] (the condition image I, display-referred) or uint8.
    hole: (H, W) float, the hole mask M (1 = nothing landed); pixels with M > HOLE_THRESHOLD are filled.
    Returns (H, W, 3) uint8. A frame without holes comes back as it is; a frame that is all hole has nothing to fill
    from and comes back as it is too (black where the renderer left holes)."""
    import cv2

    rgb = image if image.dtype == np.uint8 else to_uint8(image)
    mask = np.ascontiguousarray(hole > HOLE_THRESHOLD, dtype=np.uint8)
    if not mask.any() or mask.all():
        return np.ascontiguousarray(rgb)
    return cv2.inpaint(np.ascontiguousarray(rgb), mask, float(radius), getattr(cv2, METHODS[method]))


def inpaint_video(image, hole, method: str = DEFAULT_METHOD, radius: int = DEFAULT_RADIUS, on_frame=None):
    """Every frame filled in, one at a time.

    image: (F, 3, H, W) float in [0, 1] (``generate.load_conditions``'s I; a torch tensor or numpy array).
    hole: (F, 1, H, W) or (F, H, W), the hole mask M (or pass 1 − validity).
    on_frame(i, frame): called after each frame (i from 0); returning True stops early.
    Returns (F', H, W, 3) uint8 with F' = F unless stopped."""
    image, hole = np.asarray(image), np.asarray(hole)
    hole = hole[:, 0] if hole.ndim == 4 else hole
    out = []
    for i in range(len(image)):
        frame = inpaint_frame(np.moveaxis(image[i], 0, -1), hole[i], method, radius)
        out.append(frame)
        if on_frame is not None and on_frame(i, frame):
            break
    H, W = image.shape[2:]
    return np.stack(out) if out else np.zeros((0, H, W, 3), np.uint8)
