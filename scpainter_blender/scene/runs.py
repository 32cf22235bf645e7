"""Backend runs from Blender: write the job, start the backend, load what it made. Shared by the operators (modal
or blocking) and the headless commands; plus the runtime state the panel and preferences show (never saved)."""

from __future__ import annotations

import os

import bpy

from ..backend_client import BackendError, BackendJob
from ..core import files, outputs
from . import job_export, preferences, props, results

#: The ``path`` of an InputError about an add-on preference (``field``: the preference's name).
PREFERENCES = "(add-on preferences)"

#: The run in progress (one at a time): command, stage, done, total, out.
ACTIVE: dict = {}
#: The last "Check Backend" report: ok, text, report.
DOCTOR: dict = {}


def start(context, command: str, extra=()) -> tuple[BackendJob, str]:
    """Export the scene's job into its output folder and start ``python -m backend <command> job.json *extra``.
    InputError (SceneError, or ``PREFERENCES`` for a missing checkpoint folder) before anything is written when
    the scene or the preferences cannot make a job; BackendError when the backend cannot be started."""
    scene = context.scene
    out = props.output_dir(scene)
    prefs = preferences.get(context)
    ckpt = bpy.path.abspath(prefs.checkpoint_dir) if prefs and prefs.checkpoint_dir else ""
    if command == "generate" and not ckpt:
        raise files.InputError(PREFERENCES, "checkpoint_dir", "no checkpoint folder is set",
                               hint="Preferences > Add-ons > SCPainter > Checkpoint Folder (or --checkpoint), made "
                                    "with `python -m backend init-checkpoint --svd SVD_DIR --out DIR`")
    outputs.make_folder(out, "scene.scpainter_output_dir")
    job_path = os.path.join(out, "job.json")
    job_export.export_job(context, job_path, checkpoint=ckpt)
    device = prefs.device.lower() if prefs else "auto"
    # the job's output folder is the one the user set (and its inputs are the files they imported): the add-on
    # says so with --allow-outside, which a job from someone else, run by hand, does not get
    job = BackendJob([command, job_path, "--device", device, "--allow-outside", *extra],
                     python=prefs.backend_python if prefs else "")
    return job, out


def finish(context, command: str, out: str, done: dict) -> str:
    """Load what the run made and show it behind the camera; returns a one-line report."""
    if command == "render":
        img = results.load_conditions(out)
        results.show_behind_camera(context.scene, img)
        return f"Condition layers of {done.get('frames', '?')} frames in {os.path.join(out, 'conditions')}"
    img, _clip = results.load_generated(out)
    results.show_behind_camera(context.scene, img)
    return f"Video {done.get('video')}"


def failure_message(e: BackendError, out: str) -> str:
    """One line for the user: the backend's message and where to read more (the log its error event names, its
    output folder's log, or the end of its stderr when it died before writing one)."""
    if e.log_path:  # already in str(e): the traceback of an internal error
        return str(e)
    log = os.path.join(out, "backend.log")
    if os.path.isfile(log):
        return f"{e} (log: {log})"
    tail = " | ".join(line for line in (e.log or "").strip().splitlines()[-3:])
    return f"{e}" + (f" (stderr: {tail})" if tail and tail not in str(e) else "")


class Follower:
    """The state machine of a run followed from a UI timer: ``tick()`` reads new events, keeps ``ACTIVE``
    (progress for the panel), and says whether the run is still going; ``stop()`` is Esc. The modal operator only
    adds the window-manager calls around it, so this logic is tested without a display."""

    def __init__(self, command: str, job: BackendJob, out: str, timeout: float = 0.0):
        import time

        self.command, self.job, self.out, self.timeout = command, job, out, timeout
        self.t0 = time.monotonic()
        ACTIVE.clear()
        ACTIVE.update(command=command, stage="starting", done=0, total=1, out=out)

    @property
    def fraction(self) -> float:
        return ACTIVE["done"] / max(ACTIVE["total"], 1) if ACTIVE else 1.0

    @property
    def status_text(self) -> str:
        return f"SCPainter {self.command}: {ACTIVE['stage']} {ACTIVE['done']}/{ACTIVE['total']}  (Esc to stop)"

    def tick(self) -> str:
        """'running', 'finished', 'failed' or 'timeout' (the last three end the run and clear ``ACTIVE``)."""
        import time

        for ev in self.job.poll():
            if ev.get("event") == "progress":
                ACTIVE.update(stage=ev["stage"], done=ev["done"], total=max(ev["total"], 1))
        if self.timeout and time.monotonic() - self.t0 > self.timeout:
            self.stop()
            return "timeout"
        if not self.job.finished:
            return "running"
        ACTIVE.clear()
        return "finished" if self.job.proc.returncode == 0 and self.job.error is None else "failed"

    def stop(self) -> None:
        self.job.cancel()
        ACTIVE.clear()

    def report(self, context, status: str) -> tuple[str, str]:
        """(level, message) for the end of a run; loads the results when it finished."""
        if status == "timeout":
            return "ERROR", f"{self.command} stopped after {self.timeout:.0f} s (timeout); finished outputs kept"
        if status == "cancelled":
            return "WARNING", f"{self.command} cancelled: finished outputs are kept in {self.out}"
        try:
            done = self.job.result()
        except BackendError as e:
            return "ERROR", failure_message(e, self.out)
        return "INFO", finish(context, self.command, self.out, done)
