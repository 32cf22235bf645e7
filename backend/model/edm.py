"""SVD's EDM denoiser and sampler, written out (`docs/design.md`, "The model and generation"; Karras et al. 2022;
diffusers' EulerDiscreteScheduler configured as SVD's).

Conventions: x is a latent already multiplied by the VAE scaling factor, (B, F, C, h, w) around the network (batch,
frames, channels, latent height and width); σ is the EDM noise level, x_σ = x_0 + σ ε (data scale σ_data = 1).

**The denoiser** (``Denoiser``; sampling and the training loss both call it, nothing else calls the UNet). The
UNet F sees the preconditioned latent concatenated with the condition latent along the channels, c_noise, the CLIP
image embedding and SVD's added time ids, and predicts v; the denoised estimate is

    D(x_σ, σ) = c_skip·x_σ + c_out·F(c_in·x_σ ‖ cond, c_noise; clip, time ids)
    c_skip = 1/(σ²+1),   c_out = −σ/√(σ²+1),   c_in = 1/√(σ²+1),   c_noise = ¼ ln σ.

Added time ids (``time_ids``, one row per sample): [fps − 1, motion_bucket_id, noise_aug_strength].

**The schedule** (``Schedule``, read from the checkpoint's ``scheduler/scheduler_config.json`` as diffusers'
EulerDiscreteScheduler reads it; only SVD's EDM kind is accepted): n Karras noise levels followed by 0,

    σ_i = (σ_max^(1/ρ) + i/(n−1)·(σ_min^(1/ρ) − σ_max^(1/ρ)))^ρ,   i = 0 … n−1,   σ_n = 0,   ρ = 7;

the initial latents are ε·√(σ_max²+1) ("leading" timestep spacing, SVD's; ε·σ_max for "linspace" and
"trailing"), and each step is an Euler step of the probability-flow ODE

    x ← x + (σ_{i+1} − σ_i)·(x − D(x, σ_i))/σ_i.

Classifier-free guidance mixes the two branches' denoised estimates, D_u + s·(D_c − D_u) (``guide``); D is affine
in v with the same x_σ, so this is SVD's mix of v exactly, up to rounding.

Precision: every formula computes in the dtype of its inputs. Callers keep x and the schedule in float32; the
denoiser casts only the network's inputs to its ``dtype`` and its output back (bench/sampler_stability.py: with the
formulas in fp16, σ² = 490 000 becomes inf at σ_max and the first step is lost).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import torch

from scpainter_blender.core.job import GENERATE_SAMPLERS as SAMPLERS

from .checkpoint_config import CheckpointError, json_object, show_value

SCHEDULER_FILE = os.path.join("scheduler", "scheduler_config.json")   # in a checkpoint or SVD snapshot folder
KARRAS_RHO = 7.0            # diffusers' EulerDiscreteScheduler uses ρ = 7 for use_karras_sigmas (not a config key)
SPACINGS = ("leading", "linspace", "trailing")
SIGMA_RANGE = (1e-10, 1e10)  # accepted sigma_min/sigma_max: σ², 1/σ and ln σ stay finite in the float32 sampler
SCHEDULER_HINT = ("SVD's scheduler_config.json is an EulerDiscreteScheduler with prediction_type \"v_prediction\", "
                  "timestep_type \"continuous\", use_karras_sigmas true, sigma_min 0.002 and sigma_max 700: restore "
                  "the file from the SVD snapshot the checkpoint was made from")


# ------------------------------------------------------------------------------------------------ the schedule

def karras_sigmas(steps: int, sigma_min: float, sigma_max: float, rho: float = KARRAS_RHO,
                  dtype=torch.float32) -> torch.Tensor:
    """(steps + 1,) decreasing noise levels from σ_max to σ_min, then a final 0 (computed in float64)."""
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    ramp = torch.linspace(0, 1, steps, dtype=torch.float64)
    lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
    sig = (hi + ramp * (lo - hi)) ** rho
    return torch.cat([sig, torch.zeros(1, dtype=torch.float64)]).to(dtype)


@dataclass(frozen=True)
class Schedule:
    """The sampler's noise levels, as diffusers' EulerDiscreteScheduler derives them from SVD's scheduler config:
    Karras sigmas (ρ = ``rho``) from ``sigma_max`` down to ``sigma_min``, then 0; ``timestep_spacing`` only sets
    the initial noise's scale (``init_noise_sigma``)."""

    sigma_min: float
    sigma_max: float
    rho: float = KARRAS_RHO
    timestep_spacing: str = "leading"

    @property
    def init_noise_sigma(self) -> float:
        """The initial latents' scale: √(σ_max² + 1) for "leading" spacing (SVD's), σ_max otherwise."""
        return (self.sigma_max ** 2 + 1.0) ** 0.5 if self.timestep_spacing == "leading" else self.sigma_max

    def sigmas(self, steps: int, dtype=torch.float32) -> torch.Tensor:
        """(steps + 1,) the noise level at the start of each step, then the final 0 (``karras_sigmas``)."""
        return karras_sigmas(steps, self.sigma_min, self.sigma_max, self.rho, dtype)

    @classmethod
    def from_config(cls, config: dict, path: str = SCHEDULER_FILE) -> Schedule:
        """The schedule of a scheduler config (the dict of ``scheduler_config.json``), refusing any config that
        is not SVD's EDM kind with a CheckpointError naming ``path`` and the field.

        Read as diffusers' EulerDiscreteScheduler reads it; a missing key takes diffusers' default. Required:
        ``_class_name`` (when present) "EulerDiscreteScheduler"; ``prediction_type`` "v_prediction" (default
        "epsilon"); ``timestep_type`` "continuous" (default "discrete": c_noise = ¼ ln σ needs it);
        ``use_karras_sigmas`` true, ``use_exponential_sigmas`` and ``use_beta_sigmas`` false; ``sigma_min`` and
        ``sigma_max`` numbers in ``SIGMA_RANGE``, sigma_min < sigma_max (diffusers would fall back to the range
        of its training betas; SVD's config sets both); ``final_sigmas_type`` "zero"; ``timestep_spacing`` one of
        ``SPACINGS`` (default "linspace"). Other keys (betas, interpolation, steps_offset) do not change Karras
        sigmas with an explicit range and are ignored."""

        def refuse(field, message):
            raise CheckpointError(path, field, message, hint=SCHEDULER_HINT)

        def got(key, default=None):
            if key in config:
                return f"is {show_value(config[key])}"
            return "is missing" + (f" (diffusers' default: {json.dumps(default)})" if default is not None else "")

        if not isinstance(config, dict):
            refuse("(file)", f"expected a JSON object, got {show_value(config)}")
        if "_class_name" in config and config["_class_name"] != "EulerDiscreteScheduler":
            refuse("_class_name", f"{got('_class_name')}, expected \"EulerDiscreteScheduler\" (SVD's "
                                  "scheduler): only its EDM configuration is implemented")
        wanted = (("prediction_type", "epsilon", "v_prediction",
                   "SVD's UNet predicts v and the denoiser converts v to x_0; a model that predicts anything else "
                   "is not SVD"),
                  ("timestep_type", "discrete", "continuous", "SVD's UNet is conditioned on c_noise = ¼ ln σ"),
                  ("use_karras_sigmas", False, True, "SVD samples on Karras sigmas"),
                  ("use_exponential_sigmas", False, False, "SVD samples on Karras sigmas"),
                  ("use_beta_sigmas", False, False, "SVD samples on Karras sigmas"),
                  ("final_sigmas_type", "zero", "zero", "the sampler's last Euler step goes to σ = 0"))
        for key, default, want, why in wanted:
            v = config.get(key, default)
            if type(v) is not type(want) or v != want:   # type: 1 is not true
                refuse(key, f"{got(key, default)}, expected {json.dumps(want)}: {why}")
        values, (lo, hi) = {}, SIGMA_RANGE
        for key in ("sigma_min", "sigma_max"):
            v = config.get(key)
            number = isinstance(v, (int, float)) and not isinstance(v, bool)
            if not number or not lo <= v <= hi:   # NaN fails both comparisons; a huge int compares exactly
                refuse(key, f"{got(key)}, expected a number in [{lo:g}, {hi:g}] (SVD's config sets sigma_min "
                            "0.002 and sigma_max 700)")
            values[key] = float(v)
        if values["sigma_min"] >= values["sigma_max"]:
            refuse("sigma_min", f"is {values['sigma_min']:g}, not below sigma_max {values['sigma_max']:g}")
        spacing = config.get("timestep_spacing", "linspace")
        if spacing not in SPACINGS:
            refuse("timestep_spacing", f"{got('timestep_spacing', 'linspace')}, expected one of "
                                       f"{', '.join(map(json.dumps, SPACINGS))}")
        return cls(values["sigma_min"], values["sigma_max"], KARRAS_RHO, spacing)

    @classmethod
    def from_folder(cls, folder: str) -> Schedule:
        """The schedule of a checkpoint or SVD snapshot folder: its ``scheduler/scheduler_config.json``."""
        path = os.path.join(folder, SCHEDULER_FILE)
        return cls.from_config(json_object(path), path)


