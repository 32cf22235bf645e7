"""``blender -c scpainter <command> ...``: the add-on's headless commands for batch pipelines.

    blender -c scpainter import predictions.npz --camera-height 1.6 --save scene.blend
    blender -c scpainter import predictions.npz --extrinsic-convention camera_to_world --crop "0 77 0 77"
    blender -c scpainter import predictions.npz --depth-edge-ratio off
    blender -c scpainter render scene.blend [--output DIR] [--device cpu|cuda|auto]
    blender -c scpainter generate scene.blend --checkpoint /models/scpainter
    blender -c scpainter generate scene.blend [--inpaint telea|navier-stokes]    # no checkpoint: the baseline
    blender -c scpainter batch a.blend b.blend jobs/c.json [--list scenes.txt] --command generate [--shard 0/4]
    blender -c scpainter batch a.blend b.blend jobs/c.json --command generate --ray [HEAD:6379] [--retries 2]

``render``/``generate`` open the .blend, write its job into the scene's output folder and run the backend there
(blocking); the .blend itself is never written. Without a checkpoint (``--checkpoint`` or the preference)
``generate`` makes the baseline, OpenCV inpainting of the condition holes (no model); each output says which
(``model``: "scpainter" or "baseline", and ``description``). ``batch`` does that for every .blend (job files go
straight to the backend), goes on past failures, prints one summary with each item's status, time and outputs, and
exits 1 if any failed; ``--shard K/N`` (or torchrun's RANK/WORLD_SIZE) takes every N-th item from K.
``--ray`` exports every .blend's job first, then runs all the jobs as one Ray batch (``python -m backend batch
--ray``, backend/batch/ray_pool.py): the same summary, each item with its ``worker`` and ``attempts``.

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
import shutil
import sys
import tempfile
import traceback

import bpy

from .. import backend_client
from ..core import batch_items as batch_mod
from ..core import errors, files
from ..core import job as job_mod
from . import importer, preferences, props, runs


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would sys.exit() from inside Blender: bad input, exit 2 instead
        """An ``ArgumentError`` (file "(command line)") whose field is the argument argparse names."""
        raise errors.ArgumentError.from_argparse(message, self.prog)


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
            c.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                           help="export every .blend's job, then run all jobs as one Ray batch (python -m backend "
                                "batch --ray: one task per job, retried when a worker dies): the cluster at ADDRESS, "
                                "else RAY_ADDRESS or the one `ray start` started here, else a new local one; files "
                                "on a shared file system (README)")
            c.add_argument("--retries", type=int, default=None,
                           help="--ray: run a job again at most this often when its worker dies (default "
                                f"{batch_mod.DEFAULT_RETRIES}, at most {batch_mod.MAX_RETRIES})")
            c.add_argument("--cpus-per-job", type=float, default=None,
                           help="--ray on a cluster without GPUs: CPUs each job asks for (default "
                                f"{batch_mod.DEFAULT_CPUS_PER_JOB:g})")
        else:
            c.add_argument("blend", help="the scene (.blend)")
            c.add_argument("--output", help="output folder (default: the scene's SCPainter output folder)")
        c.add_argument("--device", choices=["auto", "cpu", "cuda"], help="default: the add-on preference")
        c.add_argument("--backend-python", help="interpreter for the backend (default: the add-on preference)")
        c.add_argument("--checkpoint", help="SCPainter checkpoint folder (default: the add-on preference)")
        c.add_argument("--timeout", type=float, default=0.0,
                       help="stop a scene's backend after this many s (batch --ray: the whole batch's)")
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
    except errors.InputError as e:  # named as the option the user typed
        raise errors.ArgumentError("--" + e.field.replace("_", "-"), e.message, hint=e.hint) from None
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
        raise errors.ArgumentError("--backend-python", f"{args.backend_python} is not a file",
                                  hint="give the interpreter that has the backend's packages, e.g. .venv/bin/python")
    if args.checkpoint and not os.path.isdir(args.checkpoint):
        raise errors.ArgumentError("--checkpoint", f"{args.checkpoint} is not a folder",
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
        job = f" {ev['status']}: {ev['job']}" if "job" in ev and "status" in ev else ""  # batch --ray: a job ended
        print(f"scpainter: {ev['stage']} {ev['done']}/{ev['total']}{job}", file=sys.stderr, flush=True)


def _open_blend(blend: str, args, output: str | None = None) -> None:
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


def _run_blend(blend: str, command: str, args, output: str | None = None) -> dict:
    _open_blend(blend, args, output)
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
    # model / description: which generator made the video ("baseline": OpenCV inpainting, no model); the paths are
    # the done event's (render and generate name their output_dir), never worked out here
    keep = ("frames", "rendered", "skipped", "video", "frames_dir", "model", "description", "seconds")
    return {"output_dir": out or done.get("output_dir") or "", **{k: done[k] for k in keep if k in done}}


def _shard(args) -> tuple[int, int]:
    """(K, N) from ``--shard K/N`` (ArgumentError unless 0 <= K < N) or torchrun's RANK / WORLD_SIZE
    (``core.batch_items.ranks_from_env``: InputError "(environment)")."""
    if args.shard:
        try:
            k, n = (int(x) for x in args.shard.split("/"))
        except ValueError:  # (int() of the user's text)
            raise errors.ArgumentError("--shard", f"{args.shard!r}: expected K/N, e.g. 0/4") from None
        if not 0 <= k < n:
            raise errors.ArgumentError("--shard", f"{k}/{n}: K must be in [0, N)")
        return k, n
    return batch_mod.ranks_from_env()[:2]


def _failure(e: Exception) -> dict:
    """A failed batch item's fields: ``error``; bad input (an InputError, or the backend's exit code 2) adds
    ``file`` and ``field``; a backend's internal error its ``log``; any other exception is a bug: ``bug`` true,
    its traceback on standard error."""
    if isinstance(e, errors.InputError):
        return {"error": str(e), "hint": e.hint, "file": e.path, "field": e.field}
    if isinstance(e, backend_client.BackendError):
        return {"error": str(e), **({"file": e.file, "field": e.field} if e.bad_input else {}),
                **({"log": e.log_path} if e.log_path else {})}
    traceback.print_exception(type(e), e, e.__traceback__, file=sys.stderr)
    return {"error": f"{type(e).__name__}: {e}", "bug": True}


def _batch(args) -> tuple[dict, int]:
    import time

    # checked before any scene is exported; given without --ray they are refused, not ignored
    args.retries, args.cpus_per_job = batch_mod.ray_options(args.ray, args.retries, args.cpus_per_job)
    items = list(args.items) + [p for f in args.list or [] for p in batch_mod.read_list(f)]
    if not items:
        raise errors.ArgumentError("items", "no .blend or job files given", hint="give paths, or --list FILE")
    if args.ray is not None:
        return _batch_ray(args, items)
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
    return {"what": args.what, "shard": f"{k}/{n}", "jobs": len(results), "failed": failed,
            "counts": batch_mod.status_counts(results), "items": results}, (1 if failed else 0)


def _batch_ray(args, items: list) -> tuple[dict, int]:
    """``batch --ray``: every .blend's job exported here (into the output folder its scene names, as ``render``
    does), then all jobs run as one ``python -m backend batch --ray`` (backend/batch/ray_pool.py; its progress goes to
    standard error as it comes), its results mapped back to the items in order. An item whose scene cannot make a
    job fails here and is not sent; two scenes naming the same output folder are refused (their jobs would be the
    same file). SIGTERM is passed on to the backend, which cancels the jobs not finished and still reports."""
    import time

    if args.shard:
        raise errors.ArgumentError("--shard", "not with --ray: Ray schedules every item",
                                  hint="give each Ray batch its whole list; --shard splits a list over processes")
    t0 = time.perf_counter()
    results, jobs, seen = {}, [], {}   # item index -> failed result; (index, job path, exported); job -> item
    for i, path in enumerate(items):
        try:
            if path.endswith(".json"):  # listed twice: the backend runs it once and gives each item its result
                job_path, exported = os.path.abspath(path), False
            else:
                print(f"scpainter batch: exporting {path}", file=sys.stderr, flush=True)
                _open_blend(path, args)
                job_path, exported = os.path.join(props.output_dir(bpy.context.scene), "job.json"), True
                if job_path in seen:  # checked before exporting: the other item's job stays as it is
                    raise errors.InputError(path, "scene.scpainter_output_dir",
                                           f"{os.path.dirname(job_path)} is also the output folder of "
                                           f"{seen[job_path]}", hint="give each scene its own SCPainter output folder")
                runs.export(bpy.context)  # (writes job_path)
            seen.setdefault(job_path, path)
            jobs.append((i, job_path, exported))
        except Exception as e:  # noqa: BLE001  bad input or a bug: recorded; go on with the rest
            results[i] = {"item": path, "status": "failed", **_failure(e)}
    if jobs:
        for i, r in zip([i for i, _, _ in jobs], _run_ray_jobs(args, jobs)):
            results[i] = {"item": items[i], **r}
    ordered = [results[i] for i in range(len(items))]
    failed = sum(r["status"] != "ok" for r in ordered)
    # the cluster asked for: the address given, else RAY_ADDRESS, else "auto" (`ray start`'s here, or a new one)
    return {"what": args.what, "ray": args.ray or os.environ.get("RAY_ADDRESS") or "auto", "jobs": len(ordered),
            "failed": failed, "counts": batch_mod.status_counts(ordered), "items": ordered,
            "seconds": time.perf_counter() - t0}, (1 if failed else 0)


def _run_ray_jobs(args, jobs: list) -> list:
    """One backend ``batch --ray`` over ``jobs`` ((index, job path, exported here) in order); its result per job
    (status, outputs, ``worker``, ``attempts``, ``seconds``; a failure's ``error``, ``file``, ``field``,
    ``log``). BackendError when the batch itself could not run (a bad address, no cluster)."""
    import signal

    prefs = preferences.get(bpy.context)
    lists = tempfile.mkdtemp(prefix="scpainter-batch-")
    try:
        # jobs from job.json items as given; the ones exported from .blend files may lead outside their folder
        for name, exported in (("jobs.txt", False), ("trusted.txt", True)):
            with open(os.path.join(lists, name), "w", encoding="utf-8") as f:
                f.writelines(p + "\n" for _, p, e in jobs if e == exported)
        cmd = ["batch", "--command", args.what, "--list", os.path.join(lists, "jobs.txt"),
               "--trusted-list", os.path.join(lists, "trusted.txt"), "--ray", *([args.ray] if args.ray else []),
               "--retries", str(args.retries), "--cpus-per-job", str(args.cpus_per_job),
               "--device", args.device or (prefs.device.lower() if prefs else "auto")]
        cmd += ["--checkpoint", os.path.abspath(args.checkpoint)] if args.what == "generate" and args.checkpoint else []
        cmd += ["--inpaint", args.inpaint] if args.what == "generate" and args.inpaint else []
        cmd += ["--allow-outside"] if args.allow_outside else []
        job = backend_client.BackendJob(cmd, python=prefs.backend_python if prefs else "")
        # SIGTERM to Blender: the backend's driver cancels what is not finished and still sends its summary
        previous = signal.signal(signal.SIGTERM, lambda *_: job.proc.terminate())
        try:
            done = job.wait(timeout=args.timeout or None, on_event=_progress)
        except backend_client.BackendError:
            if job.done is None:  # no summary: the batch itself failed (its error event is raised)
                raise
            done = job.done       # exit 1: some jobs failed; each says why in the summary
        finally:
            signal.signal(signal.SIGTERM, previous)
    finally:
        shutil.rmtree(lists, ignore_errors=True)
    # the backend's order: --list, then --trusted-list
    order = [k for k, (_, _, e) in enumerate(jobs) if not e] + [k for k, (_, _, e) in enumerate(jobs) if e]
    returned = [None] * len(jobs)
    for k, r in zip(order, done["items"], strict=True):
        returned[k] = r
    out = []
    for r in returned:
        keep = {k: r[k] for k in ("status", "error", "hint", "file", "field", "log", "worker", "attempts", "seconds")
                if k in r}
        if args.what == "render":  # skipped: frames reused, as the render command counts them (known when ok)
            r = {k: v for k, v in r.items() if k != "skipped"}
            if r.get("status") == "ok":
                r["skipped"] = r["frames"] - r["rendered"]
        made = "frames" in r or "video" in r  # ok, or stopped with its finished frames
        out.append({**keep, **(_outputs(r, r.get("output_dir")) if made else {})})
    return out


def execute(argv) -> int:
    if not props.registered():  # the bpy module with the add-on not enabled: the scene settings it reads
        props.register()
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
    except errors.InputError as e:  # bad input, caught by name (never as a ValueError): exit 2
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

