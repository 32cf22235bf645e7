"""TensorBoard logging for the trainer: scalars, images and GIF videos, or nothing at all (``TrainLog(None)``).

Images and videos are (3, H, W) / (F, 3, H, W) floats in [0, 1], sRGB display values (no tone mapping here); they
are stored as 8-bit. Importing this module imports nothing heavy: torch's SummaryWriter (and tensorboard) is
imported when a real ``TrainLog`` is made, so the no-op object never loads it.
"""

from __future__ import annotations

import io
import os
from typing import Any


def _to_uint8(x: Any, ndim: int, what: str):
    """Tensor or array with ``ndim`` dims and 3 channels at dim -3, floats in [0, 1] -> uint8 numpy, channels last.

    Non-finite values become 0 (a NaN would otherwise cast to an arbitrary byte); the rest is clipped and rounded.
    """
    import numpy as np

    if hasattr(x, "detach"):  # torch tensor, possibly on a GPU, in bf16, or needing grad
        x = x.detach().float().cpu().numpy()
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != ndim or x.shape[-3] != 3 or 0 in x.shape:
        raise ValueError(f"{what} must be a non-empty {'(F, 3, H, W)' if ndim == 4 else '(3, H, W)'} array, "
                         f"got shape {x.shape}")
    x = np.where(np.isfinite(x), x, 0.0)
    x = np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
    return np.ascontiguousarray(np.moveaxis(x, -3, -1))


def encode_gif(frames: Any, fps: float = 7) -> bytes:
    """(F, 3, H, W) floats in [0, 1] -> the bytes of a looping animated GIF, ``1000 / fps`` ms a frame.

    Non-finite values are written as 0 (black). GIF keeps at most 256 colours a frame (Pillow's adaptive palette) and
    frame times in 10 ms steps; Pillow merges consecutive identical frames into one longer frame.
    """
    return _gif_from_uint8(_to_uint8(frames, 4, "frames"), fps)


def _gif_from_uint8(frames, fps: float) -> bytes:
    """(F, H, W, 3) uint8 -> animated GIF bytes (see encode_gif)."""
    from PIL import Image

    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    images = [Image.fromarray(f) for f in frames]
    buf = io.BytesIO()
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
    return buf.getvalue()


class TrainLog:
    """TensorBoard event writer for one training run; ``TrainLog(None)`` is a no-op with the same methods.

    In multi-process training only rank 0 should write: pass ``log_dir`` there and ``None`` on the other ranks, so
    call sites need no ``if``. Steps are the caller's global step (an int, usually optimiser steps).
    Usable as a context manager (closes on exit).
    """

    def __init__(self, log_dir: str | os.PathLike | None):
        self.log_dir = None if log_dir is None else os.fspath(log_dir)
        self._writer = None
        if self.log_dir is not None:
            from torch.utils.tensorboard import SummaryWriter  # lazy: ~seconds of imports, and absent on no-op ranks

            self._writer = SummaryWriter(self.log_dir)

    @property
    def enabled(self) -> bool:
        """True when this object writes events (a log_dir was given and it is not closed)."""
        return self._writer is not None

    def scalars(self, step: int, values: dict[str, float]) -> None:
        """One scalar per tag (e.g. ``{"loss/train": 0.12, "lr": 1e-4}``) at ``step``; tensors are read with float()."""
        if self._writer is None:
            return
        for tag, value in values.items():
            self._writer.add_scalar(tag, float(value), int(step))

    def image(self, tag: str, step: int, image: Any) -> None:
        """One image, (3, H, W) tensor or array, floats in [0, 1] sRGB; non-finite values are written as 0."""
        if self._writer is None:
            return
        # Converted here rather than by add_image, which truncates instead of rounding and lets NaN through.
        self._writer.add_image(tag, _to_uint8(image, 3, "image"), int(step), dataformats="HWC")

    def video(self, tag: str, step: int, frames: Any, fps: int = 7) -> None:
        """A clip, (F, 3, H, W) tensor or array, floats in [0, 1] sRGB, shown in TensorBoard's Images tab as a
        looping animated GIF at ``fps`` frames a second. Non-finite values are written as 0 (black); colours are
        quantised to a 256-colour palette a frame (see ``encode_gif``).

        SummaryWriter.add_video would need moviepy, so the GIF is encoded here with Pillow and written as the same
        Image summary add_video writes.
        """
        if self._writer is None:
            return
        from tensorboard.compat.proto.summary_pb2 import Summary

        frames = _to_uint8(frames, 4, "frames")
        _, height, width, _ = frames.shape
        gif = _gif_from_uint8(frames, fps)
        image = Summary.Image(height=height, width=width, colorspace=3, encoded_image_string=gif)
        # SummaryWriter has no public method for a prebuilt Summary; add_video itself goes through _get_file_writer.
        self._writer._get_file_writer().add_summary(Summary(value=[Summary.Value(tag=tag, image=image)]), int(step))

    def flush(self) -> None:
        """Write pending events to disk (SummaryWriter otherwise flushes every 120 s or 10 events)."""
        if self._writer is not None:
            self._writer.flush()

    def close(self) -> None:
        """Flush and close the event file; later calls do nothing."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> TrainLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
