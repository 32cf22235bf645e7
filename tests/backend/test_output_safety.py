"""A job from someone else reads and writes only its own folder; one run per output folder; clean-up deletes only
what this project wrote (issue 14, points 4 and 5). Runs ``python -m backend`` in-process on small jobs."""

import json
import os
import shutil
import subprocess
import sys

import pytest

from scpainter_blender.core import files, locking
from scpainter_blender.core import job as J
from tests_support import run_backend_here, small_job, variant_jobs


def run(*args):
    """(exit code, events) of ``python -m backend *args`` run in this process, with no traceback."""
    code, evs, err = run_backend_here(*args)
    assert "Traceback" not in err, err
    return code, evs


def snapshot(folder):
    """Every path under ``folder`` with its size and modification time (links: their target)."""
    seen = {}
    for root, dirs, names in os.walk(folder):
        for n in dirs + names:
            p = os.path.join(root, n)
            seen[p] = os.readlink(p) if os.path.islink(p) else (os.lstat(p).st_size, os.lstat(p).st_mtime_ns)
    return seen


@pytest.fixture
def case(tmp_path):
    """A job folder and, beside it, a folder of the user's files that no run may touch."""
    outside = tmp_path / "outside"
    outside.mkdir()
    for name in ("frame_000001.exr", "preview_000001.png", "backend.log", "notes.txt"):
        (outside / name).write_text("the user's own file\n")
    return small_job(tmp_path / "job"), outside


def edit(job_path, **changes):
    job = J.load(job_path).to_dict()
    job.update(changes)
    J.save(job_path, job)


@pytest.mark.parametrize("output_dir", ["../outside", "../outside/conditions", "/tmp/scpainter-escape", "sub/../.."])
def test_output_dir_may_not_leave_the_job_folder(case, output_dir):
    job_path, outside = case
    edit(job_path, output_dir=output_dir)
    before = snapshot(os.path.dirname(outside))
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 2 and ev[-1]["field"] == "output_dir" and "--allow-outside" in ev[-1]["hint"]
    assert ev[-1]["file"] == job_path
    assert snapshot(os.path.dirname(outside)) == before            # nothing written anywhere
    assert not os.path.exists("/tmp/scpainter-escape")


def test_inputs_may_not_leave_the_job_folder(case):
    job_path, outside = case
    folder = os.path.dirname(job_path)
    os.replace(os.path.join(folder, "car.ply"), outside / "car.ply")
    os.symlink(outside / "car.ply", os.path.join(folder, "car.ply"))   # a link pointing out counts as outside
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 2 and ev[-1]["field"] == "assets[0].ply" and "symbolic link" in ev[-1]["message"]
    edit(job_path, scene={**J.load(job_path).to_dict()["scene"], "predictions": "../outside/predictions.npz"})
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 2 and ev[-1]["field"] == "scene.predictions"
    # the user may say so
    os.replace(os.path.join(folder, "predictions.npz"), outside / "predictions.npz")
    code, ev = run("render", job_path, "--device", "cpu", "--allow-outside")
    assert code == 0 and ev[-1]["rendered"] == 2


def test_allow_outside_writes_where_the_user_said(case, tmp_path):
    job_path, _ = case
    edit(job_path, output_dir=str(tmp_path / "elsewhere"))
    code, ev = run("render", job_path, "--device", "cpu", "--allow-outside")
    assert code == 0 and os.path.isfile(tmp_path / "elsewhere" / "conditions" / "frame_000002.exr")


