"""The trainer end to end on the street clip with the tiny model: exact resume, checkpoints generate loads, logs,
configuration errors, and the train command."""

import json
import os

import pytest
import torch
from safetensors.torch import load_file
from tests_support import run_backend

from backend.train import config as train_config
from backend.train import trainer


def _config(tmp_path, tiny_checkpoint, street_clip_path, out="out", **kw):
    data = {"schema": "scpainter.train/1", "checkpoint": tiny_checkpoint, "clips": [street_clip_path],
            "output_dir": str(tmp_path / out), "pairs": {"width": 128, "height": 64, "frames": 2},
            "steps": 4, "learning_rate": 1e-4, "warmup_steps": 2, "ema_decay": 0.9, "num_workers": 0,
            "log_every": 1, "save_every": 100}
    data.update(kw)
    path = tmp_path / f"{out}.json"
    path.write_text(json.dumps(data))
    return str(path)


def test_resume_equals_uninterrupted_training(tmp_path, tiny_checkpoint, street_clip_path):
    straight = train_config.load(_config(tmp_path, tiny_checkpoint, street_clip_path, "straight"))
    a = trainer.train(straight, "cpu")
    split = train_config.load(_config(tmp_path, tiny_checkpoint, street_clip_path, "split"))
    first = trainer.train(split, "cpu", max_steps=2)
    assert first["step"] == 2 and first["checkpoint"].endswith("step_0000002")
    b = trainer.train(split, "cpu")
    assert b["step"] == 4 and a["losses"][2:] == b["losses"]
    for f in ("training_state/weights.safetensors", "training_state/ema.safetensors",
              "unet/diffusion_pytorch_model.safetensors", "condition_encoder/diffusion_pytorch_model.safetensors"):
        x, y = load_file(os.path.join(a["checkpoint"], f)), load_file(os.path.join(b["checkpoint"], f))
        assert x.keys() == y.keys()
        for k in x:
            assert torch.equal(x[k], y[k]), (f, k)
    opt = torch.load(os.path.join(b["checkpoint"], "training_state", "optimizer.pt"), weights_only=True)
    assert opt["state"]  # the AdamW moments came back
    # training changed the weights, and the checkpoint holds the EMA, not the raw weights
    raw = load_file(os.path.join(a["checkpoint"], "training_state", "weights.safetensors"))
    ema = load_file(os.path.join(a["checkpoint"], "unet", "diffusion_pytorch_model.safetensors"))
    base = load_file(os.path.join(tiny_checkpoint, "unet", "diffusion_pytorch_model.safetensors"))
    k = "conv_in.weight"
    assert not torch.equal(raw[f"unet.{k}"], base[k]) and not torch.equal(ema[k], raw[f"unet.{k}"])


