"""``runs/client.py``: the add-on's client of ``python -m backend`` (``run``, ``BackendJob``, ``BackendError``) against
the real backend: bad input with its file and field, a bug with its log, a missing interpreter."""

import json
import sys

import pytest

from scpainter_blender.runs import client as backend_client


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
