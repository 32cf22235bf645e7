"""Training throughput: the trainer's step (objective.loss, backward, AdamW, EMA) on SVD's full-size architecture.

    python bench/train_throughput.py [--size full|tiny] [--device cuda|cpu] [--frames 14]
                                     [--resolutions 576x320 1024x576] [--batches 1 2 4 8 16] [--steps 5]

For each resolution, with and without gradient checkpointing, the batch size doubles until it no longer fits
(CUDA out of memory) or the list ends; each fitting batch runs 2 warm-up and ``--steps`` timed steps with random
frames and conditions (the pair renderer runs in DataLoader workers beside the GPU and is not timed here).
Precision as the trainer uses it on CUDA: float32 master weights, bf16 autocast; frozen VAE and CLIP in bf16.
Reports samples/s, seconds per step and peak GPU memory, and what the paper's 30k iterations at batch 8 would cost
on 4 GPUs at the best measured rate (assuming linear DDP scaling). Writes bench/results/train_<size>_<device>.json.
The issue's figures are ``--size full --device cuda`` on the H100; ``--size tiny --device cpu`` checks the script.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import torch  # noqa: E402

from backend import events  # noqa: E402
from backend.model import configs, edm  # noqa: E402
from backend.model.checkpoint import CLIP_MEAN, CLIP_STD  # noqa: E402
from backend.model.checkpoint_config import ScpainterConfig  # noqa: E402
from backend.model.condition import ConditionEncoder  # noqa: E402
from backend.train import objective  # noqa: E402
from backend.train.config import TrainConfig  # noqa: E402
from backend.train.ema import EMA  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402


def build(size: str, device: str):
    c = configs.build_components(size, seed=0)
    cond = ConditionEncoder.from_vae(c["vae"])
    frozen_dtype = torch.bfloat16 if device == "cuda" else torch.float32
    c["vae"].to(device, frozen_dtype).eval().requires_grad_(False)
    c["image_encoder"].to(device, frozen_dtype).eval().requires_grad_(False)
    c["unet"].to(device).train()
    cond.to(device).train()
    schedule = edm.Schedule.from_config(dict(c["scheduler"].config))   # SVD's scheduler config
    return {"unet": c["unet"], "denoiser": edm.Denoiser(c["unet"], schedule), "condition_encoder": cond,
            "vae": c["vae"], "image_encoder": c["image_encoder"],
            "clip_mean": torch.tensor(CLIP_MEAN).view(1, 3, 1, 1),
            "clip_std": torch.tensor(CLIP_STD).view(1, 3, 1, 1),
            "config": ScpainterConfig()}


def run(models, device, batch, frames, W, H, steps, checkpointing):
    unet, cond = models["unet"], models["condition_encoder"]
    for m in (unet, cond):
        (m.enable_gradient_checkpointing if checkpointing else m.disable_gradient_checkpointing)()
    named = {f"u.{k}": p for k, p in unet.named_parameters()}
    named.update({f"c.{k}": p for k, p in cond.named_parameters()})
    opt = torch.optim.AdamW(list(named.values()), lr=1e-5, fused=device == "cuda")
    ema = EMA(named, 0.9999)
    cfg = TrainConfig(checkpoint="", clips=["x"], output_dir="")
    g = torch.Generator().manual_seed(0)
    data = {"target": torch.rand(batch, frames, 3, H, W, generator=g),
            "image": torch.rand(batch, frames, 3, H, W, generator=g),
            "asset_mask": torch.zeros(batch, frames, 1, H, W), "valid": torch.ones(batch, frames, 1, H, W)}
    data = {k: v.to(device) for k, v in data.items()}
    autocast = torch.bfloat16 if device == "cuda" else None
    times = []
    if device == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    for i in range(2 + steps):
        t = time.perf_counter()
        loss, _ = objective.loss(models, data, cfg, objective.generators(i, range(batch)), device, autocast)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(list(named.values()), 1.0)
        opt.step()
        opt.zero_grad(set_to_none=True)
        ema.update(named)
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t)
    peak = torch.cuda.max_memory_allocated() / 2 ** 30 if device == "cuda" else None
    del opt, ema
    step_s = sorted(times[2:])[len(times[2:]) // 2]
    return {"batch": batch, "step_s": step_s, "samples_per_s": batch / step_s, "peak_gib": peak,
            "loss_finite": bool(torch.isfinite(loss).item())}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", choices=["full", "tiny"], default="full")
    p.add_argument("--device", choices=["cuda", "cpu"], default="cuda")
    p.add_argument("--frames", type=int, default=14)
    p.add_argument("--resolutions", nargs="+", default=["576x320", "1024x576"])
    p.add_argument("--batches", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--checkpointing", choices=["both", "on", "off"], default="both")
    a = p.parse_args(argv)
    models = build(a.size, a.device)
    n_params = sum(q.numel() for m in ("unet", "condition_encoder") for q in models[m].parameters())
    rows = []
    modes = {"both": [False, True], "on": [True], "off": [False]}[a.checkpointing]
    for res in a.resolutions:
        W, H = map(int, res.split("x"))
        for ckpt in modes:
            for b in a.batches:
                try:
                    r = run(models, a.device, b, a.frames, W, H, a.steps, ckpt)
                except torch.cuda.OutOfMemoryError:
                    rows.append({"resolution": res, "checkpointing": ckpt, "batch": b, "oom": True})
                    print(f"{res:>9} ckpt={ckpt!s:5} batch {b:>3}: out of memory", flush=True)
                    for m in ("unet", "condition_encoder"):
                        for q in models[m].parameters():
                            q.grad = None
                    torch.cuda.empty_cache()
                    break
                rows.append({"resolution": res, "checkpointing": ckpt, **r})
                print(f"{res:>9} ckpt={ckpt!s:5} batch {b:>3}: {r['step_s']:.3f} s/step, "
                      f"{r['samples_per_s']:.2f} samples/s, peak {r['peak_gib'] or 0:.1f} GiB", flush=True)
    print(f"\n{'resolution':>10} {'ckpt':>5} {'batch':>5} {'s/step':>8} {'samples/s':>10} {'peak GiB':>9}")
    for r in rows:
        if r.get("oom"):
            print(f"{r['resolution']:>10} {str(r['checkpointing']):>5} {r['batch']:>5} {'OOM':>8}")
        else:
            print(f"{r['resolution']:>10} {str(r['checkpointing']):>5} {r['batch']:>5} {r['step_s']:>8.3f} "
                  f"{r['samples_per_s']:>10.2f} {r['peak_gib'] or 0:>9.1f}")
    cost = {}
    for res in a.resolutions:
        ok = [r for r in rows if r["resolution"] == res and not r.get("oom")]
        if ok:
            best = max(ok, key=lambda r: r["samples_per_s"])
            hours = 30000 * 8 / (4 * best["samples_per_s"]) / 3600
            cost[res] = {"best": best, "hours_on_4_gpus": hours, "gpu_hours": 4 * hours}
            print(f"paper schedule (30k x batch 8) at {res}: {hours:.1f} h on 4 GPUs ({4 * hours:.0f} GPU-hours) at "
                  f"{best['samples_per_s']:.2f} samples/s per GPU (batch {best['batch']}, "
                  f"checkpointing {best['checkpointing']})")
    env = {"device": torch.cuda.get_device_name(0) if a.device == "cuda" else "cpu", "torch": torch.__version__,
           "frames": a.frames, "trained_parameters": n_params, "size": a.size}
    os.makedirs(os.path.join(ROOT, "bench", "results"), exist_ok=True)
    out = os.path.join(ROOT, "bench", "results", f"train_{a.size}_{a.device}.json")
    outputs.write_json(out, events.json_safe({"env": env, "rows": rows, "paper_schedule": cost}))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
