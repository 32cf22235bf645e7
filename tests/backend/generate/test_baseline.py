"""The baseline generator (``backend/generate/baseline.py``) and ``python -m backend generate`` without a checkpoint."""

import os
from fractions import Fraction

import numpy as np
import pytest
from PIL import Image

from backend.generate import baseline
from backend.render import channels
from backend.generate.video import mp4_metadata, read_mp4
from scpainter_blender.core import job as J
from tests_support import run_backend_here, small_job


def smooth_image(H=48, W=64):
    """(H, W, 3) float in [0, 1]: smooth ramps, which inpainting should continue into a hole closely."""
    y, x = np.mgrid[0:H, 0:W] / np.array([H, W])[:, None, None]
    return np.stack([0.2 + 0.6 * x, 0.3 + 0.4 * y, 0.5 + 0.3 * np.sin(3 * x + 2 * y)], axis=-1)


def test_the_settings_and_the_opencv_flags_agree():
    assert tuple(baseline.METHODS) == J.INPAINT_METHODS == tuple(baseline.NAMES)
    assert baseline.DEFAULT_METHOD in J.INPAINT_METHODS and J.BASELINE_DEFAULTS["model"] in J.GENERATE_MODELS


@pytest.mark.parametrize("method", J.INPAINT_METHODS)
def test_a_hole_in_a_smooth_image_is_filled_close_to_it_and_known_pixels_stay(method):
    image = smooth_image()
    hole = np.zeros(image.shape[:2])
    hole[16:32, 20:44] = 1.0
    holed = image * (1 - hole[..., None])                       # as the renderer leaves it: 0 in the holes
    out = baseline.inpaint_frame(holed, hole, method, 3)
    assert out.dtype == np.uint8 and out.shape == image.shape
    known = hole == 0
    assert np.array_equal(out[known], baseline.to_uint8(image)[known])  # known pixels: the condition, in 8 bits
    filled = out[hole == 1] / 255.0
    # the hole's truth is a smooth ramp: filled within a few levels of it, while black would be off by ~0.5
    assert np.abs(filled - image[hole == 1]).mean() < 0.03
    assert np.abs(holed[hole == 1] - image[hole == 1]).mean() > 0.4


def test_frames_without_holes_or_with_nothing_known_come_back_as_they_are():
    image = smooth_image(8, 10)
    assert np.array_equal(baseline.inpaint_frame(image, np.zeros((8, 10))), baseline.to_uint8(image))
    black = np.zeros((8, 10, 3))
    assert np.array_equal(baseline.inpaint_frame(black, np.ones((8, 10))), np.zeros((8, 10, 3), np.uint8))
    # a blurred mask (an EXR re-saved by another tool): only M > 0.5 is a hole
    hole = np.full((8, 10), 0.4)
    assert np.array_equal(baseline.inpaint_frame(image, hole), baseline.to_uint8(image))


def test_inpaint_video_takes_the_condition_layout_and_stops_when_asked():
    F, H, W = 4, 12, 16
    image = np.random.default_rng(0).random((F, 3, H, W)).astype(np.float32)
    hole = np.zeros((F, 1, H, W), np.float32)
    hole[:, :, 4:8, 5:9] = 1
    out = baseline.inpaint_video(image, hole)
    assert out.shape == (F, H, W, 3)
    for i in range(F):
        assert np.array_equal(out[i], baseline.inpaint_frame(np.moveaxis(image[i], 0, -1), hole[i, 0]))
    seen = []
    part = baseline.inpaint_video(image, hole, on_frame=lambda i, f: seen.append(i) or i == 1)
    assert len(part) == 2 and seen == [0, 1] and np.array_equal(part, out[:2])


def test_job_settings_are_checked_by_name(tmp_path):
    path = small_job(tmp_path)
    job = J.load(path).to_dict()
    for gen, field in (({"model": "svd"}, "generate.model"), ({"inpaint": "fast"}, "generate.inpaint"),
                       ({"inpaint_radius": 0}, "generate.inpaint_radius"),
                       ({"inpaint_radius": 65}, "generate.inpaint_radius")):
        with pytest.raises(J.JobError) as e:
            J.validate({**job, "generate": gen}, path)
        assert e.value.field == field
    s = J.GenerateSettings.from_dict({"inpaint": "navier-stokes", "fps": 12}, path)
    assert s.model_choice() == "auto" and s.model_choice({"model": "baseline"}) == "baseline"
    assert s.resolve_baseline() == {"inpaint": "navier-stokes", "inpaint_radius": 3, "fps": 12.0}
    assert s.resolve_baseline({"inpaint": "telea", "inpaint_radius": 5})["inpaint_radius"] == 5


