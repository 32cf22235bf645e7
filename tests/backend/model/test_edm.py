"""backend.model.edm against diffusers' EulerDiscreteScheduler configured as SVD's (the stock sampler), and the
schedule read from a scheduler config as diffusers reads it."""

import pytest
import torch
from diffusers import EulerDiscreteScheduler

from backend.model import configs, edm

SVD = edm.Schedule.from_config(configs.SCHEDULER)  # stock SVD: σ from 700 to 0.002, "leading" spacing


@pytest.mark.parametrize("steps", [1, 8, 25])
def test_sigmas_and_timesteps_match_svd_scheduler(steps):
    sched = EulerDiscreteScheduler.from_config(configs.SCHEDULER)
    sched.set_timesteps(steps)
    ours = SVD.sigmas(steps)
    assert (SVD.sigma_min, SVD.sigma_max, SVD.rho, SVD.timestep_spacing) == (0.002, 700.0, 7.0, "leading")
    assert torch.allclose(ours, sched.sigmas, rtol=1e-6, atol=0)
    assert torch.allclose(edm.c_noise(ours[:-1]), sched.timesteps, rtol=1e-6, atol=1e-7)
    assert SVD.init_noise_sigma == pytest.approx(float(sched.init_noise_sigma), rel=1e-7)


def test_euler_step_matches_scheduler_step():
    steps = 6
    sched = EulerDiscreteScheduler.from_config(configs.SCHEDULER)
    sched.set_timesteps(steps)
    sigmas = SVD.sigmas(steps)
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(3, 4, 5, 6, generator=gen) * SVD.init_noise_sigma
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
        SVD.sigmas(0)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
@pytest.mark.parametrize("sigma", [SVD.sigma_max, 1.0, SVD.sigma_min])
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
    if dtype == torch.float16 and sigma == SVD.sigma_max:
        assert float(edm.c_in(s.half())) == 0.0  # why the formulas stay in float32


# -- the schedule from a scheduler config, as diffusers reads it ------------------------------------------------

@pytest.mark.parametrize("edit", [
    {"sigma_max": 80.0},
    {"sigma_min": 0.02, "sigma_max": 80},
    {"timestep_spacing": "linspace"},
    {"timestep_spacing": "trailing", "sigma_max": 300.0},
], ids=["sigma_max-80", "range", "linspace", "trailing"])
def test_other_edm_configs_give_diffusers_sigmas_and_initial_noise(edit):
    """Whatever range and spacing the config holds, our sigmas, c_noise and initial noise scale are diffusers'."""
    config = {**configs.SCHEDULER, **edit}
    ours = edm.Schedule.from_config(config)
    sched = EulerDiscreteScheduler.from_config(config)
    sched.set_timesteps(6)
    assert ours.sigma_max == float(config["sigma_max"]) and ours.sigmas(6)[0] == pytest.approx(ours.sigma_max)
    assert torch.allclose(ours.sigmas(6), sched.sigmas, rtol=1e-6, atol=0)
    assert torch.allclose(edm.c_noise(ours.sigmas(6)[:-1]), sched.timesteps, rtol=1e-6, atol=1e-6)
    assert ours.init_noise_sigma == pytest.approx(float(sched.init_noise_sigma), rel=1e-6)


def test_missing_keys_take_diffusers_defaults():
    """``timestep_spacing`` absent is diffusers' "linspace" (initial noise σ_max); absent use_exponential_sigmas,
    use_beta_sigmas and final_sigmas_type are their harmless defaults."""
    config = {k: v for k, v in configs.SCHEDULER.items() if k != "timestep_spacing"}
    assert edm.Schedule.from_config(config).init_noise_sigma == 700.0
    assert edm.Schedule.from_config({**configs.SCHEDULER, "_class_name": "EulerDiscreteScheduler",
                                     "use_beta_sigmas": False, "final_sigmas_type": "zero"}) == SVD


def _without(key):
    return {k: v for k, v in configs.SCHEDULER.items() if k != key}


