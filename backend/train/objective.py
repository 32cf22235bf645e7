"""The fine-tuning objective (docs/design.md §5): EDM with SVD's v-parameterisation, written out.

For a sample with clean latent x_0 (VAE latent of the real frames × scaling factor, (F, C, h, w)):

    σ = exp(p_mean + p_std · n), n ~ N(0, 1)          one noise level per sample (the training config's)
    x_σ = x_0 + σ ε
    x̂_0 = D(x_σ, σ; cond, clip, time ids)             edm.Denoiser: c_skip x_σ + c_out UNet(c_in x_σ ‖ cond …)
    loss = mean over the batch of  λ(σ) · mean((x̂_0 − x_0)²),   λ(σ) = (σ² + 1)/σ²

D is the sampler's own denoiser (the object ``models["denoiser"]``, the function ``pipeline`` calls), so what
training fits is exactly what generation evaluates.

λ(σ) = 1/c_out² makes the loss the plain mean squared error of v against its target (x_σ c_skip − x_0)/(−c_out),
i.e. unit weight per network output. The CLIP embedding is zeroed for a sample with probability ``drop_clip`` and,
independently, the render-condition latent with ``drop_condition`` — exactly what the sampler's unconditional
branch sees, so classifier-free guidance has something to contrast. The condition latent is multiplied by the
keep mask (not replaced), so a dropped sample still backpropagates zeros through the encoder and DDP sees every
parameter used.

Every random draw of a sample comes from its own CPU generator, seeded by the run's seed and the sample's global
index: identical on any device, after a resume, and however the global batch is split over processes (so 2
processes × batch 1 train exactly as 1 process × batch 2, up to float summation order).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..model import edm
from ..model.pipeline import clip_embeddings
from .checkpointing import condition_latents

if TYPE_CHECKING:
    from collections.abc import Iterable
    from .config import TrainConfig


def generators(seed: int, indices: Iterable[int]) -> list:
    """One CPU generator per sample, seeded by (run seed, the sample's global index)."""
    import numpy as np

    return [torch.Generator().manual_seed(int(np.random.SeedSequence([seed, int(i)]).generate_state(1)[0]))
            for i in indices]


def draw(gens: list, cfg: TrainConfig) -> dict:
    """The random choices of each sample (one generator each): σ (B,), keep_clip and keep_cond (B,) float 0/1."""
    n = torch.cat([torch.randn(1, generator=g, dtype=torch.float64) for g in gens])
    u = torch.stack([torch.rand(2, generator=g) for g in gens])
    sigma = torch.exp(cfg.p_mean + cfg.p_std * n).float()
    return {"sigma": sigma, "keep_clip": (u[:, 0] >= cfg.drop_clip).float(),
            "keep_cond": (u[:, 1] >= cfg.drop_condition).float()}


def randn(gens: list, shape: tuple) -> torch.Tensor:
    """(B, *shape) standard normal noise, sample b from gens[b] (on the CPU)."""
    return torch.stack([torch.randn(shape, generator=g) for g in gens])


@torch.no_grad()
def target_latents(vae: torch.nn.Module, target: torch.Tensor, gens: list, chunk: int = 0) -> torch.Tensor:
    """x_0 (B, F, C, h, w) float32: a sample of the VAE posterior of the frames (B, F, 3, H, W) in [0, 1], times
    the scaling factor (each sample's posterior noise from its generator). The encoder runs over ``chunk`` frames at
    a time (0: all B·F at once), each chunk's activations freed before the next; the result does not depend on it
    (the encoder works frame by frame)."""
    B, F = target.shape[:2]
    frames = target.flatten(0, 1)
    step = chunk if chunk > 0 else B * F
    dtype = next(vae.parameters()).dtype
    means, stds = [], []
    for s in range(0, B * F, step):
        dist = vae.encode((frames[s:s + step] * 2.0 - 1.0).to(dtype)).latent_dist
        means.append(dist.mean)
        stds.append(dist.std)
        del dist
    mean, std = (means[0], stds[0]) if len(means) == 1 else (torch.cat(means), torch.cat(stds))
    eps = randn(gens, (F, *mean.shape[1:])).flatten(0, 1).to(mean)
    z = (mean + std * eps).float() * vae.config.scaling_factor
    return z.view(B, F, *z.shape[1:])


def loss(models: dict, batch: dict, cfg: TrainConfig, gens: list, device: str | torch.device,
         autocast_dtype: torch.dtype | None = None) -> tuple:
    """(scalar loss, stats) for one micro-batch. ``models``: denoiser (``edm.Denoiser`` over the trained UNet),
    condition_encoder (trained), vae, image_encoder (frozen), clip_mean, clip_std, config (ScpainterConfig).
    ``batch``: target, image (B, F, 3, H, W), asset_mask, valid (B, F, 1, H, W) in [0, 1]. ``gens``: one
    generator per sample (``generators``). ``cfg``: the training config (p_mean, p_std, drop_clip,
    drop_condition)."""
    denoiser, cond_enc, config = models["denoiser"], models["condition_encoder"], models["config"]
    target = batch["target"].to(device)
    B, F = target.shape[:2]
    if len(gens) != B:
        raise ValueError(f"{len(gens)} generators for a batch of {B}")
    r = draw(gens, cfg)
    x0 = target_latents(models["vae"], target, gens, cfg.encode_chunk_frames)
    eps = randn(gens, tuple(x0.shape[1:])).to(device)
    aug = randn(gens, tuple(batch["image"].shape[1:])).flatten(0, 1)
    sigma = r["sigma"].to(device).view(B, 1, 1, 1, 1)
    x_sigma = x0 + sigma * eps
    with torch.no_grad():
        clip = clip_embeddings(models["image_encoder"], target[:, 0], models["clip_mean"], models["clip_std"])
    clip = clip * r["keep_clip"].to(device).view(B, 1, 1)
    with torch.autocast(device_type=torch.device(device).type, dtype=autocast_dtype or torch.float32,
                        enabled=autocast_dtype is not None):
        cond = condition_latents(cond_enc, batch["image"].to(device).flatten(0, 1),
                                 batch["asset_mask"].to(device).flatten(0, 1),
                                 batch["valid"].to(device).flatten(0, 1), config.noise_aug_strength, aug)
        cond = cond.float().view(B, F, *cond.shape[1:]) * r["keep_cond"].to(device).view(B, 1, 1, 1, 1)
        x0_hat = denoiser(x_sigma, sigma.view(B), cond, clip, edm.time_ids(config, B, device))
    weight = (sigma.view(B) ** 2 + 1.0) / sigma.view(B) ** 2
    per_sample = ((x0_hat - x0) ** 2).mean(dim=(1, 2, 3, 4))
    total = (weight * per_sample).mean()
    return total, {"sigma": r["sigma"], "keep_clip": r["keep_clip"], "keep_cond": r["keep_cond"],
                   "per_sample": per_sample.detach().cpu()}
