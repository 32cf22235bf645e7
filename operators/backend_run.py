"""Render Conditions / Generate / Export Labels: write the job, run the backend in a subprocess, follow it, load the
results (an export's are files: its report says where). Render / Generate All Camera Paths: the same for every
camera path of the scene, one after another (``all_cameras.AllCameras``).

A run is the scene camera's (each camera path its own): its job is seen by that camera and written into that
camera's output folder (``<scene output folder>/<camera>/``); its results are loaded under the camera's name and
shown behind it. The All Camera Paths operators pass each camera to the job export, so the scene camera stays.

From the UI the operators are modal: a timer polls the backend's event stream, progress shows in the panel and
the status bar, Esc stops the backend (SIGTERM: the frame or sampler step in progress finishes, everything done
is kept, running again resumes). In background mode (``blender -b``, the bpy module, ``blender -c scpainter``)
``execute`` runs the same work blocking. Nothing in the .blend changes unless the run finished: the job file goes
to the output folder, and the results are loaded only after success.

Generate without a checkpoint folder in the preferences makes the baseline (OpenCV inpainting of the condition
holes, no model); its tooltip, progress text and report say so.
"""

from __future__ import annotations

import bpy

from ..scpainter_blender.core import backend_protocol as protocol
from ..scpainter_blender.core import outputs
from ..scpainter_blender.runs import preferences, render_plan
from ..scpainter_blender.runs.all_cameras import AllCameras
from ..scpainter_blender.runs.camera_run import (ACTIVE, Follower, failure_message, finish, invocation, planned_model,
                                                 progress_text, start, with_warnings)
from ..scpainter_blender.runs.client import BackendError, Invocation
from ..scpainter_blender.runs.preferences import DOCTOR
from ..scpainter_blender.scene import job_export, kinds, props
from . import reports


