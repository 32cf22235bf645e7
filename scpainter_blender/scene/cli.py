"""``blender -c scpainter <command> ...``: the add-on's headless commands for batch pipelines.

    blender -c scpainter import predictions.npz --camera-height 1.6 --save scene.blend
    blender -c scpainter import predictions.npz --extrinsic-convention camera_to_world --crop "0 77 0 77"
    blender -c scpainter import predictions.npz --depth-edge-ratio off
    blender -c scpainter render scene.blend [--camera NAME] [--output DIR] [--device cpu|cuda|auto]
    blender -c scpainter generate scene.blend --checkpoint /models/scpainter
    blender -c scpainter generate scene.blend [--inpaint telea|navier-stokes]    # no checkpoint: the baseline
    blender -c scpainter export scene.blend --format kitti|coco|openlabel [--out DIR]
    blender -c scpainter batch a.blend b.blend jobs/c.json [--list scenes.txt] --command generate [--shard 0/4]
    blender -c scpainter batch a.blend b.blend jobs/c.json --command generate --ray [HEAD:6379] [--retries 2]

``render``/``generate`` open the .blend, write its job seen by the scene camera (``--camera NAME``: that camera
object) into the camera's output folder, ``<scene output folder>/<camera>/`` (``props.camera_output_dir``; the scene
output folder is ``--output`` or the scene's), and run the backend there (blocking); the .blend itself is never
written. Without a checkpoint (``--checkpoint`` or the preference)
``generate`` makes the baseline, OpenCV inpainting of the condition holes (no model); each output says which
(``model``: "scpainter" or "baseline", and ``description``). ``batch`` takes its share of the items (``--shard
K/N``, or torchrun's RANK/WORLD_SIZE: every N-th item from K), exports every .blend's job, then runs all the jobs
(job files as given) as the backend's one ``python -m backend batch``, here or with ``--ray`` on a Ray cluster
(backend/batch/ray_pool.py; each item then has its ``worker`` and ``attempts``; a .blend item runs its scene
camera, into that camera's folder): it goes on past failures, prints
one summary with each item's status, time and outputs, and exits 1 if any failed. ``export`` writes the .blend's job
as ``render`` does (``--camera`` too) and runs ``python -m backend export`` on it (missing frames rendered first; the
dataset in ``--out``, default ``<camera's output folder>/export/<format>``; docs/design.md §15).

The backend's command line is built by ``backend_client.Invocation`` from these arguments, the add-on preferences
filling in what they do not give (the preferences are never changed).

Before a scene's job runs, what it would render wrong without failing (``job_export.warnings``: frames outside the
recording) is sent as ``warning`` events (``batch``: each message starting with its .blend item).

``-c`` implies background mode; the import goes into the scene that is open (``blender -b scene.blend -c ...``
imports into scene.blend). With the ``bpy`` module (no ``-c``), call ``execute(argv)`` directly. Output: a JSON
summary on standard output; exit code 0 done, 2 bad input, 1 anything else (the backend's convention:
``core.backend_protocol``). Bad input is an ``InputError``, caught by name: a file, a scene setting, a command-line
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

from ..core import backend_protocol as protocol
from ..core import batch_items as batch_mod
from ..core import errors, files, import_options, outputs
from ..core import job as job_mod
from ..core.output_layout import OutputLayout
from ..core.variation import spec as variation_spec, variants as vary_mod
from ..runs import camera_run as runs, client as backend_client, preferences, warm_session as warm_backend
from . import importer, job_export, props, variations


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would sys.exit() from inside Blender: bad input, exit 2 instead
        """An ``ArgumentError`` (file "(command line)") whose field is the argument argparse names."""
        raise errors.ArgumentError.from_argparse(message, self.prog)


def _parser():
    p = _Parser(prog="blender -c scpainter", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    i = sub.add_parser("import", help="import VGGT predictions as points + recorded camera")
    i.add_argument("predictions")
    import_options.add_arguments(i)  # the import options, as core.import_options defines them
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
            c.add_argument(outputs.DATA_ROOT_OPTION, action="append", metavar="DIR",
                           help="a trusted folder (repeatable) job.json items' paths may lead into besides their "
                                "own folder, e.g. a recording and asset library shared by many jobs")
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
            _scene_options(c)
        _common_options(c)
        c.add_argument("--checkpoint", help="SCPainter checkpoint folder (default: the add-on preference)")
        if name != "render":
            c.add_argument("--inpaint", choices=job_mod.INPAINT_METHODS,
                           help="the baseline's OpenCV method, used without a checkpoint (default: the scene's "
                                "Baseline Inpainting, else the job's, else "
                                f"{job_mod.BASELINE_DEFAULTS['inpaint']})")
    v = sub.add_parser("vary", help="variants of a scene (camera shifts, lane changes, cars from a library placed on "
                                    "the road) as job folders with a batch list and a manifest")
    v.add_argument("source", help="the scene (.blend), or VGGT predictions (.npz) imported with the import options")
    variation_spec.add_arguments(v)
    v.add_argument("--camera", help="the camera the variants start from (default: the scene camera)")
    import_options.add_arguments(v)
    v.add_argument("--backend-python", help="interpreter for mesh conversions (default: the add-on preference)")
    x = sub.add_parser("export", help="a .blend's labels as a dataset (KITTI, COCO or OpenLABEL), rendering missing "
                                      "frames first")
    x.add_argument("blend", help="the scene (.blend)")
    x.add_argument("--format", required=True, choices=protocol.EXPORT_FORMAT_NAMES)
    x.add_argument("--out", help="destination folder, written whole (default: <output folder>/export/<format>); an "
                                 "existing one must be empty or a previous export")
    _scene_options(x)
    _common_options(x)
    return p


def _scene_options(c) -> None:
    """The options of a command that runs one .blend: its camera and its output folder."""
    c.add_argument("--camera", metavar="NAME",
                   help="the camera object whose job runs (default: the scene camera), e.g. a camera path")
    c.add_argument("--output", help="the scene's output folder (default: its SCPainter output folder); the run "
                                    "writes into its camera's folder inside it")


def _common_options(c) -> None:
    """The options every scene command has: the device, the backend's interpreter, a timeout."""
    c.add_argument("--device", choices=protocol.DEVICE_NAMES, help="default: the add-on preference")
    c.add_argument("--backend-python", help="interpreter for the backend (default: the add-on preference)")
    c.add_argument("--timeout", type=float, default=0.0,
                   help="stop the backend after this many s (batch: the whole batch's)")


