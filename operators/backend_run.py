"""Render Conditions / Generate: write the job, run the backend in a subprocess, follow it, load the results.

From the UI the operators are modal: a timer polls the backend's event stream, progress shows in the panel and
the status bar, Esc stops the backend (SIGTERM: the frame or sampler step in progress finishes, everything done
is kept, running again resumes). In background mode (``blender -b``, the bpy module, ``blender -c scpainter``)
``execute`` runs the same work blocking. Nothing in the .blend changes unless the run finished: the job file goes
to the output folder, and the results are loaded only after success.
"""

from __future__ import annotations

import os
import time

import bpy

from ..scpainter_blender.backend_client import BackendError, BackendJob
from ..scpainter_blender.scene import preferences, props
from ..scpainter_blender.scene.runs import ACTIVE, DOCTOR, failure_message, finish, start


class _BackendRun:
    bl_options = {"REGISTER"}  # no undo step: the .blend is not changed by the run itself
    command = ""

    timeout: bpy.props.FloatProperty(name="Timeout", default=0.0, min=0.0, unit="TIME_ABSOLUTE",
                                     description="Stop the backend if it runs longer (seconds; 0: no limit)")

    def extra_args(self):
        return ()

    @classmethod
    def poll(cls, context):
        if ACTIVE:
            cls.poll_message_set(f"The backend is busy ({ACTIVE['command']}): wait or press Esc")
            return False
        if context.scene.camera is None:
            cls.poll_message_set("The scene has no camera: import a reconstruction or add a camera path")
            return False
        return True

    def execute(self, context):
        """Blocking: background mode and scripts."""
        try:
            job, out = start(context, self.command, self.extra_args())
        except (ValueError, BackendError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}

        def show(ev):
            if ev.get("event") == "progress":
                print(f"scpainter {self.command}: {ev['stage']} {ev['done']}/{ev['total']}", flush=True)

        try:
            done = job.wait(timeout=self.timeout or None, on_event=show)
        except BackendError as e:
            self.report({"ERROR"}, failure_message(e, out))
            return {"CANCELLED"}
        self.report({"INFO"}, finish(context, self.command, out, done))
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            self._job, self._out = start(context, self.command, self.extra_args())
        except (ValueError, BackendError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self._t0 = time.monotonic()
        ACTIVE.update(command=self.command, stage="starting", done=0, total=1, out=self._out)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _cleanup(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace:
            context.workspace.status_text_set(None)
        ACTIVE.clear()
        _redraw(context)

    def modal(self, context, event):
        if event.type == "ESC":
            self._job.cancel()
            self._cleanup(context)
            self.report({"WARNING"}, f"{self.command} cancelled: finished outputs are kept in {self._out}")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        for ev in self._job.poll():
            if ev.get("event") == "progress":
                ACTIVE.update(stage=ev["stage"], done=ev["done"], total=max(ev["total"], 1))
        if self.timeout and time.monotonic() - self._t0 > self.timeout:
            self._job.cancel()
            self._cleanup(context)
            self.report({"ERROR"}, f"{self.command} stopped after {self.timeout:.0f} s (timeout)")
            return {"CANCELLED"}
        frac = ACTIVE["done"] / ACTIVE["total"]
        context.window_manager.progress_update(int(1000 * frac))
        if context.workspace:
            context.workspace.status_text_set(f"SCPainter {self.command}: {ACTIVE['stage']} "
                                              f"{ACTIVE['done']}/{ACTIVE['total']}  (Esc to stop)")
        _redraw(context)
        if not self._job.finished:
            return {"PASS_THROUGH"}
        self._cleanup(context)
        try:
            done = self._job.result()
        except BackendError as e:
            self.report({"ERROR"}, failure_message(e, self._out))
            return {"CANCELLED"}
        self.report({"INFO"}, finish(context, self.command, self._out, done))
        return {"FINISHED"}


def _redraw(context):
    for area in context.screen.areas if context.screen else ():
        if area.type in ("VIEW_3D", "IMAGE_EDITOR"):
            area.tag_redraw()


class SCPAINTER_OT_render_conditions(_BackendRun, bpy.types.Operator):
    """Render the condition layers (image, holes, asset mask) of every frame with the backend"""

    bl_idname = "scpainter.render_conditions"
    bl_label = "Render Conditions"
    command = "render"


class SCPAINTER_OT_generate(_BackendRun, bpy.types.Operator):
    """Generate the video with the SCPainter checkpoint (renders missing conditions first)"""

    bl_idname = "scpainter.generate"
    bl_label = "Generate"
    command = "generate"

    steps: bpy.props.IntProperty(name="Steps", default=0, min=0, soft_max=50,
                                 description="Sampler steps (0: the job's, 25); fewer is faster and rougher")

    def extra_args(self):
        return ("--steps", str(self.steps)) if self.steps else ()


class SCPAINTER_OT_open_output(bpy.types.Operator):
    """Open the scene's SCPainter output folder in the file browser of the system"""

    bl_idname = "scpainter.open_output"
    bl_label = "Open Output Folder"

    def execute(self, context):
        try:
            out = props.output_dir(context.scene)
        except ValueError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        os.makedirs(out, exist_ok=True)
        bpy.ops.wm.path_open(filepath=out)
        return {"FINISHED"}


class SCPAINTER_OT_check_backend(bpy.types.Operator):
    """Run `python -m backend doctor` with the configured interpreter and report what is missing"""

    bl_idname = "scpainter.check_backend"
    bl_label = "Check Backend"

    def execute(self, context):
        prefs = preferences.get(context)
        args = ["doctor"]
        if prefs and prefs.checkpoint_dir:
            args += ["--checkpoint", bpy.path.abspath(prefs.checkpoint_dir)]
        DOCTOR.clear()
        try:
            report = BackendJob(args, python=prefs.backend_python if prefs else "").wait(timeout=120)["report"]
        except BackendError as e:
            DOCTOR.update(ok=False, text=str(e))
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        problems = [f"missing {', '.join(report['missing'])}"] if report.get("missing") else []
        if report.get("checkpoint") not in (None, "ok"):
            problems.append(report["checkpoint"])
        gpu = ", ".join(report.get("devices") or []) or "no CUDA GPU"
        text = (f"Python {report['python']}, torch {report.get('torch')}, {gpu}"
                + (f"; {'; '.join(problems)}" if problems else "; ready"))
        DOCTOR.update(ok=not problems, text=text, report=report)
        self.report({"WARNING" if problems else "INFO"}, text)
        return {"FINISHED"}


classes = (SCPAINTER_OT_render_conditions, SCPAINTER_OT_generate, SCPAINTER_OT_open_output,
           SCPAINTER_OT_check_backend)
