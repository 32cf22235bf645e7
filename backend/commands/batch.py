"""``python -m backend batch``: run render or generate over many jobs (``backend/batch/command.py``): sharded under
torchrun / accelerate (``--shard`` or the ranks of the environment), or on a Ray cluster with ``--ray``
(``backend/batch/ray_pool.py``; this process is then the driver). docs/design.md §12.

Every option is checked before a cluster is started or joined and before any job runs; a failed job is recorded
in the summary (the ``done`` event, in every ending) and the batch goes on. Exit 0 only when every job succeeded.
"""

from __future__ import annotations

import argparse
import os

from .. import events
from . import export as export_cmd, options

NAME = "batch"
ORDER = 50


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``batch``'s parser."""
    from scpainter_blender.core import backend_protocol as protocol
    from scpainter_blender.core.job import INPAINT_METHODS

    b = sub.add_parser(NAME, help="run render or generate over many jobs; sharded under torchrun/accelerate; export: "
                                  "one dataset of them all")
    b.add_argument("jobs", nargs="*", help="job.json files")
    b.add_argument("--list", action="append", help="a text file of job paths, one per line, relative ones taken "
                                                   "from the list file's folder (repeatable); before the first "
                                                   "path it may declare 'data-root: DIR' lines, a --data-root for "
                                                   "its own jobs")
    b.add_argument("--command", dest="command_name", choices=["render", "generate", "export"], default="render",
                   help="what each job runs (default render); export: every job into one dataset, in this process "
                        "(--format, --out, --split as export's)")
    options.device_option(b, "each job's device (default auto: CUDA when there is one); with --ray, the workers'")
    b.add_argument("--checkpoint", help="checkpoint for generate (default: each job's generate.checkpoint)")
    options.confinement_options(b)
    options.proposals_option(b)
    b.add_argument("--trusted-list", action="append", metavar="FILE",
                   help="like --list, and these jobs may lead outside their folder (--allow-outside for them only): "
                        "jobs a tool wrote itself, such as blender -c scpainter batch's exports of .blend files")
    b.add_argument("--inpaint", choices=INPAINT_METHODS,
                   help="--command generate: the baseline's OpenCV method for every job made without a checkpoint "
                        "(default: each job's)")
    b.add_argument("--half-float", action="store_true", help=options.HALF_FLOAT_HELP + " (--command render)")
    b.add_argument("--format", choices=export_cmd.FORMAT_CHOICES,
                   help="--command export: the formats, separated by commas "
                        f"({', '.join(protocol.EXPORT_FORMATS)})")
    b.add_argument("--out", help="--command export: the dataset's folder, written whole (new, empty or a previous "
                                 "dataset)")
    export_cmd.dataset_options(b, " (--command export)")
    export_cmd.nuscenes_options(b, ", --command export")
    b.add_argument("--shard", help="K/N: run every N-th job starting at K in this process alone, reporting only "
                                   "those (default: RANK/WORLD_SIZE of torchrun / accelerate, the ranks gathering "
                                   "one summary); 0/1 runs every job here whatever the environment says")
    options.ray_options(b, "the jobs")
    b.set_defaults(func=run)
    return b


def run(args: argparse.Namespace) -> int:
    """Check the options, run the jobs (here, sharded, or on Ray) and report the summary; exit 0 when every job
    succeeded, else 1."""
    from scpainter_blender.core import batch_items as batch_mod
    from scpainter_blender.core import outputs
    from scpainter_blender.core.errors import ArgumentError

    from ..batch import command as batch

    # checked before a cluster is started or joined; given without --ray they are refused, not ignored
    args.retries, args.cpus_per_job = batch_mod.ray_options(args.ray, args.retries, args.cpus_per_job)
    if args.checkpoint and args.command_name == "generate":  # once, before any job (not a failure per job)
        from ..model import checkpoint as ckpt_mod

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
    if args.command_name == "export":  # one dataset from every job: one process writes it (export's own form)
        return _export(args, items, allow_outside, data_roots)
    for option, value in (("--format", args.format), ("--out", args.out), ("--split", args.split),
                          ("--version", args.version), ("--keyframe-hz", args.keyframe_hz)):
        if value is not None:
            raise ArgumentError(option, "applies to --command export only")
    shard = batch_mod.shard_option(args.shard, args.ray)  # checked before any job
    if args.ray is not None:  # Ray schedules the jobs (backend/batch/ray_pool.py); this process is the driver
        from ..batch import ray_pool as batch_ray

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
                                              data_roots=data_roots, proposals=args.proposals)
        reports = True
    else:
        results, reports = batch.run_batch(items, args.command_name, options.resolve_device(args.device),
                                           args.checkpoint, allow_outside=allow_outside, half=args.half_float,
                                           overrides=overrides, shard_of=shard, data_roots=data_roots,
                                           proposals=args.proposals)
    summary = batch_mod.summary(results)
    if reports:  # in every ending (SIGTERM, Ctrl-C too): ok, failed, stopped and not_run apart (BATCH_SUMMARY_FIELDS)
        events.done(command=NAME, **summary, items=results)
    return events.EXIT_OK if summary["ok"] == summary["jobs"] else events.EXIT_FAILED


def _export(args: argparse.Namespace, items: list, allow_outside: bool | frozenset, data_roots: dict) -> int:
    """``batch --command export``: the jobs as one dataset (``export.run_dataset``); the options that spread jobs
    over processes or machines are refused (one process writes one dataset)."""
    from scpainter_blender.core import batch_items as batch_mod
    from scpainter_blender.core.errors import ArgumentError

    from ..export import dataset

    for option, given in (("--ray", args.ray is not None), ("--shard", bool(args.shard)),
                          ("--checkpoint", bool(args.checkpoint)), ("--half-float", args.half_float)):
        if given:
            raise ArgumentError(option, "not with --command export: one process writes the whole dataset")
    if batch_mod.ranks_from_env()[1] > 1:
        raise ArgumentError("--command", "export under torchrun/accelerate (WORLD_SIZE > 1): one process writes "
                                         "the whole dataset", hint="run it as one process")
    if args.format is None:
        raise ArgumentError("--format", "--command export needs --format (e.g. coco,kitti,openlabel)")
    return export_cmd.run_dataset(items, dataset.parse_formats(args.format), args.out,
                                  dataset.parse_split(args.split), args.device, allow_outside, data_roots,
                                  command_name=NAME, proposals=args.proposals,
                                  fmt_options=export_cmd.format_options(args))
