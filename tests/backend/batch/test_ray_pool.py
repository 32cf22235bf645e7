"""``python -m backend batch --ray``: jobs scheduled on a local Ray cluster of 2 CPUs (``backend/batch/ray_pool.py``)."""

import glob
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from backend.batch import command as batch, ray_pool as batch_ray
from backend.render import channels
from scpainter_blender.core import locking
from tests_support import run_backend, small_job, variant_jobs

ray = pytest.importorskip("ray")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def events_of(text):
    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


def exr_mtimes(job_path):
    folder = os.path.join(os.path.dirname(job_path), "out", "conditions")
    return {f: os.stat(f).st_mtime_ns for f in glob.glob(os.path.join(folder, "*.exr"))}


def test_six_jobs_over_two_workers_then_a_rerun_skips_them(ray_cluster, tmp_path, capsys):
    jobs = [small_job(tmp_path / f"job{i}", frames=tuple(range(1, 2 + i))) for i in range(6)]
    arrived = tmp_path / "arrived"
    arrived.mkdir()

    def two_at_once(path, *args, **options):
        """The real job, once a second job has started too. These jobs take milliseconds: a worker left warm by an
        earlier test would finish all six before the cluster's second worker is up (seconds), so nothing would show
        that the pool runs two at a time."""
        (arrived / os.path.basename(os.path.dirname(path))).touch()
        deadline = time.monotonic() + 120
        while len(os.listdir(arrived)) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        return batch.run_one(path, *args, **options)

    results = batch_ray.run_ray_batch(jobs, "render", "cpu", job_fn=two_at_once)
    assert [r["job"] for r in results] == jobs and all(r["status"] == "ok" for r in results)
    assert [r["rendered"] for r in results] == [1, 2, 3, 4, 5, 6] and not any(r["skipped"] for r in results)
    assert all(r["attempts"] == 1 for r in results)
    # two at a time, never more: the most jobs running at one moment (from each job's own start and end)
    moments = sorted([(r["started"], 1) for r in results] + [(r["finished"], -1) for r in results])
    running = [sum(d for _, d in moments[:k + 1]) for k in range(len(moments))]
    assert max(running) == 2
    progress = [e for e in events_of(capsys.readouterr().out) if e["event"] == "progress"]
    assert [e["done"] for e in progress] == [1, 2, 3, 4, 5, 6] and all(e["total"] == 6 for e in progress)
    assert all(e["failed"] == 0 and 0 <= e["running"] <= 2 for e in progress)
    assert progress[-1]["running"] == 0
    # the same jobs again: each finds its frames up to date (the render's job key) and writes nothing
    before = {j: exr_mtimes(j) for j in jobs}
    again = batch_ray.run_ray_batch(jobs, "render", "cpu")
    assert all(r["status"] == "ok" and r["skipped"] and r["rendered"] == 0 for r in again)
    assert {j: exr_mtimes(j) for j in jobs} == before


def test_a_job_that_fails_once_succeeds_on_retry_and_one_that_always_fails_is_reported(ray_cluster, tmp_path):
    marker = str(tmp_path / "failed_once")

    def flaky(path, *args, **options):
        """A transient failure (a GPU error, a network file system hiccup) on this job's first attempt only."""
        if path.endswith("flaky/job.json") and not os.path.exists(marker):
            open(marker, "w").close()
            raise OSError("transient: the shared file system went away for a moment")
        if path.endswith("broken/job.json"):
            raise RuntimeError("a bug that fails every time")
        return batch.run_one(path, *args, **options)

    good, flaky_job, broken = (small_job(tmp_path / n) for n in ("good", "flaky", "broken"))
    bad_input = small_job(tmp_path / "bad_input")
    os.remove(tmp_path / "bad_input" / "predictions.npz")
    results = batch_ray.run_ray_batch([good, flaky_job, broken, bad_input], "render", "cpu", retries=2, job_fn=flaky)
    by = {os.path.basename(os.path.dirname(r["job"])): r for r in results}
    assert by["good"]["status"] == "ok" and by["good"]["attempts"] == 1
    assert by["flaky"]["status"] == "ok" and by["flaky"]["attempts"] == 2 and by["flaky"]["rendered"] == 2
    assert by["broken"]["status"] == "failed" and by["broken"]["attempts"] == 3      # 1 + 2 retries
    assert "a bug that fails every time" in by["broken"]["error"]
    assert "log" in by["broken"]  # None here: it failed before opening its job's backend.log
    # bad input is a result, not retried: running it again could not change it
    assert by["bad_input"]["status"] == "failed" and by["bad_input"]["attempts"] == 1
    assert by["bad_input"]["file"].endswith("predictions.npz") and "not found" in by["bad_input"]["error"]