def _import(args) -> dict:
    opts = import_options.from_arguments(args)  # checked: ArgumentError names the option
    result = importer.import_vggt(bpy.context, args.predictions, opts)
    out = {"points": result.num_points, "points_object": result.points.name, "camera": result.camera.name,
           "depth_edge_ratio": result.depth_edge_ratio, "depth_edge_points": result.depth_edge_points,
           "scale": result.fit.scale, "scale_method": result.fit.method, "residual_m": result.fit.residual_m,
           "warnings": result.warnings, "predictions": result.load_report.to_json(), "timings_s": result.timings,
           # a camera path stays the scene camera when the scene had one (importer.import_vggt)
           "scene_camera": bpy.context.scene.camera.name if bpy.context.scene.camera else None}
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


def _vary(args) -> tuple[dict, int]:
    """``vary``: the .blend opened (or the predictions imported into an empty scene with the import options), its
    job seen from ``--camera`` the base, the variants written (``scene/variations.py``); exit 1 when none could
    be placed (the summary says why)."""
    spec = variation_spec.from_arguments(args)  # checked before a scene is opened
    if args.source.lower().endswith(".npz"):
        bpy.ops.wm.read_homefile(use_empty=True)
        importer.import_vggt(bpy.context, args.source, import_options.from_arguments(args))
    else:
        given = import_options.given(args)
        if given:  # a .blend's points were imported already: the options would change nothing
            raise errors.ArgumentError(given[0], "is an import option: it applies to a predictions (.npz) source, "
                                                 f"not to the scene {args.source}",
                                       hint="leave it out, or give the predictions file instead of the .blend")
        _open_blend(args.source, args)
    camera = props.named_camera(bpy.context.scene, args.camera, args.source)
    python = args.backend_python or preferences.python(preferences.get(bpy.context))

    def progress(done, total):
        print(f"scpainter: vary {done}/{total}", file=sys.stderr, flush=True)

    manifest = variations.make_variations(bpy.context, spec, args.out, camera, python, progress)
    for w in vary_mod.warnings(manifest):
        print(json.dumps(protocol.event(protocol.WARNING, **w)), flush=True)
    code = protocol.EXIT_OK if manifest["summary"]["placed"] else protocol.EXIT_FAILED
    return vary_mod.done_fields(manifest, args.out), code


