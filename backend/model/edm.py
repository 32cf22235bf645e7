"""EDM sampling math for SVD's v-parameterisation, written out (DESIGN §5; Karras et al. 2022; SVD's scheduler).

Conventions: x is a latent already multiplied by the VAE scaling factor; σ is the EDM noise level (x_σ = x_0 + σ ε).
The network F sees c_in·x_σ and c_noise = ¼ ln σ and predicts v; the denoised estimate is

    x_0 = c_skip·x_σ + c_out·F,   c_skip = 1/(σ²+1),   c_out = −σ/√(σ²+1),   c_in = 1/√(σ²+1).

Sampling starts from ε·√(σ_max²+1) (SVD's scheduler with "leading" spacing) and takes Euler steps
x ← x + (σ_next − σ)·(x − x_0)/σ over Karras sigmas (ρ = 7) followed by 0. Every function computes in the dtype of
its inputs; callers keep x and the schedule in float32 and cast only the network's input (see bench/sampler.py for
what fp16/bf16 would cost).
"""

from __future__ import annotations

import torch

SIGMA_MIN = 0.002
SIGMA_MAX = 700.0
RHO = 7.0


def karras_sigmas(steps: int, sigma_min: float = SIGMA_MIN, sigma_max: float = SIGMA_MAX, rho: float = RHO,
                  dtype=torch.float32) -> torch.Tensor:
    """(steps + 1,) decreasing noise levels from σ_max to σ_min, then a final 0 (computed in float64)."""
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    ramp = torch.linspace(0, 1, steps, dtype=torch.float64)
    lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
    sig = (hi + ramp * (lo - hi)) ** rho
    return torch.cat([sig, torch.zeros(1, dtype=torch.float64)]).to(dtype)


def c_in(sigma):
    return 1.0 / torch.sqrt(sigma * sigma + 1.0)


def c_noise(sigma):
    return 0.25 * torch.log(sigma)


def v_to_x0(x, v, sigma):
    """The denoised estimate from the network's v prediction at noise level σ (broadcastable)."""
    s2 = sigma * sigma + 1.0
    return x / s2 - v * (sigma / torch.sqrt(s2))


def euler_step(x, x0, sigma, sigma_next):
    """One Euler step of the probability-flow ODE from σ to σ_next given the denoised estimate."""
    return x + (sigma_next - sigma) * ((x - x0) / sigma)


def init_noise_sigma(sigma_max: float = SIGMA_MAX) -> float:
    return (sigma_max ** 2 + 1.0) ** 0.5


def guidance_ramp(frames: int, g_min: float, g_max: float, device=None, dtype=torch.float32) -> torch.Tensor:
    """Per-frame guidance rising linearly from g_min (first frame) to g_max (last), as SVD does; (frames,)."""
    return torch.linspace(g_min, g_max, frames, device=device, dtype=dtype)


def guide(uncond, cond, scale):
    """Classifier-free guidance mix u + s·(c − u); ``scale`` broadcasts over frames."""
    return uncond + scale * (cond - uncond)
