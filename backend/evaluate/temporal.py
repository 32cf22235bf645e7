"""Temporal consistency of a video: the flow-warping error (Lai et al. 2018, "Learning Blind Video Temporal
Consistency", §5; occlusions by the forward-backward check of Sundaram et al. 2010).

Convention: a video is a float array (T, H, W, 3), display (sRGB) values in [0, 1], frames in time order. For each
pair of consecutive frames (t, t + 1):

* optical flow with OpenCV's DIS (``cv2.DISOpticalFlow``, preset ``MEDIUM``) on the 8-bit grey frames, forward
  F (t -> t + 1) and backward B (t + 1 -> t), in pixels, (H, W, 2) as (dx, dy);
* frame t + 1 warped onto t: W(x) = I_{t+1}(x + F(x)), bilinear (``cv2.remap``);
* a pixel counts when x + F(x) lies inside the image and the flows agree,
  |F(x) + B(x + F(x))|² < ALPHA · (|F(x)|² + |B(x + F(x))|²) + BETA (Sundaram's test, Lai's constants);
* the pair's error is the mean over counted pixels and the 3 channels of (I_t − W)².

``warping_error`` returns a ``WarpingScore``: the mean over the pairs (the video's E_warp) and the per-pair
values. A static video scores 0, a camera moving smoothly over a textured scene scores near 0, flicker (noise that
changes every frame) scores high; a generated video's score is read against its ground truth's own (its floor:
real motion has occlusions and lighting the flow does not explain).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ALPHA = 0.01   # forward-backward tolerance, relative (Sundaram et al. 2010; Lai et al. 2018)
BETA = 0.5     # forward-backward tolerance, absolute (px²)


@dataclass
class WarpingScore:
    """``mean``: the mean of ``pairs`` (NaN for a video of fewer than two frames); ``pairs`` (T - 1,) the error of
    each consecutive pair (NaN where no pixel counts); ``counted`` (T - 1,) the fraction of pixels that counted."""

    mean: float
    pairs: np.ndarray
    counted: np.ndarray


def _grey8(frame: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor((np.clip(frame, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)


def _sample(image: np.ndarray, at_x: np.ndarray, at_y: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C) float32 sampled bilinearly at pixel coordinates (at_x, at_y) (H, W) float32."""
    import cv2

    return cv2.remap(image, at_x, at_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def pair_error(a: np.ndarray, b: np.ndarray, flow_engine=None) -> tuple[float, float]:
    """(error, fraction counted) of frame ``b`` (the next) warped onto ``a``, both (H, W, 3) in [0, 1]; see the
    module docstring. ``flow_engine``: a ``cv2.DISOpticalFlow`` to reuse (one is made when None)."""
    import cv2

    dis = flow_engine or cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    ga, gb = _grey8(a), _grey8(b)
    forward = dis.calc(ga, gb, None)
    backward = dis.calc(gb, ga, None)
    H, W = ga.shape
    xs, ys = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    to_x, to_y = xs + forward[..., 0], ys + forward[..., 1]
    inside = (to_x >= 0) & (to_x <= W - 1) & (to_y >= 0) & (to_y <= H - 1)
    back = _sample(backward, to_x, to_y)
    gap = ((forward + back) ** 2).sum(-1)
    agree = gap < ALPHA * ((forward ** 2).sum(-1) + (back ** 2).sum(-1)) + BETA
    counted = inside & agree
    if not counted.any():
        return float("nan"), 0.0
    warped = _sample(np.ascontiguousarray(b, np.float32), to_x, to_y)
    sq = ((np.asarray(a, np.float64) - warped) ** 2).mean(-1)
    return float(sq[counted].mean()), float(counted.mean())


def warping_error(video) -> WarpingScore:
    """The flow-warping error of ``video`` (T, H, W, 3) float in [0, 1] (see the module docstring). ValueError for
    another shape (a programming error: callers read videos through checked loaders)."""
    import cv2

    video = np.asarray(video)
    if video.ndim != 4 or video.shape[-1] != 3:
        raise ValueError(f"a video is (T, H, W, 3), got shape {video.shape}")
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    results = [pair_error(video[t], video[t + 1], dis) for t in range(len(video) - 1)]
    pairs = np.array([r[0] for r in results], np.float64)
    counted = np.array([r[1] for r in results], np.float64)
    finite = pairs[np.isfinite(pairs)]
    return WarpingScore(float(finite.mean()) if len(finite) else float("nan"), pairs, counted)
