"""``python -m backend <command>``: the backend's command line (docs/design.md §4.4).

Exit codes: 0 done; 2 bad input: an ``InputError`` (the error event has ``file`` and ``field``; a command-line
argument is file "(command line)" with the option as field, argparse's own errors included); 1 anything else: a
failure the command explains (``errors.CleanFailure``: a busy output folder, a model producing NaN; no
traceback), or a bug (any other exception, a plain ValueError included): its traceback on standard error and in the
command's log (``<output_dir>/backend.log``), whose path the error event's ``log`` field gives; 130 interrupted by
Ctrl-C (an error event). Standard output carries JSON events only. The codes, device names and event kinds:
``scpainter_blender.core.backend_protocol``; the add-on writes this command line with
``scpainter_blender.runs.client.Invocation`` (a test parses its ``argv()`` with ``build_parser``).

Over 400 lines because it is the whole command line in one place: ``build_parser`` (every option and its help) and
one thin handler per command (``_cmd_*``: check the arguments, call the command's module, emit its events), so an
option sits beside the code that reads it; the work itself lives in the command modules.
"""

from __future__ import annotations

import argparse
import os
import sys

from . import events


def _cmd_doctor(args) -> int:
    import contextlib
    import importlib.metadata
    import importlib.util
    import platform

    report = {"python": sys.version.split()[0], "platform": platform.platform(), "executable": sys.executable}
    for mod in ("numpy", "torch", "numba", "OpenEXR", "cv2", "diffusers", "transformers", "safetensors", "av", "open3d",
                "trimesh"):
        spec = importlib.util.find_spec(mod)
        report[mod] = None
        if spec is not None:
            try:  # standard output is the event stream: what an import prints (cv2 without numpy) goes to stderr
                with contextlib.redirect_stdout(sys.stderr):
                    report[mod] = __import__(mod).__version__
            except Exception as e:  # an installed but broken package is worth reporting, not crashing on
                report[mod] = f"broken: {e}"
    if report.get("cv2") and not str(report["cv2"]).startswith("broken"):
        report["opencv"] = _opencv_report()
    if report.get("torch") and not str(report["torch"]).startswith("broken"):
        import torch

        report["cuda"] = torch.cuda.is_available()
        report["devices"] = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
    try:  # optional (batch --ray, evaluate --ray); its version without importing it (a second)
        report["ray"] = importlib.metadata.version("ray") if importlib.util.find_spec("ray") else None
    except importlib.metadata.PackageNotFoundError:
        report["ray"] = "installed, version unknown"
    needed = ("numpy", "torch", "numba", "OpenEXR", "cv2", "diffusers", "transformers", "safetensors", "av", "trimesh")
    report["missing"] = [m for m in needed if not report.get(m) or str(report[m]).startswith("broken")]
    if report["missing"]:
        from scpainter_blender.core.backend_protocol import install_hint

        report["install"] = install_hint(sys.executable)
    if args.checkpoint and "numpy" in report["missing"]:
        report["checkpoint"] = "not checked: this Python lacks numpy"
    elif args.checkpoint:
        from scpainter_blender.core import errors

        from .model import checkpoint, checkpoint_config

        try:
            checkpoint_config.ScpainterConfig.load(os.path.join(checkpoint.resolve(args.checkpoint), "scpainter.json"))
            report["checkpoint"] = "ok"
        except errors.InputError as e:
            report["checkpoint"] = str(e)
    events.done(command="doctor", report=report)
    return events.EXIT_OK


#: The PyPI distributions that install the module cv2 (more than one installed: they overwrite each other's files).
OPENCV_DISTRIBUTIONS = ("opencv-contrib-python-headless", "opencv-contrib-python", "opencv-python-headless",
                        "opencv-python")


