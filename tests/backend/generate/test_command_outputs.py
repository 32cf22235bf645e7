"""What ``generate`` reads and writes, under hostile conditions (issue 30): condition EXRs that do not fit the job,
and a run killed while it replaces another run's frames."""

import os
import selectors
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from backend.render import channels
from scpainter_blender.core import files
from tests_support import run_backend_here, small_job

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def _frames(out, frames):
    return {f: (out / "generated" / f"frame_{f:06d}.png").read_bytes() for f in frames}


def _kill_while_writing_frames(job, *args, deadline_s=600):
    """Start ``generate JOB *args`` and SIGKILL it while it writes its PNG frames: its events go through a pipe
    shrunk to one page, read until its first ``generated`` artifact (the first frame replaced) and then no more, so
    the writer blocks on the pipe a few events later — long before its last frame (each frame emits one event), the
    video and the manifest. Deterministic: no timing, only the bounded wait for that first event."""
    import fcntl

    read_fd, write_fd = os.pipe()
    fcntl.fcntl(read_fd, fcntl.F_SETPIPE_SZ, 4096)
    with open(os.devnull, "wb") as devnull:
        p = subprocess.Popen([sys.executable, "-m", "backend", "generate", str(job), "--device", "cpu", *args],
                             cwd=ROOT, stdout=write_fd, stderr=devnull, stdin=subprocess.DEVNULL)
    os.close(write_fd)
    sel = selectors.DefaultSelector()
    sel.register(read_fd, selectors.EVENT_READ)
    seen, end = b"", time.monotonic() + deadline_s
    try:
        while b'"kind": "generated"' not in seen:
            left = end - time.monotonic()
            assert left > 0, "no generated frame within the deadline"
            if sel.select(timeout=left):
                chunk = os.read(read_fd, 1 << 16)
                assert chunk, f"generate ended (exit {p.wait()}) before writing a frame"
                seen += chunk
        assert p.poll() is None, "generate finished before it was killed"
        p.send_signal(signal.SIGKILL)
        assert p.wait(timeout=60) == -signal.SIGKILL
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        sel.close()
        os.close(read_fd)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="F_SETPIPE_SZ (a one-page pipe) is Linux's")
def test_a_generate_killed_while_writing_frames_leaves_no_folder_called_up_to_date(tmp_path):
    """Issue 30: after a finished Telea video, a run with other settings killed while it replaced the frames, then
    the first command again answered "up to date" over the killed run's frames. Now the finished run's manifest is
    removed before its first frame is replaced: the first command generates again, every frame the clean run's."""
    frames = tuple(range(1, 81))  # 80 frames: their events fill a one-page pipe many times over
    job = small_job(tmp_path, frames=frames, resolution=(32, 24))
    out = tmp_path / "out"
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0 and not ev[-1]["skipped"], err[-2000:]
    clean = _frames(out, frames)

    _kill_while_writing_frames(job, "--inpaint", "navier-stokes")
    mixed = _frames(out, frames)
    replaced = [f for f in frames if mixed[f] != clean[f]]
    assert 0 < len(replaced) < len(frames)          # killed mid-way: some frames are the killed run's
    assert not (out / "generated" / "manifest.json").exists()   # nothing says this folder is finished

    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0 and ev[-1]["skipped"] is False, err[-2000:]
    assert _frames(out, frames) == clean
    manifest = files.read_json(out / "generated" / "manifest.json")
    assert manifest["settings"]["inpaint"] == "telea" and manifest["frames"] == list(frames)


def _rendered(tmp_path, frames=(1, 2, 3)):
    job = small_job(tmp_path, frames=frames, resolution=(32, 24))
    code, ev, err = run_backend_here("render", job, "--device", "cpu")
    assert code == 0, err[-2000:]
    return job, tmp_path / "out" / "conditions"


