"""backend.model.edm against diffusers' EulerDiscreteScheduler configured as SVD's (the stock sampler)."""

import pytest
import torch
from diffusers import EulerDiscreteScheduler

from backend.model import configs, edm


@pytest.mark.parametrize("steps", [1, 8, 25])
def test_sigmas_and_timesteps_match_svd_scheduler(steps):
    sched = EulerDiscreteScheduler.from_config(configs.SCHEDULER)
    sched.set_timesteps(steps)
    ours = edm.karras_sigmas(steps)
    assert torch.allclose(ours, sched.sigmas, rtol=1e-6, atol=0)
    assert torch.allclose(edm.c_noise(ours[:-1]), sched.timesteps, rtol=1e-6, atol=1e-7)
    assert edm.init_noise_sigma() == pytest.approx(float(sched.init_noise_sigma), rel=1e-7)


def test_euler_step_matches_scheduler_step():
    steps = 6
    sched = EulerDiscreteScheduler.from_config(configs.SCHEDULER)
    sched.set_timesteps(steps)
    sigmas = edm.karras_sigmas(steps)
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(3, 4, 5, 6, generator=gen) * edm.init_noise_sigma()
    x_ref = x.clone()
    for i, t in enumerate(sched.timesteps):
        v = torch.randn(x.shape, generator=gen)
        assert torch.allclose(sched.scale_model_input(x_ref, t), edm.c_in(sigmas[i]) * x, rtol=1e-5, atol=1e-6)
        x_ref = sched.step(v, t, x_ref).prev_sample
        x = edm.euler_step(x, edm.v_to_x0(x, v, sigmas[i]), sigmas[i], sigmas[i + 1])
        assert torch.allclose(x, x_ref, rtol=1e-5, atol=1e-4 * float(sigmas[i]))


def test_guidance_ramp_and_mix():
    g = edm.guidance_ramp(5, 1.0, 3.0)
    assert torch.allclose(g, torch.tensor([1.0, 1.5, 2.0, 2.5, 3.0]))
    u, c = torch.zeros(5, 2), torch.ones(5, 2)
    assert torch.allclose(edm.guide(u, c, g[:, None]), g[:, None].expand(5, 2))
    with pytest.raises(ValueError):
        edm.karras_sigmas(0)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
@pytest.mark.parametrize("sigma", [edm.SIGMA_MAX, 1.0, edm.SIGMA_MIN])
@pytest.mark.parametrize("scale", [1.0, 15.0])
def test_low_precision_network_keeps_the_sampler_finite(dtype, sigma, scale):
    """Our path: float32 formulas, only the network's input/output rounded to fp16/bf16 — finite everywhere and
    x0 close to float64. Doing the formulas in fp16 instead loses σ² = 490000 to inf at σ_max (c_in becomes 0)."""
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(4096, generator=g, dtype=torch.float64)
    x = x0 + sigma * torch.randn(4096, generator=g, dtype=torch.float64)
    s = torch.tensor(sigma, dtype=torch.float64)
    v = (x / (s * s + 1) - x0) * torch.sqrt(s * s + 1) / s
    inp = (edm.c_in(s.float()) * x.float()).to(dtype)
    assert torch.isfinite(inp).all()
    v_r = v.to(dtype).float()
    out = edm.v_to_x0(x.float(), edm.guide(v_r, v_r, torch.tensor(scale)), s.float())
    assert torch.isfinite(out).all()
    tol = 0.05 if dtype == torch.bfloat16 else 0.01
    assert float((out.double() - x0).abs().max()) < tol
    if dtype == torch.float16 and sigma == edm.SIGMA_MAX:
        assert float(edm.c_in(s.half())) == 0.0  # why the formulas stay in float32
