"""The sRGB transfer function (IEC 61966-2-1): display-encoded values (images, condition RGB, f_dc colours) to
linear light (Blender's colour attributes, glTF's vertex colours and colour factors) and back.

Values are in [0, 1]; linear_to_srgb clips negatives to 0. No bpy, no torch: numpy only.
"""

from __future__ import annotations

import numpy as np


def srgb_to_linear(c) -> np.ndarray:
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c) -> np.ndarray:
    c = np.clip(np.asarray(c, np.float64), 0.0, None)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def hue_rotation(degrees: float) -> np.ndarray:
    """(3, 3) matrix turning RGB colours' hue by ``degrees`` about the grey axis (1, 1, 1) (Rodrigues' rotation:
    greys, and so the SH offset 0.5, stay; saturation and the channel mean are kept). Linear, so it applies to
    every SH coefficient of a Gaussian as to its colour."""
    t = np.radians(degrees)
    a = np.full(3, 1.0 / np.sqrt(3.0))
    A = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.cos(t) * np.eye(3) + (1.0 - np.cos(t)) * np.outer(a, a) + np.sin(t) * A