def test_a_lists_data_root_travels_to_the_workers(ray_cluster, tmp_path):
    """The data roots of a list's jobs reach the Ray tasks (batch.run_one in a worker): the variant reading the
    shared recording runs; the same job outside that list is refused there, naming its file and field."""
    from scpainter_blender.core import batch_items

    shared, (v1, v2) = variant_jobs(tmp_path)
    listed = tmp_path / "variants.txt"
    listed.write_text("data-root: shared\nv1/job.json\n")
    jobs = batch_items.read_job_list(listed)
    results = batch_ray.run_ray_batch(jobs.paths + [v2], "render", "cpu",
                                      data_roots=batch.job_data_roots([v2], [jobs]))
    assert [r["status"] for r in results] == ["ok", "failed"] and results[0]["rendered"] == 2
    assert results[1]["file"] == v2 and results[1]["field"] == "scene.predictions" and results[1]["attempts"] == 1


def test_a_job_whose_worker_died_and_has_no_retry_left_names_its_log(ray_cluster, tmp_path):
    def dies_at_the_end(path, *args, **options):
        """The job runs (writing its backend.log), then its worker dies (out of memory, say) before it returns."""
        batch.run_one(path, *args, **options)
        os.kill(os.getpid(), signal.SIGKILL)

    job = small_job(tmp_path / "dies")
    (r,) = batch_ray.run_ray_batch([job], "render", "cpu", retries=0, job_fn=dies_at_the_end)
    assert r["status"] == "failed" and r["attempts"] == 1 and r["worker"]
    assert "died" in r["error"].lower() or "worker" in r["error"].lower(), r["error"]
    assert r["log"] == str(tmp_path / "dies" / "out" / "backend.log") and os.path.isfile(r["log"])


def test_a_worker_killed_mid_job_reruns_it_without_losing_or_repeating_a_frame(ray_cluster, tmp_path):
    job = small_job(tmp_path / "long", frames=tuple(range(1, 61)), resolution=(320, 240))
    out = tmp_path / "long" / "out"
    box = {}
    driver = threading.Thread(target=lambda: box.update(results=batch_ray.run_ray_batch([job], "render", "cpu")))
    driver.start()
    killed = None
    deadline = time.monotonic() + 300
    while killed is None and time.monotonic() < deadline and driver.is_alive():
        owner = locking.OutputLock(str(out), "test")._owner()
        frames = finished_frames(job)
        if isinstance(owner, dict) and owner.get("command") == "render" and 5 <= len(frames) < 50:
            os.kill(owner["pid"], signal.SIGKILL)           # the worker dies mid-job, its lock left behind
            killed = (owner["pid"], len(frames))
        time.sleep(0.01)
    driver.join(timeout=300)
    assert killed, "the job finished before the worker could be killed mid-job"
    (r,) = box["results"]
    assert r["status"] == "ok" and r["attempts"] == 2 and r["worker"] != f"{killed[0]}"
    # the retry kept the frames finished before the kill and rendered only the rest: none lost, none twice
    assert r["rendered"] <= 60 - killed[1]
    exrs = sorted(glob.glob(str(out / "conditions" / "frame_*.exr")))
    assert [os.path.basename(p) for p in exrs] == [f"frame_{f:06d}.exr" for f in range(1, 61)]
    assert all(channels.read(p)["R"].shape == (240, 320) for p in exrs)  # every frame whole
    assert not glob.glob(str(out / "conditions" / ".*.tmp")) and not (out / locking.LOCK_NAME).exists()


def test_the_command_line_driver_prints_one_stream_and_exits_1_when_a_job_failed(tmp_path):
    good = small_job(tmp_path / "good")
    bad = small_job(tmp_path / "bad")
    os.remove(tmp_path / "bad" / "car.ply")
    code, ev, err = run_backend("batch", good, bad, "--ray", "--device", "cpu", "--command", "render")
    assert code == 1, err[-2000:]
    assert [e["event"] for e in ev] == ["progress", "progress", "done"]   # only the driver's own events
    done = ev[-1]
    assert done["command"] == "batch" and done["jobs"] == 2 and done["failed"] == 1
    assert done["counts"] == {"ok": 1, "failed": 1}
    assert [i["status"] for i in done["items"]] == ["ok", "failed"] and done["items"][1]["file"].endswith("car.ply")
    code, ev, _ = run_backend("batch", good, "--ray", "--device", "cpu", "--cpus-per-job", "0")
    assert code == 2 and ev[-1]["field"] == "--cpus-per-job"


