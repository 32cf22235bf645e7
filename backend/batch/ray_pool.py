"""``python -m backend batch JOBS --ray [ADDRESS]``: the jobs of ``batch``, scheduled by a Ray cluster.

    ray start --head                                   # on one machine; `ray start --address HEAD:6379` on others
    python -m backend batch --list jobs.txt --command generate --ray           # RAY_ADDRESS, a local cluster, or
    python -m backend batch --list jobs.txt --command generate --ray HEAD:6379 # a new one on this machine

Why Ray rather than ``batch``'s static sharding (``torchrun``: rank r takes jobs r, r + N, …): each job is one Ray
task, started on whichever worker is free, so one slow or dead GPU holds up only the job it runs, and the jobs of a
dead worker run again elsewhere.

* **Resources.** A task asks for one GPU when the cluster has GPUs (device ``cuda``; Ray sets
  ``CUDA_VISIBLE_DEVICES`` per task), else ``cpus_per_job`` CPUs (device ``cpu``).
* **Bookkeeping on the driver.** Each attempt is a generator task (``_run_job``): its first item says it started
  and on which worker, its second is the job's result. The driver alone counts attempts, running and ended jobs and
  decides retries: no actor or other process holds the batch's state, so a worker's death (killed, Ray's memory
  monitor, the kernel's OOM killer, a lost node) costs only the attempt it ran, and a job whose result reached the
  driver is never run again.
* **Retries** (``retries``, sent again by the driver; Ray's own retries are off). A worker that dies or a job that
  raises an unexpected exception (a bug, or a transient failure such as a GPU error) is run again, up to
  ``retries`` times. Bad input (``InputError``) and failures a job explains
  (``CleanFailure``: NaN output, a folder another live run holds) are results, never retried: running them again
  cannot change them. A retry resumes like any second run: finished frames are kept (written atomically) and the
  dead attempt's output lock is taken over, on any host (``locking.TASK_ENV``).
* **Finished jobs** are skipped by the jobs themselves, with the keys a second ``render`` or ``generate`` uses
  (``skipped``: true in the job's result).
* **Events.** The driver prints one stream: a ``progress`` event (stage ``batch``) each time a job ends, with
  ``done``, ``total``, ``failed`` (items ``failed`` so far) and ``running``, then the same ``done`` event as
  ``batch`` (``backend_protocol.BATCH_SUMMARY_FIELDS``; ``items``: one result per job, in the order given, with
  ``worker`` "host:pid", ``attempts`` (those that started) and its own ``seconds``). Each job's own
  events and log go to its ``backend.log`` and Ray's worker logs, never to the driver's standard output.
* **SIGTERM** on the driver (``stop`` for a caller; the first Ctrl-C too, in ``batch`` and ``evaluate``) cancels every job not finished (``ray.cancel``, asked again
  every ``CANCEL_AGAIN_S`` while any is pending: Ray's cancel is best effort). A queued job never starts: its result
  is ``not run (SIGTERM)`` with ``attempts`` 0, counted in the summary's ``not_run``, never
  ``failed``. A running job gets a SIGINT on its worker (``_interrupt``, a task on its node) as its ``stop`` flag
  (``_on_sigint``; not ``ray.cancel``, after which Ray drops what a generator task yields), so it ends as ``render`` and ``generate`` end on SIGTERM: after its current frame
  or sampler step, every file it wrote whole, its output lock released; its result is ``stopped`` with its counts
  (``rendered``: the frames it finished). A job Ray interrupted outside that flag is ``stopped`` too, with an
  ``error`` saying its counts are unknown. A job whose worker died and whose retry had not started yet is ``stopped`` too. The driver then prints its
  ``done`` event and ``batch`` exits 1; the
  same command again renders only the missing frames, on workers that are free at once.
* **Refused at once, where Ray would wait for ever:** an address (HOST:PORT) where no head answers within
  ``CONNECT_TIMEOUT_S`` (or that answers, but not as a Ray head), and ``cpus_per_job`` above the largest node's CPUs
  (``ArgumentError``). A job listed twice (the same file in the same folder, by ``st_dev``/``st_ino``: a hard or symbolic
  link, another spelling; ``batch_items.job_identity``) runs once; the copy's item repeats its result with
  ``duplicate_of`` (the item that ran it) and ``attempts`` 0, so the exit code is the same as without Ray. A job
  naming the output folder of an earlier, other job (``batch_items.shared_output_items``) is never sent: ``failed``
  as bad input with ``attempts`` 0, as in the sequential ``batch``.
* **Files.** Jobs, their inputs and outputs, and this code must be on a file system every node mounts at the same
  path (the tasks get the job's path, a string, and open the files themselves; each worker imports this code from
  the driver's ``PYTHONPATH``). Nothing from a user's file is pickled: tasks take strings and numbers and return
  plain dicts.

(Just over 400 lines: the worker's task (``_run_job``) and the driver's loop (``run_ray_batch``) are two sides of
one protocol, the task's first yielded item (``STARTED``), its statuses and the driver's retry and stop rules, kept
in one module so that a change to one side is read beside the other.)
"""

