"""``python -m backend evaluate --ray``: the tasks' jobs on a local Ray cluster of 2 CPUs, the metrics in this
process (``protocol.run_jobs_on_pool``), equal to an evaluation without Ray."""

import glob
import json
import os
import socket

import numpy as np
import pytest
import torch

from backend.errors import CleanFailure
from backend.evaluate import protocol
from backend.train import clip as clip_mod
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import job_inputs, locking
from scpainter_blender.core.errors import InputError
from tests_support import copy_clip, run_backend

ray = pytest.importorskip("ray")


def settings(clip_path, out, **changes):
    """The smallest evaluation worth running: 2 frames at 64 x 32, one shift."""
    return protocol.EvalSettings(**{"clips": [clip_path], "output_dir": str(out), "width": 64, "height": 32,
                                    "frames": 2, "shifts": (2.0,), "steps": 1, "crop_min_px": 4, "crop_size": 32,
                                    **changes})


def tiny_extractor():
    """A fixed random feature extractor (N, 3, H, W) -> (N, 8): FID's plumbing without Inception's cost."""
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Conv2d(3, 8, 5, stride=4), torch.nn.Tanh(), torch.nn.AdaptiveAvgPool2d(1),
                               torch.nn.Flatten()).eval()


def numbers(rows):
    """evaluation.json rows keyed by (clip, task, output), their numbers as floats (None: NaN)."""
    return {(r["clip"], r["task"], r["output"]): {k: np.nan if v is None else float(v) for k, v in r.items()
                                                  if k not in ("clip", "task", "output")} for r in rows}


def events_of(text):
    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


def test_the_pool_runs_the_jobs_and_the_metrics_equal_an_evaluation_without_it(ray_cluster, street_clip_path,
                                                                                tiny_checkpoint, tmp_path, capsys):
    # one task (a shift with its ground-truth view), its video generated in a worker; the driver only scores it
    s = {"checkpoint": tiny_checkpoint, "insertion": False}
    local = protocol.evaluate(settings(street_clip_path, tmp_path / "local", **s), "cpu", extractor=tiny_extractor())
    capsys.readouterr()
    pooled = protocol.evaluate(settings(street_clip_path, tmp_path / "ray", **s), "cpu", extractor=tiny_extractor(),
                               pool=protocol.RayPool(device="cpu"))
    ev = {}
    for name, r in (("local", local), ("ray", pooled)):
        with open(r["evaluation"]) as f:
            ev[name] = json.load(f)
    # the same rows, the same numbers: the pool only moved where the videos were made
    for key in ("ground_truth", "temporal"):
        a, b = numbers(ev["local"][key]), numbers(ev["ray"][key])
        assert a.keys() == b.keys() and len(a) >= 3
        for row in a:
            assert b[row] == pytest.approx(a[row], rel=1e-4, abs=1e-5, nan_ok=True), (key, row)
    assert ev["ray"]["counts"] == ev["local"]["counts"]
    for name, v in ev["local"]["fid"].items():
        assert ev["ray"]["fid"][name] == pytest.approx(v, rel=1e-4, abs=1e-6), name
    # auto resolved once, for the workers' device (CPU here), and recorded; without Ray too
    assert ev["ray"]["settings"]["precision"] == ev["local"]["settings"]["precision"] == "fp32"
    assert "jobs" not in ev["local"]
    # the task's job ran in a Ray worker, once, and took its time there
    (job,) = ev["ray"]["jobs"]
    assert (job["clip"], job["task"]) == ("000_street", "nvs_+2m")
    assert job["worker"] != f"{socket.gethostname()}:{os.getpid()}"
    assert job["attempts"] == 1 and job["seconds"] > 0 and not job["skipped"]
    # the driver found the video up to date (the same precision in its key) and generated nothing itself
    folder = tmp_path / "ray" / "000_street" / "nvs_+2m"
    log = (folder / "backend.log").read_text()
    assert log.count("fp32 on cpu, checkpoint") == 1 and log.count("is up to date") == 1, log
    with open(folder / "generated" / "manifest.json") as f:
        assert json.load(f)["precision"] == "fp32"
    progress = [(e["stage"], e["done"], e["total"]) for e in events_of(capsys.readouterr().out)
                if e["event"] == "progress" and e["stage"].startswith("evaluate")]
    assert progress == [("evaluate-jobs", 1, 1), ("evaluate", 1, 1)]


