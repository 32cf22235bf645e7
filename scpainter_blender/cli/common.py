"""What the commands of ``blender -c scpainter`` share: the parser that reports instead of exiting, the options of
the scene commands, opening a .blend for a run, the backend's command line built from the arguments, its progress,
a run's outputs and failures, and the one scene run of ``render``, ``generate`` and ``export``.

The backend's command line is built by ``client.Invocation`` from these arguments, the add-on preferences
filling in what they do not give (the preferences are never changed).

Before a scene's job runs, what it would render wrong without failing (``job_export.warnings``: frames outside the
recording) is sent as ``warning`` events (``batch``: each message starting with its .blend item).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import traceback

import bpy

from ..runs import client
from ..core import backend_protocol as protocol
from ..core import batch_items as batch_mod
from ..core import errors, files
from ..core import job as job_mod
from ..core.variation import proposals
from ..runs import camera_run, warm_session
from ..core import rig as core_rig
from ..scene import job_export, props
from ..scene import rig as rig_scene


class Parser(argparse.ArgumentParser):
    """argparse's parser whose errors are bad input (exit 2) instead of a ``sys.exit()`` from inside Blender."""

    def error(self, message: str) -> None:  # argparse would sys.exit() from inside Blender: bad input, exit 2 instead
        """An ``ArgumentError`` (file "(command line)") whose field is the argument argparse names."""
        raise errors.ArgumentError.from_argparse(message, self.prog)


# -- options shared by several commands --------------------------------------------------------------------------

def scene_options(c: argparse.ArgumentParser) -> None:
    """The options of a command that runs one .blend: its camera and its output folder."""
    c.add_argument("--camera", metavar="NAME",
                   help="the camera object whose job runs (default: the scene camera), e.g. a camera path")
    c.add_argument("--output", help="the scene's output folder (default: its SCPainter output folder); the run "
                                    "writes into its camera's folder inside it")
    c.add_argument("--rig", metavar="PRESET|FILE",
                   help="mount a camera rig on the run's camera for this run (the .blend is not written): a preset "
                        f"({', '.join(core_rig.PRESETS)}, with its LiDAR), 'recording' (the recording's own) or a "
                        "rig file (.json); the run renders every camera of it (default: the camera's own rig, if any)")
    c.add_argument("--rig-scale", type=float, metavar="F",
                   help="the --rig's cameras' resolution times F (only with --rig; default 1: nuScenes' 1600 x 900)")


def common_options(c: argparse.ArgumentParser) -> None:
    """The options every scene command has: the device, the backend's interpreter, a timeout."""
    c.add_argument("--device", choices=protocol.DEVICE_NAMES, help="default: the add-on preference")
    c.add_argument("--backend-python", help="interpreter for the backend (default: the add-on preference)")
    c.add_argument("--timeout", type=float, default=0.0,
                   help="stop the backend after this many s (batch: the whole batch's)")


def proposals_option(c: argparse.ArgumentParser) -> None:
    """``--proposals accept|ignore|off`` (render, export): passed on to the backend's option of that name."""
    c.add_argument("--proposals", choices=proposals.MODES,
                   help="objects of the reconstruction that nothing labels: label them (accept), make them ignore "
                        f"regions (ignore) or leave them (off); default {proposals.DEFAULT_MODE}, the backend's")


def checkpoint_option(c: argparse.ArgumentParser) -> None:
    """``--checkpoint``: the SCPainter checkpoint a command's jobs name (``render``, ``generate``, ``batch``)."""
    c.add_argument("--checkpoint", help="SCPainter checkpoint folder (default: the add-on preference)")


def inpaint_option(c: argparse.ArgumentParser) -> None:
    """``--inpaint``: the baseline's method for this run (``generate``, ``batch``)."""
    c.add_argument("--inpaint", choices=job_mod.INPAINT_METHODS,
                   help="the baseline's OpenCV method, used without a checkpoint (default: the scene's "
                        "Baseline Inpainting, else the job's, else "
                        f"{job_mod.BASELINE_DEFAULTS['inpaint']})")