# ------------------------------------------------------------------------------------------------ the denoiser

def c_in(sigma):
    return 1.0 / torch.sqrt(sigma * sigma + 1.0)


def c_noise(sigma):
    return 0.25 * torch.log(sigma)


def v_to_x0(x, v, sigma):
    """The denoised estimate c_skip·x + c_out·v from the network's v prediction at noise level σ (broadcastable)."""
    s2 = sigma * sigma + 1.0
    return x / s2 - v * (sigma / torch.sqrt(s2))


def time_ids(config, batch: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """(batch, 3) SVD's added time ids [fps − 1, motion_bucket_id, noise_aug_strength], the same row for every
    sample; ``config`` is a ``checkpoint_config.ScpainterConfig`` (or anything with those three fields)."""
    row = [[config.fps - 1, config.motion_bucket_id, config.noise_aug_strength]]
    return torch.tensor(row, dtype=dtype, device=device).repeat(batch, 1)


class Denoiser:
    """x_0 = D(x_σ, σ; cond, clip, time ids): SVD's UNet ``net`` inside the EDM preconditioning (module docstring).

    The one function from a noisy latent to x_0: the sampler (``pipeline.SCPainterPipeline``) and the training loss
    (``train.objective.loss``) both call it. ``schedule`` is the checkpoint's (``Schedule.from_folder``), kept here
    so that whoever holds the denoiser holds its noise levels. ``dtype``: what the network's inputs are cast to
    (bf16/fp16 UNet weights on CUDA); None leaves them float32 (training, where autocast casts inside the UNet)."""

    def __init__(self, net, schedule: Schedule, dtype=None):
        self.net, self.schedule, self.dtype = net, schedule, dtype

    def __call__(self, x, sigma, cond, clip, time_ids) -> torch.Tensor:
        """x (B, F, C, h, w) float32 noisy latents at noise level ``sigma`` (a number, shape () or (B,), or
        anything of B elements); cond (B, F, C_cond, h, w) the condition latent (zeros: unconditional); clip
        (B, 1, D) the CLIP image embedding (zeros: unconditional); time_ids (B, 3) (``time_ids``). Returns x_0
        (B, F, C, h, w) in x's dtype; gradients flow when the caller's do."""
        B = x.shape[0]
        s = torch.as_tensor(sigma, dtype=x.dtype, device=x.device).reshape(-1).expand(B)   # (B,)
        s5 = s.view(B, 1, 1, 1, 1)
        inp = torch.cat([c_in(s5) * x, cond], dim=2)                                        # (B, F, C + C_cond, h, w)
        dt = self.dtype or inp.dtype
        v = self.net(inp.to(dt), c_noise(s).to(dt), encoder_hidden_states=clip.to(dt),
                     added_time_ids=time_ids.to(dt), return_dict=False)[0].to(x.dtype)
        return v_to_x0(x, v, s5)


# ------------------------------------------------------------------------------------------------- the sampler

# Three samplers of the same probability-flow ODE dx/dσ = (x − D(x, σ))/σ over the same Karras noise levels
# (``SAMPLERS`` in core/job.py names them). One step goes from σ = σ_i to σ_next = σ_{i+1}; x0 = D(x, σ).
#
#   euler    one evaluation a step (stock SVD's, diffusers' EulerDiscreteScheduler):
#            x ← x + (σ_next − σ)·(x − x0)/σ.
#   heun     Karras et al. 2022, Algorithm 1 without churn: the Euler step as a predictor x', then the trapezoid rule
#            with the slope at x' (a second evaluation, D(x', σ_next)); the last step (σ_next = 0) stays Euler.
#            Two evaluations a step except the last: 2n − 1 for n steps.
#   dpmpp2m  DPM-Solver++(2M) (Lu et al. 2022, the multistep second-order solver in the data-prediction form), in
#            σ: with λ = −ln σ, h = λ_next − λ and r = h_prev/h,
#                x ← (σ_next/σ)·x + (1 − σ_next/σ)·D,   D = (1 + 1/(2r))·x0 − (1/(2r))·x0_prev,
#            where x0_prev is the previous step's x0; the first step (no x0_prev) and the last (σ_next = 0, whose
#            result is x0 itself) use D = x0 (a first-order DDIM step), as k-diffusion's sample_dpmpp_2m does. One
#            evaluation a step; a step needs x0_prev (and the previous σ), so a resume state holds x0_prev.


def euler_step(x, x0, sigma, sigma_next):
    """One Euler step of the probability-flow ODE from σ to σ_next given the denoised estimate."""
    return x + (sigma_next - sigma) * ((x - x0) / sigma)


def heun_correct(x, x0, x_pred, x0_pred, sigma, sigma_next):
    """Heun's corrector (Karras et al. 2022, Alg. 1): the step from x at σ to σ_next > 0 with the mean of the slopes
    at x (denoised ``x0``) and at the Euler prediction ``x_pred`` (denoised ``x0_pred`` at σ_next)."""
    d, d_next = (x - x0) / sigma, (x_pred - x0_pred) / sigma_next
    return x + (sigma_next - sigma) * 0.5 * (d + d_next)


def dpmpp_2m_step(x, x0, sigma, sigma_next, x0_prev=None, sigma_prev=None):
    """One DPM-Solver++(2M) step from σ to σ_next (comment above): ``x0_prev`` and ``sigma_prev`` are the previous
    step's denoised estimate and starting σ (None on the first step: a first-order step)."""
    if float(sigma_next) == 0.0:
        return x0.clone()
    ratio = sigma_next / sigma
    denoised = x0
    if x0_prev is not None:
        h = torch.log(sigma / sigma_next)
        r = torch.log(sigma_prev / sigma) / h
        denoised = (1 + 1 / (2 * r)) * x0 - (1 / (2 * r)) * x0_prev
    return ratio * x + (1 - ratio) * denoised


def guidance_ramp(frames: int, g_min: float, g_max: float, device=None, dtype=torch.float32) -> torch.Tensor:
    """Per-frame guidance rising linearly from g_min (first frame) to g_max (last), as SVD does; (frames,)."""
    return torch.linspace(g_min, g_max, frames, device=device, dtype=dtype)


def guide(uncond, cond, scale):
    """Classifier-free guidance mix u + s·(c − u); ``scale`` broadcasts over frames."""
    return uncond + scale * (cond - uncond)
