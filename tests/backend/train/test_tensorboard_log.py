"""backend.train.tensorboard_log: events written by TrainLog, read back with TensorBoard's own EventAccumulator."""

import io
import os
import subprocess
import sys
import textwrap

import numpy as np
import torch
from PIL import Image

from backend.train.tensorboard_log import TrainLog

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def flat_frames(F=4, H=16, W=24):
    """(F, 3, H, W) float32 of four flat quadrants a frame, colours on the 8-bit grid (c / 255) and few enough that
    the GIF palette keeps them exactly; every frame differs, so Pillow merges none."""
    frames = np.zeros((F, 3, H, W), np.float32)
    for f in range(F):
        for q, (r0, c0) in enumerate([(0, 0), (0, W // 2), (H // 2, 0), (H // 2, W // 2)]):
            rgb = np.array([(40 * f + 60 * q) % 256, (255 - 30 * q), (17 * f + 90 * (q % 2))], np.float32) / 255
            frames[f, :, r0:r0 + H // 2, c0:c0 + W // 2] = rgb[:, None, None]
    return frames


def test_round_trip(tmp_path):
    from tensorboard.backend.event_processing import event_accumulator

    frames = flat_frames()
    nan_frames = frames.copy()
    nan_frames[0, :, 0, 0] = np.nan  # non-finite -> 0 (black)
    nan_frames[0, 1, 1, 1] = np.inf
    picture = torch.from_numpy(frames[2])
    with TrainLog(tmp_path) as log:
        assert log.enabled
        for step, loss in [(0, 2.5), (10, 1.25), (20, 0.5)]:  # float32-exact values
            log.scalars(step, {"loss/train": loss, "lr": torch.tensor(0.125)})
        log.video("val/clip", 20, torch.from_numpy(nan_frames), fps=10)
        log.image("val/frame", 20, picture)
    assert not log.enabled

    acc = event_accumulator.EventAccumulator(str(tmp_path), size_guidance={k: 0 for k in
                                                                           event_accumulator.DEFAULT_SIZE_GUIDANCE})
    acc.Reload()
    assert [(e.step, e.value) for e in acc.Scalars("loss/train")] == [(0, 2.5), (10, 1.25), (20, 0.5)]
    assert [(e.step, e.value) for e in acc.Scalars("lr")] == [(0, 0.125), (10, 0.125), (20, 0.125)]
    assert sorted(acc.Tags()["images"]) == ["val/clip", "val/frame"]

    (clip,) = acc.Images("val/clip")
    assert (clip.step, clip.height, clip.width) == (20, 16, 24)
    gif = Image.open(io.BytesIO(clip.encoded_image_string))
    assert gif.format == "GIF" and gif.n_frames == 4 and gif.info["loop"] == 0 and gif.info["duration"] == 100
    expect = np.rint(np.moveaxis(frames, 1, -1) * 255).astype(np.uint8)
    expect[0, 0, 0] = 0
    expect[0, 1, 1, 1] = 0
    got = np.stack([np.asarray((gif.seek(i), gif.convert("RGB"))[1]) for i in range(4)])
    assert np.array_equal(got, expect)

    (img,) = acc.Images("val/frame")
    assert (img.step, img.height, img.width) == (20, 16, 24)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(img.encoded_image_string)).convert("RGB")), expect[2])


def test_noop_writes_nothing_and_imports_nothing(tmp_path):
    """TrainLog(None): every method runs, nothing is written (not even SummaryWriter's default ./runs), and neither
    torch nor tensorboard is imported (checked in a fresh interpreter, since this one has both)."""
    code = textwrap.dedent("""
        import sys
        import numpy as np
        from backend.train.tensorboard_log import TrainLog

        with TrainLog(None) as log:
            assert not log.enabled
            log.scalars(0, {"loss": 1.0})
            log.image("i", 0, np.zeros((3, 4, 4)))
            log.video("v", 0, np.zeros((2, 3, 4, 4)))
            log.flush()
        log.close()
        loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "tensorboard", "PIL"))
        assert not loaded, loaded
    """)
    env = dict(os.environ, PYTHONPATH=ROOT)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert os.listdir(tmp_path) == []
