"""``python -m backend`` (backend/__main__.py): bad input and Ctrl-C as exit codes and error events."""

import json
import os
import subprocess
import sys

import pytest

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
