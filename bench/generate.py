"""Generation speed, memory and error against run time: our pipeline against diffusers' StableVideoDiffusionPipeline.

    python bench/generate.py [--sections compare speed memory decode] [--size full|tiny] [--device cuda|cpu]
                             [--frames 14 25] [--height 576 --width 1024] [--precision fp16|bf16|fp32]
                             [--compile off|default|reduce-overhead|max-autotune] [--gpu-tuning on|off]
                             [--steps-sweep 8 12 16 25] [--smoke] [--out DIR]

Sections (all by default):

* ``compare`` (the device): both pipelines get the same random-weight components (``backend.model.configs``;
  ``full`` is SVD's real architecture), image, initial noise, guidance (1 → 3) and decode chunk (8). Ours is
  conditioned on that image's latent repeated over the frames (a fresh checkpoint's condition encoder is SVD's VAE
  encoder), so with ``job.STOCK_SAMPLING`` the two compute the same video: the difference measures our arithmetic.
  Each pipeline has its own VAE (stock's stays fp16; ours decodes in the model's dtype too). Rows: seconds, frames/s
  and peak GPU memory of stock, ours with the stock settings and ours with ``GENERATE_DEFAULTS`` (``--compile``/
  ``--gpu-tuning`` on top; the compile warm-up is reported apart as ``compile_s``), one guidance-batched UNet step,
  the mean abs difference of the frames in [0, 1] against stock; then Euler steps against time and against the
  ``--steps``-step video.
* ``speed``: the error-against-run-time table of the generate settings (sampler and steps, feature reuse, guidance
  interval, dropping the unconditional branch of frames with guidance 1), each against our stock-equivalent 25-step
  Euler video at the same seed: UNet frame-evaluations (whole and with reused features), ``cost`` = their share of
  stock's with a feature-reusing evaluation counted at its FLOP share at the full architecture (``shallow_flops``,
  counted on fake tensors), seconds and the mean abs difference of the frames. ``cost`` is the device-independent
  stand-in for the speed-up: the UNet is ~90 % of a run on the H200.
* ``memory`` (always on the CPU, with fake tensors: shapes and allocations without memory or arithmetic): the peak
  memory of each stage (CLIP, condition encode, one UNet step, decoding one chunk) of stock, of our pipeline as it
  was (float32 VAE decode, condition encoder 8 frames at a time, CLIP and encoder kept) and as it is (decode in the
  model's dtype, one frame at a time, CLIP and encoder released after use), at the size asked for (the issue's:
  ``--size full --frames 14 --height 576 --width 1024 --precision fp16``); weights resident on the device included.
* ``decode``: the decoder's error in fp16 and in bf16 against a float32 decode (mean and max abs, frames in [0, 1];
  on the CPU at a small size: PyTorch's fp16 convolutions there are a slow reference path).

On a CPU: ``--size tiny --device cpu --sections speed decode`` (the speed table with the tiny model) and ``--size
full --device cpu --sections memory decode --precision fp16 --frames 14`` (the memory breakdown and the decode error
at SVD's architecture; no UNet weights are made). On a GPU: ``--device cuda --size full --frames 14``.
Writes ``<out>/generate_<size>_<device>.json`` (``--out``, default bench/results). ``--smoke``: the tiny model on the
CPU at 2 frames of 32 x 64, every section, in seconds (tests/bench/test_generate.py). Random weights: a trained
model's errors against steps can differ (its denoiser is smoother in σ than a random network's).
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
import types
import weakref

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch.utils._python_dispatch import TorchDispatchMode  # noqa: E402
from torch.utils._pytree import tree_flatten  # noqa: E402
from torch.utils.weak import WeakIdKeyDictionary  # noqa: E402

from backend import events  # noqa: E402
from backend.model import configs, edm  # noqa: E402
from backend.model.checkpoint_config import ScpainterConfig  # noqa: E402
from backend.model.condition import ConditionEncoder  # noqa: E402
from backend.model.feature_reuse import SHALLOW_FLOPS, unet_forward  # noqa: E402
from backend.model.pipeline import CONDITION_CHUNK, SCPainterPipeline, clip_embeddings  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402
from scpainter_blender.core.job import GENERATE_COMPILE, GENERATE_DEFAULTS, STOCK_SAMPLING  # noqa: E402

DTYPES = {"fp16": torch.float16, "bf16": torch.bfloat16, "fp32": torch.float32}
SECTIONS = ("compare", "speed", "memory", "decode")
SPEED_KEYS = ("sampler", "steps", "feature_reuse", "guidance_sigma_min", "guidance_sigma_max")
DEFAULT_SAMPLING = {k: GENERATE_DEFAULTS[k] for k in SPEED_KEYS}
#: The speed table's rows: a name and the settings that differ from the stock sampler (``STOCK_SAMPLING``).
SPEED_ROWS = [
    ("stock-equivalent", {}),
    ("default", DEFAULT_SAMPLING),
    *[(f"euler-{n}", {"steps": n}) for n in (8, 12, 14, 16)],
    *[(f"dpmpp2m-{n}", {"sampler": "dpmpp2m", "steps": n}) for n in (8, 12)],
    *[(f"heun-{n}", {"sampler": "heun", "steps": n}) for n in (6, 8)],
    *[(f"reuse-{n}", {"feature_reuse": n}) for n in (2, 3)],
    ("euler-16-reuse-2", {"steps": 16, "feature_reuse": 2}),
    *[(f"guidance-sigma-max-{s:g}", {"guidance_sigma_max": s}) for s in (100.0, 30.0)],
    ("guidance-sigma-min-1", {"guidance_sigma_min": 1.0}),
    ("drop-guidance-1-frames", {"drop_unguided": True}),
]
SMOKE_ROWS = ("stock-equivalent", "default", "euler-8", "reuse-2")


def sync(device):
    if device == "cuda":
        torch.cuda.synchronize()


def timed(fn, device):
    """(result, seconds, peak GiB on CUDA else None)."""
    sync(device)
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    t = time.perf_counter()
    out = fn()
    sync(device)
    peak = torch.cuda.max_memory_allocated() / 2 ** 30 if device == "cuda" else None
    return out, time.perf_counter() - t, peak


def our_pipeline(comps, dev, dt, vae_dtype=None) -> SCPainterPipeline:
    """Ours from the (float32) components, before the stock pipeline casts them: its own VAE (a deep copy in
    ``vae_dtype``, default ``dt``: decoding as stock does) and condition encoder (float32, as checkpoint.load makes
    it for an upcasting VAE); the UNet and CLIP are shared with stock (the same dtype)."""
    vae = copy.deepcopy(comps["vae"]).float()
    enc = ConditionEncoder.from_vae(vae).to(dev)
    return SCPainterPipeline({"unet": comps["unet"], "vae": vae.to(dev, vae_dtype or dt),
                              "image_encoder": comps["image_encoder"], "condition_encoder": enc,
                              "config": ScpainterConfig(noise_aug_strength=0.0),
                              "clip_mean": comps["feature_extractor"].image_mean,
                              "clip_std": comps["feature_extractor"].image_std,
                              "schedule": edm.Schedule.from_config(dict(comps["scheduler"].config))}, dev, dt)


def test_image(H, W):
    from PIL import Image

    rng = np.random.default_rng(0)
    pil = Image.fromarray(rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    return pil, torch.from_numpy(np.array(pil)).permute(2, 0, 1).float() / 255.0


# ----------------------------------------------------------------------------------------------- compare

def section_compare(args, comps, ours, log):
    from diffusers import StableVideoDiffusionPipeline

    dev, dt = args.device, DTYPES[args.precision]
    stock = StableVideoDiffusionPipeline(**comps).to(dev, dt)   # comps' VAE is stock's alone (ours has a copy)
    stock.set_progress_bar_config(disable=True)
    H, W = args.height, args.width
    pil, image = test_image(H, W)
    rows, sweep = [], []
    for frames in args.frames:
        eps = torch.randn((1, frames, 4, H // 8, W // 8), generator=torch.Generator().manual_seed(1))

        def run_stock(steps=args.steps):
            return stock(pil, height=H, width=W, num_frames=frames, num_inference_steps=steps, decode_chunk_size=8,
                         min_guidance_scale=1.0, max_guidance_scale=3.0, noise_aug_strength=0.0,
                         latents=eps.to(dev, dt), output_type="pt").frames[0].float().cpu()

        def run_ours(**settings):
            cond = ours.condition_latents(image[None].repeat(frames, 1, 1, 1), torch.zeros(frames, 1, H, W),
                                          torch.ones(frames, 1, H, W))
            x = ours.sample(cond, ours.clip_embedding(image), window=frames,
                            latents=eps[0] * ours.schedule.init_noise_sigma, **settings)
            return ours.decode(x, chunk=8)

        stock_settings = {**STOCK_SAMPLING, "steps": args.steps}
        run_stock(2), run_ours(**{**stock_settings, "steps": 2})     # warm-up (cuDNN, allocator)
        ref, t_stock, m_stock = timed(run_stock, dev)
        out, t_ours, m_ours = timed(lambda: run_ours(**stock_settings), dev)
        ours.set_speed(args.compile, args.gpu_tuning)
        _, t_first, _ = timed(lambda: run_ours(**DEFAULT_SAMPLING), dev)   # compiles when --compile is on
        fast, t_fast, m_fast = timed(lambda: run_ours(**DEFAULT_SAMPLING), dev)
        ours.set_speed("off", "off")
        sigma = ours.schedule.sigmas(args.steps)[0].to(dev)
        cond = torch.zeros(frames, 4, H // 8, W // 8, device=dev)
        clip = torch.zeros(1, 1, ours.image_encoder.config.projection_dim, device=dev)
        x = torch.randn(frames, 4, H // 8, W // 8, device=dev)
        g = edm.guidance_ramp(frames, 1.0, 3.0, device=dev)
        _, t_step, _ = timed(lambda: [ours.predict_x0(x, sigma, cond, clip, g) for _ in range(3)], dev)
        rows.append({"frames": frames, "height": H, "width": W, "steps": args.steps, "precision": args.precision,
                     "compile": args.compile, "gpu_tuning": args.gpu_tuning, "default_settings": DEFAULT_SAMPLING,
                     "stock_s": t_stock, "ours_s": t_ours, "stock_fps": frames / t_stock, "ours_fps": frames / t_ours,
                     "speedup": t_stock / t_ours, "stock_peak_gib": m_stock, "ours_peak_gib": m_ours,
                     "ours_unet_step_ms": 1e3 * t_step / 3, "mean_abs_diff": float((out - ref).abs().mean()),
                     "default_s": t_fast, "default_fps": frames / t_fast, "default_speedup": t_stock / t_fast,
                     "default_peak_gib": m_fast, "compile_s": max(t_first - t_fast, 0.0),
                     "default_mean_abs_diff": float((fast - ref).abs().mean())})
        if frames == args.frames[0]:
            for steps in args.steps_sweep:
                o, t, _ = timed(lambda: run_ours(**{**stock_settings, "steps": steps}), dev)
                sweep.append({"frames": frames, "steps": steps, "seconds": t,
                              "mean_abs_diff_vs_full_steps": float((o - out).abs().mean())})
    log("frames | steps | precision | stock s | ours s | speed-up | stock GiB | ours GiB | UNet step ms | mean |Δ| "
        "| default s | default speed-up | default GiB | compile s | default mean |Δ|")
    log("--- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | ---")
    for r in rows:
        log(f"{r['frames']} | {r['steps']} | {r['precision']} | {r['stock_s']:.2f} | {r['ours_s']:.2f} | "
            f"{r['speedup']:.2f} | {r['stock_peak_gib']} | {r['ours_peak_gib']} | {r['ours_unet_step_ms']:.0f} | "
            f"{r['mean_abs_diff']:.2e} | {r['default_s']:.2f} | {r['default_speedup']:.2f} | "
            f"{r['default_peak_gib']} | {r['compile_s']:.1f} | {r['default_mean_abs_diff']:.2e}")
    log(f"\nEuler steps | seconds | mean |Δ| vs the {args.steps}-step video")
    for r in sweep:
        log(f"{r['steps']} | {r['seconds']:.2f} | {r['mean_abs_diff_vs_full_steps']:.3e}")
    return rows, sweep


# ------------------------------------------------------------------------------------------------- speed

def shallow_flops(size: str, frames: int = 14, height: int = 576, width: int = 1024) -> float:
    """The FLOPs of a feature-reusing UNet evaluation (depth 1) as a share of a whole one, at ``size``'s
    architecture and that video size, counted on fake tensors (attention counted through the plain SDPA kernel)."""
    from diffusers import UNetSpatioTemporalConditionModel
    from torch._subclasses import FakeTensorMode
    from torch.nn.attention import SDPBackend, sdpa_kernel
    from torch.utils.flop_counter import FlopCounterMode

    cfg = configs.SIZES[size]["unet"]
    with FakeTensorMode(), torch.no_grad(), sdpa_kernel(SDPBackend.MATH):
        unet = UNetSpatioTemporalConditionModel(**cfg)
        x = torch.randn(1, frames, cfg["in_channels"], height // 8, width // 8)
        args = (x, torch.ones(1), torch.randn(1, 1, cfg["cross_attention_dim"]), torch.randn(1, 3))
        with FlopCounterMode(display=False) as whole:
            _, h_deep = unet_forward(unet, *args)
        with FlopCounterMode(display=False) as shallow:
            unet_forward(unet, *args, h_deep=h_deep)
    return shallow.get_total_flops() / whole.get_total_flops()


def section_speed(args, ours, log, rows=SPEED_ROWS):
    """(the rows, the warm-up's seconds and evaluations): each row's video against our stock-equivalent video
    (``STOCK_SAMPLING``), same seed and conditions, after an untimed warm-up."""
    dev = args.device
    F, H, W = args.speed_frames, args.speed_height, args.speed_width
    gen = torch.Generator().manual_seed(1)
    image = torch.rand(F, 3, H, W, generator=gen)
    valid = (torch.rand(F, 1, H, W, generator=gen) > 0.4).float()   # 40 % holes, as a shifted view has
    cond = ours.condition_latents(image, torch.zeros(F, 1, H, W), valid)
    clip = ours.clip_embedding(image[0])
    fraction = args.shallow_flops
    # warm-up, untimed (as section compare's): this section runs first, so its first sample paid the device's first
    # calls (CUDA's lazy module loading, cuBLAS/cuDNN handles, the allocator) in the reference row alone, which
    # flattered every time ratio
    ours.evaluations = {"full": 0, "shallow": 0}
    warm_t = time.perf_counter()
    for reuse in (1, 2):
        ours.decode(ours.sample(cond, clip, seed=3, window=F, **{**STOCK_SAMPLING, "steps": 2,
                                                                 "feature_reuse": reuse}))
    sync(dev)
    warmup = {"seconds": time.perf_counter() - warm_t, **ours.evaluations}
    table, ref = [], None
    for name, change in rows:
        settings = {**STOCK_SAMPLING, **change}
        ours.evaluations = {"full": 0, "shallow": 0}
        video, t, _ = timed(lambda: ours.decode(ours.sample(cond, clip, seed=3, window=F, **settings)), dev)
        if ref is None:
            ref, stock_evals, t_ref = video, ours.evaluations["full"], t
        e = ours.evaluations
        table.append({"name": name, **{k: settings[k] for k in SPEED_KEYS},
                      "drop_unguided": bool(settings.get("drop_unguided")), "evaluations": e["full"],
                      "shallow_evaluations": e["shallow"],
                      "cost": (e["full"] + fraction * e["shallow"]) / stock_evals, "seconds": t,
                      "time_ratio": t / t_ref, "mean_abs_error": float((video - ref).abs().mean()),
                      "max_abs_error": float((video - ref).abs().max())})
    log(f"\nsettings ({F} frames {W}x{H}, {args.size} model, random weights) | UNet frame-evaluations (reused) | "
        f"cost vs stock (reused at {fraction:.2f}) | seconds | time vs stock | mean |Δ| vs stock 25-step Euler")
    log("--- | --- | --- | --- | --- | ---")
    for r in table:
        log(f"{r['name']} | {r['evaluations']} ({r['shallow_evaluations']}) | {r['cost']:.2f} | {r['seconds']:.2f} | "
            f"{r['time_ratio']:.2f} | {r['mean_abs_error']:.2e}")
    return table, warmup


# ------------------------------------------------------------------------------------------------ memory

class LiveBytes(TorchDispatchMode):
    """Bytes of the tensor storages that operators allocate inside the ``with`` block and still alive (``live``), and
    their maximum (``peak``): a storage counts from the operator that made it until it is freed; storages an
    operator receives that were made before (inputs, weights, and views of them) do not count. Works on fake
    tensors (their storages have sizes, no memory); a number the host reads from one (``float(t)``, ``bool(t)``: the
    pipeline's guidance and NaN checks) is ``SCALAR``: guidance above 1, checks passed."""

    SCALAR = 3

    def __init__(self):
        super().__init__()
        self.live = self.peak = 0
        self.seen = WeakIdKeyDictionary()

    def _free(self, nbytes):
        self.live -= nbytes

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func is torch.ops.aten._local_scalar_dense.default:
            return self.SCALAR
        for t in tree_flatten((args, kwargs))[0]:   # storages made before the block (inputs, weights): not counted
            if isinstance(t, torch.Tensor) and t.untyped_storage() not in self.seen:
                self.seen[t.untyped_storage()] = 0
        out = func(*args, **(kwargs or {}))
        for t in tree_flatten(out)[0]:
            if isinstance(t, torch.Tensor):
                st = t.untyped_storage()
                if st not in self.seen:
                    self.seen[st] = n = st.nbytes()
                    self.live += n
                    self.peak = max(self.peak, self.live)
                    weakref.finalize(st, self._free, n)
        return out


def section_memory(args, log):
    """Peak memory of each stage, on fake tensors (module docstring)."""
    from diffusers import AutoencoderKLTemporalDecoder, StableVideoDiffusionPipeline, UNetSpatioTemporalConditionModel
    from torch._subclasses import FakeTensorMode
    from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

    cfg, dt = configs.SIZES[args.size], DTYPES[args.precision]
    F, H, W, h, w = args.memory_frames, args.height, args.width, args.height // 8, args.width // 8
    gib = 2 ** -30

    def build(make, dtype):
        before = torch.get_default_dtype()
        torch.set_default_dtype(dtype)   # fake parameters cannot be cast after construction
        try:
            return make().eval()
        finally:
            torch.set_default_dtype(before)

    def peak(fn, modules):
        weights = sum(t.untyped_storage().nbytes() for m in modules for t in m.state_dict().values())
        with LiveBytes() as live, torch.no_grad():
            fn()
        return (weights + live.peak) * gib

    with FakeTensorMode():
        unet = build(lambda: UNetSpatioTemporalConditionModel(**cfg["unet"]), dt)
        clip = build(lambda: CLIPVisionModelWithProjection(CLIPVisionConfig(**cfg["clip"])), dt)
        vae = {d: build(lambda: AutoencoderKLTemporalDecoder(**cfg["vae"]), d) for d in {dt, torch.float32}}
        enc = build(lambda: ConditionEncoder(in_channels=4, **{k: cfg["vae"][k] for k in (
            "latent_channels", "down_block_types", "block_out_channels", "layers_per_block")}), torch.float32)
        schedule = edm.Schedule.from_config(configs.SCHEDULER)

        def ours(vae_dtype):
            return SCPainterPipeline({"unet": unet, "vae": vae[vae_dtype], "image_encoder": clip,
                                      "condition_encoder": enc, "config": ScpainterConfig(), "clip_mean": (0.5,) * 3,
                                      "clip_std": (0.5,) * 3, "schedule": schedule}, "cpu", dt)

        before, now = ours(torch.float32), ours(dt)
        stock = types.SimpleNamespace(vae=vae[dt])   # what StableVideoDiffusionPipeline.decode_latents reads
        size = cfg["clip"]["image_size"]
        ehs = cfg["unet"]["cross_attention_dim"]
        # each stage's inputs exist before it (not counted: ours keeps the conditions and the frames on the host)
        pixels, image = torch.randn(1, 3, size, size, dtype=dt), torch.rand(1, 3, H, W)
        conditions = (torch.rand(F, 3, H, W), torch.rand(F, 1, H, W), torch.rand(F, 1, H, W))
        stock_step = (torch.randn(2, F, 8, h, w, dtype=dt), torch.ones(2, dtype=dt), torch.randn(2, 1, ehs, dtype=dt),
                      torch.randn(2, 3, dtype=dt))
        our_step = (torch.randn(F, 4, h, w), torch.tensor(1.0), torch.randn(F, 4, h, w), torch.randn(1, 1, ehs),
                    edm.guidance_ramp(F, 1.0, 3.0))
        stock_latents, latents = torch.randn(1, F, 4, h, w, dtype=dt), torch.randn(F, 4, h, w)
        stages = {
            "CLIP embedding": (
                lambda: clip(pixels).image_embeds,
                lambda p: clip_embeddings(clip, image, p.clip_mean, p.clip_std)),
            "condition encode (stock: one image, float32)": (
                lambda: vae[torch.float32].encode(image).latent_dist.mode(),
                lambda p: p.condition_latents(*conditions, chunk=8 if p is before else CONDITION_CHUNK)),
            "UNet step (guidance batch of 2)": (
                lambda: unet(stock_step[0], stock_step[1], encoder_hidden_states=stock_step[2],
                             added_time_ids=stock_step[3]),
                lambda p: p.predict_x0(*our_step)),
            "decode (chunk 8)": (
                lambda: StableVideoDiffusionPipeline.decode_latents(stock, stock_latents, F, 8),
                lambda p: p.decode(latents, chunk=8)),
        }
        table = []
        for i, (name, (run_stock, run_ours)) in enumerate(stages.items()):
            # the stock pipeline upcasts its whole VAE to float32 to encode; ours releases CLIP and the condition
            # encoder once both are done (generate's release_encoders), before the UNet runs
            stock_vae = vae[torch.float32] if name.startswith("condition") else vae[dt]
            table.append({"stage": name,
                          "stock_gib": peak(run_stock, [unet, clip, stock_vae]),
                          "ours_before_gib": peak(lambda: run_ours(before), [unet, clip, vae[torch.float32], enc]),
                          "ours_gib": peak(lambda: run_ours(now), [unet, vae[dt]] + ([clip, enc] if i < 2 else []))})
    table.append({"stage": "peak", **{k: max(r[k] for r in table) for k in ("stock_gib", "ours_before_gib",
                                                                             "ours_gib")}})
    log(f"\nstage ({args.size}, {F} frames {W}x{H}, {args.precision}; fake tensors, weights included) | stock GiB | "
        "ours before GiB (fp32 decode, encode 8 frames) | ours GiB")
    log("--- | --- | --- | ---")
    for r in table:
        log(f"{r['stage']} | {r['stock_gib']:.2f} | {r['ours_before_gib']:.2f} | {r['ours_gib']:.2f}")
    return table


# ------------------------------------------------------------------------------------------------ decode

def section_decode(args, log):
    """The VAE decoder (``--size``'s, random weights) in fp16 and bf16 against float32 (``pipeline.decode_dtype``
    chooses fp16 on CUDA)."""
    from diffusers import AutoencoderKLTemporalDecoder

    dev = args.device
    torch.manual_seed(0)
    vae = AutoencoderKLTemporalDecoder(**configs.SIZES[args.size]["vae"]).to(dev).eval()
    F, h, w = args.decode_frames, args.decode_height // 8, args.decode_width // 8
    z = torch.randn(F, 4, h, w, generator=torch.Generator().manual_seed(2)).to(dev)
    rows = []
    with torch.no_grad():
        ref = ((vae.decode(z, num_frames=F).sample.float() + 1) / 2).clamp(0, 1)
        for name in ("fp16", "bf16"):
            low = copy.deepcopy(vae).to(DTYPES[name])
            out, t, _ = timed(lambda: ((low.decode(z.to(DTYPES[name]), num_frames=F).sample.float() + 1) / 2)
                              .clamp(0, 1), dev)
            rows.append({"dtype": name, "frames": F, "height": args.decode_height, "width": args.decode_width,
                         "size": args.size, "seconds": t, "mean_abs_error": float((out - ref).abs().mean()),
                         "max_abs_error": float((out - ref).abs().max())})
    for r in rows:
        log(f"\ndecode in {r['dtype']} vs float32 ({args.size} VAE, random weights, {F} frames "
            f"{args.decode_width}x{args.decode_height}): mean |Δ| {r['mean_abs_error']:.2e}, "
            f"max |Δ| {r['max_abs_error']:.2e}, {r['seconds']:.2f} s")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    p.add_argument("--size", choices=["full", "tiny"], default="full")
    p.add_argument("--device", choices=["cuda", "cpu"], default="cuda")
    p.add_argument("--frames", type=int, nargs="+", default=[14, 25])
    p.add_argument("--height", type=int, default=576)
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--steps", type=int, default=STOCK_SAMPLING["steps"])
    p.add_argument("--precision", choices=list(DTYPES),
                   help="the models' dtype (default: fp16 on CUDA, fp32 on the CPU, whose fp16 kernels are slow)")
    p.add_argument("--compile", choices=GENERATE_COMPILE, default="off",
                   help="torch.compile of our UNet for the default-settings row (reduce-overhead: CUDA graphs)")
    p.add_argument("--gpu-tuning", choices=("on", "off"), default=GENERATE_DEFAULTS["gpu_tuning"])
    p.add_argument("--steps-sweep", type=int, nargs="*", default=[8, 12, 16, 25])
    p.add_argument("--speed-size", type=int, nargs=3, metavar=("FRAMES", "HEIGHT", "WIDTH"),
                   help="the speed table's video (default: 8 64 96 on the CPU, the first --frames at --height x "
                        "--width on CUDA)")
    p.add_argument("--speed-rows", nargs="+", metavar="NAME",
                   help="the speed table's rows by name (default: all; stock-equivalent always): "
                        + "; ".join(name for name, _ in SPEED_ROWS))
    p.add_argument("--smoke", action="store_true", help="tiny model, CPU, 2 frames of 32 x 64: seconds")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    args = p.parse_args(argv)
    if args.smoke:
        args.size, args.device, args.frames, args.height, args.width = "tiny", "cpu", [2], 32, 64
        args.steps, args.steps_sweep, args.precision = 3, [2], "fp32"
    args.precision = args.precision or ("fp16" if args.device == "cuda" else "fp32")
    if args.device == "cuda" and not torch.cuda.is_available():
        p.error("--device cuda: no CUDA device here (use --device cpu, or --smoke)")
    speed = args.speed_size or ((2, 32, 64) if args.smoke else (8, 64, 96) if args.device == "cpu"
                                else (args.frames[0], args.height, args.width))
    args.speed_frames, args.speed_height, args.speed_width = speed
    args.memory_frames = args.frames[0]
    args.decode_frames, args.decode_height, args.decode_width = (1, 32, 32) if args.smoke else (
        (2, 64, 64) if args.device == "cpu" else (8, args.height, args.width))
    lines = []

    def log(line=""):
        print(line, flush=True)
        lines.append(line)

    result = {"device": torch.cuda.get_device_name() if args.device == "cuda" else "cpu", "size": args.size,
              "smoke": args.smoke, "defaults": {k: GENERATE_DEFAULTS[k] for k in (*SPEED_KEYS, "compile",
                                                                                   "gpu_tuning")}}
    # real weights only where a section computes (memory runs on fake tensors)
    comps = configs.build_components(args.size, seed=0) if {"compare", "speed"} & set(args.sections) else None
    dt = DTYPES[args.precision]
    if "speed" in args.sections or "compare" in args.sections:
        for m in (comps["unet"], comps["image_encoder"]):
            m.to(args.device, dt).eval()
        ours = our_pipeline(comps, args.device, dt)
    if "speed" in args.sections:
        t = time.perf_counter()
        # the table counts a shallow evaluation at the full architecture's share (the tiny UNet has no attention at
        # its first level); it is counted again here (~25 s on a CPU; the smoke run counts the tiny one's)
        share = shallow_flops("tiny" if args.smoke else "full", *((2, 32, 64) if args.smoke else (14, 576, 1024)))
        args.shallow_flops = SHALLOW_FLOPS
        result["shallow_flops"] = {"architecture": "tiny" if args.smoke else "full", "share": share,
                                   "share_used": SHALLOW_FLOPS, "seconds": time.perf_counter() - t}
        chosen = SMOKE_ROWS if args.smoke else args.speed_rows or [name for name, _ in SPEED_ROWS]
        unknown = set(chosen) - {name for name, _ in SPEED_ROWS}
        if unknown:
            p.error(f"--speed-rows: no row named {sorted(unknown)}")
        rows = [r for r in SPEED_ROWS if r[0] in chosen or r[0] == "stock-equivalent"]
        result["speed"], result["speed_warmup"] = section_speed(args, ours, log, rows)
    if "memory" in args.sections:
        result["memory"] = section_memory(args, log)
    if "decode" in args.sections:
        result["decode"] = section_decode(args, log)
    if "compare" in args.sections:
        result["rows"], result["steps_sweep"] = section_compare(args, comps, ours, log)
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, f"generate_{args.size}_{args.device}.json")
    outputs.write_json(path, events.json_safe({**result, "table": lines}))
    print(f"\nwrote {path}")
    return result


if __name__ == "__main__":
    main()