def test_generate_without_a_checkpoint_writes_the_baseline_video_marked_as_such(tmp_path):
    path = small_job(tmp_path, frames=(1, 2, 3), resolution=(32, 24))
    code, ev, err = run_backend_here("generate", path, "--device", "cpu", "--check")
    assert code == 0 and ev[-1]["model"] == "baseline" and ev[-1]["checkpoint"] is None, err[-2000:]
    assert not (tmp_path / "out").exists()                           # --check renders nothing

    code, ev, err = run_backend_here("generate", path, "--device", "cpu")
    assert code == 0, err[-3000:]
    done = ev[-1]
    assert done["event"] == "done" and done["model"] == "baseline" and done["frames"] == 3
    assert "no model" in done["description"] and "--checkpoint" in done["hint"]
    assert done["inpaint"] == "telea" and done["fps"] == J.BASELINE_DEFAULTS["fps"]
    progress = [e for e in ev if e["event"] == "progress" and e["stage"] == "generate"]
    assert [e["done"] for e in progress] == [1, 2, 3] and all(e["model"] == "baseline" for e in progress)
    artifacts = [e for e in ev if e["event"] == "artifact"]
    assert {e["kind"] for e in artifacts} >= {"generated", "video"}
    assert all(e["model"] == "baseline" for e in artifacts if e["kind"] in ("generated", "video"))
    assert "not the model" in err                                      # said on standard error too

    out = tmp_path / "out"
    manifest = J.read_json(out / "generated" / "manifest.json")
    assert manifest["model"] == "baseline" and manifest["checkpoint"] is None and "no model" in manifest["description"]
    assert manifest["frames"] == [1, 2, 3] and manifest["settings"]["inpaint"] == "telea"
    tags = mp4_metadata(done["video"])
    assert tags["title"] == "SCPainter baseline" and "no model" in tags["comment"]
    assert read_mp4(done["video"]).shape == (3, 24, 32, 3)
    # each PNG is its condition frame inpainted: the same function, the same bytes
    for f in (1, 2, 3):
        layers = channels.read(str(out / "conditions" / f"frame_{f:06d}.exr"))
        image = np.stack([layers[c] for c in channels.IMAGE], axis=-1)
        expected = baseline.inpaint_frame(image, layers[channels.HOLE])
        assert np.array_equal(np.asarray(Image.open(out / "generated" / f"frame_{f:06d}.png")), expected)

    code, ev, _ = run_backend_here("generate", path, "--device", "cpu")    # the same again: up to date
    assert code == 0 and ev[-1]["skipped"] is True and ev[-1]["model"] == "baseline" and ev[-1]["ignored"] == []
    # the model's settings given to the baseline: said, not silently dropped
    code, ev, err = run_backend_here("generate", path, "--device", "cpu", "--model", "baseline", "--steps", "9",
                                "--precision", "bf16")
    assert code == 0 and ev[-1]["skipped"] is True and ev[-1]["ignored"] == ["--steps", "--precision"]
    assert "the baseline ignores --steps, --precision" in err
    code, ev, _ = run_backend_here("generate", path, "--device", "cpu", "--inpaint", "navier-stokes")
    assert code == 0 and ev[-1]["skipped"] is False and ev[-1]["inpaint"] == "navier-stokes"
    assert J.read_json(out / "generated" / "manifest.json")["settings"]["inpaint"] == "navier-stokes"


def test_asking_for_the_model_without_a_checkpoint_fails_fast(tmp_path):
    path = small_job(tmp_path)
    code, ev, _ = run_backend_here("generate", path, "--device", "cpu", "--model", "scpainter")
    assert code == 2 and ev[-1]["field"] == "generate.checkpoint" and "init-checkpoint" in ev[-1]["message"]
    assert not (tmp_path / "out").exists()                           # nothing rendered before failing
    job = J.load(path).to_dict()
    J.save(path, {**job, "generate": {"model": "scpainter"}})        # the job's own choice, the same
    code, ev, _ = run_backend_here("generate", path, "--device", "cpu")
    assert code == 2 and ev[-1]["field"] == "generate.checkpoint"
    code, ev, _ = run_backend_here("generate", path, "--device", "cpu", "--inpaint-radius", "0", "--model", "baseline")
    assert code == 2 and ev[-1]["field"] == "--inpaint-radius"
    assert not os.path.exists(tmp_path / "out")