from __future__ import annotations

import os
import socket
import time

from scpainter_blender.core import batch_items
from scpainter_blender.core.backend_protocol import ITEM_FAILED as FAILED, ITEM_NOT_RUN as NOT_RUN, \
    ITEM_OK as OK, ITEM_STOPPED as STOPPED

from .. import events

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: A job is run again at most this many times after its worker died or it raised an unexpected exception.
DEFAULT_RETRIES = batch_items.DEFAULT_RETRIES
#: How long ``connect`` waits for a Ray head at HOST:PORT to answer before calling the address wrong (s).
CONNECT_TIMEOUT_S = 10.0
#: After SIGTERM the driver cancels the jobs still pending again this often (s): Ray's ``ray.cancel`` is best effort.
CANCEL_AGAIN_S = 2.0
#: How long the driver waits, at its end, for the SIGINTs it sent to running jobs to be delivered (s).
INTERRUPT_WAIT_S = 30.0
#: The key of the first item a job's task yields (``_run_job``): the worker ("host:pid") the attempt started on.
STARTED = "started_on"


def connect(address: str | None = None, stop: list | None = None):
    """The ``ray`` module, connected: to ``address`` (``HOST:PORT`` of a cluster's head, ``ray://HOST:PORT`` for Ray
    Client, ``auto``), else to ``RAY_ADDRESS`` or the cluster ``ray start`` started on this machine, else to a new
    local cluster of this machine's CPUs and GPUs (Ray's own order), whose workers import this code from ``ROOT``
    (``PYTHONPATH``). Already connected (a caller's ``ray.init``): that connection, as it is (its workers must be
    able to import ``backend``: started from this checkout, or with it on their ``PYTHONPATH``). Workers' output
    stays in Ray's logs (``log_to_driver=False``): the driver's standard output carries only this command's events.

    The caller's SIGTERM handler (``events.stop_on_sigterm``) is kept: ``ray.init`` installs its own (``sys.exit``)
    and it is put back once the cluster is joined. ``stop`` (that handler's list): a SIGTERM that came while
    ``ray.init`` ran is appended to it, with the cluster left, instead of ending the process before its summary;
    the caller then runs nothing (``run_ray_batch`` with ``stop`` set). None: ``SystemExit`` as Ray raises it.
    Without the ``ray`` package: ``ArgumentError`` naming ``--ray``, with what to install."""
    import signal
    import sys
    import threading

    try:
        import ray
    except ImportError as e:  # an optional package of the backend: say so, not "an internal error"
        from scpainter_blender.core.errors import ArgumentError

        raise ArgumentError("--ray", f"needs the ray package, which this Python ({sys.executable}) cannot import "
                                     f"({e})", hint="pip install ray (requirements.txt pins the version tested) "
                                                    "here and on every node of the cluster, or run without --ray") \
            from None

    if not ray.is_initialized():
        _check_reachable(address)
        # workers import this code from the driver's checkout (the same path on every node: a shared file system)
        python_path = os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p)
        main = threading.current_thread() is threading.main_thread()  # only there does ray.init set its handler
        previous = signal.getsignal(signal.SIGTERM) if main else None
        try:
            ray.init(address=address or None, log_to_driver=False, include_dashboard=False, configure_logging=False,
                     runtime_env={"env_vars": {"PYTHONPATH": python_path}})
        except ConnectionError as e:  # a head that answers but cannot be joined (Ray Client, a proxy, versions)
            given = address or os.environ.get("RAY_ADDRESS")
            if not given:  # a local cluster that would not start: not an address to blame
                raise
            raise _address_error(address, f"could not join the Ray cluster at {given}: {e}") from None
        except SystemExit as e:  # Ray's handler: SIGTERM while it started or joined the cluster
            if stop is None or e.code != signal.SIGTERM:
                raise
            stop.append(True)
            ray.shutdown()  # what it had started (a local cluster's processes) goes with it
            events.log("batch --ray: SIGTERM while joining the Ray cluster: no job is sent")  # (Ctrl-C: stop, above)
        finally:
            if main:
                signal.signal(signal.SIGTERM, previous)
    return ray


