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
