"""``blender -c scpainter <command> ...``: the add-on's headless commands for batch pipelines.

    blender -c scpainter import predictions.npz --camera-height 1.6 --save scene.blend
    blender -c scpainter import predictions.npz --extrinsic-convention camera_to_world --crop "0 77 0 77"
    blender -c scpainter import predictions.npz --depth-edge-ratio off
    blender -c scpainter render scene.blend [--output DIR] [--device cpu|cuda|auto]
    blender -c scpainter generate scene.blend --checkpoint /models/scpainter
    blender -c scpainter generate scene.blend [--inpaint telea|navier-stokes]    # no checkpoint: the baseline
    blender -c scpainter batch a.blend b.blend jobs/c.json [--list scenes.txt] --command generate [--shard 0/4]

``render``/``generate`` open the .blend, write its job into the scene's output folder and run the backend there
(blocking); the .blend itself is never written. Without a checkpoint (``--checkpoint`` or the preference)
``generate`` makes the baseline, OpenCV inpainting of the condition holes (no model); each output says which
(``model``: "scpainter" or "baseline", and ``description``). ``batch`` does that for every .blend (job files go
straight to the backend), goes on past failures, prints one summary with each item's status, time and outputs, and
exits 1 if any failed; ``--shard K/N`` (or torchrun's RANK/WORLD_SIZE) takes every N-th item from K.

``-c`` implies background mode; the import goes into the scene that is open (``blender -b scene.blend -c ...``
imports into scene.blend). With the ``bpy`` module (no ``-c``), call ``execute(argv)`` directly. Output: a JSON
summary on standard output; exit code 0 done, 2 bad input, 1 anything else (the backend's convention,
docs/design.md §4.4). Bad input is an ``InputError``, caught by name: a file, a scene setting, a command-line
argument (file "(command line)", field the option), or the backend's own exit 2 for the scene's job; its error
event has ``file`` and ``field``. Any other exception, a plain ValueError included, is a bug: exit 1, its traceback
on standard error.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
import tempfile
import traceback

import bpy

from .. import backend_client
from ..core import batch_items as batch_mod
from ..core import files
from ..core import job as job_mod
from . import importer, preferences, props, runs


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would sys.exit() from inside Blender: bad input, exit 2 instead
        """An ``ArgumentError`` (file "(command line)") whose field is the argument argparse names."""
        named = re.match(r"argument ([^:]+): (.*)", message, re.S)
        required = re.match(r"the following arguments are required: (.*)", message, re.S)
        field = named.group(1) if named else required.group(1) if required else "(arguments)"
        raise files.ArgumentError(field, named.group(2) if named else message, hint=f"see {self.prog} --help")


def _ratio_or_off(text: str) -> float | None:
    """``--depth-edge-ratio``: a number, or "off" (None); its range is ``ImportOptions.check``'s."""
    if text.strip().lower() == "off":
        return None
    try:
        return float(text)
    except ValueError:  # (float() of the user's text)
        raise argparse.ArgumentTypeError(f"{text!r}: expected a fraction of the pixel's depth such as 0.05, "
                                         f"or off") from None