def finished_frames(job_path):
    """The EXRs of a job's finished frames: those whose labels exist (the render writes a frame's EXR, preview and
    labelled preview, then its labels, which mark it finished: render's resume rule)."""
    folder = os.path.join(os.path.dirname(job_path), "out", "conditions")
    return {p for p in glob.glob(os.path.join(folder, "frame_*.exr"))
            if os.path.exists(p.replace("frame_", "labels_").replace(".exr", ".json"))}


def test_sigterm_on_the_driver_stops_running_jobs_cancels_queued_ones_and_a_rerun_renders_only_the_rest(
        ray_cluster, tmp_path):
    n = 40   # frames per job: a few seconds each on a CPU worker, so the driver is stopped mid-job
    jobs = [small_job(tmp_path / f"job{i}", frames=tuple(range(1, n + 1)), resolution=(320, 240)) for i in range(4)]
    locks = [os.path.join(os.path.dirname(j), "out", locking.LOCK_NAME) for j in jobs]
    command = [sys.executable, "-m", "backend", "batch", *jobs, "--ray", ray_cluster, "--device", "cpu",
               "--command", "render"]
    with open(tmp_path / "stderr.txt", "w") as err:
        driver = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True)
        try:
            # stopped while the two CPUs each run a job (its output folder locked; one has finished frames, the
            # other may still load its scene) and the other two jobs wait
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and driver.poll() is None:
                running = sum(os.path.exists(p) for p in locks)
                counts = sorted(len(finished_frames(j)) for j in jobs)
                if running == 2 and counts[-1] >= 3:
                    break
                time.sleep(0.01)
            assert running == 2 and 3 <= counts[-1] < n, f"not two jobs mid-way: {running} running, {counts} frames"
            driver.send_signal(signal.SIGTERM)
            sent = time.monotonic()
            out, _ = driver.communicate(timeout=60)
            stopped_in = time.monotonic() - sent
        finally:
            if driver.poll() is None:
                driver.kill()
    stderr = (tmp_path / "stderr.txt").read_text()
    assert driver.returncode == 1, stderr[-3000:]
    ev = [json.loads(line) for line in out.splitlines()]          # standard output: JSON events only
    assert ev[-1]["event"] == "done" and all(e["event"] == "progress" for e in ev[:-1]), out
    done = ev[-1]
    items = done["items"]
    assert [i["job"] for i in items] == jobs and (done["failed"], done["stopped"], done["not_run"]) == (0, 2, 2)
    # the running jobs stop after their current frame, keeping and counting what they finished
    ran = [i for i in items if i["status"] == "stopped"]
    queued = [i for i in items if i["status"] == "not run (SIGTERM)"]
    assert len(ran) == 2 and len(queued) == 2, [(i["status"], i.get("error")) for i in items]
    assert stopped_in < 10, f"the driver took {stopped_in:.1f} s to stop"
    kept = {}
    for i in ran:
        frames = finished_frames(i["job"])
        assert i["attempts"] == 1 and i["frames"] == n and i["rendered"] < n and not i["skipped"]
        assert len(frames) == i["rendered"] and "error" not in i
        kept[i["job"]] = {p: os.stat(p).st_mtime_ns for p in frames}
    assert max(len(f) for f in kept.values()) >= 3
    for i in queued:   # never started: nothing written, no attempt recorded
        assert i["attempts"] == 0 and not os.path.exists(os.path.join(os.path.dirname(i["job"]), "out"))
    # nothing half-written, no output folder left locked, and nothing still writing after the driver exited
    time.sleep(1.0)
    for j in jobs:
        out_dir = os.path.join(os.path.dirname(j), "out")
        assert not glob.glob(os.path.join(out_dir, "conditions", ".*.tmp"))
        assert not os.path.exists(os.path.join(out_dir, locking.LOCK_NAME))
    assert {j: {p: os.stat(p).st_mtime_ns for p in finished_frames(j)} for j in kept} == kept
    # the same command again finishes everything, at once (no stopped job still holds a worker), rendering only
    # the missing frames
    t0 = time.time()
    code, ev, err = run_backend(*command[3:])
    assert code == 0, err[-3000:]
    again = {i["job"]: i for i in ev[-1]["items"]}
    assert all(i["status"] == "ok" and i["attempts"] == 1 for i in again.values())
    assert sorted(i["started"] for i in again.values())[1] - t0 < 20   # two jobs at once, as soon as it is up
    for j in jobs:
        assert again[j]["rendered"] == n - len(kept.get(j, {}))
        exrs = sorted(glob.glob(os.path.join(os.path.dirname(j), "out", "conditions", "frame_*.exr")))
        assert [os.path.basename(p) for p in exrs] == [f"frame_{f:06d}.exr" for f in range(1, n + 1)]
        assert all(channels.read(p)["R"].shape == (240, 320) for p in exrs)   # every frame whole
    for j, frames in kept.items():   # frames finished before the SIGTERM were not rendered again
        assert {p: os.stat(p).st_mtime_ns for p in frames} == frames