def test_a_data_root_lets_variant_jobs_share_one_recording_and_nothing_else(tmp_path):
    """Variants in their own folders read one recording and asset through ../shared: refused without a data root,
    accepted with --data-root (check and run); a path outside both the job's folder and the root still refused."""
    shared, (v1, v2) = variant_jobs(tmp_path)
    code, ev = run("render", v1, "--check")
    assert code == 2 and ev[-1]["file"] == v1 and ev[-1]["field"] == "scene.predictions"
    assert "--data-root" in ev[-1]["hint"]
    code, ev = run("render", v1, "--check", "--data-root", shared)
    assert code == 0 and ev[-1]["check"] is True and ev[-1]["output_dir"] == os.path.join(os.path.dirname(v1), "out")
    code, ev = run("render", v1, "--device", "cpu", "--data-root", shared)
    assert code == 0 and ev[-1]["rendered"] == 2
    assert os.path.isfile(os.path.join(os.path.dirname(v1), "out", "conditions", "frame_000002.exr"))
    for command in (("generate", "--check"), ("export", "--format", "kitti")):   # the other job commands alike
        code, ev = run(*command, v1, "--data-root", shared)
        assert code == 0, (command, ev[-1])
        code, ev = run(*command, v1)
        assert code == 2 and ev[-1]["field"] == "scene.predictions", (command, ev[-1])
    # an asset outside the job's folder and the root: refused, naming the field and both folders
    (tmp_path / "elsewhere").mkdir()
    os.replace(os.path.join(shared, "car.ply"), tmp_path / "elsewhere" / "car.ply")
    os.symlink(tmp_path / "elsewhere" / "car.ply", os.path.join(shared, "car.ply"))   # in the root by name only
    before = snapshot(tmp_path)
    code, ev = run("render", v2, "--device", "cpu", "--data-root", shared)
    assert code == 2 and ev[-1]["file"] == v2 and ev[-1]["field"] == "assets[0].ply"
    assert "symbolic link" in ev[-1]["message"] and shared in ev[-1]["message"]
    assert os.path.dirname(v2) in ev[-1]["message"]
    assert snapshot(tmp_path) == before                                 # nothing written
    code, ev = run("render", v2, "--check", "--data-root", shared, "--allow-outside")   # which overrides it
    assert code == 0
    for root in (tmp_path / "missing", tmp_path / "elsewhere" / "car.ply"):  # a data root must be a folder
        code, ev = run("render", v1, "--check", "--data-root", root)
        assert code == 2 and ev[-1]["file"] == "(command line)" and ev[-1]["field"] == "--data-root"


def test_a_batch_list_declares_its_data_root_for_its_own_jobs(tmp_path):
    """batch --list: a list's data-root: line trusts the shared folder for that list's jobs only; a job of the
    same list naming a file outside it fails with its file and field, the others run."""
    shared, (v1, v2, v3) = variant_jobs(tmp_path, ("v1", "v2", "v3"))
    job = J.load(v2).to_dict()
    job["assets"][0]["ply"] = "../elsewhere/car.ply"
    J.save(v2, job)
    (tmp_path / "elsewhere").mkdir()
    shutil.copy(os.path.join(shared, "car.ply"), tmp_path / "elsewhere" / "car.ply")
    listed = tmp_path / "variants.txt"
    listed.write_text("# the variants of one drive\ndata-root: shared\n\nv1/job.json\nv2/job.json\n")
    # v3 is given on the command line: the list's root is not its
    code, ev = run("batch", v3, "--list", listed, "--device", "cpu")
    assert code == 1
    items = {os.path.basename(os.path.dirname(r["job"])): r for r in ev[-1]["items"]}
    assert items["v1"]["status"] == "ok" and items["v1"]["rendered"] == 2
    assert items["v2"]["status"] == "failed" and items["v2"]["file"] == v2 and items["v2"]["field"] == "assets[0].ply"
    assert shared in items["v2"]["error"] and "--data-root" in items["v2"]["hint"]
    assert items["v3"]["status"] == "failed" and items["v3"]["file"] == v3
    assert items["v3"]["field"] == "scene.predictions" and "data root" not in items["v3"]["error"]
    assert not os.path.exists(os.path.join(os.path.dirname(v2), "out", "conditions"))
    # --data-root trusts it for every job; v2's asset stays outside both
    code, ev = run("batch", v3, "--list", listed, "--device", "cpu", "--data-root", shared)
    assert code == 1 and [r["status"] for r in ev[-1]["items"]] == ["ok", "ok", "failed"]
    assert ev[-1]["items"][0]["rendered"] == 2 and ev[-1]["items"][2]["field"] == "assets[0].ply"
    # a bad data-root: line is bad input of the list file, before any job
    listed.write_text("v1/job.json\ndata-root: shared\n")
    code, ev = run("batch", "--list", listed, "--device", "cpu")
    assert code == 2 and ev[-1]["file"] == str(listed) and ev[-1]["field"] == "line 2"


