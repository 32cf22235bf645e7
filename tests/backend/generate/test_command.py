"""``python -m backend generate`` and ``init-checkpoint`` end to end with a tiny checkpoint on the street."""

import copy
import json
import os
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from backend.generate.video import read_mp4
from scpainter_blender.core import job as J
from tests_support import run_backend_here, street_with_car

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


backend = run_backend_here


@pytest.fixture(scope="module")
def street_job(street, tmp_path_factory, addon, tiny_checkpoint):
    """The street with a car beside the road, seen from a path 2 m to the left at half resolution; 3 steps. Its
    predictions and checkpoint lie outside its folder: it runs with --allow-outside."""
    import bpy  # here, not at the top: the tests below that need no Blender run without bpy too

    d = tmp_path_factory.mktemp("generate")
    street_with_car(street, d, count=5000)
    bpy.context.scene.render.resolution_percentage = 50  # 259 x 147: the tiny model's CPU time stays small
    path = d / "job.json"
    bpy.ops.scpainter.export_job(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    job = J.load(path).to_dict()
    job["generate"] = {"checkpoint": tiny_checkpoint, "steps": 3, "window": 14, "overlap": 4, "seed": 11}
    J.save(path, job)
    return str(path)


def frames_of(out):
    d = os.path.join(out, "generated")
    return {f: np.asarray(Image.open(os.path.join(d, f))) for f in sorted(os.listdir(d)) if f.endswith(".png")}


def test_generate_end_to_end(street_job):
    code, ev, err = backend("generate", street_job, "--device", "cpu", "--allow-outside")
    assert code == 0, err[-3000:]
    done = ev[-1]
    assert done["event"] == "done" and done["frames"] == 16 and done["precision"] == "fp32"
    stages = [e["stage"] for e in ev if e["event"] == "progress"]
    assert stages.count("render") == 16 and stages.count("generate") == 3   # conditions were rendered first
    frames = frames_of(os.path.dirname(done["video"]))
    assert len(frames) == 16 and all(f.shape == (147, 259, 3) for f in frames.values())
    video = read_mp4(done["video"])
    assert video.shape[0] == 16 and video.shape[1:3] == (148, 260)  # H.264 4:2:0 needs even sizes
    assert not os.path.exists(os.path.join(os.path.dirname(done["video"]), "generate_state.safetensors"))
    # the same job again: up to date, nothing recomputed
    code, ev, _ = backend("generate", street_job, "--device", "cpu", "--allow-outside")
    assert code == 0 and ev[-1]["skipped"] is True


def test_sigterm_then_resume_gives_the_uninterrupted_frames(street_job, tmp_path):
    job = J.load(street_job).to_dict()
    reference = frames_of(J.resolve(street_job, job["output_dir"]))
    assert reference, "test_generate_end_to_end runs first and leaves its frames"
    job["output_dir"] = job["output_dir"].rstrip("/") + "_resumed"
    path = os.path.join(os.path.dirname(street_job), "job_resumed.json")
    J.save(path, job)
    proc = subprocess.Popen([sys.executable, "-m", "backend", "generate", path, "--device", "cpu", "--allow-outside"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    for line in proc.stdout:
        seen.append(json.loads(line))
        if seen[-1]["event"] == "progress" and seen[-1]["stage"] == "generate" and seen[-1]["done"] == 1:
            proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=600)
    assert proc.returncode == 1 and seen[-1]["event"] == "error" and "resume" in seen[-1]["hint"]
    out = J.resolve(path, job["output_dir"])
    assert os.path.isfile(os.path.join(out, "generate_state.safetensors"))
    assert not os.path.exists(os.path.join(out, "generated.mp4"))
    code, ev, err = backend("generate", path, "--device", "cpu", "--allow-outside")
    assert code == 0, err[-3000:]
    stopped_after = [e["done"] for e in seen if e["event"] == "progress" and e.get("stage") == "generate"][-1]
    assert stopped_after < 3        # the steps done before the stop are not done again:
    resumed_steps = [e["done"] for e in ev if e["event"] == "progress" and e["stage"] == "generate"]
    assert resumed_steps == list(range(stopped_after + 1, 4))
    resumed = frames_of(out)
    assert resumed.keys() == reference.keys()
    assert all(np.array_equal(resumed[k], reference[k]) for k in reference)


def test_asking_for_the_model_without_a_checkpoint_fails_fast(street_job, tiny_svd, tmp_path):
    job = J.load(street_job).to_dict()
    del job["generate"]["checkpoint"]
    path = tmp_path / "job.json"
    shutil.copy(J.resolve(street_job, job["scene"]["predictions"]), tmp_path / "predictions.npz")
    job["scene"]["predictions"] = "predictions.npz"
    job.pop("assets")
    J.save(path, job)
    code, ev, _ = backend("generate", path, "--device", "cpu", "--model", "scpainter")  # without: the baseline
    assert code == 2 and "init-checkpoint" in ev[-1]["message"]
    assert not (tmp_path / "out").exists()                           # nothing rendered before failing
    code, ev, _ = backend("generate", path, "--device", "cpu", "--checkpoint", tiny_svd)
    assert code == 2 and "stock SVD snapshot" in ev[-1]["message"]


def test_init_checkpoint_command(tiny_svd, tmp_path):
    out = tmp_path / "ckpt"
    code, ev, err = backend("init-checkpoint", "--svd", tiny_svd, "--out", out)
    assert code == 0, err
    assert ev[-1]["checkpoint"] == str(out)
    cfg = json.loads((out / "scpainter.json").read_text())
    assert cfg["schema"] == "scpainter.checkpoint/1" and cfg["base"] == tiny_svd and cfg["trained_steps"] == 0
    assert (out / "condition_encoder" / "diffusion_pytorch_model.safetensors").is_file()
    code, ev, _ = backend("init-checkpoint", "--svd", tiny_svd, "--out", out)
    assert code == 2 and "already exists" in ev[-1]["message"]
    bad = tmp_path / "svd-bin"
    shutil.copytree(tiny_svd, bad)
    os.remove(bad / "unet" / "diffusion_pytorch_model.safetensors")
    (bad / "unet" / "diffusion_pytorch_model.bin").write_bytes(b"pickle")
    code, ev, _ = backend("init-checkpoint", "--svd", bad, "--out", tmp_path / "never")
    assert code == 2 and "unet" in ev[-1]["message"] and ".bin" in ev[-1]["message"]
    assert not (tmp_path / "never").exists()


def _nan_checkpoint(tiny_checkpoint, folder):
    """A copy of the tiny checkpoint whose UNet outputs NaN (its last convolution's bias is NaN)."""
    from safetensors.torch import load_file, save_file

    out = os.path.join(str(folder), "nan-ckpt")
    shutil.copytree(tiny_checkpoint, out)
    weights = os.path.join(out, "unet", "diffusion_pytorch_model.safetensors")
    state = load_file(weights)
    state["conv_out.bias"] = state["conv_out.bias"] * float("nan")
    save_file(state, weights)
    return out


def test_a_model_that_outputs_nan_is_an_error_not_a_video(tiny_checkpoint, tmp_path):
    """Issue 14: exit 1 naming the step and σ, suggesting a precision; no frames, no MP4, no manifest, and no
    resume state holding NaN (so the next run cannot 'finish' a black clip)."""
    from tests_support import small_job

    job_path = small_job(tmp_path / "job", frames=(1, 2, 3), resolution=(64, 64),
                         generate={"checkpoint": _nan_checkpoint(tiny_checkpoint, tmp_path), "steps": 2,
                                   "window": 3, "overlap": 1})
    code, ev, err = backend("generate", job_path, "--device", "cpu", "--allow-outside")
    assert code == 1, err[-3000:]
    error = ev[-1]
    assert error["event"] == "error" and error["step"] == 1 and error["stage"] == "generate", error
    assert error["sigma"] == pytest.approx(700.0, rel=1e-3)
    assert "fp32" in error["hint"] and "checkpoint" in error["hint"]     # in fp32 rounding is not the cause
    assert "Traceback" not in err
    out = tmp_path / "job" / "out"
    assert (out / "conditions" / "frame_000003.exr").is_file()          # the conditions are fine and kept
    assert not (out / "generated.mp4").exists() and not (out / "generated").exists()
    assert not (out / "generate_state.safetensors").exists()


def test_generate_checks_everything_before_any_work(tiny_checkpoint, tmp_path):
    """Issue 14: fps 1e300, a missing source frame, a bad override or a window the checkpoint cannot hold fail
    at once, naming file and field; nothing is rendered or loaded (no output folder)."""
    from tests_support import small_job

    job_path = small_job(tmp_path / "job", generate={"checkpoint": "ckpt"})
    shutil.copytree(tiny_checkpoint, tmp_path / "job" / "ckpt", copy_function=os.link)
    code, ev, err = backend("generate", job_path, "--check")
    assert code == 0 and ev[-1]["check"] and ev[-1]["settings"]["window"] == 14, err[-2000:]
    base = J.load(job_path).to_dict()
    for change, field in [({"fps": 1e300}, "generate.fps"), ({"overlap": 14}, "generate.overlap"),
                          ({"window": 4, "overlap": 4}, "generate.overlap")]:
        job = copy.deepcopy(base)
        job["generate"] = {"checkpoint": "ckpt", **change}
        with open(job_path, "w") as f:  # as someone else's tool writes it, unvalidated
            json.dump(job, f)
        code, ev, _ = backend("generate", job_path)
        assert code == 2 and ev[-1]["field"] == field and ev[-1]["file"] == job_path, ev[-1]
    job["generate"] = {"checkpoint": "ckpt"}
    job["frames"][1]["source_frames"] = [1, 2]
    J.save(job_path, job)
    code, ev, _ = backend("generate", job_path)
    assert code == 2 and ev[-1]["field"] == "frames[1].source_frames" and "has 2 frames" in ev[-1]["message"]
    code, ev, _ = backend("generate", job_path, "--steps", "0")
    assert code == 2 and ev[-1]["field"] == "--steps"
    # the speed settings (issue 44): checked the same way, and the command line reaches the run's settings
    code, ev, _ = backend("generate", job_path, "--feature-reuse", "0")
    assert code == 2 and ev[-1]["field"] == "--feature-reuse"
    code, ev, _ = backend("generate", job_path, "--guidance-sigma-min", "50", "--guidance-sigma-max", "5")
    assert code == 2 and ev[-1]["field"] == "--guidance-sigma-min"
    job["frames"][1]["source_frames"] = [1]
    J.save(job_path, job)
    code, ev, err = backend("generate", job_path, "--check", "--sampler", "dpmpp2m", "--feature-reuse", "3",
                            "--compile", "reduce-overhead", "--gpu-tuning", "off")
    assert code == 0, err[-2000:]
    got = ev[-1]["settings"]
    assert (got["sampler"], got["feature_reuse"], got["compile"], got["gpu_tuning"]) == \
        ("dpmpp2m", 3, "reduce-overhead", "off") and got["guidance_sigma_max"] == J.GENERATE_DEFAULTS[
            "guidance_sigma_max"]
    assert not (tmp_path / "job" / "out").exists()


def test_a_resume_state_holding_nan_is_never_used(tmp_path):
    """The sampler never saves non-finite latents; a state file that holds them anyway (damaged, or planted) is
    ignored, so it can neither be resumed from nor decoded into a black video."""
    import torch

    from backend.generate import command as G

    path = str(tmp_path / "generate_state.safetensors")
    G.save_state(path, torch.ones(2, 4, 3, 3), 5, "key")
    latents, step = G.load_state(path, "key")
    assert step == 5 and torch.equal(latents, torch.ones(2, 4, 3, 3))
    G.save_state(path, torch.full((2, 4, 3, 3), float("nan")), 5, "key")
    assert G.load_state(path, "key") == (None, 0)


def test_checkpoint_window_reaches_a_blender_exported_job(street, addon, tiny_checkpoint, tmp_path):
    """The export writes no generation settings, so a checkpoint trained with window 8 samples in windows of 8
    (the export used to write 14 whatever the checkpoint said)."""
    import bpy

    ckpt = tmp_path / "ckpt-window8"
    shutil.copytree(tiny_checkpoint, ckpt, copy_function=os.link)
    config = json.loads((ckpt / "scpainter.json").read_text())
    os.remove(ckpt / "scpainter.json")                       # a link: never edit the shared fixture through it
    (ckpt / "scpainter.json").write_text(json.dumps({**config, "window": 8, "fps": 5}))
    scene = street_with_car(street, tmp_path, count=2000)
    scene.frame_start, scene.frame_end = 1, 10               # two windows of 8: [0, 8) and [2, 10), end-aligned
    scene.render.resolution_percentage = 25
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.checkpoint_dir = str(ckpt)
    try:
        path = tmp_path / "job.json"
        assert bpy.ops.scpainter.export_job(filepath=str(path)) == {"FINISHED"}
    finally:
        prefs.checkpoint_dir = ""
        bpy.ops.wm.read_homefile(use_empty=True)
    exported = json.loads(path.read_text())
    assert exported["generate"] == {"checkpoint": str(ckpt)}  # no window, guidance or fps of its own
    code, ev, err = backend("generate", str(path), "--device", "cpu", "--allow-outside", "--steps", "1")
    assert code == 0, err[-3000:]
    done = ev[-1]
    assert done["window"] == 8 and done["fps"] == 5.0 and done["overlap"] == 4 and done["frames"] == 10
    manifest = json.loads((tmp_path / "generated" / "manifest.json").read_text())
    assert manifest["settings"]["window"] == 8
    log = (tmp_path / "backend.log").read_text()
    assert "window 8 overlap 4" in log


def test_precision_auto_is_resolved_for_the_device_that_makes_the_video():
    from backend.generate.command import resolve_precision

    assert [resolve_precision("auto", d) for d in ("cuda", "cpu")] == ["bf16", "fp32"]
    assert [resolve_precision(p, "cuda") for p in ("fp32", "fp16", "bf16")] == ["fp32", "fp16", "bf16"]


def test_the_compile_options_help_says_where_it_runs_and_where_kernels_go():
    """``--compile``'s help said "torch.compile the UNet on CUDA": it compiles on the CPU too (minutes for the tiny
    test model: 368 s for a 4-step, 4-frame 64 x 64 job on this 2-core machine, against 4 s off), and it named no
    cache folder."""
    import argparse

    from backend.__main__ import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    (action,) = [a for a in sub.choices["generate"]._actions if "--compile" in a.option_strings]
    assert "on CUDA" not in action.help and "CPU" in action.help
    assert "~/.cache/scpainter/inductor" in action.help and "TORCHINDUCTOR_CACHE_DIR" in action.help