def test_a_task_that_failed_on_the_pool_ends_the_evaluation_before_any_metric(ray_cluster, street_clip_path,
                                                                              tmp_path):
    # a failure the job explains (its output folder held by another live process): a CleanFailure naming the task
    s = settings(street_clip_path, tmp_path / "busy", shifts=(2.0, -2.0), insertion=False)
    held = tmp_path / "busy" / "000_street" / "nvs_-2m"
    held.mkdir(parents=True)
    with locking.OutputLock(str(held), "test"):
        with pytest.raises(CleanFailure, match="1 of 2 evaluation tasks failed") as e:
            protocol.evaluate(s, "cpu", extractor=tiny_extractor(), pool=protocol.RayPool(device="cpu"))
    (failed,) = e.value.fields["failed"]
    assert (failed["clip"], failed["task"]) == ("000_street", "nvs_-2m")
    assert f"being written by another run: pid {os.getpid()}" in failed["error"]
    assert "000_street/nvs_-2m" in str(e.value)
    assert not (tmp_path / "busy" / "evaluation.json").exists()
    assert not glob.glob(str(tmp_path / "busy" / "*" / "*" / "contact_sheet.png"))  # no task was scored

    # bad input met by a worker (the clip's predictions gone after its job was written): an InputError naming them
    clip = copy_clip(street_clip_path, tmp_path, lambda data, folder: None)
    s = settings(str(clip / "clip.json"), tmp_path / "gone", insertion=False)
    work = protocol.write_jobs([clip_mod.load(str(clip / "clip.json"))], s, s.output_dir)
    predictions = clip_mod.load(str(clip / "clip.json")).predictions.path
    os.remove(predictions)
    with pytest.raises(InputError) as e:
        protocol.run_jobs_on_pool(work, s, protocol.RayPool(device="cpu"))
    assert e.value.path == predictions and e.value.field == "(file)"
    # the message the job itself gives (it names the file once), then the task
    with pytest.raises(InputError) as job_error:
        job_inputs.check_inputs(work[0].job, job_mod.load(work[0].job), True)
    assert str(e.value) == f"{job_error.value} (evaluation task 000_clip/nvs_+2m, job {work[0].job})"


def test_the_command_line_prints_only_events_and_refuses_a_bad_pool_option_first(ray_cluster, street_clip_path,
                                                                                tmp_path):
    args = ("evaluate", os.path.dirname(street_clip_path), "--resolution", "64", "32", "--frames", "2", "--shifts",
            "2", "--no-insertion", "--device", "cpu")
    code, ev, err = run_backend(*args, "--output-dir", tmp_path / "e", "--ray", ray_cluster)
    assert code == 0, err[-3000:]
    # standard output is the driver's events only (run_backend parsed every line as JSON), ending in done
    assert ev[-1]["event"] == "done" and ev[-1]["command"] == "evaluate"
    assert [e["stage"] for e in ev if e["event"] == "progress"][:1] == ["evaluate-jobs"]
    with open(tmp_path / "e" / "evaluation.json") as f:
        (job,) = json.load(f)["jobs"]
    assert job["task"] == "nvs_+2m" and job["attempts"] == 1
    code, ev, _ = run_backend(*args, "--output-dir", tmp_path / "f", "--ray", ray_cluster, "--cpus-per-job", "0")
    assert code == 2 and ev[-1]["field"] == "--cpus-per-job" and not (tmp_path / "f").exists()


def test_sigterm_during_the_pool_phase_stops_the_evaluation(ray_cluster, street_clip_path, tmp_path):
    """``stop`` is the list SIGTERM appends to (``events.stop_on_sigterm``): the pool cancels its jobs and the
    evaluation ends as it does without Ray, stopped, no metric written."""
    s = settings(street_clip_path, tmp_path / "e", insertion=False)
    assert protocol.evaluate(s, "cpu", stop=[True], pool=protocol.RayPool(device="cpu")) == {"stopped": True}
    assert os.path.isfile(tmp_path / "e" / "000_street" / "nvs_+2m" / "job.json")
    assert not (tmp_path / "e" / "evaluation.json").exists()