def _check_paths(args) -> None:
    """A ``--backend-python`` or ``--checkpoint`` that does not exist is bad input (``ArgumentError``), said before
    any scene is opened."""
    if args.backend_python and not os.path.isfile(args.backend_python):
        raise errors.ArgumentError("--backend-python", f"{args.backend_python} is not a file",
                                   hint="give the interpreter that has the backend's packages, e.g. .venv/bin/python")
    if getattr(args, "checkpoint", None) and not os.path.isdir(args.checkpoint):
        raise errors.ArgumentError("--checkpoint", f"{args.checkpoint} is not a folder",
                                   hint="make one with `python -m backend init-checkpoint --svd SVD_DIR --out DIR`")


def _checkpoint(args) -> str | None:
    """The checkpoint folder the command line gives (absolute), None when it gives none."""
    return os.path.abspath(args.checkpoint) if getattr(args, "checkpoint", None) else None


def _invocation(args, command: str, **options) -> backend_client.Invocation:
    """``python -m backend <command>`` with this command line's device and interpreter, the add-on preferences'
    where it gives none (the preferences themselves are never changed), and ``options``."""
    run = runs.invocation(bpy.context, command, **options)
    return run.replace(device=args.device or run.device,
                       python=os.path.abspath(args.backend_python) if args.backend_python else run.python)


def _progress(ev) -> None:
    if protocol.kind_of(ev) == protocol.PROGRESS:
        job = f" {ev['status']}: {ev['job']}" if "job" in ev and "status" in ev else ""  # batch: a job ended
        print(f"scpainter: {ev['stage']} {ev['done']}/{ev['total']}{job}", file=sys.stderr, flush=True)
    elif protocol.kind_of(ev) == protocol.WARNING:  # the backend's warning events, passed on as they are
        print(json.dumps(ev), flush=True)


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


def _run_blend(args) -> dict:
    """``render`` / ``generate`` / ``export``: the scene's job seen by ``--camera`` (else the scene camera),
    exported into that camera's output folder (naming ``--checkpoint``, else the preference's) and run."""
    _open_blend(args.blend, args, args.output)
    camera = props.named_camera(bpy.context.scene, args.camera, args.blend)
    options = {}
    if args.command == "export":
        options = {"export_format": args.format, "out": os.path.abspath(args.out) if args.out else None}
    warned = _export_warnings(bpy.context)
    with warm_backend.one_shot():  # one command and the process ends: nothing to keep warm
        job, out = runs.start(bpy.context, _invocation(args, args.command, **options), _checkpoint(args), camera)
    try:
        done = job.wait(timeout=args.timeout or None, on_event=_progress)
    except backend_client.BackendError as e:  # the same error, its message saying where the log is
        raise backend_client.BackendError(runs.failure_message(e, out), exit_code=e.exit_code, log=e.log,
                                          file=e.file, field=e.field, log_path=e.log_path) from None
    return {**_outputs(done, out), "camera": (camera or bpy.context.scene.camera).name,
            "warnings": warned + len(job.warnings)}


def _export_warnings(context, item: str | None = None) -> int:
    """Print a ``warning`` event for each thing the scene's job will render wrong without failing
    (``job_export.warnings``: frames outside the recording), its message naming ``item`` (batch); their number."""
    found = job_export.warnings(context)
    for w in found:
        message = f"{item}: {w['message']}" if item else w["message"]
        print(json.dumps(protocol.event(protocol.WARNING, **{**w, "message": message})), flush=True)
    return len(found)


def _outputs(done: dict, out: str) -> dict:
    # model / description: which generator made the video ("baseline": OpenCV inpainting, no model); output_dir is
    # the folder the scene names (the one its job was exported to), the other paths the done event's
    keep = ("frames", "rendered", "skipped", "video", "frames_dir", "model", "description", "seconds", "format", "out",
            "objects", "images")
    return {"output_dir": out, **{k: done[k] for k in keep if k in done}}