def _opencv_report() -> dict:
    """What ``doctor`` says of OpenCV beside cv2's version: ``distributions`` ({name: version} of those installed;
    requirements.txt pins one, opencv-contrib-python-headless), ``contrib`` (opencv_contrib's modules are there:
    ``cv2.ximgproc``), ``video_io`` (the "Video I/O" section of ``cv2.getBuildInformation()``: {backend: "YES ..." |
    "NO"}, e.g. FFMPEG, GStreamer, v4l/v4l2)."""
    import importlib.metadata

    import cv2

    dists = {}
    for name in OPENCV_DISTRIBUTIONS:
        try:
            dists[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    video_io, inside = {}, False
    for line in cv2.getBuildInformation().splitlines():
        if line.strip() == "Video I/O:":
            inside = True
        elif inside and line.startswith("    ") and not line.startswith("      ") and ":" in line:
            name, value = line.strip().split(":", 1)  # a backend, not one of its libraries (indented deeper)
            video_io[name.strip()] = value.strip()
        elif inside and line.strip() and not line.startswith("    "):
            break  # the next section
    return {"distributions": dists, "contrib": hasattr(cv2, "ximgproc"), "video_io": video_io}


def _device(name: str) -> str:
    """cpu, cuda or auto; CUDA is touched only when asked for (auto or cuda), never at start-up."""
    if name == "cpu":
        return "cpu"
    import torch

    if torch.cuda.is_available():
        return "cuda"
    if name == "cuda":
        from scpainter_blender.core.errors import ArgumentError

        raise ArgumentError("--device", "cuda: torch sees no CUDA GPU on this machine",
                            hint="use --device cpu or auto")
    return "cpu"


def _cmd_render(args) -> int:
    import time

    from scpainter_blender.core import job_inputs, locking, outputs
    from scpainter_blender.core import job as job_mod

    from .render import command

    roots = outputs.data_roots_option(args.data_root)
    job = job_mod.load(args.job)
    if args.check:  # (render_job checks the same before it writes anything)
        paths = job_inputs.check_inputs(args.job, job, args.allow_outside, roots)
        outputs.check_output(paths["output_dir"], args.allow_outside)
        command.warn_inputs(job, paths)
        events.done(command="render", check=True, frames=len(job.frames), output_dir=paths["output_dir"],
                    locked_by=locking.lock_owner(paths["output_dir"]))
        return events.EXIT_OK
    device = _device(args.device)
    t0 = time.perf_counter()
    with events.stop_on_sigterm() as stop:
        result = command.render_job(args.job, job, device, force=args.force, point_radius=args.point_radius,
                                    stop=stop, allow_outside=args.allow_outside, half=args.half_float,
                                    data_roots=roots)
    if result["stopped"]:
        events.error(f"stopped by SIGTERM after {result['rendered'] + result['skipped']} of {result['frames']} "
                     "frames", hint="finished frames are kept: run the same command again to resume")
        return events.EXIT_FAILED
    result.pop("stopped")
    events.done(command="render", device=device, seconds=time.perf_counter() - t0, **result)
    return events.EXIT_OK


def _cmd_export(args) -> int:
    import time

    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core import outputs

    from .export import command

    roots = outputs.data_roots_option(args.data_root)
    if args.out is not None and not args.out.strip():
        from scpainter_blender.core.errors import ArgumentError

        raise ArgumentError("--out", "is empty", hint="give a folder, or leave --out out for export/<format>/")
    job = job_mod.load(args.job)
    device = _device(args.device)
    t0 = time.perf_counter()
    with events.stop_on_sigterm() as stop:
        result = command.export_job(args.job, job, args.format, args.out, device, args.allow_outside, stop, roots)
    if result.pop("stopped"):
        events.error("stopped by SIGTERM while rendering the missing frames: nothing exported",
                     hint="finished frames are kept: run the same command again to resume")
        return events.EXIT_FAILED
    events.done(command="export", device=device, seconds=time.perf_counter() - t0, **result)
    return events.EXIT_OK


def _cmd_generate(args) -> int:
    import time

    from scpainter_blender.core import locking, outputs
    from scpainter_blender.core import job as job_mod

    from .generate import command as generate

    roots = outputs.data_roots_option(args.data_root)
    job = job_mod.load(args.job)
    overrides = {"steps": args.steps, "seed": args.seed, "model": args.model, "inpaint": args.inpaint,
                 "inpaint_radius": args.inpaint_radius}
    # everything is checked before anything is rendered or loaded: the job, the overrides, the checkpoint (its
    # config and that it holds only safetensors), the settings they make together, and the input files
    plan = generate.prepare(args.job, job, args.checkpoint, overrides, args.allow_outside, roots)
    # the model's settings mean nothing to the baseline: said, rather than silently dropped
    ignored = [o for o, v in (("--checkpoint", args.checkpoint), ("--steps", args.steps), ("--seed", args.seed),
                              ("--precision", args.precision != "auto" or None)) if v is not None]
    ignored = ignored if plan.model == "baseline" else []
    if ignored:
        events.log(f"generate: the baseline ignores {', '.join(ignored)} (model settings; the baseline is OpenCV "
                   "inpainting)")
    if args.check:
        from .render import command as render_command

        render_command.warn_inputs(job, plan.paths)
        events.done(command="generate", check=True, frames=len(job.frames), model=plan.model, ignored=ignored,
                    description=plan.description(), checkpoint=plan.checkpoint, settings=plan.settings,
                    output_dir=plan.output_dir, locked_by=locking.lock_owner(plan.output_dir))
        return events.EXIT_OK
    device = _device(args.device)
    t0 = time.perf_counter()
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
    events.done(command="generate", device=device, seconds=time.perf_counter() - t0, ignored=ignored, **result)
    return events.EXIT_OK


def _cmd_init_checkpoint(args) -> int:
    from .model import checkpoint_init

    out = checkpoint_init.init_checkpoint(args.svd, args.out, log=events.log)
    events.done(command="init-checkpoint", checkpoint=out)
    return events.EXIT_OK


def _cmd_batch(args) -> int:
    from scpainter_blender.core import batch_items as batch_mod
    from scpainter_blender.core import outputs
    from scpainter_blender.core.errors import ArgumentError

    from .batch import command as batch

    # checked before a cluster is started or joined; given without --ray they are refused, not ignored
    args.retries, args.cpus_per_job = batch_mod.ray_options(args.ray, args.retries, args.cpus_per_job)
    if args.checkpoint and args.command_name == "generate":  # once, before any job (not a failure per job)
        from .model import checkpoint as ckpt_mod

        ckpt_mod.resolve(args.checkpoint)
    roots = outputs.data_roots_option(args.data_root)
    listed = [batch_mod.read_job_list(f) for f in args.list or []]
    trusted = [p for f in args.trusted_list or [] for p in batch_mod.read_job_list(f).paths]
    items = list(args.jobs) + [p for jobs in listed for p in jobs.paths] + trusted
    # --allow-outside: every job; --trusted-list: its own jobs (a tool's exports), as they are written in the list
    allow_outside = True if args.allow_outside else frozenset(trusted)
    # --data-root: every job; a list's data-root: lines, that list's jobs
    data_roots = batch.job_data_roots(args.jobs, listed, roots)
    overrides = {"inpaint": args.inpaint} if args.inpaint else None
    if overrides and args.command_name != "generate":
        raise ArgumentError("--inpaint", "applies to --command generate only")
    if not items:
        given = list(args.list or []) + list(args.trusted_list or [])
        from scpainter_blender.core.output_layout import VariationLayout

        raise ArgumentError("jobs", "no jobs given" + (f": {', '.join(given)} list no jobs" if given else ""),
                            hint=f"a vary run lists only its placed variants (its {VariationLayout.MANIFEST} says "
                                 "why none was)" if given else "give job.json paths, or --list FILE")
    if args.half_float and args.command_name != "render":
        raise ArgumentError("--half-float", "applies to --command render only",
                            hint="render the conditions with batch --command render --half-float first; generate "
                                 "keeps the precision of the conditions it finds")
    shard = batch_mod.shard_option(args.shard, args.ray)  # checked before any job
    if args.ray is not None:  # Ray schedules the jobs (backend/batch/ray_pool.py); this process is the driver
        from .batch import ray_pool as batch_ray

        events.reserve_stdout()  # Ray's driver prints its workers' errors to sys.stdout
        # Ctrl-C too: jobs on other machines are cancelled and the summary still says what ran (a second one aborts)
        with events.stop_on_sigterm(sigint=True) as stop:
            batch_ray.connect(args.ray, stop)  # keeps our handler (ray.init installs its own); SIGTERM in it: stop
            # the checkpoint absolute: a worker's working directory is not this process's
            checkpoint = os.path.abspath(args.checkpoint) if args.checkpoint else None
            results = batch_ray.run_ray_batch(items, args.command_name, args.device, checkpoint,
                                              allow_outside=allow_outside, half=args.half_float,
                                              address=args.ray, retries=args.retries,
                                              cpus_per_job=args.cpus_per_job, stop=stop, overrides=overrides,
                                              data_roots=data_roots)
        reports = True
    else:
        results, reports = batch.run_batch(items, args.command_name, _device(args.device), args.checkpoint,
                                           allow_outside=allow_outside, half=args.half_float, overrides=overrides,
                                           shard_of=shard, data_roots=data_roots)
    summary = batch_mod.summary(results)
    if reports:  # in every ending (SIGTERM, Ctrl-C too): ok, failed, stopped and not_run apart (BATCH_SUMMARY_FIELDS)
        events.done(command="batch", **summary, items=results)
    return events.EXIT_OK if summary["ok"] == summary["jobs"] else events.EXIT_FAILED


def _cmd_train(args) -> int:
    from .train import config as train_config
    from .train import trainer

    cfg = train_config.load(args.config)
    device = _device(args.device)
    with events.stop_on_sigterm() as stop:
        result = trainer.train(cfg, device, stop, args.max_steps)
    result.pop("losses", None)
    if result.pop("stopped"):
        events.error(f"stopped by SIGTERM at step {result['step']}; checkpoint saved at {result['checkpoint']}",
                     hint="run the same command again to resume")
        return events.EXIT_FAILED
    from scpainter_blender.core.batch_items import ranks_from_env

    if ranks_from_env()[0] == 0:  # under torchrun / accelerate launch: one done event, from rank 0
        events.done(command="train", device=device, **result)
    return events.EXIT_OK


def _cmd_evaluate(args) -> int:
    from .evaluate import protocol

    from scpainter_blender.core.batch_items import ray_options

    args.retries, args.cpus_per_job = ray_options(args.ray, args.retries, args.cpus_per_job)
    settings, pool = protocol.EvalSettings.from_args(args), protocol.RayPool.from_args(args)
    if pool is not None:  # the tasks' jobs run on a Ray cluster (backend/batch/ray_pool.py); the metrics here
        from .batch import ray_pool as batch_ray

        events.reserve_stdout()  # Ray's driver prints its workers' errors to sys.stdout
    # with --ray, --device names the workers' device (run_ray_batch checks it against the cluster); this process
    # computes the metrics on its own GPU if it has one, so a CPU head node may drive GPU workers
    device = _device(args.device if pool is None or args.device == "cpu" else "auto")
    with events.stop_on_sigterm(sigint=pool is not None) as stop:
        if pool is not None:
            batch_ray.connect(pool.address, stop)  # keeps our handler (ray.init installs its own)
        result = protocol.evaluate(settings, device, stop, pool=pool)
    if result.pop("stopped", False):
        events.error("stopped by SIGTERM", hint="finished renders and videos are kept: run again to resume")
        return events.EXIT_FAILED
    events.done(command="evaluate", **result)
    return events.EXIT_OK


def _cmd_serve(args) -> int:
    from . import serve

    return serve.serve(args.idle_timeout, _device(args.device))


def _cmd_mesh_asset(args) -> int:
    from .mesh import asset as mesh_asset

    result = mesh_asset.convert(args.mesh, args.out, count=args.count, up=args.up, seed=args.seed,
                                progress=events.progress)
    events.artifact(result["ply"], kind="gaussians")
    events.done(command="mesh-asset", result=result)
    return events.EXIT_OK


def _cmd_splat_asset(args) -> int:
    from . import splat_asset

    result = splat_asset.convert(args.splats, args.out)
    events.artifact(result["ply"], kind="gaussians")
    events.done(command="splat-asset", result=result)
    return events.EXIT_OK


def _cmd_vary(args) -> int:
    from .vary import command

    fields, code = command.vary(args)
    events.done(command="vary", **fields)
    return code


def _cmd_contact_sheet(args) -> int:
    from .vary import sheet

    result = sheet.contact_sheet(args.folder, args.out)
    events.artifact(result["path"], kind="contact_sheet")
    events.done(command="contact-sheet", **result)
    return events.EXIT_OK


ALLOW_OUTSIDE_HELP = ("let the job's paths (output_dir, predictions, assets, checkpoint) lead anywhere; without it "
                      "they must stay inside the job file's folder or a --data-root (a job from someone else then "
                      "cannot read or write elsewhere)")
DATA_ROOT_HELP = ("a trusted folder (repeatable) the job's paths (output_dir, predictions, assets, checkpoint) may "
                  "lead into besides the job file's folder, e.g. the recording and asset library many variant "
                  "jobs share; symbolic links and .. are followed, so nothing outside it or the job's folder is "
                  "reached")
HALF_FLOAT_HELP = ("store the image I and the masks M, M_a of the condition EXRs as half floats (Z stays float32): "
                   "files ~40%% smaller than the lossless float32 default, error <= 2.4e-4; a change re-renders "
                   "finished frames")


def _bounded_int(lo: int, hi: int):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], got {value}")
        return value
    return parse


