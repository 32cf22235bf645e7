"""``python -m backend batch JOBS --ray [ADDRESS]``: the jobs of ``batch``, scheduled by a Ray cluster.

    ray start --head                                   # on one machine; `ray start --address HEAD:6379` on others
    python -m backend batch --list jobs.txt --command generate --ray           # RAY_ADDRESS, a local cluster, or
    python -m backend batch --list jobs.txt --command generate --ray HEAD:6379 # a new one on this machine

Why Ray rather than ``batch``'s static sharding (``torchrun``: rank r takes jobs r, r + N, …): each job is one Ray
task, started on whichever worker is free, so one slow or dead GPU holds up only the job it runs, and the jobs of a
dead worker run again elsewhere.

* **Resources.** A task asks for one GPU when the cluster has GPUs (device ``cuda``; Ray sets
  ``CUDA_VISIBLE_DEVICES`` per task), else ``cpus_per_job`` CPUs (device ``cpu``).
* **Retries** (``retries``, Ray's ``max_retries`` and ``retry_exceptions``). A worker that dies (killed, out of
  memory, its node lost) or a job that raises an unexpected exception (a bug, or a transient failure such as a GPU
  error) is run again, up to ``retries`` times. Bad input (``InputError``) and failures a job explains
  (``CleanFailure``: NaN output, a folder another live run holds) are results, never retried: running them again
  cannot change them. A retry resumes like any second run: finished frames are kept (written atomically) and the
  dead attempt's output lock is taken over, on any host (``locking.TASK_ENV``).
* **Finished jobs** are skipped by the jobs themselves, with the keys a second ``render`` or ``generate`` uses
  (``skipped``: true in the job's result).
* **Events.** The driver prints one stream: a ``progress`` event (stage ``batch``) each time a job ends, with
  ``done``, ``total``, ``failed`` and ``running``, then the same ``done`` event as ``batch`` (``items``: one result
  per job, in the order given, with ``worker`` "host:pid", ``attempts`` and its own ``seconds``). Each job's own
  events and log go to its ``backend.log`` and Ray's worker logs, never to the driver's standard output.
* **Files.** Jobs, their inputs and outputs, and this code must be on a file system every node mounts at the same
  path (the tasks get the job's path, a string, and open the files themselves; each worker imports this code from
  the driver's ``PYTHONPATH``). Nothing from a user's file is pickled: tasks take strings and numbers and return
  plain dicts.
"""

from __future__ import annotations

import os
import socket
import time

from . import events

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: A job is run again at most this many times after its worker died or it raised an unexpected exception.
DEFAULT_RETRIES = 2


def connect(address: str | None = None):
    """The ``ray`` module, connected: to ``address`` (``HOST:PORT`` of a cluster's head, ``ray://HOST:PORT`` for Ray
    Client, ``auto``), else to ``RAY_ADDRESS`` or the cluster ``ray start`` started on this machine, else to a new
    local cluster of this machine's CPUs and GPUs (Ray's own order), whose workers import this code from ``ROOT``
    (``PYTHONPATH``). Already connected (a caller's ``ray.init``): that connection, as it is (its workers must be
    able to import ``backend``: started from this checkout, or with it on their ``PYTHONPATH``). Workers' output
    stays in Ray's logs (``log_to_driver=False``): the driver's standard output carries only this command's events."""
    import ray

    if not ray.is_initialized():
        # workers import this code from the driver's checkout (the same path on every node: a shared file system)
        python_path = os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p)
        ray.init(address=address or None, log_to_driver=False, include_dashboard=False, configure_logging=False,
                 runtime_env={"env_vars": {"PYTHONPATH": python_path}})
    return ray


def _run_job(path: str, command: str, device: str, checkpoint, allow_outside: bool, half: bool, task: str,
             board, job_fn=None) -> dict:
    """One job in a Ray worker (``job_fn``, default ``batch.run_one``). Bad input and explained failures come back
    as a ``failed`` result; any other exception propagates, so Ray retries it. ``task`` marks the output lock so a
    retry may take over the lock its dead attempt left, on any host."""
    from scpainter_blender.core import locking
    from scpainter_blender.core.files import InputError

    from . import batch
    from .errors import CleanFailure

    import ray

    worker = f"{socket.gethostname()}:{os.getpid()}"
    # not waited for here: a task blocked in ray.get gives its CPUs back, and Ray would start another job on them
    noted = board.started.remote(task, worker)
    os.environ[locking.TASK_ENV] = task
    t0, started = time.perf_counter(), time.time()
    try:
        with events.log_scope():  # a bug's traceback goes to this job's backend.log
            out = (job_fn or batch.run_one)(path, command, device, checkpoint, (), allow_outside, half)
        result = {"status": "stopped" if out.pop("stopped") else "ok", **out}
    except (InputError, CleanFailure) as e:
        result = {"status": "failed", **batch.failure(e, path)}
    except Exception as e:  # a bug or a transient failure: its traceback to the job's log, then Ray retries it
        e.scpainter_log = events.report_bug(e, f"batch: {path} failed on {worker}")
        raise
    finally:
        os.environ.pop(locking.TASK_ENV, None)
    result = {**result, "worker": worker, "seconds": time.perf_counter() - t0, "started": started,
              "finished": time.time()}
    ray.get([noted, board.ended.remote(task)])  # recorded before the driver sees the result
    return result