def test_checkpoint_generates_and_logs_hold_losses_and_a_sample_video(tmp_path, tiny_checkpoint, street_clip_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from backend.model.pipeline import SCPainterPipeline

    cfg = train_config.load(_config(tmp_path, tiny_checkpoint, street_clip_path, steps=2, sample_every=2,
                                    sample_steps=2, save_every=1, keep_checkpoints=1))
    r = trainer.train(cfg, "cpu")
    assert [os.path.basename(p) for p in trainer.checkpoints(cfg.resolve(cfg.output_dir))] == ["step_0000002"]
    with open(os.path.join(r["checkpoint"], "scpainter.json")) as f:
        assert json.load(f)["trained_steps"] == 2
    pipe = SCPainterPipeline.from_checkpoint(r["checkpoint"])
    cond = torch.zeros(2, 4, 8, 16)
    video = pipe.decode(pipe.sample(cond, torch.zeros(1, 1, 32), steps=2))
    assert video.shape == (2, 3, 64, 128) and torch.isfinite(video).all()
    acc = EventAccumulator(os.path.join(cfg.resolve(cfg.output_dir), "logs"), size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    assert [e.step for e in acc.Scalars("loss")] == [1, 2]
    (img,) = acc.Images("sample/condition|generated|target")
    assert (img.width, img.height) == (3 * 128, 64) and img.encoded_image_string[:3] == b"GIF"


@pytest.mark.parametrize("edit, field", [
    ({"stpes": 3}, "stpes"),
    ({"steps": 0}, "steps"),
    ({"drop_clip": 1.5}, "drop_clip"),
    ({"pairs": {"width": 100}}, "pairs"),
    ({"pairs": {"widht": 128}}, "pairs"),
    ({"mixed_precision": "fp8"}, "mixed_precision"),
    ({"clips": []}, "clips"),
])
def test_bad_configs_name_the_setting(tmp_path, edit, field):
    data = {"schema": "scpainter.train/1", "checkpoint": "c", "clips": ["x"], "output_dir": "o", **edit}
    with pytest.raises(train_config.TrainConfigError, match=f"train.json: {field}"):
        train_config.from_dict(data, str(tmp_path / "train.json"))


def test_8bit_optimizer_without_bitsandbytes_says_what_to_install(tmp_path):
    try:
        import bitsandbytes  # noqa: F401
        pytest.skip("bitsandbytes is installed here")
    except ImportError:
        pass
    cfg = train_config.from_dict({"schema": "scpainter.train/1", "checkpoint": "c", "clips": ["x"],
                                  "output_dir": "o", "optimizer": "adamw8bit"}, str(tmp_path / "t.json"))
    with pytest.raises(train_config.TrainConfigError, match="bitsandbytes"):
        trainer.make_optimizer(cfg, [torch.nn.Parameter(torch.zeros(2))])


def test_train_command(tmp_path, tiny_checkpoint, street_clip_path):
    cfg = _config(tmp_path, tiny_checkpoint, street_clip_path, steps=3)
    from scpainter_blender.core import locking

    out = str(tmp_path / "out")
    os.makedirs(out)
    with locking.OutputLock(out, "train"):   # another live run writes this run folder: refused, nothing written
        code, events, err = run_backend("train", cfg, "--device", "cpu", "--max-steps", "1")
        assert code == 1 and events[-1]["event"] == "error", err
        assert f"being written by another run: pid {os.getpid()}" in events[-1]["message"]
        assert events[-1]["owner"]["command"] == "train" and os.listdir(out) == [locking.LOCK_NAME]
    code, events, err = run_backend("train", cfg, "--device", "cpu", "--max-steps", "1")
    assert code == 0, err
    assert not os.path.exists(os.path.join(out, locking.LOCK_NAME))
    done = events[-1]
    assert done["event"] == "done" and done["step"] == 1 and os.path.isdir(done["checkpoint"])
    assert [e["done"] for e in events if e["event"] == "progress"] == [1]
    code, events, _ = run_backend("train", str(tmp_path / "missing.json"))
    assert code == 2 and "missing.json: (file): not found" in events[-1]["message"]


def test_two_processes_train_like_one_with_twice_the_batch(tmp_path, tiny_checkpoint, street_clip_path):
    """DDP through accelerate, on the CPU (gloo): torchrun with 2 processes × batch 1 gives the weights of one
    process × batch 2 (same samples, same noise; gradients averaged over the ranks). A larger Adam ε keeps Adam's
    normalisation from blowing up float summation noise in near-zero gradients (with ε = 1e-8 the updates of such
    parameters are ±lr whatever their tiny gradient's rounding)."""
    import subprocess
    import sys

    common = {"steps": 2, "warmup_steps": 0, "ema_decay": 0.0, "adam_eps": 1e-4}
    one = _config(tmp_path, tiny_checkpoint, street_clip_path, "one", batch_size=2, **common)
    two = _config(tmp_path, tiny_checkpoint, street_clip_path, "two", batch_size=1, **common)
    a = trainer.train(train_config.load(one), "cpu")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    p = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "-m", "backend",
                        "train", two, "--device", "cpu"], cwd=root, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    done = [e for e in map(json.loads, p.stdout.splitlines()) if e["event"] == "done"]
    assert len(done) == 1 and done[0]["step"] == 2  # one done event, from rank 0
    x = load_file(os.path.join(a["checkpoint"], "training_state", "weights.safetensors"))
    y = load_file(os.path.join(done[0]["checkpoint"], "training_state", "weights.safetensors"))
    base = load_file(os.path.join(tiny_checkpoint, "unet", "diffusion_pytorch_model.safetensors"))
    base = {f"unet.{k}": v for k, v in base.items()}
    keys = [k for k in x if k in base]
    dx = torch.cat([(x[k] - base[k]).flatten() for k in keys])
    dy = torch.cat([(y[k] - base[k]).flatten() for k in keys])
    rel = float((dx - dy).norm() / dx.norm())
    assert float(dx.norm()) > 0 and rel < 1e-4, rel


def test_missing_clip_is_refused_before_the_models_load(tmp_path, tiny_checkpoint, street_clip_path):
    cfg = train_config.load(_config(tmp_path, tiny_checkpoint, street_clip_path,
                                    clips=[street_clip_path, str(tmp_path / "no_clip")]))
    with pytest.raises(train_config.TrainConfigError, match="clips: 1 clip folders have no clip.json"):
        trainer.Trainer(cfg, "cpu")


def test_a_bad_clip_met_in_a_worker_stops_training_with_its_name(tmp_path, tiny_checkpoint, street_clip_path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(os.path.dirname(street_clip_path), bad)
    # the clip loads (every frame is a regular file), sampling fails in the worker: the frame is not an image
    (bad / "frames" / "frame_000005.png").write_bytes(b"not a PNG")
    cfg = train_config.load(_config(tmp_path, tiny_checkpoint, str(bad), num_workers=1, pairs={
        "width": 128, "height": 64, "frames": 16}))
    with pytest.raises(ValueError, match="training sample 0: .*frame_000005.png"):
        trainer.train(cfg, "cpu")
