"""``python -m backend batch``: many jobs, one summary; sharded across processes under torchrun / accelerate.

    torchrun --standalone --nproc_per_node 4 -m backend batch jobs/*.json --command generate
    accelerate launch --num_processes 4 -m backend batch --list jobs.txt --command render

Each process takes every WORLD_SIZE-th job starting at its RANK (the variables torchrun and accelerate set; one
process without them), on GPU LOCAL_RANK when CUDA is there. Every process first looks at all the items: a job
listed again (a hard or symbolic link, another spelling: ``batch_items.first_items``) goes with its first item and
runs once, its copies repeating its result with ``duplicate_of``; a job naming the output folder of an earlier,
other job is refused before anything runs (``batch_items.shared_output_items``: ``failed``, bad input naming
``output_dir``). A job that fails is recorded and the batch goes on
(``failure``: bad input with its ``file`` and ``field``, a bug with the ``log`` holding its traceback). SIGTERM or
a first Ctrl-C stops the running job after its current frame or sampler step (``stopped``, finished outputs kept);
the jobs after it are ``not run (SIGTERM)``, and the summary is printed as in any other ending (a second Ctrl-C
aborts).
At the end the ranks exchange their results (torch.distributed, gloo: no GPU needed for this) and rank 0 emits one
``done`` event listing every job with its rank, status, time and outputs. Every rank exits 1 if any job failed.
``--shard K/N`` instead: this process runs its share alone (no gathering) and reports it (``blender -c scpainter
batch`` passes 0/1 for the share of scenes it exported).
"""

from __future__ import annotations

import os
import time

from scpainter_blender.core.backend_protocol import ITEM_FAILED as FAILED, ITEM_NOT_RUN as NOT_RUN, \
    ITEM_OK as OK, ITEM_STOPPED as STOPPED
from scpainter_blender.core.batch_items import first_items, job_shard, ranks_from_env, shared_output_items

from .. import events


def run_one(job_path: str, command: str, device: str, checkpoint: str | None, stop, allow_outside: bool = False,
            half: bool = False, precision: str = "auto", overrides: dict | None = None, data_roots=(),
            proposals: str | None = None) -> dict:
    """One job: ``render`` (``half``: half-float EXRs, ``render_cmd.render_job``) or ``generate`` (``precision``
    and ``overrides`` as ``generate_job``'s: the settings a job's ``generate`` block sets, e.g. ``inpaint``). Its
    paths stay in its folder and ``data_roots`` unless ``allow_outside`` (``job_inputs.job_paths``). ``proposals``:
    what its labels make of the objects nothing labels, as ``render``'s ``--proposals`` (None: its default), so a
    batch's labels are a single run's."""
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core.variation import proposals as proposals_core

    from ..render import proposals as render_proposals

    job = job_mod.load(job_path)
    job, _ = render_proposals.apply(job_path, job, proposals or proposals_core.DEFAULT_MODE, allow_outside,
                                    data_roots)
    if command == "render":
        from ..render import command as render_cmd

        r = render_cmd.render_job(job_path, job, device, stop=stop, allow_outside=allow_outside, half=half,
                                  data_roots=data_roots)
        return {"output_dir": r["output_dir"], "frames": r["frames"], "rendered": r["rendered"],
                "skipped": not r["stopped"] and r["rendered"] == 0, "stopped": r["stopped"]}
    from ..generate.command import generate_job

    r = generate_job(job_path, job, device, checkpoint, precision, stop=stop, overrides=overrides,
                     allow_outside=allow_outside, data_roots=data_roots)
    return {"output_dir": r.get("output_dir"), "video": r.get("video"), "frames": r.get("frames"),
            "skipped": bool(r.get("skipped")), "stopped": r["stopped"], "model": r.get("model"),
            "description": r.get("description")}


def allows_outside(allow_outside, path: str) -> bool:
    """Whether the job at ``path`` may lead outside its folder: ``allow_outside`` True (every job, the user said
    ``--allow-outside``) or a collection of paths (those jobs: ``--trusted-list``, the jobs a tool wrote itself)."""
    return allow_outside is True or (not isinstance(allow_outside, bool) and path in allow_outside)


def job_data_roots(jobs: list, lists: list, data_roots: tuple = ()) -> dict:
    """``{job path: its data roots}`` for a batch: ``data_roots`` (``--data-root``) for every job, given as
    ``jobs`` (the command line's) or in ``lists`` (``batch_items.JobList``), plus the ``data-root:`` folders of the
    lists naming it (a job named in several lists: all of theirs), never another list's. Keyed by the path as
    listed, as ``run_batch`` and ``run_ray_batch`` look it up."""
    out = {p: tuple(data_roots) for p in jobs}
    for listed in lists:
        for p in listed.paths:
            out[p] = tuple(dict.fromkeys(out.get(p, tuple(data_roots)) + listed.data_roots))
    return out


