"""SCPainter generation, read top to bottom: CLIP embedding, condition latents, windowed EDM sampling, decoding.

Shapes: frames F, latent channels C = 4, latent size h x w = H/8 x W/8. Latents are float32 throughout the
sampler; only the UNet's input is cast to the model dtype (bf16/fp16 on CUDA).

The UNet is called only through ``edm.Denoiser`` (x_σ, σ, condition latent, CLIP, time ids → x_0), the same
function the training loss calls; the noise levels are the checkpoint's (``edm.Schedule`` from
``scheduler/scheduler_config.json``, which ``checkpoint.load`` reads).

Windows: the UNet denoises ``window`` frames at a time. A longer clip is covered by windows that overlap by
``overlap`` frames (the last one aligned to the clip's end); at every step each window predicts x_0 for its frames
and frames seen by several windows take the mean, then one Euler step moves the whole clip. A clip that fits one
window is one window: the same arithmetic as SVD's own loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F

from scpainter_blender.core.job import GENERATE_DEFAULTS

from ..errors import NonFiniteError
from . import edm
from .condition import encode_conditions

if TYPE_CHECKING:
    from collections.abc import Callable

PRECISION_NAMES = {torch.float32: "fp32", torch.bfloat16: "bf16", torch.float16: "fp16"}


def precision_hint(dtype: torch.dtype) -> str:
    """What to try after NaN/inf from a network that ran in ``dtype`` (named as ``--precision`` spells it)."""
    name = PRECISION_NAMES.get(dtype, str(dtype))
    if dtype == torch.float16:
        return f"it ran in {name}, whose range (±65504) overflows easily: run again with --precision bf16 or fp32"
    if dtype == torch.bfloat16:
        return f"it ran in {name}: run again with --precision fp32"
    return (f"it ran in {name}, so rounding is not the cause: the checkpoint's weights may hold NaN/inf (a diverged "
            "training run?); try an earlier or another checkpoint")


def window_starts(frames: int, window: int, overlap: int) -> list[int]:
    """First frame of each window covering ``frames``; consecutive windows share ≥ ``overlap`` frames."""
    if frames <= window:
        return [0]
    if not 0 <= overlap < window:
        raise ValueError(f"overlap must be in [0, window), got {overlap} for window {window}")
    stride = window - overlap
    starts = list(range(0, frames - window, stride))
    return starts + [frames - window]


class SCPainterPipeline:
    """``components``: unet, vae, image_encoder, condition_encoder, config (ScpainterConfig), clip_mean, clip_std
    (3 numbers each) and schedule (``edm.Schedule``), as ``checkpoint.load`` returns them; a ready ``denoiser``
    (``edm.Denoiser``, used as it is, its dtype included) may stand for unet and schedule."""

    def __init__(self, components: dict, device: str | torch.device = "cpu",
                 dtype: torch.dtype = torch.float32) -> None:
        self.denoiser = components.get("denoiser") or edm.Denoiser(components["unet"], components["schedule"], dtype)
        self.vae = components["vae"]
        self.image_encoder = components["image_encoder"]
        self.condition_encoder = components["condition_encoder"]
        self.config = components["config"]
        self.clip_mean = torch.tensor(components["clip_mean"]).view(1, 3, 1, 1)
        self.clip_std = torch.tensor(components["clip_std"]).view(1, 3, 1, 1)
        self.device, self.dtype = torch.device(device), dtype

    @classmethod
    def from_checkpoint(cls, path: str, device: str | torch.device = "cpu",
                        dtype: torch.dtype = torch.float32) -> SCPainterPipeline:
        """Load an SCPainter checkpoint folder (local files only, see ``checkpoint.load``)."""
        from . import checkpoint

        return cls(checkpoint.load(path, device, dtype), device, dtype)

    @property
    def unet(self) -> torch.nn.Module:
        """The denoiser's network (assignable: ``torch.compile`` it in place)."""
        return self.denoiser.net

    @unet.setter
    def unet(self, net: torch.nn.Module) -> None:
        self.denoiser.net = net

    @property
    def schedule(self) -> edm.Schedule:
        return self.denoiser.schedule

    @property
    def pixel_multiple(self) -> int:
        """Image sizes must be multiples of this: the VAE's 8 times the UNet's downsampling."""
        return self.condition_encoder.downsample * 2 ** (len(self.unet.config.block_out_channels) - 1)

    @torch.no_grad()
    def clip_embedding(self, image: torch.Tensor) -> torch.Tensor:
        """(1, 1, D) CLIP image embedding of one (3, H, W) image in [0, 1] (see ``clip_embeddings``)."""
        return clip_embeddings(self.image_encoder, image[None].to(self.device), self.clip_mean, self.clip_std)

    @torch.no_grad()
    def condition_latents(self, image: torch.Tensor, asset_mask: torch.Tensor, valid: torch.Tensor,
                          seed: int = GENERATE_DEFAULTS["seed"], chunk: int = 8) -> torch.Tensor:
        """(F, C, h, w) float32 from I (F, 3, H, W), the asset mask M_a and the validity V (F, 1, H, W) in [0, 1],
        encoded in chunks."""
        gen = torch.Generator().manual_seed(seed + 1)
        out = []
        for i in range(0, len(image), chunk):
            sl = slice(i, i + chunk)
            out.append(encode_conditions(self.condition_encoder, image[sl].to(self.device),
                                         asset_mask[sl].to(self.device), valid[sl].to(self.device),
                                         self.config.noise_aug_strength, gen))
        return torch.cat(out)

    def initial_latents(self, shape: tuple[int, ...], seed: int) -> torch.Tensor:
        """ε · the schedule's initial noise scale (√(σ_max² + 1) for SVD), drawn on the CPU so a seed gives the
        same video on any device."""
        gen = torch.Generator().manual_seed(seed)
        return (torch.randn(shape, generator=gen) * self.schedule.init_noise_sigma).to(self.device)

    @torch.no_grad()
    def predict_x0(self, x: torch.Tensor, sigma: torch.Tensor, cond: torch.Tensor, clip: torch.Tensor,
                   guidance: torch.Tensor) -> torch.Tensor:
        """x_0 (F, C, h, w) float32 of one window: x (F, C, h, w) float32 at noise level σ, cond (F, C, h, w),
        clip (1, 1, D), guidance (F,) per frame (≤ 1 everywhere: no classifier-free guidance)."""
        ids = edm.time_ids(self.config, 1, self.device, self.dtype)
        if float(guidance.max()) <= 1.0:
            return self.denoiser(x[None], sigma, cond[None], clip, ids)[0]
        # one batched pass: the unconditional branch (row 0) has zero CLIP and zero condition latent
        x0 = self.denoiser(torch.stack([x, x]), sigma, torch.stack([torch.zeros_like(cond), cond]),
                           torch.cat([torch.zeros_like(clip), clip]), ids.repeat(2, 1))
        return edm.guide(x0[0], x0[1], guidance.view(-1, 1, 1, 1).to(x0))

    @torch.no_grad()
    def sample(self, cond: torch.Tensor, clip: torch.Tensor, steps: int = GENERATE_DEFAULTS["steps"],
               seed: int = GENERATE_DEFAULTS["seed"], window: int | None = None,
               overlap: int = GENERATE_DEFAULTS["overlap"], min_guidance: float | None = None,
               max_guidance: float | None = None, latents: torch.Tensor | None = None, start_step: int = 0,
               on_step: Callable[[int, int, torch.Tensor], bool | None] | None = None) -> torch.Tensor:
        """Denoise the whole clip; returns latents (F, C, h, w) float32 (still scaled by the VAE factor).

        ``latents``/``start_step`` resume from a saved state (the sampler is deterministic: no noise is drawn after
        the initial latents). ``on_step(step, total, latents)`` runs after each step; returning True stops there.

        Raises ``NonFiniteError`` (fields ``stage="generate"``, ``step`` 1-based, ``sigma`` the step's starting σ)
        as soon as a step leaves NaN/inf anywhere in the latents, before ``on_step`` sees them: a caller that saves
        resume state there never saves a poisoned one. The check is on the latents after the Euler step, so it
        also catches NaN/inf from either guidance branch alone (u + s·(c − u) is NaN when u is NaN or inf).
        """
        c = self.config
        window = window or c.window
        g_min = c.min_guidance if min_guidance is None else min_guidance
        g_max = c.max_guidance if max_guidance is None else max_guidance
        cond = cond.to(self.device)
        frames = len(cond)
        sigmas = self.schedule.sigmas(steps).to(self.device)
        x = self.initial_latents(cond.shape, seed) if latents is None else latents.to(self.device).float()
        starts = window_starts(frames, window, overlap)
        for i in range(start_step, steps):
            sigma, sigma_next = sigmas[i], sigmas[i + 1]
            acc = torch.zeros_like(x)
            count = torch.zeros(frames, 1, 1, 1, device=self.device)
            for s in starts:
                e = min(s + window, frames)
                g = edm.guidance_ramp(e - s, g_min, g_max, device=self.device)
                acc[s:e] += self.predict_x0(x[s:e], sigma, cond[s:e], clip, g)
                count[s:e] += 1
            x = edm.euler_step(x, acc / count, sigma, sigma_next)
            # one reduction over the whole clip per step (one host sync, as cheap as the step's progress event)
            if not bool(torch.isfinite(x).all()):
                raise NonFiniteError(
                    f"the model produced NaN/inf latents at step {i + 1} of {steps} (σ = {float(sigma):.4g})",
                    hint=precision_hint(self.dtype), stage="generate", step=i + 1, sigma=float(sigma))
            if on_step is not None and on_step(i + 1, steps, x):
                break
        return x

    @torch.no_grad()
    def decode(self, latents: torch.Tensor, chunk: int = GENERATE_DEFAULTS["decode_chunk"]) -> torch.Tensor:
        """(F, 3, H, W) in [0, 1] from latents, ``chunk`` frames at a time (the temporal decoder sees each chunk).

        Raises ``NonFiniteError`` (``stage="decode"``, ``frames`` [first, end) of the chunk, 0-based) when the
        decoder returns NaN/inf: checked before the clamp, which would turn ±inf into plausible 0/1 pixels."""
        vdt = next(self.vae.parameters()).dtype
        out = []
        for i in range(0, len(latents), chunk):
            z = latents[i:i + chunk] / self.vae.config.scaling_factor
            img = self.vae.decode(z.to(self.device, vdt), num_frames=len(z)).sample.float()
            if not bool(torch.isfinite(img).all()):
                raise NonFiniteError(
                    f"the VAE decoder produced NaN/inf pixels in frames {i}-{i + len(z) - 1} (0-based) of "
                    f"{len(latents)}",
                    hint=precision_hint(vdt), stage="decode", frames=[i, i + len(z)])
            out.append(((img + 1.0) / 2.0).clamp(0.0, 1.0).cpu())
        return torch.cat(out)


