"""One camera's backend run from Blender: write the job, start the backend, follow it, load what it made. Shared
by the operators (modal or blocking) and the headless commands; plus the run in progress the panel shows
(``ACTIVE``, never saved).

A run is a camera's: its job is seen by that camera (default: the scene camera), written into that camera's output
folder (``props.camera_output_dir``), and its results are loaded under that camera's name and shown behind it
(``scene.results``). ``all_cameras.AllCameras`` runs every camera path of the scene so, one after another."""

from __future__ import annotations

import os

import bpy

from ..core import backend_protocol as protocol
from ..core import job as job_mod
from ..core import outputs
from ..core.errors import InputError
from ..core.output_layout import OutputLayout
from ..scene import job_export, props, results
from . import preferences, warm_session
from .client import BackendError, BackendRun, Invocation

#: The run in progress (one at a time): command, model (the generator, None for render), stage, done, total, out.
ACTIVE: dict = {}


#: What the UI calls each generator (panel, status bar, reports): the baseline is never to be taken for the model.
MODEL_NAMES = {"scpainter": "SCPainter", "baseline": "Baseline"}
#: The Generate button and the note under it when no checkpoint is set (``generate_ui``).
BASELINE_BUTTON = "Generate (Baseline)"
BASELINE_NOTE = ("No checkpoint: shows the OpenCV inpainting",
                 "baseline, not the SCPainter model.",
                 "Set one: Preferences > Add-ons > SCPainter",
                 "> Checkpoint Folder")


def checkpoint_dir(context) -> str:
    """The preferences' checkpoint folder, absolute; "" when none is set."""
    prefs = preferences.get(context)
    return bpy.path.abspath(prefs.checkpoint_dir) if prefs and prefs.checkpoint_dir else ""


def planned_model(context, command: str = "generate") -> str | None:
    """The generator a run of ``command`` from this context will use: "scpainter" when the preferences name a
    checkpoint folder, else "baseline" (the backend's ``auto`` rule applied to the job ``start`` exports, which names
    the checkpoint only when one is set); None for ``render``."""
    if command != "generate":
        return None
    return "scpainter" if checkpoint_dir(context) else "baseline"


def generate_ui(context) -> tuple[str, tuple[str, ...]]:
    """(text of the Generate button, lines of the note under it): "Generate" and no note with a checkpoint; the
    baseline's button and ``BASELINE_NOTE`` without one."""
    if planned_model(context) == "baseline":
        return BASELINE_BUTTON, BASELINE_NOTE
    return "Generate", ()


def export(context, checkpoint: str | None = None, camera=None) -> tuple[str, str]:
    """Export the scene's job seen by ``camera`` (default: the scene camera) into that camera's output folder:
    (job.json path, output folder). Nothing in the scene is changed to choose the camera. The job names
    ``checkpoint`` (None: the preferences' checkpoint folder) when one is set; without one ``generate`` makes the
    OpenCV inpainting baseline (the backend's ``generate.model`` auto). InputError (SceneError) before anything is
    written when the scene cannot make a job. Its output folder is the one the user set and its inputs the files
    they imported: whoever runs it says so with ``--allow-outside`` (or lists it in ``batch --trusted-list``), which
    a job from someone else, run by hand, does not get."""
    camera = camera or context.scene.camera
    out = props.camera_output_dir(context.scene, camera)
    outputs.make_folder(out, "scene.scpainter_output_dir")
    job_path = OutputLayout(out).job
    job_export.export_job(context, job_path, checkpoint=checkpoint_dir(context) if checkpoint is None else checkpoint,
                          camera=camera)
    return job_path, out


def invocation(context, command: str, **options) -> Invocation:
    """``python -m backend <command>`` as the preferences set it up (their device and interpreter), with
    ``options`` (``Invocation``'s fields, e.g. ``steps``); the job is ``start``'s to add. ``allow_outside``: the job
    ``start`` exports is the user's own (``export``)."""
    prefs = preferences.get(context)
    return Invocation(command, **{"device": preferences.device(prefs), "python": preferences.python(prefs),
                                  "allow_outside": True, **options})


def start(context, run: Invocation | str, checkpoint: str | None = None, camera=None,
          exported: tuple[str, str] | None = None) -> tuple[BackendRun, str]:
    """Export the scene's job seen by ``camera`` (``export``, naming ``checkpoint``) and start ``run`` on it: an
    ``Invocation`` (the operators': ``invocation``; the command line's: ``blender -c scpainter``), or a command run
    as the preferences say; (the run, the camera's output folder). The run is a request to the session's warm
    backend when the preferences keep one, else a process of its own (``warm_session.launch``). BackendError when
    the backend cannot be started. ``exported``: (job path, output folder) ``export`` wrote for this very run a
    moment ago (``render_plan``), so it is not exported twice."""
    run = invocation(context, run) if isinstance(run, str) else run
    job_path, out = exported or export(context, checkpoint, camera)
    keep = preferences.keep_backend(preferences.get(context))
    return warm_session.launch(run.replace(jobs=(job_path,)), keep), out