def test_baseline_ignores_a_configured_checkpoint_when_asked(tmp_path):
    path = small_job(tmp_path)
    job = J.load(path).to_dict()
    J.save(path, {**job, "generate": {"checkpoint": "no/such/checkpoint"}})
    code, ev, _ = run_backend_here("generate", path, "--device", "cpu", "--check")  # auto: the model; no such folder
    assert code == 2 and "does not exist" in ev[-1]["message"] and ev[-1]["file"].endswith("no/such/checkpoint")
    code, ev, err = run_backend_here("generate", path, "--device", "cpu", "--model", "baseline")
    assert code == 0 and ev[-1]["model"] == "baseline", err[-2000:]


def test_batch_generate_without_a_checkpoint_makes_each_jobs_baseline(tmp_path):
    jobs = [small_job(tmp_path / name, asset=False) for name in ("a", "b")]
    code, ev, err = run_backend_here("batch", *jobs, "--command", "generate", "--device", "cpu")
    assert code == 0, err[-2000:]
    items = ev[-1]["items"]
    assert [r["status"] for r in items] == ["ok", "ok"] and all(r["model"] == "baseline" for r in items)
    assert all(os.path.isfile(r["video"]) for r in items)


def test_the_video_plays_at_the_jobs_frame_rate(tmp_path):
    """With ``fps`` in the job (the scene's rate, which the labels' timestamps use) the MP4 plays at it, exactly
    (29.97 stays 2997/100); changing it alone writes the video again; without it, the generation's fps (7)."""
    import av

    from scpainter_blender.core import files

    def rate(job_path):
        with av.open(os.path.join(os.path.dirname(job_path), "out", "generated.mp4")) as c:
            return c.streams.video[0].average_rate

    job = small_job(tmp_path / "a", frames=(1, 2, 3), fps=29.97)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0, err
    assert rate(job) == Fraction(2997, 100)
    manifest = files.read_json(os.path.join(os.path.dirname(job), "out", "generated", "manifest.json"))
    assert manifest["playback_fps"] == 29.97
    labels = files.read_json(os.path.join(os.path.dirname(job), "out", "conditions", "labels_000002.json"))
    assert labels["fps"] == 29.97 and abs(labels["timestamp_s"] - 1 / 29.97) < 1e-12
    d = J.load(job).to_dict()
    d["fps"] = 10.0
    J.save(job, d)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0 and not ev[-1]["skipped"] and rate(job) == 10
    other = small_job(tmp_path / "b", frames=(1, 2))
    assert run_backend_here("generate", other, "--device", "cpu")[0] == 0 and rate(other) == 7


def test_a_frame_step_job_plays_at_the_times_its_labels_say(tmp_path):
    """Every 2nd scene frame (Blender's Frame Step 2) at 10 fps: the labels say 0, 0.2, 0.4 s and the MP4 shows
    its frames at those times (not 0.1 s apart); a video written before its frame times were recorded in the
    manifest (one tick apart) is not up to date for such a job."""
    from backend.generate import command as generate_cmd
    from backend.generate.video import frame_times
    from scpainter_blender.core import files, outputs

    job = small_job(tmp_path, frames=(1, 3, 5), fps=10.0, asset=False)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0, err
    out = os.path.join(os.path.dirname(job), "out")
    said = [files.read_json(os.path.join(out, "conditions", f"labels_{f:06d}.json"))["timestamp_s"] for f in (1, 3, 5)]
    assert said == pytest.approx([0.0, 0.2, 0.4], abs=1e-12)
    assert frame_times(os.path.join(out, "generated.mp4")) == pytest.approx(said, abs=1e-9)
    manifest_path = os.path.join(out, "generated", "manifest.json")
    manifest = files.read_json(manifest_path)
    assert manifest["video_ticks"] == [0, 2, 4]
    fps, ticks = manifest["playback_fps"], generate_cmd.video_ticks(J.load(job))
    assert generate_cmd._up_to_date(os.path.join(out, "generated"), os.path.join(out, "generated.mp4"),
                                    manifest["key"], fps, ticks)
    del manifest["video_ticks"]  # as written before
    outputs.write_json(manifest_path, manifest)
    assert not generate_cmd._up_to_date(os.path.join(out, "generated"), os.path.join(out, "generated.mp4"),
                                        manifest["key"], fps, ticks)
