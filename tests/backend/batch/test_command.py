"""``python -m backend batch``: sharding, failures recorded and passed over, two processes under torchrun."""

import glob
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from backend.batch import command as batch
from scpainter_blender.core import job as J
from scpainter_blender.core import shapes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def test_shard_covers_every_item_once():
    from scpainter_blender.core.batch_items import job_shard, shard

    items = [f"j{i}" for i in range(11)]
    parts = [shard(items, r, 4) for r in range(4)]
    assert sorted(sum(parts, [])) == sorted(items) and parts[1] == ["j1", "j5", "j9"]
    assert shard(items, 0, 1) == items
    with pytest.raises(ValueError):
        shard(items, 4, 4)
    # by job: without copies the same shares; a copy (item 5 of item 2's job) goes with its job
    assert [job_shard(list(range(11)), r, 4) for r in range(4)] == [list(range(r, 11, 4)) for r in range(4)]
    assert job_shard([0, 1, 2, 3, 4, 2], 2, 4) == [2, 5] and job_shard([0, 1, 2, 3, 4, 2], 1, 4) == [1]
    with pytest.raises(ValueError):
        job_shard([0], 4, 4)


def _car_job(folder, name, ply_ok=True):
    """A small assets-only job (a car seen from 8 m back, 48 x 32 pixels, 2 frames)."""
    os.makedirs(folder, exist_ok=True)
    if ply_ok:
        shapes.save_as_amodal3r(os.path.join(folder, "car.ply"), shapes.procedural_car_gaussians(count=2000, seed=1))
    w2c = np.eye(4)
    w2c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    w2c[:3, 3] = -w2c[:3, :3] @ np.array([0.0, -8.0, 0.3])
    obj = (np.diag([4.5 / 0.98] * 3 + [1.0]) @ np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]]))
    frames = [{"frame": f, "K": [[40, 0, 24], [0, 40, 16], [0, 0, 1]], "world_to_camera": w2c.tolist()}
              for f in (1, 2)]
    job = {"schema": J.SCHEMA, "resolution": [48, 32], "frames": frames, "output_dir": f"out_{name}",
           "assets": [{"name": "car", "ply": "car.ply", "object_to_world": {"1": obj.tolist(), "2": obj.tolist()}}]}
    path = os.path.join(folder, f"{name}.json")
    J.save(path, job)
    return path