def _parser():
    p = _Parser(prog="blender -c scpainter", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    i = sub.add_parser("import", help="import VGGT predictions as points + recorded camera")
    i.add_argument("predictions")
    scale = i.add_mutually_exclusive_group()
    scale.add_argument("--scale-factor", type=float, help="metres per VGGT unit")
    scale.add_argument("--trajectory", help="metric camera path (.npz world_to_camera, xyz or TUM text)")
    scale.add_argument("--camera-height", type=float, help="camera height over the road, metres")
    i.add_argument("--confidence-percentile", type=float, default=50.0)
    i.add_argument("--point-source", choices=["depth", "world_points"], default="depth")
    i.add_argument("--extrinsic-convention", choices=["auto", "world_to_camera", "camera_to_world"], default="auto",
                   help="what the file's extrinsic holds; auto: VGGT's world-to-camera, checked against world_points")
    i.add_argument("--crop", default="auto", help="borders to leave out: auto (VGGT's white padding), none, or "
                                                  "'LEFT TOP RIGHT BOTTOM' pixels")
    i.add_argument("--depth-edge-ratio", type=_ratio_or_off, default=importer.DEPTH_EDGE_RATIO,
                   help="drop pixels whose depth jumps by more than this fraction of their own to a neighbour "
                        "(VGGT's flying pixels across depth edges); off or 0: keep them; the exported job renders "
                        f"with the same setting (default {importer.DEPTH_EDGE_RATIO})")
    i.add_argument("--save", help="write the scene to this .blend (written to a temporary file, then renamed)")
    for name in ("render", "generate", "batch"):
        c = sub.add_parser(name, help={"render": "render a .blend's condition layers",
                                       "generate": "generate a .blend's video",
                                       "batch": "render or generate many .blend / job files"}[name])
        if name == "batch":
            c.add_argument("items", nargs="*", help=".blend or job.json files")
            c.add_argument("--list", action="append", help="a text file of paths, one per line (repeatable)")
            c.add_argument("--command", dest="what", choices=["render", "generate"], default="render")
            c.add_argument("--shard", help="K/N: run every N-th item starting at K (default: RANK/WORLD_SIZE)")
            c.add_argument("--allow-outside", action="store_true",
                           help="let job.json items' paths lead outside their folder (.blend items always may: "
                                "their output folder is the one the scene names)")
        else:
            c.add_argument("blend", help="the scene (.blend)")
            c.add_argument("--output", help="output folder (default: the scene's SCPainter output folder)")
        c.add_argument("--device", choices=["auto", "cpu", "cuda"], help="default: the add-on preference")
        c.add_argument("--backend-python", help="interpreter for the backend (default: the add-on preference)")
        c.add_argument("--checkpoint", help="SCPainter checkpoint folder (default: the add-on preference)")
        c.add_argument("--timeout", type=float, default=0.0, help="stop a scene's backend after this many s")
        if name != "render":
            c.add_argument("--inpaint", choices=job_mod.INPAINT_METHODS,
                           help="the baseline's OpenCV method, used without a checkpoint (default: the scene's "
                                "Baseline Inpainting, else the job's, else "
                                f"{job_mod.BASELINE_DEFAULTS['inpaint']})")
    return p


def _import(args) -> dict:
    opts = importer.ImportOptions(confidence_percentile=args.confidence_percentile, point_source=args.point_source,
                                  extrinsic_convention=args.extrinsic_convention, crop=args.crop,
                                  depth_edge_ratio=args.depth_edge_ratio)
    if args.trajectory:
        opts.scale_mode, opts.trajectory_path = "TRAJECTORY", args.trajectory
    elif args.camera_height is not None:
        opts.scale_mode, opts.camera_height = "CAMERA_HEIGHT", args.camera_height
    else:
        opts.scale_mode, opts.scale_factor = "FACTOR", 1.0 if args.scale_factor is None else args.scale_factor
    try:
        opts.check()
    except files.InputError as e:  # named as the option the user typed
        raise files.ArgumentError("--" + e.field.replace("_", "-"), e.message, hint=e.hint) from None
    result = importer.import_vggt(bpy.context, args.predictions, opts)
    out = {"points": result.num_points, "points_object": result.points.name, "camera": result.camera.name,
           "depth_edge_ratio": result.depth_edge_ratio, "depth_edge_points": result.depth_edge_points,
           "scale": result.fit.scale, "scale_method": result.fit.method, "residual_m": result.fit.residual_m,
           "warnings": result.warnings, "predictions": result.load_report.to_json(), "timings_s": result.timings}
    if args.save:
        path = os.path.abspath(args.save)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        # into a fresh private folder beside the target (Blender makes its own "@" temporary and ".blend1" backup
        # of an existing file there), then renamed over the target
        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(path)}.", dir=os.path.dirname(path))
        try:
            bpy.ops.wm.save_as_mainfile(filepath=os.path.join(tmp, "scene.blend"), copy=True)
            os.replace(os.path.join(tmp, "scene.blend"), path)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        out["blend"] = path
    return out


