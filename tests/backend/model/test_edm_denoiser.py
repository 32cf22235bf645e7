"""One denoiser (issue 15): training's loss and the sampler go through the same ``edm.Denoiser`` object, and the
noise levels are the checkpoint's ``scheduler/scheduler_config.json``, not constants.

Calls are recorded by wrapping ``edm.Denoiser.__call__``; every test also checks real outputs against the recorded
calls (the loss recomputed from the denoiser's x̂_0, the sampler's latents from a hand-written Euler loop)."""

import json
import math
import os
import shutil

import pytest
import torch

from backend.model import checkpoint, checkpoint_init, edm
from backend.model.checkpoint_config import CheckpointError
from backend.model.pipeline import SCPainterPipeline
from backend.train import objective
from backend.train.config import TrainConfig
from scpainter_blender.core.job import STOCK_SAMPLING

STOCK = {k: v for k, v in STOCK_SAMPLING.items() if k != "steps"}   # the hand-written loops below are stock's Euler


@pytest.fixture
def calls(monkeypatch):
    """[(denoiser object, sigma (B,), output x_0)] for every ``edm.Denoiser`` call while the test runs."""
    real, seen = edm.Denoiser.__call__, []

    def record(self, x, sigma, cond, clip, time_ids):
        out = real(self, x, sigma, cond, clip, time_ids)
        seen.append((self, torch.as_tensor(sigma).reshape(-1).expand(x.shape[0]).clone(), out.detach().clone()))
        return out

    monkeypatch.setattr(edm.Denoiser, "__call__", record)
    return seen


def _copy(tiny_checkpoint, tmp_path, **scheduler):
    """A real copy of the tiny checkpoint (never hard links) with ``scheduler`` merged into its scheduler config."""
    path = shutil.copytree(tiny_checkpoint, tmp_path / "ckpt")
    cfg_path = os.path.join(path, "scheduler", "scheduler_config.json")
    with open(cfg_path) as f:
        data = json.load(f)
    with open(cfg_path, "w") as f:
        json.dump({**data, **scheduler}, f)
    return str(path)


def test_training_and_sampling_call_the_same_denoiser(tiny_checkpoint, calls):
    """Two optimiser steps of the real loss, then sampling with a pipeline holding the very same denoiser object:
    every UNet evaluation of both is that object's; the loss is the λ-weighted error of the x̂_0 it returned; the
    sampler's latents are an Euler loop over its x_0; and the trained weights are what sampling used."""
    c = checkpoint.load(tiny_checkpoint)
    denoiser = edm.Denoiser(c["unet"], c["schedule"])
    assert c["schedule"] == edm.Schedule.from_folder(tiny_checkpoint)   # the loader read the scheduler config
    unet, cond_enc = c["unet"], c["condition_encoder"]
    pipe = SCPainterPipeline({**{k: v for k, v in c.items() if k not in ("unet", "schedule")}, "denoiser": denoiser})
    models = {**c, "denoiser": denoiser, "clip_mean": pipe.clip_mean, "clip_std": pipe.clip_std}
    assert pipe.denoiser is denoiser and pipe.unet is unet and pipe.schedule is c["schedule"]

    F, H, W, steps = 2, 32, 32, 2
    g = torch.Generator().manual_seed(0)
    image = torch.rand(F, 3, H, W, generator=g)
    cond = pipe.condition_latents(image, torch.zeros(F, 1, H, W), torch.ones(F, 1, H, W))
    clip = pipe.clip_embedding(image[0])
    before = pipe.sample(cond, clip, steps=steps, seed=3, max_guidance=1.0, **STOCK)
    calls.clear()

    # -- train: two AdamW steps through objective.loss
    batch = {"target": torch.rand(1, F, 3, 64, 64, generator=g), "image": torch.rand(1, F, 3, 64, 64, generator=g),
             "asset_mask": (torch.rand(1, F, 1, 64, 64, generator=g) > 0.8).float(),
             "valid": torch.ones(1, F, 1, 64, 64)}
    cfg = TrainConfig(checkpoint="", clips=["x"], output_dir="", drop_clip=0.0, drop_condition=0.0)
    for m in (unet, cond_enc):
        m.train().requires_grad_(True)
    w0 = unet.conv_in.weight.detach().clone()
    opt = torch.optim.AdamW([p for m in (unet, cond_enc) for p in m.parameters()], lr=1e-3)
    try:
        for step in range(2):
            loss, stats = objective.loss(models, batch, cfg, objective.generators(step, [0]), "cpu")
            assert len(calls) == step + 1 and calls[-1][0] is denoiser   # one call per micro-batch, this object
            # the loss is made of that call's x̂_0: λ(σ)·mean((x̂_0 − x_0)²) with x_0 drawn as the loss drew it
            gens = objective.generators(step, [0])
            objective.draw(gens, cfg)
            x0 = objective.target_latents(c["vae"], batch["target"], gens)
            _, sigma, x0_hat = calls[-1]
            assert torch.equal(sigma, stats["sigma"])
            expect = ((sigma ** 2 + 1) / sigma ** 2 * ((x0_hat - x0) ** 2).mean(dim=(1, 2, 3, 4))).mean()
            assert float(loss.detach()) == pytest.approx(float(expect), rel=1e-6)
            opt.zero_grad()
            loss.backward()
            opt.step()
    finally:
        for m in (unet, cond_enc):
            m.eval().requires_grad_(False)
    assert not torch.equal(unet.conv_in.weight, w0)   # the steps trained the UNet the denoiser holds
    calls.clear()

    # -- sample with the same object: one window, no guidance, one denoiser call per step
    out = pipe.sample(cond, clip, steps=steps, seed=3, max_guidance=1.0, **STOCK)
    assert len(calls) == steps and all(d is denoiser for d, _, _ in calls)
    sigmas = c["schedule"].sigmas(steps)
    assert [float(s) for _, s, _ in calls] == [float(s) for s in sigmas[:-1]]
    x = pipe.initial_latents(cond.shape, 3)
    with torch.no_grad():
        for i in range(steps):
            x0 = denoiser(x[None], sigmas[i], cond[None], clip, edm.time_ids(c["config"], 1))[0]
            x = edm.euler_step(x, x0, sigmas[i], sigmas[i + 1])
    assert torch.equal(out, x)
    assert not torch.allclose(out, before)   # sampling used the trained weights
    # with guidance: still one call per step, both branches in it
    calls.clear()
    pipe.sample(cond, clip, steps=steps, seed=3, max_guidance=3.0, **STOCK)
    assert len(calls) == steps and all(d is denoiser and len(s) == 2 for d, s, _ in calls)