def test_two_processes_under_torchrun(tmp_path):
    jobs = [_car_job(tmp_path / "a", "a"), _car_job(tmp_path / "b", "b", ply_ok=False), _car_job(tmp_path / "c", "c")]
    (tmp_path / "list.txt").write_text("# three jobs\nc/c.json\n\n")
    torchrun = os.path.join(os.path.dirname(sys.executable), "torchrun")
    p = subprocess.run([torchrun, "--standalone", "--nproc_per_node", "2", "-m", "backend", "batch", jobs[0],
                        jobs[1], "--list", str(tmp_path / "list.txt"), "--command", "render", "--device", "cpu"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": ROOT, "OMP_NUM_THREADS": "1"})
    assert p.returncode != 0  # one job failed: every rank says so
    events = [json.loads(line) for line in p.stdout.splitlines() if line.startswith("{")]
    done = [e for e in events if e["event"] == "done"]
    assert len(done) == 1, p.stdout + p.stderr[-3000:]  # one summary, from rank 0
    items = {os.path.basename(r["job"]): r for r in done[0]["items"]}
    assert set(items) == {"a.json", "b.json", "c.json"} and done[0]["failed"] == 1
    assert items["a.json"]["rank"] == 0 and items["b.json"]["rank"] == 1 and items["c.json"]["rank"] == 0
    assert items["a.json"]["status"] == "ok" and items["c.json"]["status"] == "ok"
    assert items["b.json"]["status"] == "failed" and "car.ply" in items["b.json"]["error"]
    assert items["b.json"]["file"] == str(tmp_path / "b" / "car.ply") and "log" not in items["b.json"]  # bad input
    for name in ("a", "c"):
        made = os.listdir(tmp_path / name / f"out_{name}" / "conditions")
        assert len([f for f in made if f.startswith(("frame_", "preview_"))]) == 4   # 2 EXR + 2 PNG


def test_a_distributed_run_without_its_rendezvous_is_refused_before_any_job(tmp_path):
    """WORLD_SIZE=2 without MASTER_ADDR/PORT would render its share and only then fail to gather: bad input."""
    job = _car_job(tmp_path / "a", "a")
    env = {k: v for k, v in os.environ.items() if k not in ("MASTER_ADDR", "MASTER_PORT")}
    env.update(RANK="0", WORLD_SIZE="2", PYTHONPATH=ROOT)
    proc = subprocess.run([sys.executable, "-m", "backend", "batch", job, "--command", "render", "--device", "cpu"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 2 and last["file"] == "(environment)" and last["field"] == "MASTER_ADDR", last
    assert not os.path.exists(tmp_path / "a" / "out_a")


def test_ray_options_without_ray_are_refused_not_ignored(tmp_path):
    job = _car_job(tmp_path / "a", "a")
    proc = subprocess.run([sys.executable, "-m", "backend", "batch", job, "--retries", "3"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 2 and last["field"] == "--retries" and "--ray only" in last["message"], last
    assert not os.path.exists(tmp_path / "a" / "out_a")


def test_a_ray_dashboard_url_is_refused_as_bad_input_not_an_internal_error(tmp_path, monkeypatch):
    """Issue 42: ``--ray http://127.0.0.1:8265`` (or that URL in RAY_ADDRESS, ``--ray`` without an address) exited 1
    as "an internal error … please report it"; now exit 2 naming the option or the variable, with what to give,
    before any cluster is joined or job run. In-process (``backend.__main__.main``)."""
    import contextlib
    import io

    from backend.__main__ import main

    job = _car_job(tmp_path / "a", "a")

    def run(*args):
        out = io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
            code = main(["batch", job, "--command", "render", "--device", "cpu", *args])
        return code, json.loads(out.getvalue().strip().splitlines()[-1])

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    code, last = run("--ray", "http://127.0.0.1:8265")
    assert code == 2 and last["field"] == "--ray" and "web address" in last["message"], last
    assert "ray://HEAD:10001" in last["hint"]
    monkeypatch.setenv("RAY_ADDRESS", "http://127.0.0.1:8265")
    code, last = run("--ray")
    assert code == 2 and (last["file"], last["field"]) == ("(environment)", "RAY_ADDRESS"), last
    assert not os.path.exists(tmp_path / "a" / "out_a")


def test_a_checkpoint_that_is_not_one_is_refused_before_any_job(tmp_path):
    job = _car_job(tmp_path / "a", "a")
    proc = subprocess.run([sys.executable, "-m", "backend", "batch", job, "--command", "generate", "--checkpoint",
                           str(tmp_path / "nope")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 2 and last["event"] == "error" and last["file"] == str(tmp_path / "nope"), last
    assert not os.path.exists(tmp_path / "a" / "out_a")


def test_ctrl_c_on_a_batch_stops_the_running_job_and_still_prints_the_summary(tmp_path):
    """Without Ray too: the first Ctrl-C stops the running job after its frame; the jobs after it are not_run,
    apart from the failed one, in the summary. SIGINT's disposition is set in the child (a background pytest's
    children inherit SIGINT ignored)."""
    import glob
    import signal
    import time

    from tests_support import small_job

    bad = small_job(tmp_path / "bad")
    os.remove(tmp_path / "bad" / "car.ply")
    long, after = (small_job(tmp_path / n, frames=tuple(range(1, 41)), resolution=(320, 240)) for n in ("l", "m"))
    run = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
           "runpy.run_module('backend', run_name='__main__', alter_sys=True)")
    proc = subprocess.Popen([sys.executable, "-c", run, "batch", bad, long, after, "--command", "render", "--device",
                             "cpu"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        first = json.loads(proc.stdout.readline())          # the bad job's progress event: the long one starts next
        assert first["event"] == "progress" and first["status"] == "failed", first
        labels = str(tmp_path / "l" / "out" / "conditions" / "labels_*.json")
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not glob.glob(labels):   # a frame of the long job finished
            time.sleep(0.01)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    done = json.loads(out.strip().splitlines()[-1])
    assert proc.returncode == 1 and done["event"] == "done", out
    assert (done["failed"], done["stopped"], done["not_run"], done["ok"]) == (1, 1, 1, 0), done["items"]
    assert [i["status"] for i in done["items"]] == ["failed", "stopped", "not run (SIGTERM)"]
    assert 1 <= done["items"][1]["rendered"] < 40 and not os.path.exists(tmp_path / "m" / "out")


def _short_copy(job_path, name, frames):
    """A copy of the job beside it (``name``), its frame range cut to ``frames``: the same output folder."""
    job = J.load(job_path).to_dict()
    job["frames"] = [f for f in job["frames"] if f["frame"] in frames]
    path = os.path.join(os.path.dirname(job_path), name)
    J.save(path, job)
    return path


def test_two_jobs_sharing_an_output_folder_refuse_the_later_one_before_anything_runs(tmp_path):
    """A job copied beside itself with a shorter frame range writes to the same output folder: run after the first,
    it would remove the first job's other frames. The later item fails (bad input naming it, output_dir, the other
    job, a hint); the first one's frames are all kept; the exit code says an item failed."""
    from tests_support import small_job

    job = small_job(tmp_path / "j", frames=(1, 2, 3, 4))
    short = _short_copy(job, "job_short.json", (1, 2))
    (tmp_path / "list.txt").write_text("j/job.json\nj/job_short.json\n")
    proc = subprocess.run([sys.executable, "-m", "backend", "batch", "--list", str(tmp_path / "list.txt"),
                           "--command", "render", "--device", "cpu"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "PYTHONPATH": ROOT})
    done = json.loads(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 1 and done["event"] == "done", proc.stdout + proc.stderr[-3000:]
    first, later = done["items"]
    assert first["status"] == "ok" and first["rendered"] == 4, first
    assert later["status"] == "failed" and later["file"] == short and later["field"] == "output_dir", later
    assert job in later["error"] and "own output_dir" in later["hint"], later
    exrs = glob.glob(str(tmp_path / "j" / "out" / "conditions" / "frame_*.exr"))
    assert len(exrs) == 4, exrs          # frames 3 and 4 of the first job are still there


def test_a_job_listed_again_runs_once_and_each_rank_refuses_the_same_items(tmp_path):
    """Without Ray as with it (batch_items.first_items): the same job through a hard link, a symbolic link to its
    folder or a ``..`` spelling runs once, the copies repeating its result with ``duplicate_of``; a copy is run by
    the rank of its job's first item. Every rank sees every item, so a rank refuses a job sharing the output folder
    of a job another rank runs, though it never runs that one. A job path naming nothing fails with a hint."""
    from tests_support import small_job

    job = small_job(tmp_path / "j")
    os.link(job, tmp_path / "j" / "hard.json")
    os.symlink(tmp_path / "j", tmp_path / "link")
    items = [job, str(tmp_path / "j" / "hard.json"), str(tmp_path / "link" / "job.json"),
             os.path.join(str(tmp_path), "link", "..", "j", "job.json"), str(tmp_path / "missing.json")]
    results, reports = batch.run_batch(items, "render", "cpu", shard_of=(0, 1))
    assert reports and [r["status"] for r in results] == ["ok"] * 4 + ["failed"], results
    assert [r.get("duplicate_of") for r in results] == [None, 0, 0, 0, None]
    assert [r["job"] for r in results] == items and all(r["rendered"] == 2 for r in results[:4])
    assert results[4]["hint"] and results[4]["file"] == items[4], results[4]

    other = small_job(tmp_path / "k", frames=(1, 2, 3))
    items = [other, _short_copy(other, "short.json", (1,)), job, str(tmp_path / "k" / "." / "job.json")]
    rank1, _ = batch.run_batch(items, "render", "cpu", shard_of=(1, 2))   # item 1 alone: item 3 goes with item 0
    assert [r["job"] for r in rank1] == [items[1]] and rank1[0]["status"] == "failed", rank1
    assert rank1[0]["field"] == "output_dir" and other in rank1[0]["error"], rank1
    assert not os.path.exists(tmp_path / "k" / "out")                     # refused before anything ran
    rank0, _ = batch.run_batch(items, "render", "cpu", shard_of=(0, 2))   # items 0 and 2, and 3 (a copy of 0)
    assert [r["job"] for r in rank0] == [items[0], items[2], items[3]], rank0
    assert [r["status"] for r in rank0] == ["ok"] * 3 and rank0[2]["duplicate_of"] == 0 and rank0[0]["rendered"] == 3


def test_the_jobs_of_one_process_clean_their_shared_points_once(tmp_path):
    """Variants of one recording in one batch process: the second job takes the points the first cleaned (its
    backend.log says so) and renders the same layers as the job run alone. Nothing stays kept after the batch (a
    changed file is read again: tests/backend/render/test_scene_cache.py)."""
    from backend.render import channels, scene_cache
    from backend.render import command as render_cmd
    from tests_support import variant_jobs

    shared, jobs = variant_jobs(tmp_path)
    served = "batch: the points of"

    def log(job):
        with open(os.path.join(os.path.dirname(job), "out", "backend.log")) as f:
            return f.read()

    results, _ = batch.run_batch(jobs, "render", "cpu", shard_of=(0, 1), data_roots={j: (shared,) for j in jobs})
    assert [r["status"] for r in results] == ["ok", "ok"], results
    assert served not in log(jobs[0])
    assert served in log(jobs[1]) and "served from memory (loaded by an earlier job of this batch)" in log(jobs[1])
    assert scene_cache._kept is None
    alone = tmp_path / "alone"
    os.makedirs(alone)
    J.save(alone / "job.json", J.load(jobs[1]).to_dict())
    render_cmd.render_job(str(alone / "job.json"), J.load(alone / "job.json"), "cpu", data_roots=(shared,))
    for f in (1, 2):
        name = os.path.join("out", "conditions", f"frame_{f:06d}.exr")
        got, want = (channels.read(os.path.join(d, name)) for d in (os.path.dirname(jobs[1]), str(alone)))
        assert all(np.array_equal(got[k], want[k], equal_nan=True) for k in want)
