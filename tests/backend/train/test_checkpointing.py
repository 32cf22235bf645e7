"""What the step keeps for backward changes, what it computes does not: the tiny model's training steps with the
UNet checkpointed by blocks, the condition encoder in checkpointed one-frame chunks and the target encoded frame by
frame give the losses and weights of the step before issue 44 (diffusers' checkpointing, everything at once)."""

import copy

import pytest
import torch

from backend.train import checkpointing, memory, objective


@pytest.fixture(scope="module")
def tiny():
    return memory.build("tiny", "cpu", torch.float32)


def _grads(models, setting):
    """The loss and the gradients of the trained parameters for one batch (B=2, 3 frames: six frames, so six
    condition chunks and six target chunks)."""
    models = copy.deepcopy(models)
    step_models, named, _, _, cfg = memory.prepare(models, setting, "cpu")
    batch = memory.random_batch(setting.batch, 3, 64, 64, "cpu", seed=0)
    gens = [torch.Generator().manual_seed(b) for b in range(setting.batch)]
    loss, _ = objective.loss(step_models, batch, cfg, gens, "cpu", None)
    loss.backward()
    return float(loss.detach()), {k: p.grad.clone() for k, p in named.items()}


def test_chunked_block_checkpointed_step_equals_the_step_before(tiny):
    """Same loss; gradients agree to 1e-5 of the largest (a few parameters' true gradients are zero, e.g. attention
    keys over one CLIP token, and hold rounding noise that no comparison of their own can pass: perturbing the
    target by 1e-6 changes them as much). The UNet's block units alone are bit-identical."""
    loss0, g0 = _grads(tiny, memory.Setting.before(2))
    scale = max(float(g.abs().max()) for g in g0.values())
    for setting in (memory.Setting(2, "blocks", 1, 1), memory.Setting(2, "blocks", 0, 0)):
        loss, g = _grads(tiny, setting)
        assert loss == pytest.approx(loss0, rel=1e-6), setting
        assert g.keys() == g0.keys()
        worst = max(float((g[k] - g0[k]).abs().max()) for k in g)
        assert worst <= 1e-5 * scale, (setting, worst / scale)
        if setting.condition_chunk == 0:
            assert worst == 0, setting   # only the chunks' convolutions round differently


def test_block_units_wrap_resnets_and_transformers_and_keep_the_state_dict(tiny):
    unet = copy.deepcopy(tiny["unet"])
    keys = list(unet.state_dict())
    checkpointing.checkpoint_unet(unet, "blocks")
    types = checkpointing._block_types()
    wrapped = [n for n, m in unet.named_modules() if "forward" in m.__dict__]
    assert wrapped and all(isinstance(unet.get_submodule(n), types) for n in wrapped)
    assert len(wrapped) == sum(isinstance(m, types) for m in unet.modules())
    assert list(unet.state_dict()) == keys and not unet.is_gradient_checkpointing
    checkpointing.checkpoint_unet(unet, "diffusers")
    assert unet.is_gradient_checkpointing and not any("forward" in m.__dict__ for m in unet.modules())
    checkpointing.checkpoint_unet(unet, None)
    assert not unet.is_gradient_checkpointing
    with pytest.raises(ValueError, match="blocks"):
        checkpointing.checkpoint_unet(unet, "layers")


def test_condition_chunks_keep_one_chunk_and_match_the_whole(tiny):
    enc = tiny["condition_encoder"]
    g = torch.Generator().manual_seed(3)
    image, mask = torch.rand(4, 3, 64, 64, generator=g), (torch.rand(4, 1, 64, 64, generator=g) > 0.5).float()
    valid, noise = torch.ones(4, 1, 64, 64), torch.randn(4, 3, 64, 64, generator=g)
    whole = checkpointing.condition_latents(enc, image, mask, valid, 0.02, noise)
    chunks = checkpointing.FrameChunks(enc, 1, True)
    parts = checkpointing.condition_latents(chunks, image, mask, valid, 0.02, noise)
    assert torch.allclose(parts, whole, atol=1e-6)
    parts.square().mean().backward()   # gradients flow through the checkpointed chunks
    assert all(p.grad is not None for p in enc.parameters())
    enc.zero_grad(set_to_none=True)
