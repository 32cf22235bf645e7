"""``python -m backend batch --ray``: jobs scheduled on a local Ray cluster of 2 CPUs (``backend/batch_ray.py``)."""

import glob
import json
import os
import signal
import threading
import time

import pytest

from backend import batch, batch_ray
from backend.render import channels
from scpainter_blender.core import locking
from tests_support import run_backend, small_job

ray = pytest.importorskip("ray")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def cluster():
    """A new local Ray cluster of 2 CPUs (2 workers at a time; never one `ray start` left running), shared by this
    module's tests."""
    ray.init(address="local", num_cpus=2, log_to_driver=False, include_dashboard=False, configure_logging=False,
             runtime_env={"env_vars": {"PYTHONPATH": ROOT}})
    yield
    ray.shutdown()


def events_of(text):
    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


def exr_mtimes(job_path):
    folder = os.path.join(os.path.dirname(job_path), "out", "conditions")
    return {f: os.stat(f).st_mtime_ns for f in glob.glob(os.path.join(folder, "*.exr"))}


def test_six_jobs_over_two_workers_then_a_rerun_skips_them(cluster, tmp_path, capsys):
    jobs = [small_job(tmp_path / f"job{i}", frames=tuple(range(1, 2 + i))) for i in range(6)]
    results = batch_ray.run_ray_batch(jobs, "render", "cpu")
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


def test_a_job_that_fails_once_succeeds_on_retry_and_one_that_always_fails_is_reported(cluster, tmp_path):
    marker = str(tmp_path / "failed_once")

    def flaky(path, *args):
        """A transient failure (a GPU error, a network file system hiccup) on this job's first attempt only."""
        if path.endswith("flaky/job.json") and not os.path.exists(marker):
            open(marker, "w").close()
            raise OSError("transient: the shared file system went away for a moment")
        if path.endswith("broken/job.json"):
            raise RuntimeError("a bug that fails every time")
        return batch.run_one(path, *args)

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


def test_a_worker_killed_mid_job_reruns_it_without_losing_or_repeating_a_frame(cluster, tmp_path):
    job = small_job(tmp_path / "long", frames=tuple(range(1, 61)), resolution=(320, 240))
    out = tmp_path / "long" / "out"
    box = {}
    driver = threading.Thread(target=lambda: box.update(results=batch_ray.run_ray_batch([job], "render", "cpu")))
    driver.start()
    killed = None
    deadline = time.monotonic() + 300
    while killed is None and time.monotonic() < deadline and driver.is_alive():
        owner = locking.OutputLock(str(out), "test")._owner()
        frames = [p for p in glob.glob(str(out / "conditions" / "frame_*.exr"))  # a frame is its EXR and preview
                  if os.path.exists(p.replace("frame_", "preview_").replace(".exr", ".png"))]
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
    assert [i["status"] for i in done["items"]] == ["ok", "failed"] and done["items"][1]["file"].endswith("car.ply")
    code, ev, _ = run_backend("batch", good, "--ray", "--device", "cpu", "--cpus-per-job", "0")
    assert code == 2 and ev[-1]["field"] == "--cpus-per-job"