def _failure(e: Exception) -> dict:
    """A failed batch item's fields: ``error``; bad input (an InputError, or the backend's exit code 2) adds
    ``file`` and ``field``; a backend's internal error its ``log``; any other exception is a bug: ``bug`` true,
    its traceback on standard error."""
    if isinstance(e, errors.InputError):
        return batch_mod.bad_input_fields(e)
    if isinstance(e, backend_client.BackendError):
        return {"error": str(e), **({"file": e.file, "field": e.field} if e.bad_input else {}),
                **({"log": e.log_path} if e.log_path else {})}
    traceback.print_exception(type(e), e, e.__traceback__, file=sys.stderr)
    return {"error": f"{type(e).__name__}: {e}", "bug": True}


def _batch(args) -> tuple[dict, int]:
    """``batch``: this process's share of the items (``--shard K/N``, else torchrun's RANK / WORLD_SIZE; with
    ``--ray`` every item), every .blend's job exported into the output folder its scene names (as ``render``
    does), then all the jobs run as one ``python -m backend batch`` (``_run_jobs``), its results mapped back to the
    items in order. An item whose scene cannot make a job fails here and is not sent; two scenes naming the same
    output folder are refused (their jobs would be the same file)."""
    import time

    # checked before any scene is exported; given without --ray they are refused, not ignored
    args.retries, args.cpus_per_job = batch_mod.ray_options(args.ray, args.retries, args.cpus_per_job)
    shard = batch_mod.shard_option(args.shard, args.ray)
    args.data_root = outputs.data_roots_option(args.data_root)  # checked, absolute; the backend applies them
    listed = [batch_mod.read_job_list(f) for f in args.list or []]
    items = list(args.items) + [p for jl in listed for p in jl.paths]
    # a list's data-root: lines trust those folders for the job files it names (as the backend's batch does)
    roots_of = {}
    for jl in listed:
        for p in jl.paths:
            roots_of[os.path.abspath(p)] = tuple(dict.fromkeys(roots_of.get(os.path.abspath(p), ()) + jl.data_roots))
    if not items:
        raise errors.ArgumentError("items", "no .blend or job files given", hint="give paths, or --list FILE")
    k, n = (0, 1) if args.ray is not None else shard or batch_mod.ranks_from_env()[:2]
    items = batch_mod.shard(items, k, n)   # the others' scenes are not even opened
    t0 = time.perf_counter()
    results, jobs, seen = {}, [], {}   # item index -> failed result; (index, job path, exported); job -> item
    for i, path in enumerate(items):
        t = time.perf_counter()
        try:
            if path.endswith(".json"):  # listed twice: the backend runs it once and gives each item its result
                job_path, exported = os.path.abspath(path), False
            else:
                print(f"scpainter batch: exporting {path}", file=sys.stderr, flush=True)
                _open_blend(path, args)
                job_path, exported = OutputLayout(props.camera_output_dir(bpy.context.scene)).job, True
                if job_path in seen:  # checked before exporting: the other item's job stays as it is
                    raise errors.InputError(path, "scene.scpainter_output_dir",
                                            f"{os.path.dirname(job_path)} is also the output folder of "
                                            f"{seen[job_path]}", hint="give each scene its own SCPainter output folder")
                runs.export(bpy.context, _checkpoint(args))  # (writes job_path)
                _export_warnings(bpy.context, path)
            seen.setdefault(job_path, path)
            jobs.append((i, job_path, exported))
        except Exception as e:  # noqa: BLE001  bad input or a bug: recorded; go on with the rest
            results[i] = {"item": path, "status": protocol.ITEM_FAILED, **_failure(e), "seconds": time.perf_counter() - t}
    if jobs:
        for i, r in zip([i for i, _, _ in jobs], _run_jobs(args, jobs, roots_of)):
            results[i] = {"item": items[i], **r}
    ordered = [results[i] for i in range(len(items))]
    counts = batch_mod.summary(ordered)   # ok, failed, stopped and not_run apart, as the backend's summary
    # the cluster asked for: the address given, else RAY_ADDRESS, else "auto" (`ray start`'s here, or a new one)
    where = ({"ray": args.ray or os.environ.get("RAY_ADDRESS") or "auto"} if args.ray is not None
             else {"shard": f"{k}/{n}"})
    good = counts["ok"] == counts["jobs"]
    return {"what": args.what, **where, **counts, "items": ordered,
            "seconds": time.perf_counter() - t0}, (protocol.EXIT_OK if good else protocol.EXIT_FAILED)