def proc_stat(pid):
    """(state, parent pid) of a process from /proc, None once it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return fields[0], int(fields[1])


def children(pid):
    """The live (not zombie) processes whose parent is ``pid``."""
    stats = {int(p.split("/")[2]): proc_stat(p.split("/")[2]) for p in glob.glob("/proc/[0-9]*/stat")}
    return [c for c, st in stats.items() if st is not None and st[1] == pid and st[0] != "Z"]


def alive(pid):
    st = proc_stat(pid)
    return st is not None and st[0] != "Z"


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc to see the driver's child processes")
def test_sigterm_while_the_driver_starts_its_cluster_ends_in_a_summary_with_nothing_run(tmp_path):
    # ray.init puts in its own SIGTERM handler (sys.exit) while it starts a local cluster; a SIGTERM then must still
    # end in the summary (nothing run), not in an exit with no JSON, and the cluster's processes must go
    job = small_job(tmp_path / "job")
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}   # a new local cluster
    driver = subprocess.Popen([sys.executable, "-m", "backend", "batch", job, "--ray", "--device", "cpu",
                               "--command", "render"], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and driver.poll() is None and not children(driver.pid):
            time.sleep(0.005)
        started = children(driver.pid)   # ray.init is starting the cluster's processes
        assert started, "the driver started no cluster"
        driver.send_signal(signal.SIGTERM)
        out, err = driver.communicate(timeout=60)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode == 1, err[-3000:]
    ev = events_of(out)
    assert len(ev) == 1 and len(out.splitlines()) == 1, out   # standard output: the summary, nothing else
    assert ev[0]["event"] == "done" and ev[0]["counts"] == {"not run (SIGTERM)": 1}
    assert ev[0]["items"] == [{"job": job, "status": "not run (SIGTERM)", "attempts": 0}]
    assert "no job is sent" in err and not os.path.exists(os.path.join(os.path.dirname(job), "out"))
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and any(alive(p) for p in started):
        time.sleep(0.1)
    assert not any(alive(p) for p in started), "the cluster's processes outlived the driver"


def test_without_the_ray_package_the_option_is_refused_saying_what_to_install(tmp_path):
    # sys.modules["ray"] = None: Python's own way to make a package unimportable (a backend environment without it)
    job = small_job(tmp_path / "job")
    run = ("import runpy, sys; sys.modules['ray'] = None; "
           "runpy.run_module('backend', run_name='__main__', alter_sys=True)")
    r = subprocess.run([sys.executable, "-c", run, "batch", job, "--ray", "--command", "render"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr[-2000:]
    (error,) = events_of(r.stdout)
    assert error["event"] == "error" and error["field"] == "--ray" and "needs the ray package" in error["message"]
    assert "pip install ray" in error["hint"] and "Traceback" not in r.stderr
    assert not os.path.exists(os.path.join(os.path.dirname(job), "out"))


def test_a_job_interrupted_outside_its_stop_flag_is_reported_as_run_and_a_queued_one_as_not_run(ray_cluster,
                                                                                               tmp_path):
    marker = tmp_path / "started"

    def deaf(path, *args, **options):
        """A job that never sees its stop flag: Ray's cancel reaches it as a KeyboardInterrupt (as it would a job
        running in a thread), so its task ends as "cancelled" although it ran."""
        signal.signal(signal.SIGINT, signal.default_int_handler)
        marker.touch()
        for _ in range(6000):  # short sleeps: Ray's interrupt is seen between them, not within one
            time.sleep(0.01)

    jobs = [small_job(tmp_path / "first"), small_job(tmp_path / "second")]
    stop, box = [], {}
    driver = threading.Thread(target=lambda: box.update(results=batch_ray.run_ray_batch(
        jobs, "render", "cpu", cpus_per_job=2, stop=stop, job_fn=deaf)))   # 2 CPUs each: one at a time
    driver.start()
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert marker.exists(), "the job did not start"
    stop.append(True)   # what the driver's SIGTERM handler does
    sent = time.monotonic()
    driver.join(timeout=30)
    assert not driver.is_alive() and time.monotonic() - sent < 10
    ran, queued = sorted(box["results"], key=lambda r: -r["attempts"])
    # it ran (the board saw it start), so "stopped", saying its counts are unknown; never "not run"
    assert ran["status"] == "stopped" and ran["attempts"] == 1 and "not known" in ran["error"] and ran["worker"]
    assert queued == {"job": queued["job"], "status": "not run (SIGTERM)", "attempts": 0}


def test_an_address_nobody_answers_at_is_bad_input_at_once_not_a_hang(monkeypatch):
    from scpainter_blender.core import errors

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    t = time.monotonic()
    with pytest.raises(errors.ArgumentError) as e:
        batch_ray._check_reachable("127.0.0.1:1")       # nothing listens on port 1: refused at once
    assert e.value.field == "--ray" and "no Ray head answers at 127.0.0.1:1" in e.value.message
    with pytest.raises(errors.ArgumentError) as e:
        batch_ray._check_reachable("head-without-port")
    assert e.value.field == "--ray" and "HOST:PORT" in e.value.message
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(errors.InputError) as e:
        batch_ray._check_reachable(None)
    assert (e.value.path, e.value.field) == ("(environment)", "RAY_ADDRESS")
    assert time.monotonic() - t < batch_ray.CONNECT_TIMEOUT_S
    for left_to_ray in ("auto", "ray://head:10001"):
        batch_ray._check_reachable(left_to_ray)


def test_an_address_where_another_service_listens_is_refused_not_a_hang(ray_cluster, monkeypatch):
    # a web server (or Redis, or the dashboard's port) accepts the TCP connection; ray.init would then wait for ever
    import http.server

    from scpainter_blender.core import errors

    monkeypatch.setattr(batch_ray, "CONNECT_TIMEOUT_S", 2.0)
    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        t = time.monotonic()
        with pytest.raises(errors.ArgumentError) as e:
            batch_ray._check_reachable(f"127.0.0.1:{server.server_address[1]}")
        assert e.value.field == "--ray" and "not as a Ray head" in e.value.message and "8265" in e.value.hint
        assert time.monotonic() - t < 2.0 + 1.0
    finally:
        server.shutdown()
        server.server_close()
    batch_ray._check_reachable(ray_cluster)   # a real head passes both tests


def test_more_cpus_per_job_than_any_node_has_and_a_job_listed_twice(ray_cluster, tmp_path):
    from scpainter_blender.core import errors

    job = small_job(tmp_path / "job")
    with pytest.raises(errors.ArgumentError) as e:       # Ray would queue it for ever
        batch_ray.run_ray_batch([job], "render", "cpu", cpus_per_job=3)
    assert e.value.field == "--cpus-per-job" and "largest node" in e.value.message
    with pytest.raises(errors.ArgumentError) as e:
        batch_ray.run_ray_batch([job], "render", "cpu", cpus_per_job=float("inf"))
    assert e.value.field == "--cpus-per-job"
    again = os.path.join(str(tmp_path), ".", "job", "job.json")   # the same file, spelled another way
    os.symlink(tmp_path / "job", tmp_path / "link")
    linked = str(tmp_path / "link" / "job.json")                    # and through a link to its folder
    hard = str(tmp_path / "job" / "same.json")                      # and through a hard link beside it
    os.link(job, hard)
    results = batch_ray.run_ray_batch([job, again, linked, hard], "render", "cpu")
    # run once (together they would meet at the output lock); each copy gets the job's result, so nothing "fails"
    assert [r["status"] for r in results] == ["ok"] * 4 and results[0]["rendered"] == 2
    assert [r.get("duplicate_of") for r in results] == [None, 0, 0, 0]
    assert [r["attempts"] for r in results] == [1, 0, 0, 0]
    assert [r["job"] for r in results] == [job, again, linked, hard] and results[3]["rendered"] == 2


def test_ctrl_c_on_a_driver_is_a_stop_and_a_second_one_aborts():
    from backend import events

    # whatever this process got (a background job's SIGINT is ignored), the block's handler applies within it and
    # the disposition before it is put back after it
    before = signal.getsignal(signal.SIGINT)
    with events.stop_on_sigterm(sigint=True) as stop:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        assert stop == [True]
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
    assert signal.getsignal(signal.SIGINT) is before


class Driver:
    """``python -m backend batch … --ray ADDRESS`` as a subprocess whose events are read as they come (a thread
    puts each standard-output line on a queue): the tests wait on the event stream, each wait bounded. SIGINT's
    disposition is set explicitly in the child (``default_int_handler``, as an interactive Python has it), so the
    test means the same when pytest runs as a background job, where SIGINT is ignored and a child inherits that."""

    def __init__(self, argv, tmp_path):
        import queue

        run = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
               "runpy.run_module('backend', run_name='__main__', alter_sys=True)")
        self.stderr = open(tmp_path / "driver_stderr.txt", "w+")
        self.proc = subprocess.Popen([sys.executable, "-c", run, *map(str, argv)], cwd=ROOT, stdout=subprocess.PIPE,
                                     stderr=self.stderr, text=True)
        self.lines, self.events = queue.Queue(), []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put(None)

    def next_event(self, timeout=180):
        line = self.lines.get(timeout=timeout)   # queue.Empty: no event within the bound
        if line is None:
            return None
        self.events.append(json.loads(line))     # standard output: JSON events only
        return self.events[-1]

    def wait_for(self, accept, timeout=180):
        """The first event ``accept`` takes, reading on; fails at the end of the stream or after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            ev = self.next_event(max(deadline - time.monotonic(), 0.01))
            assert ev is not None, f"the stream ended first: {self.events} {self.err()[-3000:]}"
            if accept(ev):
                return ev

    def finish(self, timeout=120):
        """(exit code, the summary: the last event) once the driver has ended."""
        while self.next_event(timeout) is not None:
            pass
        return self.proc.wait(timeout=timeout), self.events[-1]

    def err(self):
        """The driver's standard error so far (all of it once closed)."""
        if self.stderr.closed:
            return self.stderr_text
        self.stderr.seek(0)
        return self.stderr.read()

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.stderr_text = self.err()
        self.stderr.close()


