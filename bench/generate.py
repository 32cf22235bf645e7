"""Generation speed and memory: our pipeline against diffusers' StableVideoDiffusionPipeline, same weights and noise.

    python bench/generate.py [--size full|tiny] [--device cuda|cpu] [--frames 14 25] [--height 576 --width 1024]
                             [--precision fp16|bf16] [--compile] [--steps-sweep 8 12 16 25]

Both pipelines get the same random-weight components (``backend.model.configs``; ``full`` is SVD's real
architecture), the same image, the same initial noise, steps, guidance (1 → 3) and decode chunk (8). Our pipeline
is conditioned on that image's latent repeated over the frames (a fresh checkpoint's condition encoder is SVD's
VAE encoder), so the two compute the same video and the difference measures our arithmetic, not a different task.
Reported: seconds per video, frames/s, peak GPU memory, one guidance-batched UNet step, the mean abs difference
of the frames in [0, 1]; then sampler steps against time and against the 25-step result (error vs run time).
Writes bench/results/generate_<size>_<device>.json. The figures in the issue are for ``--size full --device cuda``
on the H100; ``--size tiny --device cpu`` only checks that the benchmark runs.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402
import torch  # noqa: E402

from backend import events  # noqa: E402
from backend.model import configs, edm  # noqa: E402
from backend.model.checkpoint_config import ScpainterConfig  # noqa: E402
from backend.model.condition import ConditionEncoder  # noqa: E402
from backend.model.pipeline import SCPainterPipeline  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402

DTYPES = {"fp16": torch.float16, "bf16": torch.bfloat16, "fp32": torch.float32}


def sync(device):
    if device == "cuda":
        torch.cuda.synchronize()


def timed(fn, device):
    sync(device)
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    t = time.perf_counter()
    out = fn()
    sync(device)
    peak = torch.cuda.max_memory_allocated() / 2 ** 30 if device == "cuda" else None
    return out, time.perf_counter() - t, peak


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", choices=["full", "tiny"], default="full")
    p.add_argument("--device", choices=["cuda", "cpu"], default="cuda")
    p.add_argument("--frames", type=int, nargs="+", default=[14, 25])
    p.add_argument("--height", type=int, default=576)
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--steps", type=int, default=25)
    p.add_argument("--precision", choices=list(DTYPES), default="fp16")
    p.add_argument("--compile", action="store_true", help="torch.compile our UNet (default mode)")
    p.add_argument("--steps-sweep", type=int, nargs="*", default=[8, 12, 16, 25])
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    args = p.parse_args(argv)
    from diffusers import StableVideoDiffusionPipeline
    from PIL import Image

    dev, dt = args.device, DTYPES[args.precision]
    comps = configs.build_components(args.size, seed=0)
    stock = StableVideoDiffusionPipeline(**comps).to(dev, dt)
    stock.set_progress_bar_config(disable=True)
    ours = SCPainterPipeline({"unet": comps["unet"], "vae": comps["vae"], "image_encoder": comps["image_encoder"],
                              "condition_encoder": ConditionEncoder.from_vae(comps["vae"].float()).to(dev),
                              "config": ScpainterConfig(noise_aug_strength=0.0),
                              "clip_mean": comps["feature_extractor"].image_mean,
                              "clip_std": comps["feature_extractor"].image_std,
                              "schedule": edm.Schedule.from_config(dict(comps["scheduler"].config))}, dev, dt)
    ours.vae.to(dev, torch.float32 if dt == torch.float16 else dt)
    if args.compile:
        ours.unet = torch.compile(ours.unet)
    H, W = args.height, args.width
    rng = np.random.default_rng(0)
    pil = Image.fromarray(rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    image = torch.from_numpy(np.array(pil)).permute(2, 0, 1).float() / 255.0
    rows, sweep = [], []
    for frames in args.frames:
        eps = torch.randn((1, frames, 4, H // 8, W // 8), generator=torch.Generator().manual_seed(1))

        def run_stock(steps=args.steps):
            return stock(pil, height=H, width=W, num_frames=frames, num_inference_steps=steps, decode_chunk_size=8,
                         min_guidance_scale=1.0, max_guidance_scale=3.0, noise_aug_strength=0.0,
                         latents=eps.to(dev, dt), output_type="pt").frames[0].float().cpu()

        def run_ours(steps=args.steps):
            with torch.no_grad():
                cond = ours.condition_latents(image[None].repeat(frames, 1, 1, 1), torch.zeros(frames, 1, H, W),
                                              torch.ones(frames, 1, H, W))
                x = ours.sample(cond, ours.clip_embedding(image), steps=steps, window=frames,
                                latents=eps[0] * ours.schedule.init_noise_sigma)
                return ours.decode(x, chunk=8)

        run_stock(2), run_ours(2)  # warm-up (and compilation)
        ref, t_stock, m_stock = timed(run_stock, dev)
        out, t_ours, m_ours = timed(run_ours, dev)
        sigma = ours.schedule.sigmas(args.steps)[0].to(dev)
        cond = torch.zeros(frames, 4, H // 8, W // 8, device=dev)
        clip = torch.zeros(1, 1, ours.image_encoder.config.projection_dim, device=dev)
        x = torch.randn(frames, 4, H // 8, W // 8, device=dev)
        g = edm.guidance_ramp(frames, 1.0, 3.0, device=dev)
        _, t_step, _ = timed(lambda: [ours.predict_x0(x, sigma, cond, clip, g) for _ in range(3)], dev)
        rows.append({"frames": frames, "height": H, "width": W, "steps": args.steps, "precision": args.precision,
                     "compile": args.compile, "stock_s": t_stock, "ours_s": t_ours,
                     "stock_fps": frames / t_stock, "ours_fps": frames / t_ours, "speedup": t_stock / t_ours,
                     "stock_peak_gib": m_stock, "ours_peak_gib": m_ours, "ours_unet_step_ms": 1e3 * t_step / 3,
                     "mean_abs_diff": float((out - ref).abs().mean())})
        if frames == args.frames[0]:
            best = out
            for steps in args.steps_sweep:
                o, t, _ = timed(lambda: run_ours(steps), dev)
                sweep.append({"frames": frames, "steps": steps, "seconds": t,
                              "mean_abs_diff_vs_full_steps": float((o - best).abs().mean())})
    print("frames | steps | precision | stock s | ours s | speed-up | stock GiB | ours GiB | UNet step ms | mean |Δ|")
    print("--- | --- | --- | --- | --- | --- | --- | --- | --- | ---")
    for r in rows:
        print(f"{r['frames']} | {r['steps']} | {r['precision']}{' +compile' if r['compile'] else ''} | "
              f"{r['stock_s']:.2f} | {r['ours_s']:.2f} | {r['speedup']:.2f} | {r['stock_peak_gib']} | "
              f"{r['ours_peak_gib']} | {r['ours_unet_step_ms']:.0f} | {r['mean_abs_diff']:.2e}")
    print(f"\nsteps | seconds | mean |Δ| vs the {args.steps}-step video")
    for r in sweep:
        print(f"{r['steps']} | {r['seconds']:.2f} | {r['mean_abs_diff_vs_25']:.3e}")
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, f"generate_{args.size}_{args.device}.json")
    outputs.write_json(path, events.json_safe({"device": torch.cuda.get_device_name() if dev == "cuda" else "cpu",
                                               "rows": rows, "steps_sweep": sweep}))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