def finish(context, command: str, out: str, done: dict, camera: str | None = None) -> str:
    """Load what the run made as the results of the camera named ``camera`` (the run's; default: the scene
    camera) and show them behind it; returns a one-line report, which for the baseline says that it is the baseline
    (the ``done`` event's ``model``) and how to get the model's video. A camera deleted during the run gets its
    results loaded, shown behind nothing."""
    if camera is None and context.scene.camera is not None:
        camera = context.scene.camera.name
    cam = context.scene.objects.get(camera) if camera else None
    layout = OutputLayout(done.get("output_dir") or out)  # for the paths the done event does not carry
    if command == "export":  # nothing to load: the dataset is files for a training pipeline
        name = protocol.EXPORT_FORMATS.get(done.get("format"), (done.get("format"),))[0]
        images = "generated frames" if done.get("images") == "generated" else "condition previews (no video yet)"
        return (f"{name} export: {done.get('frames', '?')} frames, {done.get('objects', '?')} objects, images: "
                f"{images}, in {done.get('out')}")
    rig = _rig_of_run(layout)
    if rig is not None:  # a rig job: each camera's results from its own folder, shown behind its rig camera
        return _finish_rig(context, command, layout, done, rig, camera, cam)
    if command == "render":
        img = _load(command, layout, done, camera)
        results.show_behind_camera(context.scene, img, camera=cam)
        fresh = " (up to date: nothing changed since they were rendered)" if done.get("up_to_date") else ""
        return f"Condition layers of {done.get('frames', '?')} frames in {layout.conditions}{fresh}"
    model = done.get("model", "scpainter")  # a backend from before the baseline: always the model
    img = _load(command, layout, done, camera)
    results.show_behind_camera(context.scene, img, camera=cam)
    if model == "baseline":
        method = job_mod.INPAINT_NAMES.get(done.get("inpaint"), "")
        return (f"Baseline video (OpenCV {method + ' ' if method else ''}inpainting, no model): {done.get('video')}"
                f"; for SCPainter's video set Preferences > Add-ons > SCPainter > Checkpoint Folder")
    return f"Video {done.get('video')}"


def _load(command: str, layout: OutputLayout, done: dict, camera: str | None, own_folder: bool = False):
    """Load a render's conditions (and labelled previews) or a generation's frames and video from ``layout`` as
    the results of the camera named ``camera``; the image sequence to show. ``own_folder``: a rig camera's folder,
    whose paths are the layout's (the ``done`` event's name the rig job's top folder)."""
    if command == "render":
        img = results.load_conditions(layout.conditions, camera)
        results.load_labels(layout.conditions, camera)  # for an image editor: the camera shows the conditions
        return img
    model = done.get("model", "scpainter")
    frames_dir = layout.generated if own_folder else done.get("frames_dir") or layout.generated
    video = layout.video if own_folder else done.get("video") or layout.video
    img, _clip = results.load_generated(frames_dir, video, model, done.get("description", ""), camera)
    return img


def _rig_of_run(layout: OutputLayout):
    """The rig of the job the run ran (``layout.job``, what ``export`` wrote), None for a single-camera job or a job
    that cannot be read (then the results are looked for as one camera's)."""
    try:
        return job_mod.load(layout.job).rig
    except (OSError, InputError):
        return None


def _finish_rig(context, command: str, layout: OutputLayout, done: dict, rig, camera: str | None, cam) -> str:
    """A rig job's results: each rig camera's from ``<out>/<CAMERA>/``, loaded under the name of the Blender camera
    that is that sensor (``results.rig_cameras``; a rig removed since: "<path camera>/<sensor>") and shown behind it;
    the camera path shows the sensor it is (its rig's ``follow``)."""
    sensors, follow = results.rig_cameras(context.scene, cam)
    for rc in rig.cameras:
        obj = sensors.get(rc.name)
        img = _load(command, layout.camera(rc.name), done, obj.name if obj else f"{camera}/{rc.name}", own_folder=True)
        if obj is not None:  # (none: shown behind nothing, never behind the scene camera)
            results.show_behind_camera(context.scene, img, camera=obj)
        if rc.name == follow and cam is not None:
            results.show_behind_camera(context.scene, img, camera=cam)
    names = ", ".join(c.name for c in rig.cameras)
    if command == "render":
        fresh = " (up to date: nothing changed since they were rendered)" if done.get("up_to_date") else ""
        surround = results.load_surround(layout.root, camera)
        lidar = f" and {rig.lidar.name}" if rig.lidar is not None else ""
        seen = f"; the cameras{lidar} in image {surround.name!r}" if surround is not None else ""
        return (f"Condition layers of {len(rig.cameras)} cameras ({names}), {done.get('frames', '?')} frames in all, "
                f"in {layout.root}{fresh}{seen}")
    what = "Baseline videos (no model)" if done.get("model") == "baseline" else "Videos"
    return f"{what} of {len(rig.cameras)} cameras ({names}) in {layout.root}"