def clip_embeddings(image_encoder: torch.nn.Module, images: torch.Tensor, mean: torch.Tensor,
                    std: torch.Tensor) -> torch.Tensor:
    """(B, 1, D) float32 CLIP image embeddings of images (B, 3, H, W) in [0, 1], preprocessed as SVD's pipeline
    does: antialiased resize to the encoder's size at [−1, 1], back to [0, 1], CLIP mean/std; the encoder runs in
    its own dtype on the images' device."""
    from diffusers.pipelines.stable_video_diffusion.pipeline_stable_video_diffusion import (
        _resize_with_antialiasing,
    )

    size = image_encoder.config.image_size
    x = images.float() * 2.0 - 1.0
    x = (_resize_with_antialiasing(x, (size, size)) + 1.0) / 2.0
    x = (x - mean.to(x.device)) / std.to(x.device)
    emb = image_encoder(x.to(next(image_encoder.parameters()).dtype)).image_embeds
    return emb[:, None].float()


def pad_to_multiple(x: torch.Tensor, multiple: int, value: float = 0.0) -> torch.Tensor:
    """Pad (…, H, W) on the bottom and right up to multiples of ``multiple``."""
    H, W = x.shape[-2:]
    return F.pad(x, (0, (-W) % multiple, 0, (-H) % multiple), value=value)
