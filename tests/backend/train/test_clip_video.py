"""A clip's frames given as a video file: the same frames as the image pattern (exactly when the video is
lossless), one decode for training, undistorted like images, and bad videos refused naming ``frames``."""

import os
import shutil

import av
import numpy as np
import pytest
import torch
from PIL import Image

from backend.train import clip as clip_mod
from backend.train import pairs
from scpainter_blender.core import errors
from scpainter_blender.core.job import JobError
from tests_support import copy_clip, refusal_beside_fifo

WAYMO = [-0.3, 0.1, 1e-3, -1e-3, 0.0]


def write_video(path, frames, lossless=True):
    """frames (F, H, W, 3) uint8 -> an H.264 MP4: lossless RGB (libx264rgb, crf 0) or the usual yuv420p (crf 0:
    lossless luma, chroma subsampled)."""
    codec, pix_fmt = ("libx264rgb", "rgb24") if lossless else ("libx264", "yuv420p")
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream(codec, rate=10)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], pix_fmt
        stream.options = {"crf": "0"}
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _street_frames(clip):
    return np.stack([np.asarray(Image.open(p).convert("RGB")) for p in clip.frame_paths])


_copy = copy_clip  # tests_support: a copy of the street clip with clip.json edited


def _video_clip(street_clip_path, tmp_path, frames, lossless=True, distortion=None, name="video_clip"):
    def edit(d, folder):
        write_video(folder / "drive.mp4", frames, lossless)
        shutil.rmtree(folder / "frames")  # nothing but the video holds the frames
        d["frames"] = "drive.mp4"
        if distortion is not None:
            d["distortion"] = distortion
    return _copy(street_clip_path, tmp_path, edit, name)


@pytest.fixture(scope="module")
def street_images(street_clip_path):
    c = clip_mod.load(street_clip_path)
    return c, _street_frames(c)


def test_lossless_video_gives_the_image_patterns_frames(street_clip_path, tmp_path, street_images):
    image_clip, frames = street_images
    c = clip_mod.load(_video_clip(street_clip_path, tmp_path, frames))
    assert c.video == str(tmp_path / "video_clip" / "drive.mp4") and c.frame_paths is None
    assert c.image_size == image_clip.image_size and c.num_frames == 16
    np.testing.assert_array_equal(c.K, image_clip.K)
    assert np.array_equal(c.load_frames(518, 294), frames)  # decoded exactly
    for (W, H), ts in (((259, 147), [5, 2, 5, 15]), ((200, 100), [0, 15])):
        assert np.array_equal(c.load_frames(W, H, ts), image_clip.load_frames(W, H, ts))
    assert np.array_equal(c.load_frame(9, 259, 147), image_clip.load_frame(9, 259, 147))
    assert c.load_frames(259, 147, []).shape == (0, 147, 259, 3)


def test_yuv420_video_matches_the_images_within_its_chroma_loss(street_clip_path, tmp_path, street_images):
    """The usual H.264 (4:2:0): luma lossless at crf 0, chroma subsampled and converted back."""
    image_clip, frames = street_images
    c = clip_mod.load(_video_clip(street_clip_path, tmp_path, frames, lossless=False))
    got = c.load_frames(259, 147).astype(np.float64)
    want = image_clip.load_frames(259, 147).astype(np.float64)
    err = np.abs(got - want)
    assert err.mean() < 2.0 and np.percentile(err, 99) < 12, (err.mean(), np.percentile(err, 99))


def test_training_decodes_a_video_clip_once_and_gets_the_same_targets(street_clip_path, tmp_path, street_images):
    image_clip, frames = street_images
    c = clip_mod.load(_video_clip(street_clip_path, tmp_path, frames))
    st = pairs.PairSettings(width=259, height=147, frames=3)
    maker, reference = pairs.PairMaker(c, st), pairs.PairMaker(image_clip, st)
    assert torch.equal(maker.target(6), reference.target(6))
    assert sorted(maker._targets) == list(range(16))  # all frames kept from the one decode, at 259 x 147
    assert all(v.shape == (3, 147, 259) and v.dtype == torch.uint8 for v in maker._targets.values())
    s = maker.sample(np.random.default_rng(1), t0=5, asset=False)
    assert torch.equal(s["target"], reference.sample(np.random.default_rng(1), t0=5, asset=False)["target"])