def _address_error(address: str | None, message: str):
    """The error for a Ray address that does not lead to a head: ``ArgumentError`` naming ``--ray`` when the user
    gave it, else ``InputError`` "(environment)" ``RAY_ADDRESS``."""
    from scpainter_blender.core import errors

    hint = ("the address `ray start --head` printed (HOST:6379, the GCS port, not the dashboard's 8265); is the "
            "cluster up, and this machine allowed to reach it?")
    if address:
        return errors.ArgumentError("--ray", message, hint=hint)
    return errors.InputError("(environment)", "RAY_ADDRESS", message, hint=hint + " (or unset RAY_ADDRESS)")


def _check_reachable(address: str | None) -> None:
    """A head at HOST:PORT (``address``, else ``RAY_ADDRESS``) that does not answer within ``CONNECT_TIMEOUT_S``,
    or answers but not as a gRPC server (a Ray head's GCS is one; a web server, Redis or the dashboard's port is
    not): ``_address_error``, where ``ray.init`` would retry for ever. The second test opens a gRPC channel and
    waits for it to be ready (HTTP/2 set up), skipped with ``RAY_USE_TLS`` (the head then needs Ray's
    certificates). An address in none of ``core.batch_items.RAY_ADDRESS_FORMS`` (a dashboard URL) is refused first
    (``check_ray_address``); ``auto``, ``local``, ``ray://`` (Ray Client) and no address at all are left to Ray."""
    batch_items.check_ray_address(address)
    given = address or os.environ.get("RAY_ADDRESS", "").strip()
    if not given or given in ("auto", "local") or "://" in given:
        return
    host, _, port = given.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise _address_error(address, f"{given!r}: expected HOST:PORT of the cluster's head, e.g. 10.0.0.5:6379")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as e:
        raise _address_error(address, f"no Ray head answers at {given} ({e.strerror or e})") from None
    if os.environ.get("RAY_USE_TLS", "0").strip().lower() in ("1", "true"):
        return
    try:
        import grpc
    except ImportError:  # Ray's own dependency; without it only the TCP test stands
        return
    channel = grpc.insecure_channel(given)
    try:
        grpc.channel_ready_future(channel).result(timeout=CONNECT_TIMEOUT_S)
    except grpc.FutureTimeoutError:
        raise _address_error(address, f"{given} answers, but not as a Ray head (no gRPC within "
                                      f"{CONNECT_TIMEOUT_S:g} s): another service listens there") from None
    finally:
        channel.close()