def _non_negative(text):
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value


def _confinement_options(p) -> None:
    """``--allow-outside`` and ``--data-root`` (render, generate, export, batch): where a job's paths may lead
    (``job_inputs.job_paths``)."""
    from scpainter_blender.core import outputs

    p.add_argument(outputs.ALLOW_OUTSIDE_OPTION, action="store_true", help=ALLOW_OUTSIDE_HELP)
    p.add_argument(outputs.DATA_ROOT_OPTION, action="append", metavar="DIR", help=DATA_ROOT_HELP)


def _input_options(p) -> None:
    _confinement_options(p)
    p.add_argument("--check", action="store_true",
                   help="validate and stop, rendering and loading nothing: the job, its paths, its input files "
                        "from their headers (data corruption shows only when read), the output folder"
                        + (" and the checkpoint" if p.prog.endswith("generate") else ""))


def _ray_options(p, what: str) -> None:
    """``--ray [ADDRESS]``, ``--retries`` and ``--cpus-per-job``, the same for ``batch`` and ``evaluate``
    (``backend/batch/ray_pool.py``); ``what``: what runs on the cluster."""
    from scpainter_blender.core.batch_items import DEFAULT_CPUS_PER_JOB, DEFAULT_RETRIES, MAX_RETRIES

    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help=f"run {what} on a Ray cluster (one task per job: one GPU each, or --cpus-per-job CPUs on "
                        "a cluster without GPUs; retried when a worker dies): the cluster at ADDRESS (HOST:PORT of "
                        "its head), else RAY_ADDRESS or the one `ray start` started here, else a new local one; "
                        "files on a shared file system (README)")
    p.add_argument("--retries", type=_bounded_int(0, MAX_RETRIES), default=None,
                   help="--ray: run a job again at most this often when its worker dies or it fails unexpectedly "
                        f"(bad input is never retried; default {DEFAULT_RETRIES})")
    p.add_argument("--cpus-per-job", type=float, default=None,
                   help=f"--ray on a cluster without GPUs: CPUs each job asks for (default {DEFAULT_CPUS_PER_JOB:g})")


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        """argparse's usage and message on standard error, as always, and the error event a pipeline reads on
        standard output (file "(command line)", field the argument: ``ArgumentError.from_argparse``); exit 2."""
        from scpainter_blender.core.errors import ArgumentError

        e = ArgumentError.from_argparse(message, self.prog)
        self.print_usage(sys.stderr)
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        events.error(str(e), hint=e.hint, file=e.path, field=e.field)
        sys.exit(events.EXIT_BAD_INPUT)