def with_warnings(message: str, warnings: list) -> tuple[str, str]:
    """(report level, message) of a finished run: INFO, or WARNING with the backend's ``warning`` events counted
    and the first one quoted (a frame mostly holes, a camera inside a car: the labels flag the frames)."""
    if not warnings:
        return "INFO", message
    first = warnings[0].get("message", "")
    more = f" (and {len(warnings) - 1} more: see the output folder's log)" if len(warnings) > 1 else ""
    return "WARNING", f"{message}; {len(warnings)} warning{'s' * (len(warnings) > 1)}: {first}{more}"


def progress_text(active: dict | None = None) -> str:
    """The run in progress in a few words (panel and status bar): "generate (Baseline): render 2/4"; a rig job's
    progress names the rig camera its event names (``sensor``): "render CAM_BACK: render 1/16"; one of several
    cameras (``all_cameras.AllCameras``) says which: "render, camera 2/3: render 4/16"."""
    a = ACTIVE if active is None else active
    model = MODEL_NAMES.get(a.get("model") or "")
    what = f"{a['command']} ({model})" if model else a["command"]
    if a.get("sensor"):
        what += f" {a['sensor']}"
    if a.get("position"):
        what += ", camera {}/{}".format(*a["position"])
    return f"{what}: {a['stage']} {a['done']}/{a['total']}"


def progress_fraction(active: dict | None = None) -> float:
    """How far the run in progress is, 0..1; over all its cameras when it is one of several."""
    a = ACTIVE if active is None else active
    if not a:
        return 1.0
    i, n = a.get("position") or (1, 1)
    return (i - 1 + a["done"] / max(a["total"], 1)) / n


def failure_message(e: BackendError, out: str) -> str:
    """One line for the user: the backend's message and where to read more (the log its error event names, its
    output folder's log, or the end of its stderr when it died before writing one)."""
    if e.log_path:  # already in str(e): the traceback of an internal error
        return str(e)
    log = OutputLayout(out).log
    if os.path.isfile(log):
        return f"{e} (log: {log})"
    tail = " | ".join(line for line in (e.log or "").strip().splitlines()[-3:])
    return f"{e}" + (f" (stderr: {tail})" if tail and tail not in str(e) else "")


class Follower:
    """The state machine of a run followed from a UI timer: ``tick()`` reads new events, keeps ``ACTIVE``
    (progress for the panel), and says whether the run is still going; ``stop()`` is Esc. The modal operator only
    adds the window-manager calls around it, so this logic is tested without a display."""

    def __init__(self, command: str, job: BackendRun, out: str, timeout: float = 0.0, model: str | None = None,
                 camera: str | None = None, position: tuple[int, int] | None = None):
        """``model``: the generator the run is expected to use (``planned_model``), shown from the start; the
        backend's progress events correct it. ``camera``: the name of the camera whose run it is (its results are
        loaded as that camera's; default: the scene camera when it ends). ``position``: (i, n), this run is the
        i-th camera's of n (``all_cameras.AllCameras``)."""
        import time

        self.command, self.job, self.out, self.timeout, self.camera = command, job, out, timeout, camera
        self.t0 = time.monotonic()
        ACTIVE.clear()
        ACTIVE.update(command=command, model=model, stage="starting", done=0, total=1, out=out, camera=camera,
                      position=position)

    @property
    def fraction(self) -> float:
        return progress_fraction()

    @property
    def status_text(self) -> str:
        return f"SCPainter {progress_text()}  (Esc to stop)"

    def tick(self, context=None) -> str:
        """'running', 'finished', 'failed' or 'timeout' (the last three end the run and clear ``ACTIVE``).
        ``context`` is not needed (``all_cameras.AllCameras.tick`` needs it: the operator calls both alike)."""
        import time

        for ev in self.job.poll():
            if protocol.kind_of(ev) == protocol.PROGRESS:
                ACTIVE.update(stage=ev["stage"], done=ev["done"], total=max(ev["total"], 1),
                              sensor=ev.get(protocol.CAMERA_FIELD))   # a rig job's event names its rig camera
                if ev.get("model"):
                    ACTIVE["model"] = ev["model"]
        if self.timeout and time.monotonic() - self.t0 > self.timeout:
            self.stop()
            return "timeout"
        if not self.job.finished:
            return "running"
        ACTIVE.clear()
        return "finished" if self.job.returncode == 0 and self.job.error is None else "failed"

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
        return with_warnings(finish(context, self.command, self.out, done, self.camera), self.job.warnings)
