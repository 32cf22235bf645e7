"""Training throughput and memory: the trainer's step (objective.loss, backward, AdamW, EMA) on SVD's architecture,
the step as it was before issue 44 beside the step as it is (backend/train/memory.py ``Setting``).

    python bench/train_throughput.py [--size full|tiny] [--device cuda|cpu] [--frames 14]
                                     [--resolutions 576x320 1024x576] [--batches 1 2 4 8 16] [--steps 5]
                                     [--checkpointing both|on|off] [--settings before after] [--out DIR]
    python bench/train_throughput.py --estimate [--size full] [--batches 1 2]   # memory breakdown, CPU, no GPU
    python bench/train_throughput.py --smoke --out DIR                          # the suite's check (tiny, CPU)

Timed rows: for each resolution, setting and checkpointing, the batch size doubles until it no longer fits (CUDA
out of memory) or the list ends; each fitting batch runs 2 warm-up and ``--steps`` timed steps with random frames
and conditions (the pair renderer runs in DataLoader workers beside the GPU and is not timed here). Precision as
the trainer uses it on CUDA: float32 master weights, bf16 autocast; frozen VAE and CLIP in bf16 (the trainer keeps
them float32: +1.4 GiB at full size). Peak memory: ``torch.cuda.max_memory_allocated`` on CUDA; on the CPU the
tensors of one more step counted by ``memory.AllocationTracker`` (float32: no autocast on the CPU). Reports samples/s, seconds per step, and what the
paper's 30k iterations at batch 8 would cost on 4 GPUs at the best measured rate (linear DDP scaling assumed).

``--estimate``: no timing; the memory of one step at full size on fake tensors for each setting and batch (tens of
seconds each on the CPU; ``memory.estimate``: CUDA's autocast dtypes, no cuDNN workspaces — the H200 measured the
"before" step at 84.7 GiB against an estimate of 80.4), as a table of what is live at the peak (GiB per component) and what the forward pass
keeps for backward. Writes DIR/train_<size>_<device>.json (``--estimate``: train_estimate_<size>.json); DIR
defaults to bench/results.
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
from backend.train import memory  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402

GIB = memory.GIB


def settings(names: list, batch: int, checkpointing: bool) -> list:
    """The ``memory.Setting`` of each name ("before", "after") at ``batch``, checkpointing on or off."""
    out = []
    for n in names:
        if n == "before":
            out.append(memory.Setting.before(batch, checkpointing))
        else:
            out.append(memory.Setting(batch, "blocks" if checkpointing else None))
    return out


def timed(models, device, setting, frames, W, H, steps) -> dict:
    """Time ``2 + steps`` optimiser steps of ``setting``: step_s (median of the timed), samples_per_s, peak_gib,
    peak_source, loss_finite. Peak: CUDA's max_memory_allocated; on the CPU one more step under
    ``memory.AllocationTracker`` (every tensor the step holds, counted; the CPU has no allocator statistics)."""
    prepared = memory.prepare(models, setting, device)
    step_models, named, opt, ema, cfg = prepared
    autocast = torch.bfloat16 if device == "cuda" else None
    data = memory.random_batch(setting.batch, frames, H, W, device)
    times = []
    if device == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    for i in range(2 + steps):
        t = time.perf_counter()
        gens = [torch.Generator().manual_seed(1000 * i + b) for b in range(setting.batch)]
        loss = memory.step(step_models, named, opt, ema, data, cfg, gens, device, autocast)
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t)
    del data
    if device == "cuda":
        peak, source = torch.cuda.max_memory_allocated() / GIB, "cuda max_memory_allocated"
    else:
        peak = memory.tracked(models, prepared, setting, frames, W, H, device, autocast).peak / GIB
        source = "tracked allocations"
    step_s = sorted(times[2:])[len(times[2:]) // 2]
    return {"batch": setting.batch, "step_s": step_s, "samples_per_s": setting.batch / step_s, "peak_gib": peak,
            "peak_source": source, "loss_finite": bool(torch.isfinite(loss).item())}


def print_breakdown(estimates: list) -> None:
    """What is live at each estimate's peak (GiB per ``memory.LABELS``), then what the forward pass kept; a column
    is "<setting> b<batch>", "off" without checkpointing."""
    names = [f"{e['setting']['name']} b{e['setting']['batch']}{'' if e['setting']['checkpointing'] else ' off'}"
             for e in estimates]
    for title, key in (("live at the peak (GiB)", "at_peak_gib"), ("kept by the forward pass for backward (GiB)",
                                                                     "kept_gib")):
        print(f"\n{title:<44}" + "".join(f"{n:>14}" for n in names))
        for label in memory.LABELS:
            vals = [e[key].get(label, 0.0) for e in estimates]
            if any(vals):
                print(f"{label:<44}" + "".join(f"{v:>14.2f}" for v in vals))
        if key == "at_peak_gib":
            print(f"{'peak':<44}" + "".join(f"{e['peak_gib']:>14.2f}" for e in estimates))


def run_estimates(size, frames, W, H, batches, names, checkpointing) -> list:
    models = memory.build(size, "cpu", torch.bfloat16, fake=True)
    rows = []
    for b in batches:
        for ck in checkpointing:
            for s in settings(names, b, ck):
                e = memory.estimate(s, size, frames, (W, H), models=models).gib()
                e.update({"resolution": f"{W}x{H}", "frames": frames, "size": size})
                rows.append(e)
                print(f"estimate {s.name:>6} batch {b} checkpointing {ck!s:5}: peak {e['peak_gib']:.2f} GiB "
                      f"({e['seconds']:.0f} s)", flush=True)
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", choices=["full", "tiny"], default="full")
    p.add_argument("--device", choices=["cuda", "cpu"], default="cuda")
    p.add_argument("--frames", type=int, default=14)
    p.add_argument("--resolutions", nargs="+", default=["576x320", "1024x576"])
    p.add_argument("--batches", type=int, nargs="+", default=None, help="default 1 2 4 8 16 (--estimate: 1 2)")
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--checkpointing", choices=["both", "on", "off"], default="both")
    p.add_argument("--settings", nargs="+", choices=["before", "after"], default=["before", "after"])
    p.add_argument("--estimate", action="store_true", help="only the fake-tensor memory breakdown (CPU)")
    p.add_argument("--smoke", action="store_true", help="tiny model on the CPU, seconds (the suite's check)")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    a = p.parse_args(argv)
    if a.smoke:
        a.size, a.device, a.frames, a.resolutions, a.steps, a.checkpointing = "tiny", "cpu", 2, ["128x64"], 1, "on"
        a.batches = a.batches or [1]
    modes = {"both": [False, True], "on": [True], "off": [False]}[a.checkpointing]
    os.makedirs(a.out, exist_ok=True)
    if a.estimate:
        W, H = map(int, a.resolutions[-1].split("x"))
        rows = run_estimates(a.size, a.frames, W, H, a.batches or [1, 2], a.settings, modes)
        print_breakdown(rows)
        out = os.path.join(a.out, f"train_estimate_{a.size}.json")
        outputs.write_json(out, events.json_safe({"env": {"torch": torch.__version__, "size": a.size},
                                                  "estimates": rows}))
        print(f"wrote {out}")
        return rows
    a.batches = a.batches or [1, 2, 4, 8, 16]
    models = memory.build(a.size, a.device, torch.bfloat16 if a.device == "cuda" else torch.float32)
    n_params = sum(q.numel() for m in ("unet", "condition_encoder") for q in models[m].parameters())
    rows = []
    for res in a.resolutions:
        W, H = map(int, res.split("x"))
        for ckpt in modes:
            for name in a.settings:
                for b in a.batches:
                    (s,) = settings([name], b, ckpt)
                    head = {"setting": name, "resolution": res, "checkpointing": ckpt, "batch": b}
                    try:
                        r = timed(models, a.device, s, a.frames, W, H, a.steps)
                    except torch.cuda.OutOfMemoryError:
                        rows.append({**head, "oom": True})
                        print(f"{name:>6} {res:>9} ckpt={ckpt!s:5} batch {b:>3}: out of memory", flush=True)
                        for m in ("unet", "condition_encoder"):
                            for q in models[m].parameters():
                                q.grad = None
                        torch.cuda.empty_cache()
                        break
                    rows.append({**head, **r})
                    print(f"{name:>6} {res:>9} ckpt={ckpt!s:5} batch {b:>3}: {r['step_s']:.3f} s/step, "
                          f"{r['samples_per_s']:.2f} samples/s, peak {r['peak_gib']:.2f} GiB", flush=True)
    print(f"\n{'setting':>8} {'resolution':>10} {'ckpt':>5} {'batch':>5} {'s/step':>8} {'samples/s':>10} "
          f"{'peak GiB':>9}")
    for r in rows:
        lead = f"{r['setting']:>8} {r['resolution']:>10} {str(r['checkpointing']):>5} {r['batch']:>5}"
        if r.get("oom"):
            print(f"{lead} {'OOM':>8}")
        else:
            print(f"{lead} {r['step_s']:>8.3f} {r['samples_per_s']:>10.2f} {r['peak_gib']:>9.2f}")
    print("peak: " + ("CUDA's max_memory_allocated" if a.device == "cuda" else
                      "every tensor of one more step, tracked (backend/train/memory.py); at full size on the CPU use "
                      "--estimate"))
    cost = {}
    for res in a.resolutions:
        ok = [r for r in rows if r["resolution"] == res and not r.get("oom") and r["setting"] == a.settings[-1]]
        if ok:
            best = max(ok, key=lambda r: r["samples_per_s"])
            hours = 30000 * 8 / (4 * best["samples_per_s"]) / 3600
            cost[res] = {"best": best, "hours_on_4_gpus": hours, "gpu_hours": 4 * hours}
            print(f"paper schedule (30k x batch 8) at {res}: {hours:.1f} h on 4 GPUs ({4 * hours:.0f} GPU-hours) at "
                  f"{best['samples_per_s']:.2f} samples/s per GPU ({best['setting']}, batch {best['batch']}, "
                  f"checkpointing {best['checkpointing']})")
    env = {"device": torch.cuda.get_device_name(0) if a.device == "cuda" else "cpu", "torch": torch.__version__,
           "frames": a.frames, "trained_parameters": n_params, "size": a.size}
    out = os.path.join(a.out, f"train_{a.size}_{a.device}.json")
    result = {"env": env, "rows": rows, "paper_schedule": cost}
    outputs.write_json(out, events.json_safe(result))
    print(f"wrote {out}")
    return result


if __name__ == "__main__":
    main()
