"""The Blender session's warm backend (``runs/warm_session.py``): Render Conditions twice runs in one backend
process that serves the points from memory; a preference change or a killed server gives a new one; *Keep
Backend* 0 and ``blender -c scpainter`` run one-shot processes; ``end`` leaves no process behind. The figures
(click to first frame, click to done) are printed, not asserted."""

import os
import signal
import sys
import time

import bpy
import pytest

from tests_support import street_with_car

#: The camera folder street_with_car's camera path renders into.
CAM_DIR = "Camera_path_2_m_left"


@pytest.fixture
def scene(addon, street, tmp_path):
    scene = street_with_car(street, tmp_path)
    scene.frame_end = 4
    scene.scpainter_output_dir = str(tmp_path / "out")
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.backend_python, prefs.device = sys.executable, "CPU"
    yield scene
    _module(addon, "warm_session").end()
    prefs.backend_python, prefs.device, prefs.keep_backend = "", "AUTO", 600
    bpy.ops.wm.read_homefile(use_empty=True)


def _module(addon, name):
    return sys.modules[f"{addon}.scpainter_blender.runs.{name}"]


def _timed_render(addon):
    """``camera_run.start`` as the operators call it (the job exported, the run started), waited for: (run, seconds to
    the first frame rendered (not reused) or None, seconds to the end)."""
    camera_run = _module(addon, "camera_run")
    t0 = time.monotonic()
    first = []

    def on_event(ev):
        if ev.get("event") == "progress" and ev.get("stage") == "render" and not ev.get("reused") and not first:
            first.append(time.monotonic() - t0)

    run, out = camera_run.start(bpy.context, camera_run.invocation(bpy.context, "render"))
    run.wait(timeout=600, on_event=on_event)
    return run, (first[0] if first else None), time.monotonic() - t0


def _touch_frame(tmp_path, frame=2):
    """One frame no longer finished: its layers and labels gone (the next render renders it alone)."""
    folder = tmp_path / "out" / CAM_DIR / "conditions"
    for name in (f"frame_{frame:06d}.exr", f"labels_{frame:06d}.json"):
        (folder / name).unlink()


def test_second_render_reuses_the_process_and_its_points(scene, addon, tmp_path):
    warm_session = _module(addon, "warm_session")
    warm_session.end()
    cold, cold_first, cold_done = _timed_render(addon)        # starts the session's backend
    pid = cold.server_pid
    assert warm_session.current().pid == pid
    _touch_frame(tmp_path)
    again, first, done = _timed_render(addon)                  # one frame to render, the points in memory
    assert again.server_pid == pid and again.done["rendered"] == 1
    log = (tmp_path / "out" / CAM_DIR / "backend.log").read_text()
    # no start, no import (the same process), no loading (its log): proven by these, not by a wall-clock comparison
    # of the two first frames, which a loaded machine can reverse (the times are printed below)
    assert "warm backend: the points of" in log and "served from memory" in log
    idle, _, idle_done = _timed_render(addon)                  # nothing to do
    assert idle.server_pid == pid and idle.done["rendered"] == 0
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}   # the operator: the same process
    assert warm_session.current().pid == pid
    print(f"\nwarm backend, street {scene.render.resolution_x}x{scene.render.resolution_y}: first run "
          f"first frame {cold_first:.2f} s, done {cold_done:.2f} s; one frame changed: first frame {first:.2f} s, "
          f"done {done:.2f} s; nothing changed: done {idle_done:.2f} s")


def test_preference_change_or_a_killed_server_gives_a_new_one(scene, addon, tmp_path):
    warm_session = _module(addon, "warm_session")
    run, _, _ = _timed_render(addon)
    first = warm_session.current()
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.keep_backend = 300                                   # its update callback ends the server now
    assert first.proc.wait(timeout=60) is not None and warm_session.current() is None
    _touch_frame(tmp_path)
    run, _, _ = _timed_render(addon)
    second = warm_session.current()
    assert second.pid != first.pid and run.done["rendered"] == 1
    # killed during a run: that run fails saying so, the next one starts a new server and succeeds. The server is
    # stopped (SIGSTOP) before the request goes out and killed while it holds it: waiting for a progress event
    # instead raced the one frame's render, which can end before a loaded test process sends the kill
    _touch_frame(tmp_path)
    camera_run = _module(addon, "camera_run")
    os.kill(second.pid, signal.SIGSTOP)
    try:
        job, _ = camera_run.start(bpy.context, camera_run.invocation(bpy.context, "render"))
        assert type(job).__name__ == "WarmRun" and job.server_pid == second.pid and not job.finished
    finally:
        os.kill(second.pid, signal.SIGKILL)
    with pytest.raises(RuntimeError, match=r"warm backend \(pid \d+\) was killed by SIGKILL during this run"):
        job.wait(timeout=120)
    _touch_frame(tmp_path, 3)
    run, _, _ = _timed_render(addon)
    assert warm_session.current().pid not in (first.pid, second.pid) and run.returncode == 0


def test_keep_backend_0_and_the_command_line_run_one_shot(scene, addon):
    warm_session = _module(addon, "warm_session")
    camera_run = _module(addon, "camera_run")
    warm_session.end()
    with warm_session.one_shot():                              # what blender -c scpainter render does
        job, _ = camera_run.start(bpy.context, camera_run.invocation(bpy.context, "render"))
    assert type(job).__name__ == "BackendJob" and job.wait(timeout=600)["frames"] == 4
    bpy.context.preferences.addons[addon].preferences.keep_backend = 0
    job, _ = camera_run.start(bpy.context, camera_run.invocation(bpy.context, "render"))
    assert type(job).__name__ == "BackendJob" and job.wait(timeout=600)["rendered"] == 0
    assert warm_session.current() is None


def test_end_leaves_no_process(scene, addon):
    warm_session = _module(addon, "warm_session")
    _timed_render(addon)
    server = warm_session.current()
    warm_session.end()                                         # unregister() and atexit call this
    assert server.proc.poll() is not None and warm_session.current() is None


def test_the_key_ignores_what_the_backend_sets_for_itself(addon, monkeypatch):
    """Importing ``backend`` in Blender (to read an EXR) sets the variables ``python -m backend`` sets for itself:
    that is no reason to start another warm backend; any other variable changed is (the server would see it)."""
    warm = _module(addon, "warm_session")
    protocol = sys.modules[f"{addon}.scpainter_blender.core.backend_protocol"]
    before = warm._key(sys.executable, "cpu", 600.0)
    for name in protocol.BACKEND_SETS_ENV:
        monkeypatch.setenv(name, "set by an import of backend in this process")
    assert warm._key(sys.executable, "cpu", 600.0) == before
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "7")
    assert warm._key(sys.executable, "cpu", 600.0) != before
