"""``python -m backend generate``: render the missing conditions, then generate the video: with a checkpoint the
SCPainter model, without one the OpenCV inpainting baseline (``backend/generate/command.py``; docs/design.md §11).

Everything is checked before anything is rendered or loaded (``--check`` stops there). The model's options
(``--checkpoint``, ``--steps``, ``--seed``, ``--precision``) mean nothing to the baseline: a log line says they are
ignored, and the ``done`` event lists them. SIGTERM stops after the current stage's unit of work.
"""

from __future__ import annotations

import argparse

from .. import events
from . import options

NAME = "generate"
#: The speed settings' options (``core.job.GENERATE_DEFAULTS``; docs/design.md §11), each the job's key of its name.
SPEED_OPTIONS = ("sampler", "feature_reuse", "guidance_sigma_min", "guidance_sigma_max", "compile", "gpu_tuning")
ORDER = 30


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``generate``'s parser; the defaults it names are the job's (``core.job``)."""
    from scpainter_blender.core.job import (BASELINE_DEFAULTS, GENERATE_COMPILE, GENERATE_DEFAULTS, GENERATE_MODELS,
                                            GENERATE_SAMPLERS, INPAINT_METHODS, STOCK_SAMPLING)

    n = sub.add_parser(NAME, help="render missing conditions, then generate the video: with a checkpoint "
                                  "the SCPainter model, without one the OpenCV inpainting baseline")
    n.add_argument("job", help="job.json (the job contract: docs/design.md)")
    n.add_argument("--checkpoint", help="SCPainter checkpoint folder (default: the job's generate.checkpoint)")
    n.add_argument("--model", choices=GENERATE_MODELS,
                   help="scpainter (needs a checkpoint) or baseline (the condition image with its holes inpainted "
                        "by OpenCV; no weights); default: the job's generate.model, else auto = scpainter when a "
                        "checkpoint is configured, baseline otherwise")
    n.add_argument("--inpaint", choices=INPAINT_METHODS,
                   help=f"the baseline's OpenCV method (default: the job's, else {BASELINE_DEFAULTS['inpaint']})")
    n.add_argument("--inpaint-radius", type=int,
                   help=f"the baseline's inpainting radius in pixels (default: the job's, else "
                        f"{BASELINE_DEFAULTS['inpaint_radius']})")
    options.device_option(n)
    n.add_argument("--precision", choices=options.PRECISION_CHOICES, default="auto",
                   help="UNet/CLIP dtype (auto: bf16 on CUDA, fp32 on CPU); latents stay float32")
    n.add_argument("--steps", type=int,
                   help=f"sampler steps (default: the job's, else {GENERATE_DEFAULTS['steps']})")
    n.add_argument("--seed", type=int, help=f"seed (default: the job's, else {GENERATE_DEFAULTS['seed']})")
    n.add_argument("--sampler", choices=GENERATE_SAMPLERS,
                   help=f"the ODE sampler (default: the job's, else {GENERATE_DEFAULTS['sampler']}; stock SVD: "
                        f"{STOCK_SAMPLING['sampler']} with --steps {STOCK_SAMPLING['steps']} --feature-reuse 1 "
                        f"--guidance-sigma-max {STOCK_SAMPLING['guidance_sigma_max']:g})")
    n.add_argument("--feature-reuse", type=int, metavar="N",
                   help=f"run the whole UNet every N-th step, reusing its deep features between (1: every step; "
                        f"default: the job's, else {GENERATE_DEFAULTS['feature_reuse']})")
    n.add_argument("--guidance-sigma-min", type=float, metavar="SIGMA",
                   help=f"no classifier-free guidance below this noise level (default: the job's, else "
                        f"{GENERATE_DEFAULTS['guidance_sigma_min']:g})")
    n.add_argument("--guidance-sigma-max", type=float, metavar="SIGMA",
                   help=f"no classifier-free guidance above this noise level (default: the job's, else "
                        f"{GENERATE_DEFAULTS['guidance_sigma_max']:g})")
    n.add_argument("--compile", choices=GENERATE_COMPILE,
                   help=f"torch.compile the UNet, on any device (reduce-overhead: with CUDA graphs); the first run "
                        f"compiles, for minutes (on the CPU too, even for a small model), and later runs load the "
                        f"kernels from $TORCHINDUCTOR_CACHE_DIR, else ~/.cache/scpainter/inductor (default: the "
                        f"job's, else {GENERATE_DEFAULTS['compile']})")
    n.add_argument("--gpu-tuning", choices=("on", "off"),
                   help=f"cuDNN autotuning, channels-last UNet and fused attention kernels on CUDA (default: the "
                        f"job's, else {GENERATE_DEFAULTS['gpu_tuning']})")
    n.add_argument("--force", action="store_true", help="generate again even if the video is up to date")
    options.input_options(n)
    options.proposals_option(n)
    n.set_defaults(func=run)
    return n


def run(args: argparse.Namespace) -> int:
    """Check (``--check``) or generate the job's video; a ``done`` event, else an error event when SIGTERM stopped
    it (exit 1)."""
    import time

    from scpainter_blender.core import locking, outputs
    from scpainter_blender.core import job as job_mod

    from ..generate import command as generate
    from ..render import proposals

    roots = outputs.data_roots_option(args.data_root)
    job = job_mod.load(args.job)
    overrides = {"steps": args.steps, "seed": args.seed, "model": args.model, "inpaint": args.inpaint,
                 "inpaint_radius": args.inpaint_radius, **{k: getattr(args, k) for k in SPEED_OPTIONS}}
    # everything is checked before anything is rendered or loaded: the job, the overrides, the checkpoint (its
    # config and that it holds only safetensors), the settings they make together, and the input files
    plan = generate.prepare(args.job, job, args.checkpoint, overrides, args.allow_outside, roots)
    # the model's settings mean nothing to the baseline: said, rather than silently dropped
    ignored = [o for o, v in (("--checkpoint", args.checkpoint), ("--steps", args.steps), ("--seed", args.seed),
                              ("--precision", args.precision != "auto" or None),
                              *((f"--{k.replace('_', '-')}", getattr(args, k)) for k in SPEED_OPTIONS))
               if v is not None]
    ignored = ignored if plan.model == "baseline" else []
    if ignored:
        events.log(f"generate: the baseline ignores {', '.join(ignored)} (model settings; the baseline is OpenCV "
                   "inpainting)")
    if args.check:
        from ..render import command as render_command

        render_command.warn_inputs(job, plan.paths)
        events.done(command=NAME, check=True, frames=len(job.frames), model=plan.model, ignored=ignored,
                    description=plan.description(), checkpoint=plan.checkpoint, settings=plan.settings,
                    output_dir=plan.output_dir, locked_by=locking.lock_owner(plan.output_dir))
        return events.EXIT_OK
    device = options.resolve_device(args.device)
    t0 = time.perf_counter()
    job, _ = proposals.apply(args.job, job, args.proposals, args.allow_outside, roots)
    with events.stop_on_sigterm() as stop:
        result = generate.generate_job(args.job, job, device, args.checkpoint, args.precision, args.force, stop,
                                       overrides, allow_outside=args.allow_outside, data_roots=roots)
    if result.pop("stopped"):
        if plan.model == "baseline" and result["stage"] == "generate":  # seconds of work: it keeps none of it
            events.error(f"stopped by SIGTERM during the baseline ({result['steps_done']} frames inpainted, not "
                         "kept)", hint="run the same command again: the baseline starts again from its first frame "
                                       "(the condition layers are kept)")
            return events.EXIT_FAILED
        events.error(f"stopped by SIGTERM during {result['stage']} ({result['steps_done']} sampler steps done)",
                     hint="finished work is kept: run the same command again to resume")
        return events.EXIT_FAILED
    events.done(command=NAME, device=device, seconds=time.perf_counter() - t0, ignored=ignored, **result)
    return events.EXIT_OK