# -- checks and values of the arguments ---------------------------------------------------------------------------

def check_paths(args: argparse.Namespace) -> None:
    """A ``--backend-python`` or ``--checkpoint`` that does not exist is bad input (``ArgumentError``), said before
    any scene is opened."""
    if args.backend_python and not os.path.isfile(args.backend_python):
        raise errors.ArgumentError("--backend-python", f"{args.backend_python} is not a file",
                                   hint="give the interpreter that has the backend's packages, e.g. .venv/bin/python")
    if getattr(args, "checkpoint", None) and not os.path.isdir(args.checkpoint):
        raise errors.ArgumentError("--checkpoint", f"{args.checkpoint} is not a folder",
                                   hint="make one with `python -m backend init-checkpoint --svd SVD_DIR --out DIR`")


def checkpoint(args: argparse.Namespace) -> str | None:
    """The checkpoint folder the command line gives (absolute), None when it gives none."""
    return os.path.abspath(args.checkpoint) if getattr(args, "checkpoint", None) else None


def invocation(args: argparse.Namespace, command: str, **options: object) -> client.Invocation:
    """``python -m backend <command>`` with this command line's device and interpreter, the add-on preferences'
    where it gives none (the preferences themselves are never changed), and ``options``."""
    run = camera_run.invocation(bpy.context, command, **options)
    return run.replace(device=args.device or run.device,
                       python=os.path.abspath(args.backend_python) if args.backend_python else run.python)


# -- the scene, the backend's events, a run's result ------------------------------------------------------------

def open_blend(blend: str, args: argparse.Namespace, output: str | None = None) -> None:
    """Open the .blend (never written) with this run's settings: ``output`` folder, ``--inpaint``."""
    files.check_regular(blend)  # Blender opens it by name: a FIFO would block it, a folder confuse it
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend), load_ui=False)
    except RuntimeError as e:  # Blender's own words ("File format is not supported"), without its traceback
        raise errors.InputError(blend, "(file)", f"Blender cannot open it as a scene: {str(e).strip()}",
                                hint="give a .blend file saved by Blender") from None
    if output:
        bpy.context.scene.scpainter_output_dir = os.path.abspath(output)
    if getattr(args, "inpaint", None):  # for this run only: the .blend is not written
        bpy.context.scene.scpainter_baseline_inpaint = next(k for k, v in props.INPAINT_ITEMS.items()
                                                            if v == args.inpaint)


def progress(ev: dict) -> None:
    """A backend event as it arrives: progress as a line on standard error ("scpainter: render 1/16"; a rig job's
    names its rig camera: "scpainter CAM_BACK: render 1/16"), a warning passed on as it is."""
    if protocol.kind_of(ev) == protocol.PROGRESS:
        job = f" {ev['status']}: {ev['job']}" if "job" in ev and "status" in ev else ""  # batch: a job ended
        camera = ev.get(protocol.CAMERA_FIELD)
        who = f"scpainter {camera}" if camera else "scpainter"
        print(f"{who}: {ev['stage']} {ev['done']}/{ev['total']}{job}", file=sys.stderr, flush=True)
    elif protocol.kind_of(ev) == protocol.WARNING:  # the backend's warning events, passed on as they are
        print(json.dumps(ev), flush=True)


def export_warnings(context: bpy.types.Context, item: str | None = None) -> int:
    """Print a ``warning`` event for each thing the scene's job will render wrong without failing
    (``job_export.warnings``: frames outside the recording), its message naming ``item`` (batch); their number."""
    found = job_export.warnings(context)
    for w in found:
        message = f"{item}: {w['message']}" if item else w["message"]
        print(json.dumps(protocol.event(protocol.WARNING, **{**w, "message": message})), flush=True)
    return len(found)