@pytest.mark.parametrize("config, field, words", [
    ({**configs.SCHEDULER, "prediction_type": "epsilon"}, "prediction_type", ["is 'epsilon'", '"v_prediction"']),
    (_without("prediction_type"), "prediction_type", ["is missing", 'default: "epsilon"']),
    ({**configs.SCHEDULER, "timestep_type": "discrete"}, "timestep_type", ['"continuous"']),
    ({**configs.SCHEDULER, "use_karras_sigmas": False}, "use_karras_sigmas", ["expected true"]),
    ({**configs.SCHEDULER, "use_karras_sigmas": 1}, "use_karras_sigmas", ["expected true"]),
    ({**configs.SCHEDULER, "use_exponential_sigmas": True}, "use_exponential_sigmas", ["expected false"]),
    ({**configs.SCHEDULER, "final_sigmas_type": "sigma_min"}, "final_sigmas_type", ['"zero"']),
    (_without("sigma_min"), "sigma_min", ["is missing", "a number in [1e-10, 1e+10]"]),
    ({**configs.SCHEDULER, "sigma_max": None}, "sigma_max", ["null"]),
    ({**configs.SCHEDULER, "sigma_max": "700"}, "sigma_max", ["a string"]),
    ({**configs.SCHEDULER, "sigma_min": 0}, "sigma_min", ["is 0"]),
    ({**configs.SCHEDULER, "sigma_max": 10 ** 400}, "sigma_max", ["an integer of 401 digits"]),
    ({**configs.SCHEDULER, "sigma_max": float("inf")}, "sigma_max", ["is inf"]),
    ({**configs.SCHEDULER, "sigma_max": float("nan")}, "sigma_max", ["is nan"]),
    ({**configs.SCHEDULER, "sigma_min": 800.0}, "sigma_min", ["not below sigma_max 700"]),
    ({**configs.SCHEDULER, "timestep_spacing": "evenly"}, "timestep_spacing", ['"leading"']),
    ({**configs.SCHEDULER, "_class_name": "DDIMScheduler"}, "_class_name", ['"EulerDiscreteScheduler"']),
    ([1, 2], "(file)", ["JSON object"]),
])
def test_configs_that_are_not_svds_edm_are_refused_naming_file_and_field(config, field, words):
    from backend.model.checkpoint_config import CheckpointError
    from scpainter_blender.core.errors import InputError

    with pytest.raises(CheckpointError) as info:
        edm.Schedule.from_config(config)
    e = info.value
    assert isinstance(e, InputError) and e.path == "scheduler/scheduler_config.json" and e.field == field
    assert str(e).startswith(f"scheduler/scheduler_config.json: {field}: ") and "v_prediction" in e.hint
    for w in words:
        assert w in str(e), (w, str(e))


def test_time_ids_are_svds_micro_conditioning():
    from backend.model.checkpoint_config import ScpainterConfig

    ids = edm.time_ids(ScpainterConfig(fps=7, motion_bucket_id=127, noise_aug_strength=0.02), 3)
    assert ids.shape == (3, 3) and ids.dtype == torch.float32
    assert torch.equal(ids, torch.tensor([[6.0, 127.0, 0.02]]).repeat(3, 1))


def _gaussian_ode(sampler, steps, mu=0.3, s=0.5):
    """Mean abs error of ``sampler`` at ``steps`` against the exact probability-flow ODE solution for data
    N(mu, s²), whose denoiser is exact: D(x, σ) = mu + s²/(s² + σ²)·(x − mu), and x(0) = mu + (x_T − mu)·s/√(s² +
    σ_max²). Returns (error, denoiser evaluations)."""
    D = lambda x, sig: mu + s * s / (s * s + sig * sig) * (x - mu)  # noqa: E731
    x_T = torch.randn(2000, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * SVD.sigma_max
    exact = mu + (x_T - mu) * s / (s * s + SVD.sigma_max ** 2) ** 0.5
    sig, x, x0_prev, evals = SVD.sigmas(steps, torch.float64), x_T.clone(), None, 0
    for i in range(steps):
        a, b = sig[i], sig[i + 1]
        x0 = D(x, a)
        evals += 1
        if sampler == "euler":
            x = edm.euler_step(x, x0, a, b)
        elif sampler == "heun":
            pred = edm.euler_step(x, x0, a, b)
            if b > 0:
                x, evals = edm.heun_correct(x, x0, pred, D(pred, b), a, b), evals + 1
            else:
                x = pred
        else:
            x, x0_prev = edm.dpmpp_2m_step(x, x0, a, b, x0_prev, sig[i - 1] if i else None), x0
    return float((x - exact).abs().mean()), evals


def test_samplers_converge_at_their_order_on_an_exact_denoiser():
    """Euler is first order, Heun and DPM-Solver++(2M) second order (doubling the steps from 20 to 40 divides the
    error by ~2 and by ≥ 3.5); at 25 steps both second-order samplers are closer to the exact solution than Euler at
    40; Heun takes 2n − 1 evaluations, the others n."""
    err = {k: {n: _gaussian_ode(k, n) for n in (20, 25, 40)} for k in edm.SAMPLERS}
    assert 1.6 < err["euler"][20][0] / err["euler"][40][0] < 2.4
    for k in ("heun", "dpmpp2m"):
        assert err[k][20][0] / err[k][40][0] > 3.5
        assert err[k][25][0] < err["euler"][40][0]
    assert [err[k][25][1] for k in ("euler", "heun", "dpmpp2m")] == [25, 49, 25]
