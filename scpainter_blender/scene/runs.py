"""Backend runs from Blender: write the job, start the backend, load what it made. Shared by the operators (modal
or blocking) and the headless commands; plus the runtime state the panel and preferences show (never saved)."""

from __future__ import annotations

import os

import bpy

from ..backend_client import BackendError, BackendJob
from . import job_export, preferences, props, results

#: The run in progress (one at a time): command, stage, done, total, out.
ACTIVE: dict = {}
#: The last "Check Backend" report: ok, text, report.
DOCTOR: dict = {}


def start(context, command: str, extra=()) -> tuple[BackendJob, str]:
    """Export the scene's job into its output folder and start ``python -m backend <command> job.json *extra``."""
    scene = context.scene
    out = props.output_dir(scene)
    prefs = preferences.get(context)
    ckpt = bpy.path.abspath(prefs.checkpoint_dir) if prefs and prefs.checkpoint_dir else ""
    if command == "generate" and not ckpt:
        raise ValueError("no checkpoint folder is set: Preferences > Add-ons > SCPainter > Checkpoint Folder (make "
                         "one with `python -m backend init-checkpoint --svd SVD_DIR --out DIR`)")
    os.makedirs(out, exist_ok=True)
    job_path = os.path.join(out, "job.json")
    job_export.export_job(context, job_path, checkpoint=ckpt)
    device = prefs.device.lower() if prefs else "auto"
    job = BackendJob([command, job_path, "--device", device, *extra], python=prefs.backend_python if prefs else "")
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
    """One line for the user: the backend's message and where to read more (its log, or the end of its stderr
    when it died before writing one)."""
    log = os.path.join(out, "backend.log")
    if os.path.isfile(log):
        return f"{e} (log: {log})"
    tail = " | ".join(line for line in (e.log or "").strip().splitlines()[-3:])
    return f"{e}" + (f" (stderr: {tail})" if tail and tail not in str(e) else "")
