"""The evaluation protocol on the street clip: crop geometry, the tasks' jobs, and one end-to-end run with the tiny
model and a random-weight Inception (the statistics are tested in test_fid.py; here the plumbing)."""

import json
import os

import numpy as np
import pytest
import torch

from backend.evaluate import protocol
from backend.train import clip as clip_mod
from scpainter_blender.core import job as job_mod


def test_square_box_is_square_grown_and_inside():
    assert protocol.square_box(10, 20, 30, 30, 1.2, 100, 50) == (8, 13, 32, 37)
    x0, y0, x1, y1 = protocol.square_box(0, 0, 10, 40, 1.5, 100, 50)  # taller than the image: clipped to it
    assert (x1 - x0, y1 - y0) == (50, 50) and x0 == 0 and y0 == 0
    assert protocol.square_box(5, 5, 5, 9, 1.2, 100, 50) is None


def test_real_car_crops_come_from_projected_boxes(street, street_clip_path):
    """The crop box around a parked car's projected 3D box contains that car's pixels (instance ids)."""
    c = clip_mod.load(street_clip_path)
    inst = street.metric()["instance"]
    W, H = c.image_size
    checked = 0
    for k, car in enumerate(c.cars):
        t = 0
        b = protocol.box_crop_box(car.boxes[t], car.size, c.K[t], c.world_to_camera[t], W, H, 1.0)
        pix = inst[t] == street.info["cars"][k]["instance"]
        if b is None or pix.sum() < 50:
            continue
        x0, y0, x1, y1 = b
        inside = pix[y0:y1, x0:x1].sum() / pix.sum()
        assert inside > 0.97, (k, inside)
        checked += 1
    assert checked >= 2
    behind = np.diag([1.0, 1.0, -1.0, 1.0]) @ c.world_to_camera[0]  # a camera looking away sees no box
    assert protocol.box_crop_box(c.cars[0].boxes[0], c.cars[0].size, c.K[0], behind, W, H, 1.0) is None


def test_task_jobs_shift_cameras_and_reinsert_the_car(street_clip_path, tmp_path):
    c = clip_mod.load(street_clip_path)
    s = protocol.EvalSettings(clips=[street_clip_path], output_dir=str(tmp_path), width=128, height=64, frames=4)
    names = [t[0] for t in protocol.tasks(c, s)]
    assert names == ["nvs_+2m", "nvs_-2m", "nvs_+3m", "nvs_-3m", "insert", "insert_shift+2m"]
    job = job_mod.load(protocol.task_job(c, s, str(tmp_path / "a"), 2.0, None)).to_dict()
    centre = lambda T: -np.array(T)[:3, :3].T @ np.array(T)[:3, 3]  # noqa: E731
    moved = centre(job["frames"][1]["world_to_camera"]) - centre(c.world_to_camera[1])
    assert abs(np.linalg.norm(moved) - 2.0) < 1e-6 and "assets" not in job
    assert job["frames"][3]["source_frames"] == list(range(0, 12))
    ins = job_mod.load(protocol.task_job(c, s, str(tmp_path / "b"), 0.0, 0)).to_dict()
    assert len(ins["scene"]["removal_boxes"]) == 1 and ins["assets"][0]["name"] == c.cars[0].id


def test_shift_needs_metric_poses(street_clip_path, tmp_path):
    c = clip_mod.load(street_clip_path)
    c.metric = False
    s = protocol.EvalSettings(clips=[], output_dir=str(tmp_path))
    with pytest.raises(clip_mod.ClipError, match="poses"):
        protocol.task_job(c, s, str(tmp_path), 2.0, None)


def tiny_extractor():
    """A fixed random feature extractor (N, 3, H, W) -> (N, 8): FID's plumbing without Inception's cost."""
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Conv2d(3, 8, 5, stride=4), torch.nn.Tanh(), torch.nn.AdaptiveAvgPool2d(1),
                               torch.nn.Flatten()).eval()


