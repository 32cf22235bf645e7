"""``python -m backend evaluate``: FID / FID-C / KID on validation clips and ground-truth PSNR/SSIM
(``backend/evaluate/protocol.py``; docs/design.md §13). With ``--ray`` the tasks' render/generate jobs run on a Ray
cluster and the metrics here; ``--device`` is then the workers', while this process computes the metrics on its
own GPU if it has one, so a CPU head node may drive GPU workers.
"""

from __future__ import annotations

import argparse

from .. import events
from . import options

NAME = "evaluate"
ORDER = 80


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``evaluate``'s parser; its settings' defaults live in ``EvalSettings`` and its ``ViewSettings``."""
    from scpainter_blender.core.job import BASELINE_DEFAULTS, INPAINT_METHODS

    e = sub.add_parser(NAME, help="FID / FID-C / KID on validation clips and ground-truth PSNR/SSIM")
    e.add_argument("clips", nargs="+", help="validation clip folders (clip.json, docs/training.md)")
    e.add_argument("--output-dir", required=True, help="jobs, renders, videos and evaluation.json go here")
    e.add_argument("--checkpoint", help="SCPainter checkpoint to evaluate (without: the baselines only)")
    # no defaults here (None: not given): EvalSettings and its ViewSettings hold them (backend/train/view_settings.py)
    e.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"))
    e.add_argument("--frames", type=int, help="frames per clip, from its start")
    e.add_argument("--shifts", type=float, nargs="*", help="lateral shifts in metres (+ left)")
    e.add_argument("--no-insertion", action="store_true", help="skip the asset re-insertion tasks")
    e.add_argument("--source-window", "--window", type=int, dest="source_window",
                   help="source frames t ± N project into frame t")
    e.add_argument("--steps", type=int, help="sampler steps")
    e.add_argument("--seed", type=int)
    e.add_argument("--crop-min-px", type=int, help="cars smaller than this (pixels) make no FID-C crop")
    e.add_argument("--precision", choices=options.PRECISION_CHOICES)
    e.add_argument("--inpaint", choices=INPAINT_METHODS,
                   help=f"the inpainting baseline's OpenCV method (default {BASELINE_DEFAULTS['inpaint']})")
    e.add_argument("--inception", help="FID Inception weights (pytorch-fid's pt_inception-2015-12-05-6726825d.pth "
                                       "or a safetensors copy); without it FID/KID are skipped")
    options.device_option(e, options.DEVICE_HELP + "; with --ray the workers' (cuda when the cluster has GPUs), "
                             "while the metrics use this machine's GPU if it has one")
    options.ray_options(e, "the tasks' render/generate jobs (then the metrics here)")
    e.set_defaults(func=run)
    return e


def run(args: argparse.Namespace) -> int:
    """Evaluate; a ``done`` event with the results, else an error event when SIGTERM stopped it (exit 1)."""
    from scpainter_blender.core.batch_items import ray_options

    from ..evaluate import protocol

    args.retries, args.cpus_per_job = ray_options(args.ray, args.retries, args.cpus_per_job)
    settings, pool = protocol.EvalSettings.from_args(args), protocol.RayPool.from_args(args)
    if pool is not None:  # the tasks' jobs run on a Ray cluster (backend/batch/ray_pool.py); the metrics here
        from ..batch import ray_pool as batch_ray

        events.reserve_stdout()  # Ray's driver prints its workers' errors to sys.stdout
    # with --ray, --device names the workers' device (run_ray_batch checks it against the cluster); this process
    # computes the metrics on its own GPU if it has one, so a CPU head node may drive GPU workers
    device = options.resolve_device(args.device if pool is None or args.device == "cpu" else "auto")
    with events.stop_on_sigterm(sigint=pool is not None) as stop:
        if pool is not None:
            batch_ray.connect(pool.address, stop)  # keeps our handler (ray.init installs its own)
        result = protocol.evaluate(settings, device, stop, pool=pool)
    if result.pop("stopped", False):
        events.error("stopped by SIGTERM", hint="finished renders and videos are kept: run again to resume")
        return events.EXIT_FAILED
    events.done(command=NAME, **result)
    return events.EXIT_OK
