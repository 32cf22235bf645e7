"""SCPainterPipeline against diffusers' own StableVideoDiffusionPipeline, and the window logic."""

import numpy as np
import pytest
import torch
from PIL import Image

from backend.model.pipeline import SCPainterPipeline, window_starts


@pytest.fixture(scope="module")
def pipe(tiny_checkpoint):
    p = SCPainterPipeline.from_checkpoint(tiny_checkpoint)
    p.config.noise_aug_strength = 0.0  # the stock comparison below runs without noise augmentation
    return p


def test_window_starts():
    assert window_starts(10, 14, 4) == [0]
    assert window_starts(14, 14, 4) == [0]
    assert window_starts(16, 14, 4) == [0, 2]
    assert window_starts(30, 14, 4) == [0, 10, 16]
    assert window_starts(200, 14, 4)[-1] == 186
    with pytest.raises(ValueError):
        window_starts(30, 14, 14)


def test_one_window_equals_stock_svd_pipeline(pipe, tiny_svd):
    """Same UNet, image, initial noise, steps and guidance: our sampler reproduces diffusers' pipeline (the stock
    arithmetic) when the condition latent is SVD's image latent repeated over the frames."""
    from diffusers import StableVideoDiffusionPipeline

    frames, H, W, steps = 6, 64, 96, 4
    rng = np.random.default_rng(0)
    pil = Image.fromarray(rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    image = torch.from_numpy(np.array(pil)).permute(2, 0, 1).float() / 255.0
    eps = torch.randn((1, frames, 4, H // 8, W // 8), generator=torch.Generator().manual_seed(3))
    stock = StableVideoDiffusionPipeline.from_pretrained(tiny_svd, local_files_only=True, use_safetensors=True)
    ref = stock(pil, height=H, width=W, num_frames=frames, num_inference_steps=steps, min_guidance_scale=1.0,
                max_guidance_scale=3.0, fps=pipe.config.fps, motion_bucket_id=pipe.config.motion_bucket_id,
                noise_aug_strength=0.0, latents=eps.clone(), output_type="latent").frames[0]
    cond = pipe.condition_latents(image[None].repeat(frames, 1, 1, 1), torch.zeros(frames, 1, H, W),
                                  torch.ones(frames, 1, H, W))
    ours = pipe.sample(cond, pipe.clip_embedding(image), steps=steps, latents=eps[0] * pipe.schedule.init_noise_sigma)
    assert ours.shape == ref.shape
    assert torch.allclose(ours, ref, atol=1e-4 * float(ref.abs().max()) + 1e-5)
    # a window longer than the clip is the same single window
    again = pipe.sample(cond, pipe.clip_embedding(image), steps=steps, window=frames + 5,
                        latents=eps[0] * pipe.schedule.init_noise_sigma)
    assert torch.equal(again, ours)


def test_windows_share_frames_and_are_deterministic(pipe):
    frames, H, W = 10, 32, 32
    gen = torch.Generator().manual_seed(1)
    image = torch.rand(frames, 3, H, W, generator=gen)
    cond = pipe.condition_latents(image, torch.zeros(frames, 1, H, W), torch.ones(frames, 1, H, W))
    clip = pipe.clip_embedding(image[0])
    a = pipe.sample(cond, clip, steps=2, window=6, overlap=2, seed=5)
    b = pipe.sample(cond, clip, steps=2, window=6, overlap=2, seed=5)
    assert torch.equal(a, b) and torch.isfinite(a).all()
    # resuming from the state after step 1 gives exactly the uninterrupted result
    states = []
    pipe.sample(cond, clip, steps=2, window=6, overlap=2, seed=5, on_step=lambda i, n, x: states.append(x.clone())
                or True)
    resumed = pipe.sample(cond, clip, steps=2, window=6, overlap=2, seed=5, latents=states[0], start_step=1)
    assert torch.equal(resumed, a)
    video = pipe.decode(a, chunk=4)
    assert video.shape == (frames, 3, H, W) and 0 <= float(video.min()) and float(video.max()) <= 1


@pytest.mark.parametrize("frames", [1, 200])
def test_one_frame_and_two_hundred_frame_clips(pipe, frames):
    H = W = 32 if frames == 1 else 16  # 16 px and one frame leave the tiny UNet's GroupNorm one value per group
    gen = torch.Generator().manual_seed(2)
    image = torch.rand(frames, 3, H, W, generator=gen)
    cond = pipe.condition_latents(image, torch.zeros(frames, 1, H, W), torch.ones(frames, 1, H, W), chunk=50)
    out = pipe.sample(cond, pipe.clip_embedding(image[0]), steps=2, window=14, overlap=4, max_guidance=15.0)
    assert out.shape == (frames, 4, H // 8, W // 8) and torch.isfinite(out).all()
    video = pipe.decode(out, chunk=14)
    assert video.shape == (frames, 3, H, W) and torch.isfinite(video).all()
