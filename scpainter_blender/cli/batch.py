"""``blender -c scpainter batch``: render or generate many .blend / job files. It takes its share of the items
(``--shard K/N``, or torchrun's RANK/WORLD_SIZE: every N-th item from K), exports every .blend's job into the output
folder its scene camera names (as ``render`` does), then runs all the jobs (job files as given) as the backend's one
``python -m backend batch``, here or with ``--ray`` on a Ray cluster (backend/batch/ray_pool.py; each item then has
its ``worker`` and ``attempts``): it goes on past failures, prints one summary with each item's status, time and
outputs, and exits 1 if any failed."""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import tempfile
import time

import bpy

from ..runs import client
from ..core import backend_protocol as protocol
from ..core import batch_items as batch_mod
from ..core import errors, outputs
from ..core.output_layout import OutputLayout
from ..runs import camera_run
from ..scene import props
from . import common

NAME = "batch"
ORDER = 40


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``batch ITEMS...``, ``--list``, ``--command``, the share (``--shard``), the paths trusted, Ray's options,
    the common options, ``--checkpoint``, ``--inpaint``."""
    c = sub.add_parser(NAME, help="render or generate many .blend / job files")
    c.add_argument("items", nargs="*", help=".blend or job.json files")
    c.add_argument("--list", action="append", help="a text file of paths, one per line (repeatable)")
    c.add_argument("--command", dest="what", choices=["render", "generate"], default="render")
    c.add_argument("--shard", help="K/N: run every N-th item starting at K (default: RANK/WORLD_SIZE)")
    c.add_argument("--allow-outside", action="store_true",
                   help="let job.json items' paths lead outside their folder (.blend items always may: "
                        "their output folder is the one the scene names)")
    c.add_argument(outputs.DATA_ROOT_OPTION, action="append", metavar="DIR",
                   help="a trusted folder (repeatable) job.json items' paths may lead into besides their "
                        "own folder, e.g. a recording and asset library shared by many jobs")
    c.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="export every .blend's job, then run all jobs as one Ray batch (python -m backend "
                        "batch --ray: one task per job, retried when a worker dies): the cluster at ADDRESS, "
                        "else RAY_ADDRESS or the one `ray start` started here, else a new local one; files "
                        "on a shared file system (README)")
    c.add_argument("--retries", type=int, default=None,
                   help="--ray: run a job again at most this often when its worker dies (default "
                        f"{batch_mod.DEFAULT_RETRIES}, at most {batch_mod.MAX_RETRIES})")
    c.add_argument("--cpus-per-job", type=float, default=None,
                   help="--ray on a cluster without GPUs: CPUs each job asks for (default "
                        f"{batch_mod.DEFAULT_CPUS_PER_JOB:g})")
    common.common_options(c)
    common.checkpoint_option(c)
    common.inpaint_option(c)
    c.set_defaults(func=run)
    return c


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """This process's share of the items (``--shard K/N``, else torchrun's RANK / WORLD_SIZE; with ``--ray`` every
    item), every .blend's job exported into the output folder its scene names (as ``render`` does), then all the
    jobs run as one ``python -m backend batch`` (``_run_jobs``), its results mapped back to the items in order. An
    item whose scene cannot make a job fails here and is not sent; two scenes naming the same output folder are
    refused (their jobs would be the same file). The summary (counts, each item's result) and exit code 0, 1 when
    an item failed."""
    common.check_paths(args)
    # checked before any scene is exported; given without --ray they are refused, not ignored
    args.retries, args.cpus_per_job = batch_mod.ray_options(args.ray, args.retries, args.cpus_per_job)
    shard = batch_mod.shard_option(args.shard, args.ray)
    args.data_root = outputs.data_roots_option(args.data_root)  # checked, absolute; the backend applies them
    listed = [batch_mod.read_job_list(f) for f in args.list or []]
    items = list(args.items) + [p for jl in listed for p in jl.paths]
    # a list's data-root: lines trust those folders for the job files it names (as the backend's batch does)
    roots_of = {}
    for jl in listed:
        for p in jl.paths:
            roots_of[os.path.abspath(p)] = tuple(dict.fromkeys(roots_of.get(os.path.abspath(p), ()) + jl.data_roots))
    if not items:
        raise errors.ArgumentError("items", "no .blend or job files given", hint="give paths, or --list FILE")
    k, n = (0, 1) if args.ray is not None else shard or batch_mod.ranks_from_env()[:2]
    items = batch_mod.shard(items, k, n)   # the others' scenes are not even opened
    t0 = time.perf_counter()
    results, jobs, seen = {}, [], {}   # item index -> failed result; (index, job path, exported); job -> item
    for i, path in enumerate(items):
        t = time.perf_counter()
        try:
            if path.endswith(".json"):  # listed twice: the backend runs it once and gives each item its result
                job_path, exported = os.path.abspath(path), False
            else:
                print(f"scpainter batch: exporting {path}", file=sys.stderr, flush=True)
                common.open_blend(path, args)
                job_path, exported = OutputLayout(props.camera_output_dir(bpy.context.scene)).job, True
                if job_path in seen:  # checked before exporting: the other item's job stays as it is
                    raise errors.InputError(path, "scene.scpainter_output_dir",
                                            f"{os.path.dirname(job_path)} is also the output folder of "
                                            f"{seen[job_path]}", hint="give each scene its own SCPainter output folder")
                camera_run.export(bpy.context, common.checkpoint(args))  # (writes job_path)
                common.export_warnings(bpy.context, path)
            seen.setdefault(job_path, path)
            jobs.append((i, job_path, exported))
        except Exception as e:  # noqa: BLE001  bad input or a bug: recorded; go on with the rest
            results[i] = {"item": path, "status": protocol.ITEM_FAILED, **common.failure(e),
                          "seconds": time.perf_counter() - t}
    if jobs:
        for i, r in zip([i for i, _, _ in jobs], _run_jobs(args, jobs, roots_of)):
            results[i] = {"item": items[i], **r}
    ordered = [results[i] for i in range(len(items))]
    counts = batch_mod.summary(ordered)   # ok, failed, stopped and not_run apart, as the backend's summary
    # the cluster asked for: the address given, else RAY_ADDRESS, else "auto" (`ray start`'s here, or a new one)
    where = ({"ray": args.ray or os.environ.get("RAY_ADDRESS") or "auto"} if args.ray is not None
             else {"shard": f"{k}/{n}"})
    good = counts["ok"] == counts["jobs"]
    return {"what": args.what, **where, **counts, "items": ordered,
            "seconds": time.perf_counter() - t0}, (protocol.EXIT_OK if good else protocol.EXIT_FAILED)


def _run_jobs(args: argparse.Namespace, jobs: list[tuple[int, str, bool]],
              roots_of: dict[str, tuple[str, ...]] | None = None) -> list[dict]:
    """One backend ``batch`` over ``jobs`` ((index, job path, exported here) in order): with ``--ray`` on the
    cluster (backend/batch/ray_pool.py), else here, all of them (``--shard 0/1``: this process's share is already
    taken). Its result per job (status, outputs, ``seconds``; a failure's ``error``, ``hint``, ``file``, ``field``,
    ``log``; on Ray ``worker`` and ``attempts``). BackendError when the batch itself could not run (a bad address,
    no cluster, a bad ``--device``). SIGTERM is passed on to the backend, which stops the jobs not finished and
    still reports. ``roots_of``: the data roots the ``--list`` files declare for the job files they name."""
    ray = args.ray is not None
    generate = args.what == "generate"
    # the jobs exported here from .blend files may lead outside their folder (a job.json item naming one of them is
    # that same file); the other job.json items as given. Each list in the items' order: the backend runs them so
    exported = {p for _, p, e in jobs if e}
    trusted = [p in exported for _, p, _ in jobs]
    # the other job.json items in one list per set of data roots their --list files declared (each list's
    # data-root: lines apply to its own jobs), in the order first met
    roots_of = roots_of or {}
    groups = {}
    for k, ((_, p, _), t) in enumerate(zip(jobs, trusted)):
        if not t:
            groups.setdefault(roots_of.get(p, ()), []).append(k)
    lists = tempfile.mkdtemp(prefix="scpainter-batch-")
    try:
        job_lists = []
        for g, (roots, members) in enumerate(groups.items()):
            job_lists.append(os.path.join(lists, f"jobs{g}.txt"))
            with open(job_lists[-1], "w", encoding="utf-8") as f:
                f.writelines(f"{batch_mod.DATA_ROOT_DIRECTIVE} {r}\n" for r in roots)
                f.writelines(jobs[k][1] + "\n" for k in members)
        with open(os.path.join(lists, "trusted.txt"), "w", encoding="utf-8") as f:
            f.writelines(p + "\n" for (_, p, _), t in zip(jobs, trusted) if t)
        invocation = common.invocation(args, "batch", batch_command=args.what, lists=tuple(job_lists),
                                trusted_lists=(os.path.join(lists, "trusted.txt"),),
                                allow_outside=args.allow_outside, data_roots=args.data_root,
                                checkpoint=common.checkpoint(args) if generate else None,
                                inpaint=args.inpaint if generate else None, shard=None if ray else "0/1",
                                ray=args.ray, retries=args.retries if ray else None,
                                cpus_per_job=args.cpus_per_job if ray else None)
        job = invocation.start()
        # SIGTERM to Blender: the backend's batch stops what is not finished and still sends its summary
        previous = signal.signal(signal.SIGTERM, lambda *_: job.proc.terminate())
        try:
            done = job.wait(timeout=args.timeout or None, on_event=common.progress)
        except client.BackendError:
            if job.done is None:  # no summary: the batch itself failed (its error event is raised)
                raise
            done = job.done       # exit 1: some jobs failed; each says why in the summary
        finally:
            signal.signal(signal.SIGTERM, previous)
    finally:
        shutil.rmtree(lists, ignore_errors=True)
    # the backend's order: the --list files in turn, then --trusted-list
    order = [k for members in groups.values() for k in members] + [k for k, t in enumerate(trusted) if t]
    returned = [None] * len(jobs)
    for k, r in zip(order, done["items"], strict=True):
        returned[k] = r
    out = []
    for r in returned:  # the backend's "job" (and "rank") left out: the caller names the item
        keep = {k: r[k] for k in ("status", "error", "hint", "file", "field", "log", "worker", "attempts", "seconds")
                if k in r}
        if args.what == "render":  # skipped: frames reused, as the render command counts them (known when ok)
            r = {k: v for k, v in r.items() if k != "skipped"}
            if r.get("status") == "ok":
                r["skipped"] = r["frames"] - r["rendered"]
        made = "frames" in r or "video" in r  # ok, or stopped with its finished frames
        out.append({**keep, **(common.run_outputs(r, r.get("output_dir")) if made else {})})
    return out