def test_distorted_video_is_undistorted_like_the_distorted_images(street_clip_path, tmp_path, street_images):
    _, frames = street_images
    images = clip_mod.load(_copy(street_clip_path, tmp_path, lambda d, f: d.update(distortion=WAYMO), "images"))
    video = clip_mod.load(_video_clip(street_clip_path, tmp_path, frames, distortion=WAYMO))
    np.testing.assert_array_equal(video.K, images.K)
    assert not np.allclose(video.K, video.K_recorded)
    for W, H in ((518, 294), (259, 147)):
        assert np.array_equal(video.load_frames(W, H, [0, 11]), images.load_frames(W, H, [0, 11]))


def _bad_video(kind):
    def edit(d, folder):
        d["frames"] = "drive.mp4"
        if kind == "short":
            frames = np.stack([np.full((32, 48, 3), 10 * i, np.uint8) for i in range(15)])
            write_video(folder / "drive.mp4", frames)
        elif kind == "text":
            (folder / "drive.mp4").write_text("not a video\n" * 100)
        elif kind == "empty":
            (folder / "drive.mp4").write_bytes(b"")
        elif kind == "image":  # a frame file given without the pattern's index field reads as a 1-frame video
            d["frames"] = "frames/frame_000000.png"
    return edit


@pytest.mark.parametrize("kind, words", [
    ("short", "has 15 frames, the predictions 16"),
    ("text", "cannot decode the video"),
    ("empty", "cannot decode the video"),
    ("missing", "video file not found"),
    ("image", "has 1 frames, the predictions 16"),
])
def test_bad_videos_are_refused_naming_frames(street_clip_path, tmp_path, kind, words):
    folder = _copy(street_clip_path, tmp_path, _bad_video(kind))
    with pytest.raises(JobError) as info:
        clip_mod.load(folder)
    e = info.value
    assert isinstance(e, errors.InputError) and e.field == "frames" and words in e.message, str(e)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_in_place_of_the_video_is_refused_at_once(street_clip_path, tmp_path):
    folder = _copy(street_clip_path, tmp_path, lambda d, f: d.update(frames="drive.mp4"))
    os.mkfifo(folder / "drive.mp4")
    e = refusal_beside_fifo(lambda: clip_mod.load(folder), folder / "drive.mp4", JobError, "loading the clip's video")
    assert "is a FIFO (named pipe)" in str(e) and e.field == "frames", str(e)


def test_a_video_swapped_for_a_shorter_one_fails_when_decoded(street_clip_path, tmp_path, street_images):
    """The count is checked again when decoding: a video replaced after loading cannot give missing frames."""
    _, frames = street_images
    folder = _video_clip(street_clip_path, tmp_path, frames)
    c = clip_mod.load(folder)
    write_video(folder / "drive.mp4", frames[:4])
    with pytest.raises(clip_mod.ClipError) as info:
        c.load_frames(259, 147, [2, 10])
    assert info.value.field == "frames" and "ends after 4 decoded frames" in info.value.message


def test_fit_vae_takes_a_video_clip(street_clip_path, tmp_path, street_images):
    """The documented street run's VAE fit reads a clip's frames as training does (here a video clip, which a
    list of frame files cannot hold). Only the VAE of a tiny SVD folder: fit_vae reads nothing else."""
    from diffusers import AutoencoderKLTemporalDecoder

    from backend.model import configs
    from backend.train.vae_fit import fit_vae

    _, frames = street_images
    c = clip_mod.load(_video_clip(street_clip_path, tmp_path, frames))
    torch.manual_seed(0)
    AutoencoderKLTemporalDecoder(**configs.TINY["vae"]).save_pretrained(str(tmp_path / "svd" / "vae"))
    r = fit_vae(str(tmp_path / "svd"), c, 64, 32, steps=2)
    assert np.isfinite(r["first"]) and np.isfinite(r["last"]) and r["first"] > 0