def test_links_planted_in_the_output_folder_are_not_followed(case):
    job_path, outside = case
    out = os.path.join(os.path.dirname(job_path), "out")
    os.makedirs(out)
    os.symlink(outside / "backend.log", os.path.join(out, "backend.log"))
    before = snapshot(outside)
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 2 and "backend.log" in ev[-1]["message"] and "symbolic link" in ev[-1]["message"]
    assert snapshot(outside) == before
    os.remove(os.path.join(out, "backend.log"))
    os.symlink(outside, os.path.join(out, "conditions"))              # the whole conditions folder
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 2 and "conditions" in ev[-1]["file"] and "outside the output folder" in ev[-1]["message"]
    assert snapshot(outside) == before
    os.remove(os.path.join(out, "conditions"))
    os.makedirs(os.path.join(out, "conditions"))
    os.symlink(outside / "frame_000001.exr", os.path.join(out, "conditions", "frame_000001.exr"))  # one frame
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 0 and ev[-1]["rendered"] == 2
    assert snapshot(outside) == before                                  # the link was replaced, not written through
    assert not os.path.islink(os.path.join(out, "conditions", "frame_000001.exr"))
    assert not [n for n in os.listdir(os.path.join(out, "conditions")) if n.endswith(".tmp")]


def test_stale_frames_clean_up_deletes_only_this_jobs_files(case):
    job_path, _ = case
    cond = os.path.join(os.path.dirname(job_path), "out", "conditions")
    code, _ = run("render", job_path, "--device", "cpu")
    assert code == 0
    record = files.read_json(os.path.join(cond, "record.json"))
    assert record["files"] == ["frame_000001.exr", "preview_000001.png", "labels_000001.json", "labelled_000001.png",
                               "frame_000002.exr", "preview_000002.png", "labels_000002.json", "labelled_000002.png"]
    for name in ("frame_000777.exr", "frame_notes.txt", "preview_mine.png"):  # not this job's outputs
        with open(os.path.join(cond, name), "w") as f:
            f.write("keep me\n")
    job = J.load(job_path).to_dict()
    job["scene"]["confidence_percentile"] = 10.0                         # the scene changed: every frame is stale
    J.save(job_path, job)
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 0 and ev[-1]["rendered"] == 2
    job["frames"] = job["frames"][:1]                                    # a shorter range: frame 2's files go
    for a in job.get("assets", []):
        a["object_to_world"] = {k: v for k, v in a["object_to_world"].items() if k == str(job["frames"][0]["frame"])}
    J.save(job_path, job)
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 0 and ev[-1]["rendered"] == 0
    assert sorted(n for n in os.listdir(cond) if n.endswith("000002.exr") or n.endswith("000002.png")
                  or n.endswith("000002.json")) == []
    code, ev = run("render", job_path, "--device", "cpu", "--force")
    assert code == 0 and ev[-1]["rendered"] == 1
    for name in ("frame_000777.exr", "frame_notes.txt", "preview_mine.png"):
        assert open(os.path.join(cond, name)).read() == "keep me\n"