def job_lock(job_path):
    return os.path.join(os.path.dirname(job_path), "out", locking.LOCK_NAME)


def test_a_worker_killed_mid_batch_costs_only_its_attempt_and_no_finished_job_runs_again(ray_cluster, tmp_path):
    """The driver keeps the batch's books (no actor holds them): a worker SIGKILLed mid-batch (Ray's memory monitor,
    the kernel's OOM killer, a lost node do the same) loses only the attempt it ran. That job runs again, resuming;
    the jobs that had finished are not run again (their frames untouched), and the summary comes as always."""
    n = 40
    short = [small_job(tmp_path / f"short{i}") for i in range(2)]
    long = small_job(tmp_path / "long", frames=tuple(range(1, n + 1)), resolution=(320, 240))
    jobs = [short[0], long, short[1]]
    driver = Driver(["batch", *jobs, "--ray", ray_cluster, "--device", "cpu", "--command", "render"], tmp_path)
    try:
        # each short job ends long before the long one: its frames as it left them
        finished = {}
        while len(finished) < 2:
            ev = driver.wait_for(lambda e: e["event"] == "progress")
            assert ev["job"] in short and ev["status"] == "ok", ev
            finished[ev["job"]] = exr_mtimes(ev["job"])
        # then the long job's worker dies mid-job, its lock left behind
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(finished_frames(long)) < 3:
            time.sleep(0.01)
        owner = locking.OutputLock(os.path.dirname(job_lock(long)), "test")._owner()
        kept = len(finished_frames(long))
        assert isinstance(owner, dict) and 3 <= kept < n, (owner, kept)
        os.kill(owner["pid"], signal.SIGKILL)
        code, done = driver.finish()
    finally:
        driver.close()
    assert code == 0, driver.err()[-3000:]
    assert done["event"] == "done" and (done["jobs"], done["ok"], done["failed"], done["not_run"]) == (3, 3, 0, 0)
    by = {i["job"]: i for i in done["items"]}
    assert [by[j]["attempts"] for j in jobs] == [1, 2, 1]          # the finished jobs ran once
    assert by[long]["worker"] != f"{socket.gethostname()}:{owner['pid']}" and by[long]["rendered"] <= n - kept
    assert {j: exr_mtimes(j) for j in short} == finished            # and wrote nothing after they finished
    assert len(finished_frames(long)) == n and not os.path.exists(job_lock(long))
    assert [e["done"] for e in driver.events[:-1]] == [1, 2, 3]     # one progress event per job, none twice


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_sigterm_or_ctrl_c_on_the_driver_prints_the_summary_with_not_run_apart_from_failed(ray_cluster, tmp_path,
                                                                                           sig):
    # frames of a long job: the signal comes while one runs, and its stop (a SIGINT sent by a task Ray schedules on
    # the worker's node) lands long before the job could end, however busy the machine (40 frames once ended first)
    n = 400
    bad = small_job(tmp_path / "bad")
    os.remove(tmp_path / "bad" / "car.ply")
    jobs = [bad] + [small_job(tmp_path / f"long{i}", frames=tuple(range(1, n + 1)), resolution=(320, 240))
                    for i in range(3)]
    # 2 CPUs per job on the 2-CPU cluster: one job at a time, the others queued
    driver = Driver(["batch", *jobs, "--ray", ray_cluster, "--device", "cpu", "--command", "render",
                     "--cpus-per-job", "2"], tmp_path)
    try:
        driver.wait_for(lambda e: e["event"] == "progress" and e["status"] == "failed")   # the bad job ended
        deadline = time.monotonic() + 120   # a long job under way: its output folder locked, a frame finished
        while time.monotonic() < deadline and not any(finished_frames(j) for j in jobs[1:]):
            time.sleep(0.01)
        driver.proc.send_signal(sig)
        code, done = driver.finish()
    finally:
        driver.close()
    assert code == 1, driver.err()[-3000:]
    assert done["event"] == "done" and [e["event"] for e in driver.events[:-1]] == ["progress"] * 4
    items = {i["job"]: i for i in done["items"]}
    assert items[bad]["status"] == "failed" and items[bad]["file"].endswith("car.ply")
    # the job under way stopped after its frame; the queued ones never started: not_run, not failed
    assert (done["failed"], done["stopped"], done["ok"]) == (1, 1, 0), done["items"]
    assert done["not_run"] == 2 and done["counts"]["not run (SIGTERM)"] == 2
    for i in done["items"]:
        assert (i["attempts"] == 0) == (i["status"] == "not run (SIGTERM)")
        if i["status"] == "not run (SIGTERM)":
            assert not os.path.exists(os.path.join(os.path.dirname(i["job"]), "out"))
        if i["status"] == "stopped":
            assert 1 <= i["rendered"] == len(finished_frames(i["job"])) < n and not os.path.exists(job_lock(i["job"]))
    assert "Traceback" not in driver.err()


def test_a_job_writing_another_jobs_output_folder_is_refused_before_any_job_is_sent(ray_cluster, tmp_path):
    """Two different jobs, one output folder (a copy with a shorter frame range): the later item fails as bad input
    (output_dir, the other job named, a hint), never sent (0 attempts, no folder-busy race at the output lock);
    the same job listed again is still a copy, not a conflict; the first job's frames are all kept."""
    from scpainter_blender.core import job as J

    job = small_job(tmp_path / "j", frames=(1, 2, 3))
    content = J.load(job).to_dict()
    content["frames"] = content["frames"][:1]
    short = str(tmp_path / "j" / "job_short.json")
    J.save(short, content)
    again = os.path.join(str(tmp_path), "j", ".", "job.json")
    results = batch_ray.run_ray_batch([job, short, again], "render", "cpu")
    assert [r["status"] for r in results] == ["ok", "failed", "ok"], results
    assert results[1]["field"] == "output_dir" and results[1]["file"] == short and job in results[1]["error"]
    assert "own output_dir" in results[1]["hint"] and results[1]["attempts"] == 0
    assert results[2]["duplicate_of"] == 0
    assert len(glob.glob(str(tmp_path / "j" / "out" / "conditions" / "frame_*.exr"))) == 3