def _run_jobs(args, jobs: list, roots_of: dict | None = None) -> list:
    """One backend ``batch`` over ``jobs`` ((index, job path, exported here) in order): with ``--ray`` on the
    cluster (backend/batch/ray_pool.py), else here, all of them (``--shard 0/1``: this process's share is already
    taken). Its result per job (status, outputs, ``seconds``; a failure's ``error``, ``hint``, ``file``, ``field``,
    ``log``; on Ray ``worker`` and ``attempts``). BackendError when the batch itself could not run (a bad address,
    no cluster, a bad ``--device``). SIGTERM is passed on to the backend, which stops the jobs not finished and
    still reports."""
    import signal

    ray = args.ray is not None
    generate = args.what == "generate"
    # the jobs exported here from .blend files may lead outside their folder (a job.json item naming one of them is
    # that same file); the other job.json items as given. Each list in the items' order: the backend runs them so
    exported = {p for _, p, e in jobs if e}
    trusted = [p in exported for _, p, _ in jobs]
    # the other job.json items in one list per set of data roots their --list files declared (each list's
    # data-root: lines apply to its own jobs), in the order first met
    roots_of = roots_of or {}
    groups = {}
    for k, ((_, p, _), t) in enumerate(zip(jobs, trusted)):
        if not t:
            groups.setdefault(roots_of.get(p, ()), []).append(k)
    lists = tempfile.mkdtemp(prefix="scpainter-batch-")
    try:
        job_lists = []
        for g, (roots, members) in enumerate(groups.items()):
            job_lists.append(os.path.join(lists, f"jobs{g}.txt"))
            with open(job_lists[-1], "w", encoding="utf-8") as f:
                f.writelines(f"{batch_mod.DATA_ROOT_DIRECTIVE} {r}\n" for r in roots)
                f.writelines(jobs[k][1] + "\n" for k in members)
        with open(os.path.join(lists, "trusted.txt"), "w", encoding="utf-8") as f:
            f.writelines(p + "\n" for (_, p, _), t in zip(jobs, trusted) if t)
        run = _invocation(args, "batch", batch_command=args.what, lists=tuple(job_lists),
                          trusted_lists=(os.path.join(lists, "trusted.txt"),), allow_outside=args.allow_outside,
                          data_roots=args.data_root,
                          checkpoint=_checkpoint(args) if generate else None,
                          inpaint=args.inpaint if generate else None, shard=None if ray else "0/1",
                          ray=args.ray, retries=args.retries if ray else None,
                          cpus_per_job=args.cpus_per_job if ray else None)
        job = run.start()
        # SIGTERM to Blender: the backend's batch stops what is not finished and still sends its summary
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
    # the backend's order: the --list files in turn, then --trusted-list
    order = [k for members in groups.values() for k in members] + [k for k, t in enumerate(trusted) if t]
    returned = [None] * len(jobs)
    for k, r in zip(order, done["items"], strict=True):
        returned[k] = r
    out = []
    for r in returned:  # the backend's "job" (and "rank") left out: the caller names the item
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
        elif args.command == "vary":
            summary, code = _vary(args)
        else:
            _check_paths(args)
            if args.command == "batch":
                summary, code = _batch(args)
            else:
                summary = _run_blend(args)
    except SystemExit as e:  # --help: argparse printed it and exits, which would end Blender; return instead
        return e.code if isinstance(e.code, int) else protocol.EXIT_OK
    except errors.InputError as e:  # bad input, caught by name (never as a ValueError): exit 2
        print(json.dumps(protocol.error_event(str(e), e.hint, file=e.path, field=e.field)), flush=True)
        return protocol.EXIT_BAD_INPUT
    except backend_client.BackendError as e:  # the backend refused the scene's job (its exit 2) or failed
        fields = {k: v for k, v in _failure(e).items() if k != "error"}  # file, field (bad input); log
        print(json.dumps(protocol.error_event(str(e), **fields)), flush=True)
        return protocol.EXIT_BAD_INPUT if e.bad_input else protocol.EXIT_FAILED
    except Exception as e:  # a bug (a plain ValueError included) or a failure of Blender itself: exit 1
        traceback.print_exc(file=sys.stderr)
        print(json.dumps(protocol.error_event(f"{type(e).__name__}: {e}", "an internal error in SCPainter, not a "
                                              "problem with the input: the traceback is on standard error; please "
                                              "report it")), flush=True)
        return protocol.EXIT_FAILED
    print(json.dumps(protocol.event(protocol.DONE, command=args.command, **summary)), flush=True)
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