def _run_job(path: str, command: str, device: str, options: dict, task: str, job_fn=None):
    """One attempt of a job in a Ray worker, a generator task: it yields ``{"worker": "host:pid"}`` as it starts
    (the driver's bookkeeping: attempts, ``running``, where a dead attempt ran), then the job's result. The job:
    ``job_fn`` (default ``batch.run_one``) with ``options`` (its keyword arguments: checkpoint, allow_outside,
    data_roots, half, precision, overrides; plain values). Bad input and explained failures come back as a
    ``failed`` result; any other exception propagates, so the driver runs the job again. ``task`` marks the output
    lock so a retry may take over the lock its dead attempt left, on any host. The driver's ``ray.cancel`` (its
    SIGTERM) sets the job's ``stop`` flag: the job ends after its current frame or sampler step and returns
    ``stopped``. Nothing here waits on another Ray process: once the result is yielded the attempt has no more to
    tell, so no failure elsewhere can make a finished job run again."""
    import signal

    from scpainter_blender.core import locking
    from scpainter_blender.core.errors import InputError

    from . import command as batch
    from ..errors import CleanFailure, explained

    global _job_stop
    stop: list = []
    # the driver's stop (its SIGTERM, a first Ctrl-C) reaches a running job as SIGINT (_interrupt): as the job's stop
    # flag it ends the job as SIGTERM ends `render`, after the current frame, outputs whole, lock released, counts
    # reported. (Not ray.cancel: Ray drops what a cancelled generator task yields after it, the job's result.)
    try:
        signal.signal(signal.SIGINT, _on_sigint)
        # Ray starts its processes with SIGINT blocked (so a terminal's Ctrl-C leaves the cluster alone): this thread
        # takes it again, the only one that does, so the signal comes here (Ray's threads keep it blocked)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    except ValueError:  # not the main thread (a threaded actor): SIGINT would not reach the job
        pass
    _job_stop = stop
    try:
        worker = f"{socket.gethostname()}:{os.getpid()}"
        import ray

        yield {STARTED: worker, "node": ray.get_runtime_context().get_node_id(), "pid": os.getpid()}
        os.environ[locking.TASK_ENV] = task
        # a worker runs many jobs: what they load is kept for the next (``render.scene_cache``, bounded; a changed
        # file is read again), so variants of one recording clean its points once per worker, not once per job
        from ..render import scene_cache

        scene_cache.enable(("Ray worker", "an earlier job on this worker"))
        t0, started = time.perf_counter(), time.time()
        try:
            with events.log_scope():  # a bug's traceback goes to this job's backend.log
                out = (job_fn or batch.run_one)(path, command, device, stop=stop, **options)
            result = {"status": STOPPED if out.pop("stopped") else OK, **out}
        except (InputError, CleanFailure) as e:
            result = {"status": FAILED, **batch.failure(e, path)}
        except Exception as e:  # a bug or a transient failure: its traceback to the job's log, then a retry
            if explained(e) is None:
                e.scpainter_log = events.report_bug(e, f"batch: {path} failed on {worker}")
                raise
            result = {"status": FAILED, **batch.failure(e, path)}  # a name too long, a full disk: no retry
        finally:
            os.environ.pop(locking.TASK_ENV, None)
        yield {**result, "worker": worker, "seconds": time.perf_counter() - t0, "started": started,
               "finished": time.time()}
    finally:
        _job_stop = None  # (the handler stays: a SIGINT sent as the job ended is then ignored, not a crash)


#: The stop flag of the job this worker runs (``_run_job``), None between jobs.
_job_stop: list | None = None


def _on_sigint(*_) -> None:
    """A worker's SIGINT handler while it runs the batch's jobs: the running job's stop flag; ignored between jobs."""
    if _job_stop is not None:
        _job_stop.append(True)


def _interrupt(pid: int) -> None:
    """A task on the node of a worker running a job: SIGINT to that worker (``pid``), the job's stop flag
    (``_on_sigint``); nothing when it has already ended."""
    import signal

    try:
        os.kill(pid, signal.SIGINT)
    except ProcessLookupError:
        pass


