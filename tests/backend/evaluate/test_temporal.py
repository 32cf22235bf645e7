"""backend.evaluate.temporal: the flow-warping error scores a static video 0, smooth camera motion near 0 and
flicker high, and leaves out what the forward-backward check calls occluded."""

import cv2
import numpy as np
import pytest

from backend.evaluate import temporal


def _texture(seed=0, H=160, W=240):
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.uniform(0, 1, (H, W, 3)).astype(np.float32), (0, 0), 2.0)
    return (t - t.min()) / (t.max() - t.min())


def test_static_translating_and_flickering_videos():
    tex = _texture()
    static = np.stack([tex[20:100, 30:150]] * 5)
    moving = np.stack([tex[20:100, 30 + 2 * t:150 + 2 * t] for t in range(5)])   # the camera pans 2 px a frame
    noise = np.random.default_rng(1).normal(0, 0.05, static.shape)
    flicker = np.clip(static + noise, 0, 1).astype(np.float32)
    s, m, f = (temporal.warping_error(v) for v in (static, moving, flicker))
    assert s.mean == 0.0 and (s.counted == 1.0).all()
    assert m.mean < 1e-5 and (m.counted > 0.9).all()         # what enters the view at the edge does not count
    # per-frame noise of σ 0.05 cannot be warped away: about 2σ² per pixel (two independent frames)
    assert 0.5 * 2 * 0.05 ** 2 < f.mean < 1.5 * 2 * 0.05 ** 2
    assert f.mean > 100 * m.mean and m.pairs.shape == (4,)


def test_occluded_pixels_are_left_out():
    """A square moving over a static background: the background it uncovers has no match in the next frame,
    the flows disagree there and those pixels do not count; the error stays that of a consistent video."""
    tex, square = _texture(2), _texture(3, 40, 40)
    frames = []
    for t in range(4):
        f = tex[20:100, 30:150].copy()
        f[20:60, 20 + 6 * t:60 + 6 * t] = square
        frames.append(f)
    r = temporal.warping_error(np.stack(frames))
    assert (r.counted < 0.995).all() and (r.counted > 0.8).all()
    assert r.mean < 1e-3  # 1.3e-3 when every pixel counts


def test_short_videos_and_bad_shapes():
    one = temporal.warping_error(np.zeros((1, 8, 8, 3), np.float32))
    assert np.isnan(one.mean) and one.pairs.shape == (0,)
    with pytest.raises(ValueError, match="T, H, W, 3"):
        temporal.warping_error(np.zeros((3, 8, 8), np.float32))