def test_a_condition_exr_of_another_size_than_the_job_is_refused_naming_it(tmp_path):
    """A condition EXR of another size (re-saved by another tool, or left from another resolution) once gave a
    traceback from np.stack (or, all of one wrong size, a video at that size): now exit 2 naming the file, its size
    and the job's, with the hint to render again."""
    job, cond = _rendered(tmp_path)
    exr = cond / "frame_000002.exr"
    channels.write(str(exr), {k: v[:12, :16] for k, v in channels.read(str(exr)).items()})
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 2 and ev[-1]["event"] == "error" and "Traceback" not in err, err[-2000:]
    assert ev[-1]["file"] == str(exr) and ev[-1]["field"] == "dataWindow"
    assert "16x12" in ev[-1]["message"] and "32x24" in ev[-1]["message"]
    assert "render" in ev[-1]["hint"] and "--force" in ev[-1]["hint"]
    assert not (tmp_path / "out" / "generated").exists()

    for f in (1, 2, 3):  # every frame of one wrong size: refused the same (never a video at the wrong size)
        p = str(cond / f"frame_{f:06d}.exr")
        channels.write(p, {k: v[:12, :16] for k, v in channels.read(p).items()})
    code, ev, _ = run_backend_here("generate", job, "--device", "cpu")
    assert code == 2 and ev[-1]["file"] == str(cond / "frame_000001.exr") and "16x12" in ev[-1]["message"]
    # what the hint says works
    assert run_backend_here("render", job, "--device", "cpu", "--force")[0] == 0
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0 and ev[-1]["frames"] == 3, err[-2000:]


def test_a_folder_where_a_condition_frame_goes_is_refused_naming_it(tmp_path):
    """A folder in place of a condition EXR once gave IsADirectoryError (the render could not replace it): now
    exit 2 naming it, saying what to do."""
    job, cond = _rendered(tmp_path)
    exr = cond / "frame_000002.exr"
    os.remove(exr)
    os.mkdir(exr)
    for command in ("render", "generate"):
        code, ev, err = run_backend_here(command, job, "--device", "cpu")
        assert code == 2 and ev[-1]["event"] == "error" and "Traceback" not in err, err[-2000:]
        assert ev[-1]["file"] == str(exr) and "folder" in ev[-1]["message"] and "remove" in ev[-1]["hint"]


def _replace_layer(exr, layer, values):
    """Rewrite the condition EXR ``exr`` with ``layer`` (a ``channels.CHANNELS`` key) set to ``values``."""
    layers = channels.read(str(exr))
    layers[layer] = np.broadcast_to(np.asarray(values, np.float32), layers[layer].shape).copy()
    channels.write(str(exr), layers)


def test_a_condition_layer_with_nan_is_refused_naming_the_file_and_channel(tmp_path):
    """``image.R`` all NaN (right size, otherwise valid) once gave exit 0, no word, and a generated frame whose red
    is 0 everywhere: now exit 2 naming the file and the channel, with the hint to render again."""
    job, cond = _rendered(tmp_path)
    exr = cond / "frame_000002.exr"
    _replace_layer(exr, "R", np.nan)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 2 and ev[-1]["event"] == "error" and "Traceback" not in err, err[-2000:]
    assert ev[-1]["file"] == str(exr) and ev[-1]["field"] == "image.R"
    assert "NaN" in ev[-1]["message"] and "768 of its 768 pixels" in ev[-1]["message"]
    assert "render" in ev[-1]["hint"] and "--force" in ev[-1]["hint"]
    assert not (tmp_path / "out" / "generated").exists()
    assert run_backend_here("render", job, "--device", "cpu", "--force")[0] == 0   # what the hint says works
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0 and ev[-1]["frames"] == 3, err[-2000:]