def failure(e: Exception, path: str) -> dict:
    """The fields of a failed job's result: ``error`` (the message); for bad input (an ``InputError``) ``file``
    and ``field``; for a failure the job explains (``CleanFailure``) its fields; for anything else (a bug) the
    traceback goes to standard error and the job's ``backend.log``, named by ``log``."""
    from scpainter_blender.core.batch_items import bad_input_fields
    from scpainter_blender.core.errors import InputError

    from ..errors import CleanFailure, explained

    e = explained(e) or e  # a name too long, a full disk
    if isinstance(e, InputError):
        events.log(f"batch: {path}: bad input: {e}")
        return bad_input_fields(e, path)
    if isinstance(e, CleanFailure):
        events.log(f"batch: {path} failed: {e}")
        return {"error": str(e), "hint": e.hint, **e.fields}
    return {"error": f"{type(e).__name__}: {e}", "log": events.report_bug(e, f"batch: {path} failed")}


def gather(results: list, world: int) -> list:
    """All ranks' results on every rank (a no-op for one process)."""
    if world == 1:
        return results
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group("gloo")
    everything = [None] * world
    dist.all_gather_object(everything, results)
    dist.destroy_process_group()
    return [r for part in everything for r in part]


def run_batch(items: list[str], command: str, device: str, checkpoint: str | None = None,
              allow_outside=False, half: bool = False, overrides: dict | None = None,
              shard_of: tuple[int, int] | None = None, data_roots: dict | None = None,
              proposals: str | None = None) -> tuple[list, bool]:
    """Run this process's share; returns (the results, whether this process reports them). ``allow_outside``:
    ``allows_outside``'s; ``data_roots``: ``{job path: its data roots}`` (``job_data_roots``); ``half``: render
    half-float EXRs; ``overrides``: generate settings for every job (``run_one``). ``shard_of``: (K, N) of
    ``--shard``: this process runs its share alone and reports it; None: the share of torchrun's RANK /
    WORLD_SIZE, every rank's results gathered and rank 0 reporting them."""
    if shard_of is not None:
        (rank, world), local = shard_of, 0
    else:
        rank, world, local = ranks_from_env()  # (InputError "(environment)" naming a bad variable)
    gathered = world > 1 and shard_of is None
    for name in ("MASTER_ADDR", "MASTER_PORT") if gathered else ():  # gather() needs them: checked before any job
        if not os.environ.get(name, "").strip():
            from scpainter_blender.core.errors import InputError

            raise InputError("(environment)", name, f"not set, with WORLD_SIZE={world}: the ranks cannot gather "
                                                    "their results", hint="start the processes with torchrun or "
                                                                          "accelerate launch, which set it")
    if device == "cuda":
        import torch

        torch.cuda.set_device(local % torch.cuda.device_count())
    # every rank looks at every item (the same answers everywhere): a job listed again goes with its first item
    # and runs once; a job writing another job's output folder is refused before anything runs
    first = first_items(items)
    refused = shared_output_items(items, first)
    mine = job_shard(first, rank, world)
    events.log(f"batch rank {rank}/{world}: {len(mine)} of {len(items)} jobs on {device}")
    results, result_of = [], {}   # item index -> its result, for the copies that follow it
    # Ctrl-C too (a second one aborts): the running job stops after its current frame or step, the rest are not
    # run, and the summary still says what ran
    # the jobs of this process share what they load (``render.scene_cache``): variants of one recording clean its
    # points once, not once per job; a changed file is read again (its identity is in the key)
    from ..render import scene_cache

    with events.stop_on_sigterm(sigint=True) as stop, scene_cache.shared("batch", "an earlier job of this batch"):
        for n, k in enumerate(mine):
            path = items[k]
            if first[k] != k:  # the same job as an earlier item of this rank: its result, saying which item ran it
                results.append({**result_of[first[k]], "job": path, "duplicate_of": first[k]})
            elif k in refused:
                events.log(f"batch: {path}: bad input: {refused[k]['error']}")
                results.append({"job": path, "rank": rank, "status": FAILED, **refused[k], "seconds": 0.0})
            elif stop:
                results.append({"job": path, "rank": rank, "status": NOT_RUN})
            else:
                t = time.perf_counter()
                try:
                    with events.log_scope():  # a bug's traceback goes to this job's backend.log
                        out = run_one(path, command, device, checkpoint, stop, allows_outside(allow_outside, path),
                                      half, overrides=overrides, data_roots=(data_roots or {}).get(path, ()),
                                      proposals=proposals)
                    status = STOPPED if out.pop("stopped") else OK
                    results.append({"job": path, "rank": rank, "status": status, **out})
                except Exception as e:  # one bad scene must not stop the batch: record it and go on
                    results.append({"job": path, "rank": rank, "status": FAILED, **failure(e, path)})
                results[-1]["seconds"] = time.perf_counter() - t
            result_of[k] = results[-1]
            events.progress("batch", n + 1, len(mine), rank=rank, job=path, status=results[-1]["status"])
    if shard_of is not None:
        return results, True
    return gather(results, world), rank == 0
