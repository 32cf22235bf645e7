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
from . import edm, gpu_speed
from .condition import encode_conditions
from .feature_reuse import FeatureReuse

if TYPE_CHECKING:
    from collections.abc import Callable

#: Frames the condition encoder sees at once. It is SVD's 2D VAE encoder, frame by frame, run in float32 (the VAE
#: asks for upcasting): at 576 x 1024 its first block's activations are 0.3 GB a frame, so 8 frames at once peaked
#: 10.6 GiB above stock SVD on an H200 (which encodes one image); one frame at a time is stock's peak, and the same
#: latents (tests/backend/model/test_pipeline.py).
CONDITION_CHUNK = 1

def decode_dtype(dtype: torch.dtype, device: str | torch.device) -> torch.dtype:
    """The VAE decoder's dtype for a model running in ``dtype``: fp16 for a 16-bit model on CUDA (stock SVD decodes
    in fp16: the same memory; measured 1.9e-4 mean abs against a float32 decode, bench/generate.py section decode,
    where bf16 is 1.5e-3, above the 1e-3 the decode must keep), float32 otherwise (fp32 runs; on the CPU PyTorch's
    fp16 convolutions are a slow reference path: 46 s against 3.5 s in float32 for one small decode here)."""
    if dtype in (torch.float16, torch.bfloat16) and torch.device(device).type == "cuda":
        return torch.float16
    return torch.float32 if dtype == torch.bfloat16 else dtype


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
        self.compile, self.gpu_tuning = "off", "off"   # set_speed
        #: UNet frame-evaluations so far (batch rows × frames), whole ("full") and with reused features ("shallow")
        self.evaluations = {"full": 0, "shallow": 0}

    @classmethod
    def from_checkpoint(cls, path: str, device: str | torch.device = "cpu",
                        dtype: torch.dtype = torch.float32) -> SCPainterPipeline:
        """Load an SCPainter checkpoint folder (local files only, see ``checkpoint.load``)."""
        from . import checkpoint

        return cls(checkpoint.load(path, device, dtype), device, dtype)

    def release_encoders(self) -> None:
        """Drop CLIP and the condition encoder (``clip_embedding`` and ``condition_latents`` no longer work): a
        run that has its embeddings frees their weights (1.4 GB for SVD) before sampling and decoding, the stages
        where memory peaks (bench/generate.py, section memory)."""
        self.image_encoder = self.condition_encoder = None

    def set_speed(self, compile: str = GENERATE_DEFAULTS["compile"],
                  gpu_tuning: str = GENERATE_DEFAULTS["gpu_tuning"]) -> None:
        """The generate settings ``compile`` and ``gpu_tuning`` (``gpu_speed``): the UNet compiled and tuned in
        place, once (a FeatureReuse net compiles its own forward with the same mode)."""
        gpu_speed.tune_unet(self.unet, self.device, gpu_tuning)
        if compile != self.compile:
            self.unet = gpu_speed.compile_fn(getattr(self.unet, "_orig_mod", self.unet), compile)
        self.compile, self.gpu_tuning = compile, gpu_tuning

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
        vae_factor = 2 ** (len(self.vae.config.block_out_channels) - 1)   # the condition encoder's too
        return vae_factor * 2 ** (len(self.unet.config.block_out_channels) - 1)

    @torch.no_grad()
    def clip_embedding(self, image: torch.Tensor) -> torch.Tensor:
        """(1, 1, D) CLIP image embedding of one (3, H, W) image in [0, 1] (see ``clip_embeddings``)."""
        return clip_embeddings(self.image_encoder, image[None].to(self.device), self.clip_mean, self.clip_std)

    @torch.no_grad()
    def condition_latents(self, image: torch.Tensor, asset_mask: torch.Tensor, valid: torch.Tensor,
                          seed: int = GENERATE_DEFAULTS["seed"], chunk: int = CONDITION_CHUNK) -> torch.Tensor:
        """(F, C, h, w) float32 from I (F, 3, H, W), the asset mask M_a and the validity V (F, 1, H, W) in [0, 1],
        encoded ``chunk`` frames at a time (``CONDITION_CHUNK``: the encoder is per-frame, so the chunk sets only
        the peak memory; the noise is drawn in the same order whatever the chunk)."""
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
                   guidance: torch.Tensor, denoiser: edm.Denoiser | None = None,
                   drop_unguided: bool = False) -> torch.Tensor:
        """x_0 (F, C, h, w) float32 of one window: x (F, C, h, w) float32 at noise level σ, cond (F, C, h, w),
        clip (1, 1, D), guidance (F,) per frame (≤ 1 everywhere: no classifier-free guidance). ``denoiser``: the
        one to call (default ``self.denoiser``; the sampler passes one around a ``FeatureReuse`` net).

        ``drop_unguided`` (measured by bench/generate.py, not a setting): the unconditional branch sees only the
        frames whose guidance is > 1, in a second call (the UNet is temporal: the frames it drops change the
        others' unconditional estimates, so this is not exact). Adds the frame-evaluations to ``evaluations``."""
        denoiser = denoiser or self.denoiser
        if self.compile == "reduce-overhead":   # CUDA graphs: the outputs of earlier replays are consumed by now
            torch.compiler.cudagraph_mark_step_begin()
        ids = edm.time_ids(self.config, 1, self.device, self.dtype)
        frames = len(x)
        if float(guidance.max()) <= 1.0:
            out = denoiser(x[None], sigma, cond[None], clip, ids)[0]
            self._count(denoiser, frames)
            return out
        if drop_unguided:
            keep = guidance > 1.0
            x0_c = denoiser(x[None], sigma, cond[None], clip, ids)[0]
            self._count(denoiser, frames)
            x0_u = x0_c.clone()
            x0_u[keep] = denoiser(x[keep][None], sigma, torch.zeros_like(cond[keep])[None], torch.zeros_like(clip),
                                  ids)[0]
            self._count(denoiser, int(keep.sum()))
            return edm.guide(x0_u, x0_c, guidance.view(-1, 1, 1, 1).to(x0_c))
        # one batched pass: the unconditional branch (row 0) has zero CLIP and zero condition latent
        x0 = denoiser(torch.stack([x, x]), sigma, torch.stack([torch.zeros_like(cond), cond]),
                      torch.cat([torch.zeros_like(clip), clip]), ids.repeat(2, 1))
        self._count(denoiser, 2 * frames)
        return edm.guide(x0[0], x0[1], guidance.view(-1, 1, 1, 1).to(x0))

    def _count(self, denoiser: edm.Denoiser, frames: int) -> None:
        net = denoiser.net
        shallow = isinstance(net, FeatureReuse) and net.last_shallow
        self.evaluations["shallow" if shallow else "full"] += frames

    @torch.no_grad()
    def sample(self, cond: torch.Tensor, clip: torch.Tensor, steps: int = GENERATE_DEFAULTS["steps"],
               seed: int = GENERATE_DEFAULTS["seed"], window: int | None = None,
               overlap: int = GENERATE_DEFAULTS["overlap"], min_guidance: float | None = None,
               max_guidance: float | None = None, latents: torch.Tensor | None = None, start_step: int = 0,
               on_step: Callable[[int, int, torch.Tensor, dict | None], bool | None] | None = None,
               sampler: str = GENERATE_DEFAULTS["sampler"], feature_reuse: int = GENERATE_DEFAULTS["feature_reuse"],
               guidance_sigma_min: float = GENERATE_DEFAULTS["guidance_sigma_min"],
               guidance_sigma_max: float = GENERATE_DEFAULTS["guidance_sigma_max"], history: dict | None = None,
               drop_unguided: bool = False) -> torch.Tensor:
        """Denoise the whole clip; returns latents (F, C, h, w) float32 (still scaled by the VAE factor).

        ``sampler`` (``edm``: euler | heun | dpmpp2m) over ``steps`` Karras noise levels; ``feature_reuse`` N:
        the first evaluation of step i runs the whole UNet when i % N == 0 and reuses its deep features otherwise
        (``feature_reuse.FeatureReuse``; 1 = never); classifier-free guidance only for evaluations at σ in
        [``guidance_sigma_min``, ``guidance_sigma_max``] (a guidance interval: outside it no unconditional branch,
        the conditional estimate alone, as guidance 1). ``job.STOCK_SAMPLING`` (Euler, 25 steps, 1, [0, 1e10]) is
        stock SVD's sampler (tested against diffusers).

        ``latents``/``start_step`` resume from a saved state (the sampler is deterministic: no noise is drawn after
        the initial latents); ``history`` is what ``on_step`` handed over with those latents (DPM-Solver++(2M)'s
        previous x_0). ``on_step(step, total, latents, history)`` runs after each step; returning True stops at the
        first resume point from there. ``history`` is a dict of tensors (empty for Euler and Heun) when the latents
        and it are all the next step needs — a resume point — and None when they are not (with feature reuse,
        before a step that would reuse features the state does not hold): a caller saves resume state only at
        resume points, so a resumed run gives exactly the uninterrupted run's latents.

        Raises ``NonFiniteError`` (fields ``stage="generate"``, ``step`` 1-based, ``sigma`` the step's starting σ)
        as soon as a step leaves NaN/inf anywhere in the latents, before ``on_step`` sees them: a caller that saves
        resume state there never saves a poisoned one. The check is on the latents after the step, so it also
        catches NaN/inf from either guidance branch alone (u + s·(c − u) is NaN when u is NaN or inf).
        """
        if sampler not in edm.SAMPLERS:
            raise ValueError(f"sampler must be one of {edm.SAMPLERS}, got {sampler!r}")
        c = self.config
        window = window or c.window
        g_min = c.min_guidance if min_guidance is None else min_guidance
        g_max = c.max_guidance if max_guidance is None else max_guidance
        cond = cond.to(self.device)
        frames = len(cond)
        sigmas = self.schedule.sigmas(steps).to(self.device)
        x = self.initial_latents(cond.shape, seed) if latents is None else latents.to(self.device).float()
        starts = window_starts(frames, window, overlap)
        ramps = {s: edm.guidance_ramp(min(s + window, frames) - s, g_min, g_max, device=self.device) for s in starts}
        reuse = FeatureReuse(self.unet, compile=self.compile) if feature_reuse > 1 else None
        denoiser = self.denoiser   # the one denoiser; with feature reuse its net is the FeatureReuse while sampling
        x0_prev = None if not history or history.get("x0_prev") is None else history["x0_prev"].to(self.device)

        def denoise(x, sigma, full):
            """x_0 of the whole clip at σ: each window's, averaged where windows share frames."""
            acc = torch.zeros_like(x)
            count = torch.zeros(frames, 1, 1, 1, device=self.device)
            guided = guidance_sigma_min <= float(sigma) <= guidance_sigma_max
            for s in starts:
                e = min(s + window, frames)
                g = ramps[s] if guided else torch.ones_like(ramps[s])
                if reuse is not None:
                    reuse.key, reuse.full = (s, guided and float(g.max()) > 1.0), full
                acc[s:e] += self.predict_x0(x[s:e], sigma, cond[s:e], clip, g, denoiser, drop_unguided)
                count[s:e] += 1
            return acc / count

        net = denoiser.net
        try:
            denoiser.net = reuse or net
            with gpu_speed.tuned(self.device, self.gpu_tuning):
                return self._steps(x, sigmas, steps, start_step, sampler, feature_reuse, reuse, denoise, x0_prev,
                                   on_step)
        finally:
            denoiser.net = net

    def _steps(self, x, sigmas, steps, start_step, sampler, feature_reuse, reuse, denoise, x0_prev, on_step):
        """``sample``'s loop over the steps (its docstring)."""
        stop = False
        for i in range(start_step, steps):
            sigma, sigma_next = sigmas[i], sigmas[i + 1]
            full = i % feature_reuse == 0
            x0 = denoise(x, sigma, full)
            if sampler == "euler":
                x_new = edm.euler_step(x, x0, sigma, sigma_next)
            elif sampler == "heun":
                x_new = edm.euler_step(x, x0, sigma, sigma_next)
                if float(sigma_next) > 0:
                    x_new = edm.heun_correct(x, x0, x_new, denoise(x_new, sigma_next, False), sigma, sigma_next)
            else:
                x_new = edm.dpmpp_2m_step(x, x0, sigma, sigma_next, x0_prev, sigmas[i - 1] if i else None)
                x0_prev = x0
            x = x_new
            # one reduction over the whole clip per step (one host sync, as cheap as the step's progress event)
            if not bool(torch.isfinite(x).all()):
                raise NonFiniteError(
                    f"the model produced NaN/inf latents at step {i + 1} of {steps} (σ = {float(sigma):.4g})",
                    hint=precision_hint(self.dtype), stage="generate", step=i + 1, sigma=float(sigma))
            resumable = reuse is None or i + 1 == steps or (i + 1) % feature_reuse == 0
            state = ({"x0_prev": x0_prev} if sampler == "dpmpp2m" else {}) if resumable else None
            if on_step is not None and on_step(i + 1, steps, x, state):
                stop = True
            if stop and resumable:
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
            # to the host in the decoder's dtype: no float32 copy of the chunk on the device (memory: as stock)
            img = self.vae.decode(z.to(self.device, vdt), num_frames=len(z)).sample.cpu().float()
            if not bool(torch.isfinite(img).all()):
                raise NonFiniteError(
                    f"the VAE decoder produced NaN/inf pixels in frames {i}-{i + len(z) - 1} (0-based) of "
                    f"{len(latents)}",
                    hint=precision_hint(vdt), stage="decode", frames=[i, i + len(z)])
            out.append(((img + 1.0) / 2.0).clamp(0.0, 1.0))
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