def test_every_layer_generate_reads_is_checked_for_non_finite_and_out_of_range_values(tmp_path):
    """I (R, G, B), M and M_a: NaN, ±inf and values outside [0, 1] beyond ``VALUE_TOLERANCE`` (the renderer never
    writes them: its image is clamped to [0, 1], its masks are a coverage and a 0/1 hole) are each an ExrError
    naming the file and the channel; values within the tolerance (a lossy re-save's ringing) load clamped to
    [0, 1]; depth and instance, which generate does not read, are not checked here."""
    from backend.generate import command as gen
    from scpainter_blender.core import job as J

    job, cond = _rendered(tmp_path, frames=(1,))
    exr = cond / "frame_000001.exr"
    good = channels.read(str(exr))
    tol = gen.VALUE_TOLERANCE
    assert 2.0 ** -12 <= tol < 0.1   # beyond half's rounding (2^-12) and DWA's ringing (measured: 0.021)
    for layer in (*channels.IMAGE, channels.HOLE, channels.ASSET_MASK):
        name = channels.FILE_NAMES[layer]
        for value, said in ((np.nan, "NaN or infinite"), (np.inf, "NaN or infinite"), (-np.inf, "NaN or infinite"),
                            (7.0, "outside [0, 1]"), (-3.0, "outside [0, 1]"), (1 + 2 * tol, "outside [0, 1]")):
            bad = good[layer].copy()
            bad[3, 5] = value
            _replace_layer(exr, layer, bad)
            with pytest.raises(channels.ExrError) as e:
                gen.load_conditions(job, J.load(job))
            assert e.value.path == str(exr) and e.value.field == name, (name, value)
            assert said in e.value.message and "x=5, y=3" in e.value.message, e.value.message
            assert "--force" in e.value.hint
        for value, clamped in ((1 + tol / 2, 1.0), (-tol / 2, 0.0)):   # a lossy re-save: accepted, clamped
            bad = good[layer].copy()
            bad[3, 5] = value
            _replace_layer(exr, layer, bad)
            image, asset_mask, valid = gen.load_conditions(job, J.load(job))
            got = {"R": image[0, 0], "G": image[0, 1], "B": image[0, 2], "hole": 1 - valid[0, 0],
                   "asset_mask": asset_mask[0, 0]}[layer]
            assert float(got[3, 5]) == clamped, (name, value)
        _replace_layer(exr, layer, good[layer])
    for layer in (channels.DEPTH, channels.INSTANCE):   # not generate's: its +inf depth is the renderer's "empty"
        _replace_layer(exr, layer, np.inf)
        gen.load_conditions(job, J.load(job))


def test_masks_outside_zero_to_one_are_refused_naming_the_file_and_channel(tmp_path):
    """``hole.Y = 7`` and ``asset_mask.Y = -3`` were accepted and the frame passed through unchanged: exit 2, the
    first one found named (hole before asset_mask), with its range."""
    job, cond = _rendered(tmp_path)
    exr = cond / "frame_000003.exr"
    _replace_layer(exr, "hole", 7.0)
    _replace_layer(exr, "asset_mask", -3.0)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 2 and ev[-1]["event"] == "error" and "Traceback" not in err, err[-2000:]
    assert ev[-1]["file"] == str(exr) and ev[-1]["field"] == "hole.Y"
    assert "outside [0, 1]" in ev[-1]["message"] and "7" in ev[-1]["message"] and "--force" in ev[-1]["hint"]
    _replace_layer(exr, "hole", 0.0)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 2 and ev[-1]["field"] == "asset_mask.Y" and "-3" in ev[-1]["message"], err[-2000:]
    assert not (tmp_path / "out" / "generated").exists()


def test_a_generate_that_fails_while_writing_frames_leaves_no_folder_called_up_to_date(tmp_path):
    """The same promise as after a kill, for a run that fails while writing: a folder in place of its third
    frame. It says so (exit 2, naming it); the first command then generates again, never answering up to date."""
    job = small_job(tmp_path, frames=(1, 2, 3, 4), resolution=(32, 24))
    out = tmp_path / "out"
    assert run_backend_here("generate", job, "--device", "cpu")[0] == 0
    clean = _frames(out, (1, 2, 3, 4))
    png = out / "generated" / "frame_000003.png"
    os.remove(png)
    os.mkdir(png)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu", "--inpaint", "navier-stokes")
    assert code == 2 and ev[-1]["file"] == str(png) and "Traceback" not in err, err[-2000:]
    assert not (out / "generated" / "manifest.json").exists()
    assert _frames(out, (1, 2)) != {f: clean[f] for f in (1, 2)}   # the failed run's frames are there
    os.rmdir(png)
    code, ev, err = run_backend_here("generate", job, "--device", "cpu")
    assert code == 0 and ev[-1]["skipped"] is False, err[-2000:]
    assert _frames(out, (1, 2, 3, 4)) == clean
