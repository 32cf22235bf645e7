"""Non-finite training is an error (issue 14): a NaN loss or gradient norm stops the run with NonFiniteError naming
the step and its samples, nothing from that step reaches a checkpoint, and the same command resumes from the last
good one. The fault is injected by wrapping our own ``objective.loss`` (the tiny model and the street clip are real).
"""

import math
import os

import pytest
import torch

from backend.errors import NonFiniteError
from backend.train import config as train_config
from backend.train import objective, trainer
from tests.backend.train.test_trainer import _config


def _fault_at(monkeypatch, step: int, kind: str):
    """Make ``objective.loss`` misbehave at its ``step``-th call (one call per step: batch 1, no accumulation).
    ``nan``: the loss itself is NaN. ``grad``: the loss stays finite but its gradient is NaN (sqrt at 0 has an
    infinite slope, times the zero inner derivative)."""
    real, calls = objective.loss, []

    def loss(models, *args, **kw):
        total, stats = real(models, *args, **kw)
        calls.append(1)
        if len(calls) == step:
            if kind == "nan":
                total = total * math.nan
            else:
                w = next(models["unet"].parameters())
                total = total + torch.sqrt(w.sum() * 0.0)
        return total, stats

    monkeypatch.setattr(objective, "loss", loss)
    return calls


def _saved(cfg) -> list:
    d = os.path.join(cfg.resolve(cfg.output_dir), "checkpoints")
    return sorted(os.listdir(d)) if os.path.isdir(d) else []  # temporary .ckpt-* folders would show up here


def test_nan_loss_names_step_and_batch_keeps_the_last_good_checkpoint_and_resumes(
        tmp_path, tiny_checkpoint, street_clip_path, monkeypatch):
    cfg = train_config.load(_config(tmp_path, tiny_checkpoint, street_clip_path, steps=3, save_every=1))
    _fault_at(monkeypatch, 2, "nan")
    with pytest.raises(NonFiniteError) as e:
        trainer.train(cfg, "cpu")
    f = e.value.fields
    good = os.path.join(cfg.resolve(cfg.output_dir), "checkpoints", "step_0000001")
    assert f["stage"] == "train" and f["step"] == 2 and f["checkpoint"] == good
    (sample,) = f["batch"]  # batch 1: step 2 is global sample 1
    assert sample["sample"] == 1 and sample["clip"] == street_clip_path
    assert sample["frames"][1] - sample["frames"][0] == cfg.pairs.frames
    t0 = sample["frames"][0]
    assert str(e.value).startswith(f"train: the loss is nan at step 2 (samples: 1 (street, frames {t0}-{t0 + 1}))")
    assert f"the last good checkpoint {good} is kept" in str(e.value)
    assert f"resumes from {good}" in e.value.hint and "learning_rate" in e.value.hint
    assert _saved(cfg) == ["step_0000001"]  # neither the step's save nor the final one ran

    monkeypatch.undo()  # the same command again, without the fault: it resumes after step 1
    r = trainer.train(cfg, "cpu")
    assert r["step"] == 3 and len(r["losses"]) == 2 and all(map(math.isfinite, r["losses"]))
    assert _saved(cfg) == ["step_0000001", "step_0000002", "step_0000003"]


def test_nan_gradient_with_a_finite_loss_before_any_checkpoint(tmp_path, tiny_checkpoint, street_clip_path,
                                                               monkeypatch):
    cfg = train_config.load(_config(tmp_path, tiny_checkpoint, street_clip_path, steps=2, save_every=1))
    _fault_at(monkeypatch, 1, "grad")
    t = trainer.Trainer(cfg, "cpu")
    before = {k: p.detach().clone() for k, p in t.named.items()}
    try:
        with pytest.raises(NonFiniteError, match=r"train: the gradient norm is nan at step 1 \(samples: 0 ") as e:
            t.train()
    finally:
        t.tb.close()
    assert e.value.fields["checkpoint"] is None and "no checkpoint had been written yet" in str(e.value)
    assert "starts from the base checkpoint" in e.value.hint
    assert _saved(cfg) == []
    # the optimiser never stepped and the EMA never updated: the state is the one loaded
    assert t.step == 0 and t.ema.updates == 0
    assert all(torch.equal(p, before[k]) for k, p in t.named.items())

    # the last guard: save refuses NaN weights (however they came) and writes nothing
    with torch.no_grad():
        t.named["unet.conv_in.weight"][0, 0, 0, 0] = math.nan
    with pytest.raises(NonFiniteError, match=r"train: the weight unet\.conv_in\.weight holds NaN/inf at step 0;"):
        t.save()
    assert _saved(cfg) == []