class _BackendRun:
    bl_options = {"REGISTER"}  # no undo step: the .blend is not changed by the run itself
    command = ""

    timeout: bpy.props.FloatProperty(name="Timeout", default=0.0, min=0.0, unit="TIME_ABSOLUTE",
                                     description="Stop the backend if it runs longer (seconds; 0: no limit)")

    def backend_options(self) -> dict:
        """This run's backend options beyond the preferences' (``Invocation``'s fields)."""
        return {}

    def _run(self, context):
        """This run's backend command line: the preferences' and ``backend_options``."""
        return invocation(context, self.command, **self.backend_options())

    def _report_warnings(self, warnings):
        """Report what the job will render wrong without failing (``job_export.warnings``, read before the run
        starts: the same for every camera), as the run starts."""
        for w in warnings:
            self.report({"WARNING"}, w["message"])

    def _follower(self, context):
        """The scene camera's run, started and followed (the camera named, so a change of the scene camera during
        the run does not change whose results these are)."""
        cam = context.scene.camera
        warnings = job_export.warnings(context)
        job, out = start(context, self._run(context), camera=cam, exported=getattr(self, "_exported", None))
        self._report_warnings(warnings)
        return Follower(self.command, job, out, self.timeout, model=planned_model(context, self.command),
                        camera=cam.name)

    @classmethod
    def poll(cls, context):
        if ACTIVE:
            cls.poll_message_set(f"The backend is busy ({ACTIVE['command']}): wait or press Esc")
            return False
        if context.scene.camera is None:
            cls.poll_message_set("The scene has no camera: import a reconstruction or add a camera path")
            return False
        return True

    def _finished_already(self, context):
        """A render with nothing to render (``render_plan.check``): its results loaded and reported without
        starting the backend; None when the backend has work (the job it exported kept for ``start``)."""
        cam = context.scene.camera
        found = render_plan.check(context, self._run(context), cam)
        self._exported = None if found is None else (found.job_path, found.out)
        if found is None or found.done is None:
            return None
        self._report_warnings(job_export.warnings(context))
        level, message = with_warnings(finish(context, self.command, found.out, found.done, cam.name),
                                       found.warnings)
        self.report({level}, message)
        return {"FINISHED"}

    @reports.reported
    def execute(self, context):
        """Blocking: background mode and scripts."""
        already = self._finished_already(context)
        if already is not None:
            return already
        cam = context.scene.camera
        warnings = job_export.warnings(context)
        job, out = start(context, self._run(context), camera=cam, exported=getattr(self, "_exported", None))
        self._report_warnings(warnings)
        model = planned_model(context, self.command)

        def show(ev):
            if protocol.kind_of(ev) == protocol.PROGRESS:
                active = {**ev, "command": self.command, "model": ev.get("model") or model,
                          "sensor": ev.get(protocol.CAMERA_FIELD)}   # a rig job's event names its rig camera
                print(f"scpainter {progress_text(active)}", flush=True)

        try:
            done = job.wait(timeout=self.timeout or None, on_event=show)
        except BackendError as e:
            self.report({"ERROR"}, failure_message(e, out))
            return {"CANCELLED"}
        level, message = with_warnings(finish(context, self.command, out, done, cam.name), job.warnings)
        self.report({level}, message)
        return {"FINISHED"}

    @reports.reported_invoke
    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        already = self._finished_already(context)
        if already is not None:
            return already
        self._follow = self._follower(context)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end(self, context, status):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace:
            context.workspace.status_text_set(None)
        try:
            level, message = self._follow.report(context, status)
        except Exception as e:  # noqa: BLE001  loading the results failed: bad input or a bug (reports.message)
            level, message = "ERROR", reports.message(e)
        self.report({level}, message)
        _redraw(context)
        return {"FINISHED"} if status == "finished" else {"CANCELLED"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._follow.stop()
            return self._end(context, "cancelled")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            status = self._follow.tick(context)
        except Exception as e:  # noqa: BLE001  a bug (starting the next camera): stop the backend, end, report it
            self._follow.stop()
            self._end(context, "cancelled")
            self.report({"ERROR"}, reports.message(e))
            return {"CANCELLED"}
        if status != "running":
            return self._end(context, status)
        context.window_manager.progress_update(int(1000 * self._follow.fraction))
        if context.workspace:
            context.workspace.status_text_set(self._follow.status_text)
        _redraw(context)
        return {"PASS_THROUGH"}


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
    """Generate the video (renders missing conditions first): with the checkpoint folder of the preferences,
    SCPainter's model; without one, the baseline (OpenCV inpainting of the holes, no model)"""

    bl_idname = "scpainter.generate"
    bl_label = "Generate"
    command = "generate"

    steps: bpy.props.IntProperty(name="Steps", default=0, min=0, soft_max=50,
                                 description="The model's sampler steps (0: the job's, 25); fewer is faster and "
                                             "rougher; the baseline has none")

    @classmethod
    def description(cls, context, properties):
        """The tooltip says which generator the button runs now."""
        if planned_model(context) == "baseline":
            return ("No checkpoint folder is set: generate the baseline video, the condition images with their holes "
                    "filled by OpenCV inpainting (no model, not SCPainter's output). For the model set Preferences > "
                    "Add-ons > SCPainter > Checkpoint Folder")
        return "Generate the video with the SCPainter checkpoint of the preferences (renders missing conditions first)"

    def backend_options(self) -> dict:
        return {"steps": self.steps or None}


class SCPAINTER_OT_export_labels(_BackendRun, bpy.types.Operator):
    """Export the labels (boxes, masks, camera) of every frame as a training dataset, rendering missing frames
    first; the images are the generated video's frames, else the condition previews"""

    bl_idname = "scpainter.export_labels"
    bl_label = "Export Labels"
    command = "export"

    format: bpy.props.EnumProperty(
        name="Format", default="kitti",
        items=[(k, label, text) for k, (label, text) in protocol.EXPORT_FORMATS.items()],
        description="The dataset format (written into <output folder>/export/<format>)")

    def backend_options(self) -> dict:
        return {"export_format": self.format}


class _AllCameraPaths(_BackendRun):
    """Every camera path of the scene (``kinds.camera_paths``: name order), one after another, each into its own
    output folder; modal from the UI (Esc stops the camera running and runs no more), blocking in background mode.
    Refused (SceneError) when the scene has no camera path."""

    @classmethod
    def poll(cls, context):
        if ACTIVE:
            cls.poll_message_set(f"The backend is busy ({ACTIVE['command']}): wait or press Esc")
            return False
        if not kinds.camera_paths(context.scene):
            cls.poll_message_set("The scene has no camera paths: add one with New Camera Path")
            return False
        return True

    def _follower(self, context):
        warnings = job_export.warnings(context)
        runs = AllCameras(context, self.command, self._run(context), kinds.camera_paths(context.scene),
                          self.timeout, model=planned_model(context, self.command))
        self._report_warnings(warnings)
        return runs

    @reports.reported
    def execute(self, context):
        """Blocking: the same state machine as the modal run, polled in a loop; progress and each camera's report
        on stdout as they come."""
        import time

        runs = self._follower(context)
        shown, told, status = "", 0, "running"
        try:
            while True:
                # shown before each tick and after the last: a camera's run started (by the constructor or the last
                # tick) is printed at least once, at "starting", even when it ends before the next tick (a warm
                # backend, a busy CPU), and each camera's outcome once, the last camera's included
                text = progress_text() if ACTIVE else ""
                if text and text != shown:
                    print(f"scpainter {text}", flush=True)
                    shown = text
                for name, _, level, message in runs.outcomes[told:]:
                    print(f"scpainter {self.command} {name!r}: {level}: {message}", flush=True)
                told = len(runs.outcomes)
                if status != "running":
                    break
                if (status := runs.tick(context)) == "running":
                    time.sleep(0.1)
        except BaseException:  # Ctrl-C or a bug: the backend does not outlive the operator
            runs.stop()
            raise
        level, message = runs.report(context, status)
        self.report({level}, message)
        return {"CANCELLED"} if level == "ERROR" else {"FINISHED"}


class SCPAINTER_OT_render_all_camera_paths(_AllCameraPaths, bpy.types.Operator):
    """Render the condition layers of every camera path, one after another, each into its own output folder"""

    bl_idname = "scpainter.render_all_camera_paths"
    bl_label = "Render All Camera Paths"
    command = "render"


class SCPAINTER_OT_generate_all_camera_paths(_AllCameraPaths, bpy.types.Operator):
    """Generate the video of every camera path, one after another, each into its own output folder (renders
    missing conditions first); without a checkpoint folder in the preferences, the baseline (no model)"""

    bl_idname = "scpainter.generate_all_camera_paths"
    bl_label = "Generate All Camera Paths"
    command = "generate"

    steps: bpy.props.IntProperty(name="Steps", default=0, min=0, soft_max=50,
                                 description="The model's sampler steps (0: the job's, 25); the baseline has none")

    def backend_options(self) -> dict:
        return {"steps": self.steps or None}


class SCPAINTER_OT_open_output(bpy.types.Operator):
    """Open the scene camera's SCPainter output folder (without a camera, the scene's) in the file browser of the
    system"""

    bl_idname = "scpainter.open_output"
    bl_label = "Open Output Folder"

    @reports.reported
    def execute(self, context):
        scene = context.scene
        folder = props.camera_output_dir(scene) if scene.camera is not None else props.output_dir(scene)
        out = outputs.make_folder(folder, "scene.scpainter_output_dir")
        bpy.ops.wm.path_open(filepath=out)
        return {"FINISHED"}


class SCPAINTER_OT_check_backend(bpy.types.Operator):
    """Run `python -m backend doctor` with the configured interpreter and report what is missing"""

    bl_idname = "scpainter.check_backend"
    bl_label = "Check Backend"

    @reports.reported
    def execute(self, context):
        prefs = preferences.get(context)
        checkpoint = bpy.path.abspath(prefs.checkpoint_dir) if prefs and prefs.checkpoint_dir else None
        doctor = Invocation("doctor", checkpoint=checkpoint, python=preferences.python(prefs))
        DOCTOR.clear()
        try:
            report = doctor.start().wait(timeout=120)["report"]
        except BackendError as e:
            DOCTOR.update(ok=False, text=str(e))
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        # what is missing, and the README's fix for the interpreter the preferences name (a wrapper script may
        # start another one: the doctor knows only that one)
        python = bpy.path.abspath(prefs.backend_python) if prefs and prefs.backend_python else report["executable"]
        problems = [f"missing {', '.join(report['missing'])}: {protocol.install_hint(python)}"] \
            if report.get("missing") else []
        if report.get("checkpoint") not in (None, "ok"):
            problems.append(report["checkpoint"])
        gpu = ", ".join(report.get("devices") or []) or "no CUDA GPU"
        text = (f"Python {report['python']}, torch {report.get('torch')}, {gpu}"
                + (f"; {'; '.join(problems)}" if problems else "; ready")
                + ("" if prefs and prefs.checkpoint_dir else " (no checkpoint: Generate makes the inpainting "
                                                             "baseline, not the model)"))
        DOCTOR.update(ok=not problems, text=text, report=report)
        self.report({"WARNING" if problems else "INFO"}, text)
        return {"FINISHED"}


classes = (SCPAINTER_OT_render_conditions, SCPAINTER_OT_generate, SCPAINTER_OT_export_labels,
           SCPAINTER_OT_render_all_camera_paths, SCPAINTER_OT_generate_all_camera_paths, SCPAINTER_OT_open_output,
           SCPAINTER_OT_check_backend)
