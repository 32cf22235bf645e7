"""H.264 MP4 output through PyAV (FFmpeg's libx264), written to a temporary file and renamed when complete."""

from __future__ import annotations
from fractions import Fraction

import numpy as np

from scpainter_blender.core import outputs


def write_mp4(path: str, frames: np.ndarray, fps: float, crf: int = 18, metadata: dict | None = None) -> str:
    """frames (F, H, W, 3) uint8 RGB -> an MP4 any player opens (yuv420p). Odd sizes are padded by one edge row or
    column (4:2:0 chroma needs even sizes). ``fps``: frames per second, any positive rate (29.97 is kept exact).
    ``metadata``: container tags (``title``, ``comment``), which players and ``ffprobe`` show."""
    import av

    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"{path}: frames must be a non-empty (F, H, W, 3) uint8 array, got {frames.shape} "
                         f"{frames.dtype}")
    F, H, W, _ = frames.shape
    frames = np.pad(frames, ((0, 0), (0, H % 2), (0, W % 2), (0, 0)), mode="edge")
    with outputs.atomic_path(path) as tmp:
        with av.open(tmp, "w", format="mp4") as container:
            container.metadata.update(metadata or {})
            # an exact rational rate: 29.97 plays as 30000/1001, not 30
            stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
            stream.width, stream.height = frames.shape[2], frames.shape[1]
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(crf)}
            for f in frames:
                for packet in stream.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
    return path


def read_mp4(path: str) -> np.ndarray:
    """All frames of a video as (F, H, W, 3) uint8 (for tests and checks)."""
    import av

    with av.open(path) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def mp4_metadata(path: str) -> dict:
    """The container tags of a video (``write_mp4``'s ``metadata``)."""
    import av

    with av.open(path) as container:
        return dict(container.metadata)