def run_outputs(done: dict, out: str | None) -> dict:
    """The summary's fields of a finished run: ``output_dir`` (``out``) and what its done event says it made."""
    # model / description: which generator made the video ("baseline": OpenCV inpainting, no model); output_dir is
    # the folder the scene names (the one its job was exported to), the other paths the done event's
    keep = ("frames", "rendered", "skipped", "video", "frames_dir", "model", "description", "seconds", "format", "out",
            "objects", "images")
    return {"output_dir": out, **{k: done[k] for k in keep if k in done}}


def failure(e: Exception) -> dict:
    """A failed batch item's fields: ``error``; bad input (an InputError, or the backend's exit code 2) adds
    ``file`` and ``field``; a backend's internal error its ``log``; any other exception is a bug: ``bug`` true,
    its traceback on standard error."""
    if isinstance(e, errors.InputError):
        return batch_mod.bad_input_fields(e)
    if isinstance(e, client.BackendError):
        return {"error": str(e), **({"file": e.file, "field": e.field} if e.bad_input else {}),
                **({"log": e.log_path} if e.log_path else {})}
    traceback.print_exception(type(e), e, e.__traceback__, file=sys.stderr)
    return {"error": f"{type(e).__name__}: {e}", "bug": True}


def mount_rig(args: argparse.Namespace, camera: bpy.types.Object | None) -> None:
    """``--rig``: the rig (preset, recording or file, scaled by ``--rig-scale``) added to ``camera`` for this run,
    replacing any it has (``scene.rig.add_rig``). ``ArgumentError`` on ``--rig-scale`` outside (0, 4]; an unknown
    preset is one on ``--rig`` listing them. ``--rig-scale`` None: 1."""
    scale = 1.0 if args.rig_scale is None else args.rig_scale
    if not 0 < scale <= 4:
        raise errors.ArgumentError("--rig-scale", f"{scale:g} is not a scale in (0, 4]",
                                   hint="give e.g. 0.25 for 400 x 225 nuScenes cameras")
    rig_scene.add_rig(camera, rig_scene.make_rig(bpy.context.scene, args.rig, lidar=None, scale=scale,
                                                 field="--rig"))


def check_rig_options(args: argparse.Namespace) -> None:
    """``--rig-scale`` without ``--rig`` scales nothing: an ArgumentError rather than a run that ignores it."""
    if getattr(args, "rig_scale", None) is not None and not getattr(args, "rig", None):
        raise errors.ArgumentError("--rig-scale", "only with --rig: it scales the rig --rig mounts for the run",
                                   hint="add --rig PRESET|FILE, or drop --rig-scale (a camera's own rig is "
                                        "scaled in Blender: its cameras' resolution)")


# -- the scene run of render, generate and export ----------------------------------------------------------------

def run_scene(args: argparse.Namespace, command: str, **options: object) -> tuple[dict, int]:
    """``render`` / ``generate`` / ``export`` (``command``): the scene's job seen by ``--camera`` (else the scene
    camera), exported into that camera's output folder (naming ``--checkpoint``, else the preference's) and run as
    ``python -m backend <command>`` with ``options`` (``Invocation``'s fields), blocking. The summary (the run's
    outputs, ``camera``, the number of ``warnings``) and exit code 0; a failed run raises its ``BackendError``, its
    message saying where the log is."""
    check_paths(args)
    check_rig_options(args)
    open_blend(args.blend, args, args.output)
    camera = props.named_camera(bpy.context.scene, args.camera, args.blend)
    if args.rig:
        mount_rig(args, camera or bpy.context.scene.camera)
    warned = export_warnings(bpy.context)
    with warm_session.one_shot():  # one command and the process ends: nothing to keep warm
        job, out = camera_run.start(bpy.context, invocation(args, command, **options), checkpoint(args), camera)
    try:
        done = job.wait(timeout=args.timeout or None, on_event=progress)
    except client.BackendError as e:  # the same error, its message saying where the log is
        raise client.BackendError(camera_run.failure_message(e, out), exit_code=e.exit_code, log=e.log,
                                          file=e.file, field=e.field, log_path=e.log_path) from None
    return {**run_outputs(done, out), "camera": (camera or bpy.context.scene.camera).name,
            "warnings": warned + len(job.warnings)}, protocol.EXIT_OK