def _apply_preferences(args) -> None:
    """Command-line settings override the add-on preferences for this process (preferences are not saved). A
    ``--backend-python`` or ``--checkpoint`` that does not exist is bad input (``ArgumentError``)."""
    if args.backend_python and not os.path.isfile(args.backend_python):
        raise files.ArgumentError("--backend-python", f"{args.backend_python} is not a file",
                                  hint="give the interpreter that has the backend's packages, e.g. .venv/bin/python")
    if args.checkpoint and not os.path.isdir(args.checkpoint):
        raise files.ArgumentError("--checkpoint", f"{args.checkpoint} is not a folder",
                                  hint="make one with `python -m backend init-checkpoint --svd SVD_DIR --out DIR`")
    prefs = preferences.get(bpy.context)
    if prefs is None:
        return
    if args.backend_python:
        prefs.backend_python = os.path.abspath(args.backend_python)
    if args.checkpoint:
        prefs.checkpoint_dir = os.path.abspath(args.checkpoint)
    if args.device:
        prefs.device = args.device.upper()


def _progress(ev) -> None:
    if ev.get("event") == "progress":
        print(f"scpainter: {ev['stage']} {ev['done']}/{ev['total']}", file=sys.stderr, flush=True)


def _run_blend(blend: str, command: str, args, output: str | None = None) -> dict:
    files.check_regular(blend)  # Blender opens it by name: a FIFO would block it, a folder confuse it
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend), load_ui=False)
    except RuntimeError as e:  # Blender's own words ("File format is not supported"), without its traceback
        raise files.InputError(blend, "(file)", f"Blender cannot open it as a scene: {str(e).strip()}",
                               hint="give a .blend file saved by Blender") from None
    if output:
        bpy.context.scene.scpainter_output_dir = os.path.abspath(output)
    if getattr(args, "inpaint", None):  # for this run only: the .blend is not written
        bpy.context.scene.scpainter_baseline_inpaint = next(k for k, v in props.INPAINT_ITEMS.items()
                                                            if v == args.inpaint)
    job, out = runs.start(bpy.context, command)
    try:
        done = job.wait(timeout=args.timeout or None, on_event=_progress)
    except backend_client.BackendError as e:  # the same error, its message saying where the log is
        raise backend_client.BackendError(runs.failure_message(e, out), exit_code=e.exit_code, log=e.log,
                                          file=e.file, field=e.field, log_path=e.log_path) from None
    return _outputs(done, out)


def _run_job(path: str, command: str, args) -> dict:
    prefs = preferences.get(bpy.context)
    device = args.device or (prefs.device.lower() if prefs else "auto")
    extra = ["--checkpoint", os.path.abspath(args.checkpoint)] if command == "generate" and args.checkpoint else []
    extra += ["--inpaint", args.inpaint] if command == "generate" and getattr(args, "inpaint", None) else []
    extra += ["--allow-outside"] if getattr(args, "allow_outside", False) else []
    done = backend_client.BackendJob([command, os.path.abspath(path), "--device", device, *extra],
                                     python=prefs.backend_python if prefs else "").wait(
        timeout=args.timeout or None, on_event=_progress)
    return _outputs(done, done.get("output_dir"))


def _outputs(done: dict, out) -> dict:
    # model / description: which generator made the video ("baseline": OpenCV inpainting, no model)
    keep = ("frames", "rendered", "skipped", "video", "frames_dir", "model", "description", "seconds")
    return {"output_dir": out or os.path.dirname(done.get("video", "")), **{k: done[k] for k in keep if k in done}}


