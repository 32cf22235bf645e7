"""The backend's WebP decoder (OpenCV's ``imdecode``), which ``core.splats.sog`` reads SOG images with: set as the
process's decoder (``core.splats.webp.set_decoder``) when the ``backend`` package is imported, so every backend path
that reads an asset (``render``, ``render --check``, ``vary``, training, ``splat-asset``) reads SOG the same way.

Importing this module imports neither numpy nor OpenCV (``doctor`` runs without them); ``decode`` does.
"""

from __future__ import annotations

from scpainter_blender.core.splats import webp as core_webp


def decode(data: bytes, name: str):
    """(H, W, 4) uint8 RGBA of WebP ``data`` (``name``: for messages); ValueError when it does not decode.

    OpenCV gives BGR(A): reordered to RGBA; an image without alpha (libwebp leaves it out when every texel is
    opaque) gets alpha 255, which is what its texels hold."""
    import cv2
    import numpy as np

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"OpenCV {cv2.__version__} cannot decode {name} as WebP (corrupt, or OpenCV built "
                         "without WebP)")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"decoded to {image.dtype} {image.shape}, expected 8-bit colour")
    if image.shape[2] == 3:
        return np.ascontiguousarray(np.dstack([image[:, :, ::-1], np.full(image.shape[:2], 255, np.uint8)]))
    return np.ascontiguousarray(image[:, :, [2, 1, 0, 3]])


def register() -> None:
    """Make ``decode`` this process's WebP decoder."""
    core_webp.set_decoder(decode)