class _Board:
    """Which tasks (``run_id:index``) have started, where and how often, and which are running now: a Ray actor the
    tasks tell. The driver asks it for ``active_tasks`` after each batch of ended jobs (``running``: a small set, at
    most one per worker plus attempts whose worker died) and for ``snapshot`` once at the end (``attempts``)."""

    def __init__(self):
        self.starts, self.active = {}, set()

    def started(self, task: str, worker: str) -> None:
        self.starts.setdefault(task, []).append(worker)
        self.active.add(task)

    def ended(self, task: str) -> None:
        self.active.discard(task)

    def active_tasks(self) -> set:
        return self.active

    def snapshot(self) -> dict:
        return self.starts


def run_ray_batch(items: list[str], command: str, device: str = "auto", checkpoint: str | None = None,
                  allow_outside: bool = False, half: bool = False, address: str | None = None,
                  retries: int = DEFAULT_RETRIES, cpus_per_job: float = 1.0, stop=(), job_fn=None) -> list[dict]:
    """Run every job of ``items`` as a Ray task (see the module docstring); returns one result per item, in order:
    ``job``, ``status`` (``ok``, ``stopped``, ``failed``, ``not run (SIGTERM)``), the job's outputs, ``worker``,
    ``attempts``, ``seconds``. ``stop`` (truthy once SIGTERM came): jobs not finished are cancelled; running ones
    stop where they are, their finished frames kept. ``device`` ``cuda`` on a cluster without GPUs is an
    ``ArgumentError``. ``job_fn``: what a task runs instead of ``batch.run_one`` (same arguments and result; the
    tests' transient failures)."""
    import uuid

    from scpainter_blender.core.files import ArgumentError

    if not cpus_per_job > 0:
        raise ArgumentError("--cpus-per-job", f"expected a number of CPUs above 0, got {cpus_per_job}")
    ray = connect(address)
    gpus = ray.cluster_resources().get("GPU", 0)
    if device == "cuda" and not gpus:
        raise ArgumentError("--device", "cuda, but the Ray cluster has no GPU",
                            hint="start the workers on GPU machines, or use --device cpu")
    use_gpu = gpus > 0 and device != "cpu"
    resources = {"num_gpus": 1, "num_cpus": 1} if use_gpu else {"num_cpus": cpus_per_job}
    task = ray.remote(_run_job).options(max_retries=retries, retry_exceptions=True, **resources)
    board = ray.remote(_Board).options(num_cpus=0).remote()
    ray.get(board.active_tasks.remote())  # up before any task calls it: a call queued for it dies with its caller
    run_id = uuid.uuid4().hex[:12]
    refs = {task.remote(os.path.abspath(p), command, "cuda" if use_gpu else "cpu", checkpoint, allow_outside, half,
                        f"{run_id}:{i}", board, job_fn): i for i, p in enumerate(items)}
    events.log(f"batch --ray: {len(items)} jobs on {ray.cluster_resources().get('CPU', 0):g} CPUs and {gpus:g} GPUs "
               f"({'1 GPU' if use_gpu else f'{cpus_per_job:g} CPUs'} per job, {retries} retries)")
    results: list = [None] * len(items)
    pending, failed, cancelled, ended_ids = dict(refs), 0, False, set()
    while pending:
        if stop and not cancelled:
            for ref in pending:
                ray.cancel(ref)
            cancelled = True
        # every job that ended within the half second: one pass over the pending list per wait, not per job
        ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0.5)
        ended = []
        for ref in ready:
            i = pending.pop(ref)
            try:
                r = ray.get(ref)
            except ray.exceptions.TaskCancelledError:
                r = {"status": "not run (SIGTERM)"}
            except ray.exceptions.RayError as e:  # retries used up: the worker died, or a bug raised each time
                r = {"status": "failed", "error": _ray_error(e),
                     "log": getattr(getattr(e, "cause", None), "scpainter_log", None)}
            results[i] = {"job": items[i], **r}
            ended.append(i)
            ended_ids.add(f"{run_id}:{i}")  # also those whose last attempt died before telling the board
        if not ended:
            continue
        running = len(ray.get(board.active_tasks.remote()) - ended_ids)  # after the whole batch ended
        before = len(items) - len(pending) - len(ended)
        for n, i in enumerate(ended, 1):
            failed += results[i]["status"] != "ok"
            events.progress("batch", before + n, len(items), failed=failed, running=running, job=items[i],
                            status=results[i]["status"])
    starts = ray.get(board.snapshot.remote())
    for i, r in enumerate(results):
        r["attempts"] = len(starts.get(f"{run_id}:{i}", []))
    ray.kill(board)
    return results


def _ray_error(e) -> str:
    """One line for a task that failed after its retries: what Ray says, without its long traceback."""
    cause = getattr(e, "cause", None)
    if cause is not None and not isinstance(cause, type(e)):
        return f"{type(cause).__name__}: {cause}"
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}"[:500]