def test_a_second_run_on_the_same_folder_is_refused(case):
    job_path, _ = case
    out = os.path.join(os.path.dirname(job_path), "out")
    with locking.OutputLock(out, "render (another process)"):
        code, ev = run("render", job_path, "--check")              # --check says a run would be refused
        assert code == 0 and ev[-1]["locked_by"]["pid"] == os.getpid()
        code, ev = run("render", job_path, "--device", "cpu")
        # this process holds the lock, so it is alive: the run is refused, not run twice
        assert code == 1 and "being written by another run" in ev[-1]["message"] and str(os.getpid()) in \
            ev[-1]["message"]
        assert not os.path.exists(os.path.join(out, "conditions", "frame_000001.exr"))
    # a lock left by a process that died is taken over
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    with open(os.path.join(out, locking.LOCK_NAME), "w") as f:
        json.dump({"pid": dead.pid, "host": __import__("socket").gethostname(), "started": None,
                   "command": "render", "since": "earlier"}, f)
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 0 and ev[-1]["rendered"] == 2
    assert not os.path.exists(os.path.join(out, locking.LOCK_NAME))     # released at the end
    assert f"took over the output folder's lock from pid {dead.pid}" in open(os.path.join(out, "backend.log")).read()


def test_check_validates_and_writes_nothing(case):
    job_path, _ = case
    folder = os.path.dirname(job_path)
    before = snapshot(folder)
    code, ev = run("render", job_path, "--check")
    assert code == 0 and ev[-1]["check"] is True and ev[-1]["frames"] == 2 and ev[-1]["locked_by"] is None
    job = J.load(job_path).to_dict()
    job["frames"][0]["source_frames"] = [0, 5]                          # the predictions have 2 frames
    J.save(job_path, job)
    before = snapshot(folder)
    code, ev = run("render", job_path, "--check")
    assert code == 2 and ev[-1]["field"] == "frames[0].source_frames" and "has 2 frames" in ev[-1]["message"]
    code, ev = run("render", job_path)
    assert code == 2 and ev[-1]["field"] == "frames[0].source_frames"
    assert snapshot(folder) == before


def test_check_refuses_what_the_run_would_and_temporaries_of_a_killed_run_go(case):
    """--check looks at the output folder as the run does; a run removes what a killed run left half-written
    (only the temporaries of its own outputs)."""
    job_path, outside = case
    out = os.path.join(os.path.dirname(job_path), "out")
    os.makedirs(out)
    os.symlink(outside, os.path.join(out, "conditions"))
    code, ev = run("render", job_path, "--check")
    assert code == 2 and "outside the output folder" in ev[-1]["message"]
    os.remove(os.path.join(out, "conditions"))
    cond = os.path.join(out, "conditions")
    os.makedirs(cond)
    for name in (".frame_000002.exr.k2j4h5g6.tmp", ".record.json.a1b2c3d4.tmp", ".notes.txt.a1b2c3d4.tmp"):
        with open(os.path.join(cond, name), "w") as f:
            f.write("half written\n")
    code, ev = run("render", job_path, "--device", "cpu")
    assert code == 0
    assert sorted(n for n in os.listdir(cond) if n.endswith(".tmp")) == [".notes.txt.a1b2c3d4.tmp"]


def test_generate_names_a_missing_checkpoint(case, tmp_path):
    job_path, _ = case
    code, ev = run("generate", job_path, "--check", "--model", "scpainter")  # without --model: the baseline
    assert code == 2 and ev[-1]["file"] == job_path and ev[-1]["field"] == "generate.checkpoint"
    code, ev = run("generate", job_path, "--check", "--checkpoint", tmp_path / "nonexistent")
    assert code == 2 and "does not exist" in ev[-1]["message"] and ev[-1]["file"] == str(tmp_path / "nonexistent")
    edit(job_path, generate={"checkpoint": str(tmp_path / "models" / "ckpt")})
    code, ev = run("generate", job_path, "--check")
    assert code == 2 and ev[-1]["field"] == "generate.checkpoint" and "--checkpoint PATH" in ev[-1]["hint"]