def test_evaluate_end_to_end(street_clip_path, tiny_checkpoint, tmp_path):
    s = protocol.EvalSettings(clips=[street_clip_path], output_dir=str(tmp_path / "eval"), checkpoint=tiny_checkpoint,
                              width=128, height=64, frames=3, shifts=(2.0,), steps=2, crop_min_px=4)
    r = protocol.evaluate(s, "cpu", extractor=tiny_extractor())
    with open(r["evaluation"]) as f:
        ev = json.load(f)
    rows = {(g["task"], g["output"]): g for g in ev["ground_truth"]}
    assert set(rows) == {("nvs_+2m", "naive"), ("nvs_+2m", "baseline"), ("nvs_+2m", "generated")}
    temporal = {(r["task"], r["output"]): r for r in ev["temporal"]}
    assert {("recorded", "real"), ("nvs_+2m", "naive"), ("nvs_+2m", "baseline"), ("nvs_+2m", "generated"),
            ("nvs_+2m", "ground_truth"), ("insert", "naive"), ("insert", "baseline"),
            ("insert", "generated")} <= set(temporal)
    assert all(r["warping_error"] is not None and r["warping_error"] >= 0 for r in ev["temporal"])
    import cv2  # the pictures: a contact sheet per task (condition, baseline, generated, ground truth), the plot

    sheet = cv2.imread(str(tmp_path / "eval" / "000_street" / "nvs_+2m" / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[1] == 4 * (ev["settings"]["width"] + 2)
    assert cv2.imread(str(tmp_path / "eval" / "000_street" / "insert" / "contact_sheet.png")).shape[1] == \
        3 * (ev["settings"]["width"] + 2)   # no ground-truth view for an inserted car
    assert cv2.imread(str(tmp_path / "eval" / "metrics.png")) is not None
    naive, inpainted = rows[("nvs_+2m", "naive")], rows[("nvs_+2m", "baseline")]
    assert 0.1 < naive["hole_fraction"] < 0.7 and naive["psnr_covered"] > naive["psnr"] > 5
    # inpainting fills the holes with something closer to the street than black; covered pixels stay (8-bit I)
    assert inpainted["psnr"] > naive["psnr"] + 1 and abs(inpainted["psnr_covered"] - naive["psnr_covered"]) < 0.1
    from backend.generate.video import mp4_metadata

    assert "no model" in mp4_metadata(str(tmp_path / "eval" / "000_street" / "insert" / "baseline.mp4"))["comment"]
    assert ev["counts"]["whole"] == {"real": 3, **{f"{task}/{kind}": 3 for task in ("nvs_+2m", "insert",
                                                                                     "insert_shift+2m")
                                                   for kind in ("naive", "baseline", "generated")}}
    assert ev["counts"]["crops"]["real"] >= 2 and ev["counts"]["crops"]["insert/naive"] == 3
    for key in ("fid", "fid_c"):
        for name, v in ev[key].items():
            assert np.isfinite(v["fid"]) and v["fid"] >= 0 and v["images"] == ev["counts"][
                "whole" if key == "fid" else "crops"][name]
    assert os.path.isfile(tmp_path / "eval" / "000_street" / "insert" / "generated.mp4")
    assert ev["fid"]["nvs_+2m/generated"]["fid"] > 0  # random tiny weights do not paint the street
    assert ev["fid"]["nvs_+2m/naive"]["fid"] != ev["fid"]["nvs_+2m/generated"]["fid"]
    again = protocol.evaluate(s, "cpu", extractor=tiny_extractor())  # finished renders and videos are reused
    with open(again["evaluation"]) as f:
        assert json.load(f)["ground_truth"] == ev["ground_truth"]


def test_evaluate_says_why_a_metric_is_empty(street_clip_path, tmp_path):
    # a shift with no ground-truth view and no insertion task: both tables say why they are empty
    s = protocol.EvalSettings(clips=[street_clip_path], output_dir=str(tmp_path / "eval"), width=64, height=32,
                              frames=2, shifts=(7.0,), insertion=False, steps=1, crop_min_px=4)
    r = protocol.evaluate(s, "cpu", extractor=tiny_extractor())
    with open(r["evaluation"]) as f:
        ev = json.load(f)
    assert ev["ground_truth"] == [] and "+7" in ev["ground_truth_skipped"] and "+2" in ev["ground_truth_skipped"]
    assert ev["fid_c"] == {"skipped": "no insertion task (--no-insertion)"}
    assert "nvs_+7m/naive" in ev["fid"]   # the whole-frame metrics are still there
    table = protocol.format_table(ev)
    assert "skipped: no ground-truth view at the shifts asked (+7 m)" in table and "fid_c: skipped" in table


def test_evaluate_command_refuses_missing_inception_weights_before_any_work(street_clip_path, tmp_path):
    from tests_support import run_backend_here

    code, events, _ = run_backend_here("evaluate", os.path.dirname(street_clip_path), "--output-dir", tmp_path / "e",
                                  "--inception", tmp_path / "nope.pth", "--device", "cpu")
    assert code == 2
    msg = events[-1]["message"]
    assert "nope.pth" in msg and "pt_inception-2015-12-05-6726825d.pth" in msg and "download" in msg
    assert not os.path.exists(tmp_path / "e" / "000_street")


@pytest.mark.parametrize("args,option", [
    (["--resolution", "8", "8"], "--resolution"),       # SSIM's 11 x 11 window must fit
    (["--frames", "1"], "--frames"),                   # FID/KID need two frames per set
    (["--steps", "0"], "--steps"),
    (["--seed", "-1"], "--seed"),
    (["--source-window", "-2"], "--source-window"),
    (["--crop-min-px", "-1"], "--crop-min-px"),
    (["--shifts", "nan"], "--shifts"),
])
def test_evaluate_arguments_are_checked_before_any_work(street_clip_path, tmp_path, args, option):
    """A bad option is bad input (exit 2, named), not an internal error deep in the metrics."""
    from tests_support import run_backend_here

    code, events, _ = run_backend_here("evaluate", os.path.dirname(street_clip_path), "--output-dir", tmp_path / "e",
                                  "--device", "cpu", *args)
    assert code == 2 and events[-1]["file"] == "(command line)" and events[-1]["field"] == option, events[-1]
    assert not os.path.exists(tmp_path / "e")
