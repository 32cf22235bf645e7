"""``python -m backend``: the event stream, exit codes, and the client that runs it from Blender."""

import json
import os
import subprocess
import sys

import pytest

from scpainter_blender.runs import client as backend_client
from tests_support import run_backend  # every line of standard output is JSON

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def ray_version():
    import importlib.metadata

    try:
        return importlib.metadata.version("ray")
    except importlib.metadata.PackageNotFoundError:
        return None


def test_doctor():
    code, events, _ = run_backend("doctor")
    assert code == 0
    assert events[-1]["event"] == "done"
    report = events[-1]["report"]
    assert report["numpy"] and report["python"].startswith("3.")
    assert report["ray"] == ray_version() and "ray" not in report["missing"]   # optional: batch --ray


def test_doctor_reports_opencv():
    """cv2's version, the one OpenCV distribution the pins install (two overwrite each other's cv2), contrib's
    modules, and the video back-ends of its build (the PyPI wheels are built with FFmpeg)."""
    import cv2

    code, events, _ = run_backend("doctor")
    assert code == 0
    report = events[-1]["report"]
    assert report["cv2"] == cv2.__version__ and "cv2" not in report["missing"]
    opencv = report["opencv"]
    assert list(opencv["distributions"]) == ["opencv-contrib-python-headless"]
    assert opencv["distributions"]["opencv-contrib-python-headless"].startswith(cv2.__version__ + ".")
    assert opencv["contrib"] is True
    assert opencv["video_io"]["FFMPEG"] == "YES" and opencv["video_io"]["GStreamer"] == "NO"


def test_bad_input_exit_code_and_error_event(tmp_path):
    bad = tmp_path / "broken.json"
    bad.write_text("{not json")
    code, events, _ = run_backend("render", bad)
    assert code == 2
    assert events[-1]["event"] == "error" and "broken.json" in events[-1]["message"]
    assert events[-1]["file"] == str(bad) and events[-1]["field"] == "(file)"


def test_ctrl_c_is_exit_130_with_an_error_event_and_nothing_half_written(tmp_path):
    import glob
    import signal

    from scpainter_blender.core import locking
    from tests_support import small_job

    job = small_job(tmp_path / "job", frames=tuple(range(1, 41)), resolution=(320, 240))
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    # Ctrl-C's disposition set explicitly: a shell starts a background job (``bash .ci/run &``) with SIGINT
    # ignored, and a child inherits that (Python then installs no KeyboardInterrupt handler)
    p = subprocess.Popen([sys.executable, "-m", "backend", "render", job, "--device", "cpu"], cwd=root,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        for line in p.stdout:   # the first finished frame
            if json.loads(line)["event"] == "progress":
                break
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err[-2000:]
    last = json.loads(out.splitlines()[-1])
    assert last["event"] == "error" and "interrupted" in last["message"] and "resume" in last["hint"]
    out_dir = tmp_path / "job" / "out"
    assert not glob.glob(str(out_dir / "conditions" / ".*.tmp")) and not (out_dir / locking.LOCK_NAME).exists()


def test_client_raises_with_message(tmp_path):
    with pytest.raises(backend_client.BackendError, match="missing.json") as e:
        backend_client.run(["render", tmp_path / "missing.json"])
    assert e.value.exit_code == 2
    seen = []
    done = backend_client.run(["doctor"], on_event=seen.append)
    assert done["event"] == "done" and seen[-1] == done
    with pytest.raises(backend_client.BackendError, match="not found"):
        backend_client.run(["doctor"], python=str(tmp_path / "no-python"))


#: ``python -m backend`` with a bug planted deep in the render command (an interpreter for ``BackendJob``).
_BUGGY_BACKEND = ("import sys; from backend.render import frames; "
                  "frames.render_frame = lambda *a, **k: (_ for _ in ()).throw(ValueError('shape bug')); "
                  "from backend.__main__ import main; sys.exit(main(sys.argv[3:]))")


def test_client_shows_file_and_field_of_bad_input_and_the_log_of_a_bug(tmp_path):
    from tests_support import small_job

    job = small_job(tmp_path / "job")
    with open(job, encoding="utf-8") as f:
        broken = json.load(f)
    broken["resolution"] = [16, 0]
    (tmp_path / "broken.json").write_text(json.dumps(broken))
    with pytest.raises(backend_client.BackendError) as e:
        backend_client.run(["render", tmp_path / "broken.json", "--device", "cpu"])
    assert e.value.bad_input and e.value.exit_code == 2 and e.value.log_path is None
    assert e.value.file == str(tmp_path / "broken.json") and e.value.field.startswith("resolution")
    python = tmp_path / "python-with-a-bug"  # the real backend run by the real interpreter, render_frame broken
    python.write_text(f'#!/bin/sh\nexec "{sys.executable}" -c "{_BUGGY_BACKEND}" "$@"\n')
    python.chmod(0o755)
    with pytest.raises(backend_client.BackendError) as e:
        backend_client.run(["render", job, "--device", "cpu"], python=str(python))
    log = str(tmp_path / "job" / "out" / "backend.log")
    assert e.value.exit_code == 1 and not e.value.bad_input and e.value.file is None and e.value.log_path == log
    assert str(e.value).startswith("ValueError: shape bug") and log in str(e.value)
    assert "Traceback" in e.value.log and "Traceback" in open(log, encoding="utf-8").read()


def _without_numpy(tmp_path) -> dict:
    """An environment whose Python cannot import numpy (a package of that name that fails as a missing one would),
    as a Blender interpreter without the backend's packages is."""
    fake = tmp_path / "no_numpy" / "numpy"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ModuleNotFoundError(\"No module named 'numpy'\", name='numpy')\n")
    return {"PYTHONPATH": os.pathsep.join([str(tmp_path / "no_numpy"), ROOT])}


def test_doctor_without_numpy_says_what_to_install(tmp_path):
    """doctor imports nothing but the standard library before it reports: the missing packages and the README's fix;
    any other command says the same in its error, never a traceback."""
    env = _without_numpy(tmp_path)
    code, events, err = run_backend("doctor", "--checkpoint", str(tmp_path), env=env)
    assert code == 0, err
    report = events[-1]["report"]
    assert "numpy" in report["missing"] and "pip install -r requirements.txt" in report["install"]
    assert report["checkpoint"].startswith("not checked")
    code, events, err = run_backend("render", "job.json", env=env)
    assert code == 2 and "Traceback" not in err
    assert events[-1]["field"] == "numpy" and "tools/setup.sh" in events[-1]["hint"]
