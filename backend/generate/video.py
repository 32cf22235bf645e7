"""H.264 MP4 output through PyAV (FFmpeg's libx264), written to a temporary file and renamed when complete."""

from __future__ import annotations
from fractions import Fraction

import numpy as np

from scpainter_blender.core import outputs


def write_mp4(path: str, frames: np.ndarray, fps: float, crf: int = 18, metadata: dict | None = None,
              ticks: list | None = None) -> str:
    """frames (F, H, W, 3) uint8 RGB -> an MP4 any player opens (yuv420p). Odd sizes are padded by one edge row or
    column (4:2:0 chroma needs even sizes). ``fps``: frames per second, any positive rate (29.97 is kept exact).
    ``metadata``: container tags (``title``, ``comment``), which players and ``ffprobe`` show. ``ticks``: when each
    frame shows, in units of 1/fps (F strictly increasing ints from 0; None: 0, 1, …): a job of every 2nd scene frame
    (``core.job.Job.frame_ticks``) plays at its scene times, 0, 2/fps, …, each frame shown until the next (the last
    as long as the one before it)."""
    import av

    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"{path}: frames must be a non-empty (F, H, W, 3) uint8 array, got {frames.shape} "
                         f"{frames.dtype}")
    F, H, W, _ = frames.shape
    ticks = list(range(F)) if ticks is None else [int(t) for t in ticks]
    if len(ticks) != F or ticks[0] != 0 or any(b <= a for a, b in zip(ticks, ticks[1:])):
        raise ValueError(f"{path}: ticks must be {F} strictly increasing ints from 0, got {ticks[:8]}")
    # how long each frame shows, keyed by its tick (packets come out in decoding order)
    gaps = [b - a for a, b in zip(ticks, ticks[1:])]
    durations = dict(zip(ticks, gaps + [gaps[-1] if gaps else 1]))
    frames = np.pad(frames, ((0, 0), (0, H % 2), (0, W % 2), (0, 0)), mode="edge")
    with outputs.atomic_path(path) as tmp:
        with av.open(tmp, "w", format="mp4") as container:
            container.metadata.update(metadata or {})
            # an exact rational rate: 29.97 plays as 30000/1001, not 30
            rate = Fraction(fps).limit_denominator(1001)
            stream = container.add_stream("libx264", rate=rate)
            stream.width, stream.height = frames.shape[2], frames.shape[1]
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(crf)}

            def mux(packets):
                for packet in packets:
                    if packet.pts is not None:
                        packet.duration = durations.get(int(packet.pts), 1)
                    container.mux(packet)

            for f, tick in zip(frames, ticks):
                frame = av.VideoFrame.from_ndarray(f, format="rgb24")
                frame.pts, frame.time_base = tick, 1 / rate
                mux(stream.encode(frame))
            mux(stream.encode())
    return path


def frame_times(path: str) -> list:
    """When each frame of a video shows, in seconds (its presentation timestamps; for tests and checks)."""
    import av

    with av.open(path) as container:
        return [float(f.time) for f in container.decode(video=0)]


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