def job_device(device: str = "auto", address: str | None = None) -> str:
    """The device the pool's jobs run on: ``cuda`` when the cluster (``connect(address)``) has GPUs and ``device``
    is not ``cpu`` (each task then asks for one GPU), else ``cpu``. Callers that key outputs on the device's
    defaults (``evaluate``: ``precision auto`` is bf16 on CUDA, fp32 on CPU) resolve them with it before the pool
    starts. ``device`` ``cuda`` on a cluster without GPUs is an ``ArgumentError``."""
    from scpainter_blender.core.errors import ArgumentError

    gpus = connect(address).cluster_resources().get("GPU", 0)
    if device == "cuda" and not gpus:
        raise ArgumentError("--device", "cuda, but the Ray cluster has no GPU",
                            hint="start the workers on GPU machines, or use --device cpu")
    return "cuda" if gpus > 0 and device != "cpu" else "cpu"


def run_ray_batch(items: list[str], command: str, device: str = "auto", checkpoint: str | None = None,
                  allow_outside=False, half: bool = False, address: str | None = None,
                  retries: int = DEFAULT_RETRIES, cpus_per_job: float = batch_items.DEFAULT_CPUS_PER_JOB, stop=(),
                  job_fn=None, precision: str = "auto", overrides: dict | None = None, stage: str = "batch",
                  data_roots: dict | None = None, proposals: str | None = None) -> list[dict]:
    """Run every job of ``items`` as a Ray task (see the module docstring); returns one result per item, in order:
    ``job``, ``status`` (``ok``, ``stopped``, ``failed``, ``not run (SIGTERM)``), the job's outputs, ``worker``,
    ``attempts``, ``seconds``. ``allow_outside``: True, or the paths of the jobs that may lead outside their folder
    (``batch.allows_outside``); ``data_roots``: ``{job path: its data roots}`` (``batch.job_data_roots``), sent to
    each task as plain strings; ``precision`` and ``overrides``: ``batch.run_one``'s, for every job; ``stage``: the
    progress events' (``evaluate`` runs its tasks here too). ``stop`` (truthy once SIGTERM came): every job not
    finished is cancelled; queued ones come back ``not run (SIGTERM)`` (``attempts`` 0), running ones stop after
    their current frame or step and come back ``stopped`` with their counts, finished frames kept, nothing
    half-written, their output locks released (module docstring, **SIGTERM**); it returns once every job has ended.
    ``device`` ``cuda`` on a cluster without GPUs is an ``ArgumentError``. ``job_fn``: what a task runs instead of
    ``batch.run_one`` (same arguments and result; the tests' transient failures)."""
    import uuid

    from scpainter_blender.core.errors import ArgumentError

    from . import command as batch

    batch_items.check_ray_options(retries, cpus_per_job)
    if stop:  # SIGTERM before any job was sent (while the cluster was joined: connect's stop): none runs
        events.log(f"batch --ray: stopped (SIGTERM or Ctrl-C) before any job was sent: {len(items)} jobs not run")
        return [{"job": p, "status": NOT_RUN, "attempts": 0} for p in items]
    ray = connect(address)
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    gpus = ray.cluster_resources().get("GPU", 0)
    use_gpu = job_device(device, address) == "cuda"
    resources = {"num_gpus": 1, "num_cpus": 1} if use_gpu else {"num_cpus": cpus_per_job}
    largest = max((n["Resources"].get("CPU", 0) for n in ray.nodes() if n.get("Alive")), default=0)
    if resources["num_cpus"] > largest:  # Ray would queue every job for ever, silently
        raise ArgumentError("--cpus-per-job", f"{resources['num_cpus']:g} CPUs per job, but the largest node of the "
                                              f"Ray cluster has {largest:g}: no job could ever start",
                            hint=f"ask for at most {largest:g}, or add bigger nodes (ray start --num-cpus N)")
    # each attempt a generator task: its first item says it started (and where), its second is the job's result. The
    # driver keeps every count itself, with no actor whose death could lose the batch, and runs a failed attempt
    # again itself (Ray's own retries would hide a retry's start)
    task = ray.remote(_run_job).options(num_returns="streaming", max_retries=0, retry_exceptions=False,
                                        **resources)
    interrupt = ray.remote(_interrupt)
    run_id = uuid.uuid4().hex[:12]
    options = {"checkpoint": checkpoint, "half": half, "precision": precision, "overrides": overrides}
    if proposals is not None:  # (run_one's keyword; a test's job_fn need not take it)
        options["proposals"] = proposals
    # a job listed twice (a hard or symbolic link, another spelling) runs once: run at once, the two would meet at
    # their output lock; the copy's item gets the first's result
    first = batch_items.first_items(items)
    copies: dict = {}
    for k, i in enumerate(first):
        if k != i:
            copies.setdefault(i, []).append(k)
    # a job writing the output folder of an earlier, other job is refused before anything runs (run after it, it
    # would replace or remove that job's outputs): failed as bad input, never sent
    refused = batch_items.shared_output_items(items, first)
    todo = [i for i, j in enumerate(first) if i == j and i not in refused]

    streams: dict = {}              # an attempt's generator -> [item index, whether it has said it started]
    submitted = [0] * len(items)    # attempts sent, per item
    starts: dict = {}               # item index -> the workers its attempts started on, in order

    def submit(i):
        p = items[i]
        gen = task.remote(os.path.abspath(p), command, "cuda" if use_gpu else "cpu",
                          {**options, "allow_outside": batch.allows_outside(allow_outside, p),
                           "data_roots": (data_roots or {}).get(p, ())}, f"{run_id}:{i}", job_fn)
        streams[gen] = [i, False]
        submitted[i] += 1

    for i in todo:
        submit(i)
    again = sum(k != i for k, i in enumerate(first))
    events.log(f"batch --ray: {len(todo)} jobs on {ray.cluster_resources().get('CPU', 0):g} CPUs and {gpus:g} GPUs "
               f"({'1 GPU' if use_gpu else f'{cpus_per_job:g} CPUs'} per job, {retries} retries)"
               + (f"; {again} listed again, run once" if again else "")
               + (f"; {len(refused)} refused (another job's output folder)" if refused else ""))
    results: list = [None] * len(items)
    done, failed, cancelled_at = 0, 0, None
    interrupts: list = []   # the _interrupt tasks sent: waited for before returning, so none outlives the batch
    where: dict = {}        # a started attempt's generator -> (node id, worker pid)

    def ended(i, running):
        """Item ``i``'s result is in: its copies get it, and each gets its progress event."""
        nonlocal done, failed
        for k in (i, *copies.get(i, ())):
            if k != i:  # the copy's item: the job's result, saying which item ran it (0 attempts of its own)
                results[k] = {**results[i], "job": items[k], "duplicate_of": i, "attempts": 0}
            done += 1
            failed += results[k]["status"] == FAILED
            events.progress(stage, done, len(items), failed=failed, running=running, job=items[k],
                            status=results[k]["status"])

    for i, fields in refused.items():
        events.log(f"batch --ray: {items[i]}: bad input: {fields['error']}")
        results[i] = {"job": items[i], "status": FAILED, **fields, "attempts": 0, "seconds": 0.0}
        ended(i, 0)   # (nothing has started yet)
    while streams:
        if stop and (cancelled_at is None or time.monotonic() - cancelled_at > CANCEL_AGAIN_S):
            # asked again now and then: Ray's cancel is best effort (its docs); a running job already stopping only
            # sees its stop flag set again
            for gen, (i, said_started) in streams.items():
                if said_started:  # SIGINT to its worker: the job's stop flag, its result still comes
                    node, pid = where[gen]
                    interrupts.append(interrupt.options(num_cpus=0, max_retries=0, scheduling_strategy=(
                        NodeAffinitySchedulingStrategy(node, soft=False))).remote(pid))
                else:  # queued: it never starts
                    ray.cancel(gen, recursive=False)
            cancelled_at = time.monotonic()
        # every stream with a new item within the half second: one pass over the attempts per wait, not per job
        ready, _ = ray.wait(list(streams), num_returns=len(streams), timeout=0.5)
        finished = []
        while ready:  # every item already there, a stream's start and result alike, before counting what runs
            gen = ready.pop(0)
            i, said_started = streams[gen]
            try:
                item = ray.get(next(gen))
            except (StopIteration, ray.exceptions.RayError) as e:
                if stop and not said_started:  # cancelled before it started: not an attempt
                    submitted[i] -= 1
                if stop and starts.get(i):
                    # it did run (this attempt, stopped outside the job's stop flag or cancelled as it started, or an
                    # earlier one whose worker died): its finished frames are kept, its counts unknown; "not run"
                    # would be a lie
                    item = {"status": STOPPED, "worker": starts[i][-1],
                            "error": "cancelled by SIGTERM while it ran: its finished outputs are kept, how many is "
                                     "not known"}
                elif stop:
                    item = {"status": NOT_RUN}
                elif isinstance(e, StopIteration):  # (an attempt yields its result or raises: never seen)
                    item = {"status": FAILED, "error": "its Ray task ended without a result"}
                elif submitted[i] <= retries:  # its worker died, or a bug (a transient failure?) raised: again
                    del streams[gen]
                    events.log(f"batch --ray: {items[i]}: attempt {submitted[i]} failed ({_ray_error(e)}); "
                               "running it again")
                    submit(i)
                    continue
                else:  # a bug's traceback went to its job's log; a dead worker's job wrote there until it died
                    item = {"status": FAILED, "error": _ray_error(e),
                            "log": getattr(getattr(e, "cause", None), "scpainter_log", None) or _job_log(items[i])}
                    if starts.get(i):
                        item["worker"] = starts[i][-1]   # its last worker died with it: where it ran
            else:
                if STARTED in item:
                    starts.setdefault(i, []).append(item[STARTED])
                    streams[gen][1] = True
                    where[gen] = (item["node"], item["pid"])
                    ready += ray.wait([gen], timeout=0)[0]  # its result too, if it came with it
                    continue
            del streams[gen]
            results[i] = {"job": items[i], **item}
            finished.append(i)
        running = sum(s for _, s in streams.values())  # attempts that started and have not ended
        for i in finished:
            results[i]["attempts"] = submitted[i]
            ended(i, running)
    if interrupts:  # each a moment's work (its worker may have gone with its node: not waited for long)
        ray.wait(interrupts, num_returns=len(interrupts), timeout=INTERRUPT_WAIT_S)
    return results


def _job_log(path: str) -> str | None:
    """The job's own log, ``<output_dir>/backend.log`` (what ``render`` or ``generate`` wrote there as it ran), when
    it exists; None for a job that never opened it or cannot be read here. Only a path is worked out: nothing in
    the output folder is read."""
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core import job_inputs
    from scpainter_blender.core.errors import InputError
    from scpainter_blender.core.output_layout import OutputLayout

    try:  # allow_outside: the path is only shown, never opened
        out = job_inputs.job_paths(path, job_mod.load(path), allow_outside=True)["output_dir"]
    except (InputError, OSError, ValueError):
        return None
    log = OutputLayout(out).log
    return log if os.path.isfile(log) else None


def _ray_error(e) -> str:
    """One line for a task that failed after its retries: what Ray says, without its long traceback."""
    cause = getattr(e, "cause", None)
    if cause is not None and not isinstance(cause, type(e)):
        return f"{type(cause).__name__}: {cause}"
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}"[:500]
