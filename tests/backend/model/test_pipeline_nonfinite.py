"""Non-finite model output is an error (issue 14): the sampler and the decoder raise NonFiniteError naming the step
and σ (or the frames), and a non-finite state never reaches ``on_step`` (where generate saves its resume state).

The fault is injected with forward hooks on the tiny model's real UNet / VAE decoder, which replace their output."""

import math

import pytest
import torch

from backend.errors import NonFiniteError
from backend.model.pipeline import SCPainterPipeline, precision_hint
from scpainter_blender.core.job import STOCK_SAMPLING

FRAMES, H, W, STEPS = 4, 32, 32, 3


@pytest.fixture(scope="module")
def pipe(tiny_checkpoint):
    return SCPainterPipeline.from_checkpoint(tiny_checkpoint)


@pytest.fixture(scope="module")
def inputs(pipe):
    image = torch.rand(FRAMES, 3, H, W, generator=torch.Generator().manual_seed(0))
    cond = pipe.condition_latents(image, torch.zeros(FRAMES, 1, H, W), torch.ones(FRAMES, 1, H, W))
    return cond, pipe.clip_embedding(image[0])


def _poison_from(module, call: int, value=math.nan, rows=slice(None)):
    """Forward hook: from the ``call``-th forward (1-based) on, ``rows`` of the first output become ``value``.
    Returns the hook handle and the list of call counts."""
    calls = []

    def hook(_module, _args, out):
        calls.append(1)
        if len(calls) < call:
            return None
        first = out[0] if isinstance(out, tuple) else out
        first = first.clone()
        first[rows] = value
        return (first, *out[1:]) if isinstance(out, tuple) else first

    return module.register_forward_hook(hook), calls


def _sample(pipe, inputs, seen, **kw):
    """Stock's sampler (every evaluation through the UNet's own forward, where the poisoning hook sits)."""
    cond, clip = inputs
    kw = {**{k: v for k, v in STOCK_SAMPLING.items() if k != "steps"}, **kw}
    return pipe.sample(cond, clip, steps=STEPS, seed=1, window=FRAMES,
                       on_step=lambda i, n, x, h: seen.append((i, bool(torch.isfinite(x).all()))), **kw)


def test_nan_at_the_first_step_names_step_one_and_sigma_max(pipe, inputs):
    handle, _ = _poison_from(pipe.unet, 1)
    seen = []
    try:
        with pytest.raises(NonFiniteError) as e:
            _sample(pipe, inputs, seen)
    finally:
        handle.remove()
    sigma0 = float(pipe.schedule.sigmas(STEPS)[0])
    assert e.value.fields == {"stage": "generate", "step": 1, "sigma": sigma0}
    assert str(e.value) == f"the model produced NaN/inf latents at step 1 of {STEPS} (σ = 700)"
    assert "--precision" not in e.value.hint and "fp32" in e.value.hint  # it ran in fp32: the weights, not rounding
    assert seen == []  # on_step never saw the poisoned state


@pytest.mark.parametrize("rows, guided", [(slice(None), False), (0, True)], ids=["both-branches", "uncond-only"])
def test_nan_from_a_later_step_names_that_step(pipe, inputs, rows, guided):
    """One window, so one UNet call per step: the k-th call is step k. ``uncond-only`` poisons just the
    unconditional half of the batched guidance pass (row 0): guidance mixes it in, and the check sees it."""
    k = 2
    kw = {"max_guidance": 3.0} if guided else {"max_guidance": 1.0}  # ≤ 1: no unconditional pass at all
    handle, calls = _poison_from(pipe.unet, k, rows=rows)
    seen = []
    try:
        with pytest.raises(NonFiniteError) as e:
            _sample(pipe, inputs, seen, **kw)
    finally:
        handle.remove()
    assert len(calls) == k
    assert e.value.fields["step"] == k and e.value.fields["sigma"] == float(pipe.schedule.sigmas(STEPS)[k - 1])
    assert seen == [(i, True) for i in range(1, k)]  # the good steps before it were passed on, all finite


def test_inf_from_the_decoder_is_an_error_not_white_pixels(pipe, inputs):
    """+inf would clamp to a plausible 1.0; the check runs before the clamp. Chunk 2 of 2 is the bad one."""
    cond, _ = inputs
    handle, calls = _poison_from(pipe.vae.decoder, 2, value=math.inf)
    try:
        with pytest.raises(NonFiniteError) as e:
            pipe.decode(cond, chunk=2)
    finally:
        handle.remove()
    assert len(calls) == 2
    assert e.value.fields == {"stage": "decode", "frames": [2, 4]}
    assert "frames 2-3 (0-based) of 4" in str(e.value)


def test_a_clean_run_passes_every_check(pipe, inputs):
    seen = []
    x = _sample(pipe, inputs, seen)
    assert seen == [(i, True) for i in range(1, STEPS + 1)]
    video = pipe.decode(x)
    assert video.shape == (FRAMES, 3, H, W) and torch.isfinite(video).all()


def test_hint_names_the_precision_it_ran_and_the_next_one():
    assert "ran in fp16" in precision_hint(torch.float16) and "--precision bf16" in precision_hint(torch.float16)
    assert "ran in bf16" in precision_hint(torch.bfloat16) and "--precision fp32" in precision_hint(torch.bfloat16)
    assert "ran in fp32" in precision_hint(torch.float32) and "checkpoint" in precision_hint(torch.float32)
