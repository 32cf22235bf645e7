"""``python -m backend`` (backend/__main__.py): bad input and Ctrl-C as exit codes and error events; and the client that
runs it from Blender."""

import json
import os
import subprocess
import sys

import pytest

from scpainter_blender import backend_client
from tests_support import run_backend  # every line of standard output is JSON

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


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