#: The command pyproject.toml installs (``[project.scripts]``): the same ``main`` as ``python -m backend``.
CONSOLE_COMMAND = "scpainter-backend"


def _doctor_command(sub) -> None:
    """``doctor``'s sub-command: stdlib only, so it parses in an interpreter that lacks numpy (``main``)."""
    d = sub.add_parser("doctor", help="report the Python, packages and devices the backend would use")
    d.add_argument("--checkpoint", help="also check this SCPainter checkpoint folder")
    d.set_defaults(func=_cmd_doctor)


def _doctor_parser() -> argparse.ArgumentParser:
    """A parser of ``doctor`` alone, built from the standard library: what ``main`` uses for it."""
    p = _Parser(prog="python -m backend")
    _doctor_command(p.add_subparsers(dest="command", required=True))
    return p


def build_parser() -> argparse.ArgumentParser:
    # numpy only: no torch or CUDA at start-up
    from scpainter_blender.core.backend_protocol import DEFAULT_DEVICE, DEVICE_NAMES, EXPORT_FORMAT_NAMES, SERVE
    from scpainter_blender.core.job import BASELINE_DEFAULTS, GENERATE_DEFAULTS, GENERATE_MODELS, INPAINT_METHODS

    # the console command (pyproject.toml) names itself in usage and hints; `python -m backend` otherwise
    command = os.path.basename(sys.argv[0]) if sys.argv else ""
    p = _Parser(prog=CONSOLE_COMMAND if command == CONSOLE_COMMAND else "python -m backend", description=(
        "SCPainter's backend: render a job's condition layers, generate its video (the SCPainter model, or the "
        "inpainting baseline without a checkpoint), run many jobs, train and evaluate. Standard output carries one "
        f"JSON event per line; exit codes: {events.EXIT_OK} done, {events.EXIT_FAILED} failed, "
        f"{events.EXIT_BAD_INPUT} bad input, {events.EXIT_INTERRUPTED} interrupted."))
    sub = p.add_subparsers(dest="command", required=True)
    _doctor_command(sub)
    r = sub.add_parser("render", help="render a job's condition layers (EXR + PNG previews) frame by frame")
    r.add_argument("job", help="job.json (the job contract: docs/design.md)")
    r.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE,
                   help="auto: CUDA when torch sees a GPU, else the CPU")
    r.add_argument("--force", action="store_true", help="render frames that are already finished again")
    r.add_argument("--point-radius", type=_bounded_int(0, 16), default=0,
                   help="splat each point over (2r+1)^2 pixels (0-16)")
    r.add_argument("--half-float", action="store_true", help=HALF_FLOAT_HELP)
    _input_options(r)
    r.set_defaults(func=_cmd_render)
    n = sub.add_parser("generate", help="render missing conditions, then generate the video: with a checkpoint "
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
    n.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE,
                   help="auto: CUDA when torch sees a GPU, else the CPU")
    n.add_argument("--precision", choices=["auto", "fp32", "bf16", "fp16"], default="auto",
                   help="UNet/CLIP dtype (auto: bf16 on CUDA, fp32 on CPU); latents stay float32")
    n.add_argument("--steps", type=int,
                   help=f"sampler steps (default: the job's, else {GENERATE_DEFAULTS['steps']})")
    n.add_argument("--seed", type=int, help=f"seed (default: the job's, else {GENERATE_DEFAULTS['seed']})")
    n.add_argument("--force", action="store_true", help="generate again even if the video is up to date")
    _input_options(n)
    n.set_defaults(func=_cmd_generate)
    x = sub.add_parser("export", help="a job's labels as a training dataset (KITTI, COCO or OpenLABEL), rendering "
                                      "missing frames first; images: the generated frames, else the condition "
                                      "previews")
    x.add_argument("job", help="job.json (the job contract: docs/design.md)")
    x.add_argument("--format", required=True, choices=EXPORT_FORMAT_NAMES,
                   help="kitti (image_2, label_2, calib), coco (annotations.json with RLE masks) or openlabel "
                        "(ASAM OpenLABEL 1.0 JSON): docs/design.md §15")
    x.add_argument("--out", help="destination folder, written whole (default: <output_dir>/export/<format>); an "
                                 "existing one must be empty or a previous export")
    x.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE,
                   help="for rendering missing frames; auto: CUDA when torch sees a GPU, else the CPU")
    _confinement_options(x)
    x.set_defaults(func=_cmd_export)
    b = sub.add_parser("batch", help="run render or generate over many jobs; sharded under torchrun/accelerate")
    b.add_argument("jobs", nargs="*", help="job.json files")
    b.add_argument("--list", action="append", help="a text file of job paths, one per line, relative ones taken "
                                                   "from the list file's folder (repeatable); before the first "
                                                   "path it may declare 'data-root: DIR' lines, a --data-root for "
                                                   "its own jobs")
    b.add_argument("--command", dest="command_name", choices=["render", "generate"], default="render",
                   help="what each job runs (default render)")
    b.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE,
                   help="each job's device (default auto: CUDA when there is one); with --ray, the workers'")
    b.add_argument("--checkpoint", help="checkpoint for generate (default: each job's generate.checkpoint)")
    _confinement_options(b)
    b.add_argument("--trusted-list", action="append", metavar="FILE",
                   help="like --list, and these jobs may lead outside their folder (--allow-outside for them only): "
                        "jobs a tool wrote itself, such as blender -c scpainter batch's exports of .blend files")
    b.add_argument("--inpaint", choices=INPAINT_METHODS,
                   help="--command generate: the baseline's OpenCV method for every job made without a checkpoint "
                        "(default: each job's)")
    b.add_argument("--half-float", action="store_true", help=HALF_FLOAT_HELP + " (--command render)")
    b.add_argument("--shard", help="K/N: run every N-th job starting at K in this process alone, reporting only "
                                   "those (default: RANK/WORLD_SIZE of torchrun / accelerate, the ranks gathering "
                                   "one summary); 0/1 runs every job here whatever the environment says")
    _ray_options(b, "the jobs")
    b.set_defaults(func=_cmd_batch)
    c = sub.add_parser("init-checkpoint", help="make an SCPainter checkpoint folder from a stock SVD snapshot")
    c.add_argument("--svd", required=True, help="local stable-video-diffusion-img2vid(-xt) diffusers folder")
    c.add_argument("--out", required=True, help="new checkpoint folder")
    c.set_defaults(func=_cmd_init_checkpoint)
    t = sub.add_parser("train", help="fine-tune a checkpoint on clip folders (run under accelerate launch/torchrun "
                                     "for several GPUs); resumes from the newest checkpoint in output_dir")
    t.add_argument("config", help="training config JSON (schema scpainter.train/1, docs/training.md)")
    t.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE)
    t.add_argument("--max-steps", type=int, help="stop (with a checkpoint) after this step this time")
    t.set_defaults(func=_cmd_train)
    e = sub.add_parser("evaluate", help="FID / FID-C / KID on validation clips and ground-truth PSNR/SSIM")
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
    e.add_argument("--precision", choices=["auto", "fp32", "bf16", "fp16"])
    e.add_argument("--inpaint", choices=INPAINT_METHODS,
                   help=f"the inpainting baseline's OpenCV method (default {BASELINE_DEFAULTS['inpaint']})")
    e.add_argument("--inception", help="FID Inception weights (pytorch-fid's pt_inception-2015-12-05-6726825d.pth "
                                       "or a safetensors copy); without it FID/KID are skipped")
    e.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE,
                   help="auto: CUDA when torch sees a GPU, else the CPU; with --ray the workers' (cuda when the "
                        "cluster has GPUs), while the metrics use this machine's GPU if it has one")
    _ray_options(e, "the tasks' render/generate jobs (then the metrics here)")
    e.set_defaults(func=_cmd_evaluate)
    m = sub.add_parser("mesh-asset", help="a car mesh (GLB, glTF, OBJ, PLY, STL, OFF) as flat surface Gaussians "
                                          "(an INRIA-layout PLY, Z up, the mesh's units)")
    m.add_argument("mesh", help="mesh file; glTF/GLB/OBJ are read Y up, PLY/STL/OFF Z up (see --up)")
    m.add_argument("--out", required=True, help="Gaussian PLY to write (atomically)")
    m.add_argument("--count", type=int, default=200_000, help="number of Gaussians (default 200000)")
    m.add_argument("--up", choices=["auto", "y", "z"], default="auto", help="the file's up axis (default: by format)")
    m.add_argument("--seed", type=int, default=0)
    m.set_defaults(func=_cmd_mesh_asset)
    a = sub.add_parser("splat-asset", help="any Gaussian file the import reads (INRIA/TRELLIS PLY, SuperSplat "
                                           "compressed PLY, .splat, SOG) as an INRIA-layout PLY, values as read "
                                           "(what the import runs for formats Blender's Python cannot decode)")
    a.add_argument("splats", help="Gaussian file: a .sog bundle, a SOG's meta.json, or any other accepted file")
    a.add_argument("--out", required=True, help="Gaussian PLY to write (atomically)")
    a.set_defaults(func=_cmd_splat_asset)
    w = sub.add_parser(SERVE, help="a warm backend: run render/generate/export requests read from standard input "
                                   "(one JSON object per line) one after another in this process, keeping the "
                                   "renderer's kernels, points and assets loaded (what the add-on starts once per "
                                   "Blender session; docs/design.md §12)")
    w.add_argument("--idle-timeout", type=_non_negative, default=600.0, metavar="S",
                   help="end after S seconds without a request (0: never; default 600); it also ends when standard "
                        "input ends, on a quit request and on SIGTERM")
    w.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE,
                   help="whose kernels to load (or compile) at the start; each request names its own")
    w.set_defaults(func=_cmd_serve)
    v = sub.add_parser("vary", help="variants of a job (camera shifts, lane changes, cars from a library placed on "
                                    "the road), written as job folders with a batch list and a manifest")
    v.add_argument("job", help="the base job (job.json), e.g. as Blender exports it")
    from scpainter_blender.core.variation import spec as variation_spec  # (numpy only: the parser stays light)

    variation_spec.add_arguments(v)
    v.set_defaults(func=_cmd_vary)
    from scpainter_blender.core.output_layout import VariationLayout

    s = sub.add_parser("contact-sheet", help="the first frame of every variant of a vary folder in one picture")
    s.add_argument("folder", help="the folder vary wrote")
    s.add_argument("--out", help=f"PNG to write (default: {VariationLayout.SHEET} in the folder)")
    s.set_defaults(func=_cmd_contact_sheet)
    return p


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    # doctor first imports nothing but the standard library: it reports what this Python lacks instead of failing
    # on it; every other command needs numpy to parse its arguments, and says what to install when it is missing
    try:  # argparse errors: usage on standard error, an error event, exit 2
        args = (_doctor_parser() if argv[:1] == ["doctor"] else build_parser()).parse_args(argv)
    except ModuleNotFoundError as e:
        from scpainter_blender.core.backend_protocol import install_hint

        events.error(f"this Python ({sys.executable}) lacks the package {e.name!r} the backend needs",
                     hint=install_hint(sys.executable), file="(environment)", field=e.name)
        return events.EXIT_BAD_INPUT
    from scpainter_blender.core.errors import InputError  # (stdlib only, as is CleanFailure's module)

    from .errors import CleanFailure

    try:
        with events.log_scope():  # a bug's traceback goes to the log the command had open (backend.log)
            return args.func(args)
    except InputError as e:  # bad input, and only that: the message names the file and field
        events.error(str(e), hint=e.hint or "check the input file and arguments", file=e.path, field=e.field)
        return events.EXIT_BAD_INPUT
    except CleanFailure as e:  # explained by the command itself: no traceback
        events.error(str(e), hint=e.hint, **e.fields)
        return events.EXIT_FAILED
    except KeyboardInterrupt:  # Ctrl-C (for batch and evaluate --ray the second one: the first stops)
        events.error("interrupted (Ctrl-C)", hint="finished frames and checkpoints are kept (each written whole); run "
                                                  "the same command again to resume")
        return events.EXIT_INTERRUPTED
    except Exception as e:  # a bug (a plain ValueError included): the whole traceback, never "bad input"
        log = events.report_bug(e, f"{args.command} failed")
        where = f"{log} and standard error" if log else "standard error"
        events.error(f"{type(e).__name__}: {e}", hint=f"an internal error in SCPainter, not a problem with the "
                                                      f"input: the traceback is in {where}; please report it",
                     log=log)
        return events.EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