def _shard(args) -> tuple[int, int]:
    """(K, N) from ``--shard K/N`` (ArgumentError unless 0 <= K < N) or torchrun's RANK / WORLD_SIZE
    (``core.batch_items.ranks_from_env``: InputError "(environment)")."""
    if args.shard:
        try:
            k, n = (int(x) for x in args.shard.split("/"))
        except ValueError:  # (int() of the user's text)
            raise files.ArgumentError("--shard", f"{args.shard!r}: expected K/N, e.g. 0/4") from None
        if not 0 <= k < n:
            raise files.ArgumentError("--shard", f"{k}/{n}: K must be in [0, N)")
        return k, n
    return batch_mod.ranks_from_env()[:2]


def _failure(e: Exception) -> dict:
    """A failed batch item's fields: ``error``; bad input (an InputError, or the backend's exit code 2) adds
    ``file`` and ``field``; a backend's internal error its ``log``; any other exception is a bug: ``bug`` true,
    its traceback on standard error."""
    if isinstance(e, files.InputError):
        return {"error": str(e), "hint": e.hint, "file": e.path, "field": e.field}
    if isinstance(e, backend_client.BackendError):
        return {"error": str(e), **({"file": e.file, "field": e.field} if e.bad_input else {}),
                **({"log": e.log_path} if e.log_path else {})}
    traceback.print_exception(type(e), e, e.__traceback__, file=sys.stderr)
    return {"error": f"{type(e).__name__}: {e}", "bug": True}


def _batch(args) -> tuple[dict, int]:
    import time

    items = list(args.items) + [p for f in args.list or [] for p in batch_mod.read_list(f)]
    if not items:
        raise files.ArgumentError("items", "no .blend or job files given", hint="give paths, or --list FILE")
    k, n = _shard(args)
    results = []
    for path in batch_mod.shard(items, k, n):
        t = time.perf_counter()
        print(f"scpainter batch: {args.what} {path}", file=sys.stderr, flush=True)
        try:
            run = _run_job if path.endswith(".json") else _run_blend
            results.append({"item": path, "status": "ok", **run(path, args.what, args)})
        except Exception as e:  # noqa: BLE001  bad input, a failed backend or a bug: recorded; go on with the rest
            results.append({"item": path, "status": "failed", **_failure(e)})
        results[-1]["seconds"] = time.perf_counter() - t
    failed = sum(r["status"] != "ok" for r in results)
    return {"what": args.what, "shard": f"{k}/{n}", "items": results, "failed": failed}, (1 if failed else 0)


def execute(argv) -> int:
    try:
        args = _parser().parse_args(list(argv))
        code = 0
        if args.command == "import":
            summary = _import(args)
        else:
            _apply_preferences(args)
            if args.command == "batch":
                summary, code = _batch(args)
            else:
                summary = _run_blend(args.blend, args.command, args, args.output)
    except files.InputError as e:  # bad input, caught by name (never as a ValueError): exit 2
        print(json.dumps({"event": "error", "message": str(e), "hint": e.hint, "file": e.path, "field": e.field}),
              flush=True)
        return 2
    except backend_client.BackendError as e:  # the backend refused the scene's job (its exit 2) or failed
        ev = {"event": "error", "message": str(e)}
        ev.update({k: v for k, v in _failure(e).items() if k != "error"})  # file, field (bad input); log
        print(json.dumps(ev), flush=True)
        return 2 if e.bad_input else 1
    except Exception as e:  # a bug (a plain ValueError included) or a failure of Blender itself: exit 1
        traceback.print_exc(file=sys.stderr)
        print(json.dumps({"event": "error", "message": f"{type(e).__name__}: {e}",
                          "hint": "an internal error in SCPainter, not a problem with the input: the traceback is "
                                  "on standard error; please report it"}), flush=True)
        return 1
    print(json.dumps({"event": "done", "command": args.command, **summary}), flush=True)
    return code


_handle = None


def register():
    global _handle
    if hasattr(bpy.utils, "register_cli_command"):
        _handle = bpy.utils.register_cli_command("scpainter", execute)


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None