def test_sigma_max_comes_from_the_checkpoints_scheduler_config(tiny_checkpoint, tmp_path):
    """sigma_max 80 in scheduler/scheduler_config.json: the pipeline the loader builds starts sampling at σ = 80
    (the UNet's first c_noise is ¼ ln 80, not ¼ ln 700) from noise of scale √(80² + 1)."""
    stock = SCPainterPipeline.from_checkpoint(tiny_checkpoint)
    pipe = SCPainterPipeline.from_checkpoint(_copy(tiny_checkpoint, tmp_path, sigma_max=80.0))
    assert stock.schedule.sigma_max == 700.0 and pipe.schedule.sigma_max == 80.0
    first = []

    def hook(_module, args, _kwargs):
        first.append(float(args[1].reshape(-1)[0]))

    F, H, W = 2, 32, 32
    cond = torch.zeros(F, 4, H // 8, W // 8)
    clip = torch.zeros(1, 1, 32)
    for p in (stock, pipe):
        h = p.unet.register_forward_pre_hook(hook, with_kwargs=True)
        try:
            p.sample(cond, clip, steps=3, seed=1, max_guidance=1.0, on_step=lambda i, n, x, h: True, **STOCK)  # 1 step
        finally:
            h.remove()
    assert first == [pytest.approx(0.25 * math.log(700.0), rel=1e-6), pytest.approx(0.25 * math.log(80.0), rel=1e-6)]
    ratio = pipe.initial_latents(cond.shape, 1) / stock.initial_latents(cond.shape, 1)
    assert torch.allclose(ratio, torch.full_like(ratio, math.sqrt(80.0 ** 2 + 1) / math.sqrt(700.0 ** 2 + 1)))


@pytest.mark.parametrize("fn", [checkpoint.check, SCPainterPipeline.from_checkpoint, checkpoint.load])
def test_a_scheduler_that_is_not_v_prediction_is_refused_naming_file_and_field(tiny_checkpoint, tmp_path, fn):
    path = _copy(tiny_checkpoint, tmp_path, prediction_type="epsilon")
    with pytest.raises(CheckpointError) as info:
        fn(path)
    e = info.value
    assert e.path == os.path.join(path, "scheduler", "scheduler_config.json") and e.field == "prediction_type"
    assert str(e).startswith(f"{e.path}: prediction_type: is 'epsilon' (a string), expected \"v_prediction\"")


def test_an_svd_snapshot_without_a_sigma_range_is_refused_by_init_checkpoint(tiny_svd, tmp_path):
    svd = shutil.copytree(tiny_svd, tmp_path / "svd")
    cfg_path = os.path.join(svd, "scheduler", "scheduler_config.json")
    with open(cfg_path) as f:
        data = json.load(f)
    del data["sigma_max"]
    with open(cfg_path, "w") as f:
        json.dump(data, f)
    with pytest.raises(CheckpointError) as info:
        checkpoint_init.init_checkpoint(str(svd), str(tmp_path / "out"))
    assert info.value.path == cfg_path and info.value.field == "sigma_max" and "is missing" in str(info.value)
    assert not os.path.exists(tmp_path / "out")
