"""What ``python -m backend`` and its callers (the add-on's operators, ``blender -c scpainter``, scripts) agree on:
the device names, the exit codes and the event stream's kinds and fields (docs/design.md §4.4). Both sides import
these names; none of them is spelled anywhere else.

stdlib only, no bpy, no torch: the backend imports it as ``scpainter_blender.core.backend_protocol``, the extension
relatively.
"""

from __future__ import annotations

#: ``--device``: the names, in the order the add-on preference lists them, each with its label and description.
DEVICES = {"auto": ("Auto", "CUDA when available, else CPU"),
           "cuda": ("CUDA", "First CUDA GPU"),
           "cpu": ("CPU", "CPU only (slow)")}
#: The ``--device`` of a command that is given none: CUDA when torch sees a GPU, else the CPU.
DEFAULT_DEVICE = "auto"
DEVICE_NAMES = tuple(DEVICES)

#: ``export --format``: the dataset formats, each with its label and description (``backend/export``, design §15).
EXPORT_FORMATS = {"kitti": ("KITTI", "KITTI object: image_2, label_2, calib per frame"),
                  "coco": ("COCO", "COCO instances: annotations.json with RLE masks, images"),
                  "openlabel": ("OpenLABEL", "ASAM OpenLABEL 1.0 JSON: cuboids, boxes, camera per frame"),
                  "kitti-tracking": ("KITTI tracking", "KITTI tracking: image_02, label_02 with track ids, calib, "
                                                       "poses"),
                  "nuscenes": ("nuScenes", "nuScenes tables, samples and sweeps per camera and LiDAR, a map: what "
                                           "nuscenes-devkit and mmdetection3d's converter read")}
EXPORT_FORMAT_NAMES = tuple(EXPORT_FORMATS)


def export_format_labels() -> str:
    """The formats' labels as help texts list them: "KITTI, COCO or OpenLABEL"."""
    labels = [label for label, _ in EXPORT_FORMATS.values()]
    return labels[0] if len(labels) == 1 else ", ".join(labels[:-1]) + " or " + labels[-1]

#: Exit codes: done; a failure (explained, or a bug with its traceback); bad input (an ``InputError``: the error
#: event names ``file`` and ``field``); interrupted by Ctrl-C (128 + SIGINT, the shell's convention).
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Every event is one JSON object on a line of standard output; this field names its kind.
KIND = "event"
#: The kinds: ``progress`` (``stage``, ``done``, ``total`` and more), ``artifact`` (``path``: a file made),
#: ``done`` (the command's result: the last line of a run that succeeded; a batch's summary even when jobs failed),
#: ``error`` (``ERROR_FIELDS``: why the run ended), ``warning`` (``WARNING_FIELDS``: the run goes on, but what it
#: makes is weak or suspect — a frame mostly holes, a camera inside a car; clients show it and keep reading).
PROGRESS, ARTIFACT, DONE, ERROR, WARNING = "progress", "artifact", "done", "error", "warning"
#: (A warm backend adds ``served``: ``SERVED`` below.)
#: A warning event's fields: ``message``, ``code`` (a stable name: ``core.labels.FLAGS``), and where it applies
#: (``frame``, ``object``) when it does.
WARNING_FIELDS = ("message", "code", "frame", "object")
#: An error event's fields: ``message``, ``hint`` (what to do, may be None), ``file`` and ``field`` (bad input: the
#: file or "(command line)", and the key or option), ``log`` (a bug's traceback: ``<output_dir>/backend.log``); a
#: failure the command explains may add its own (``stage``, ``step``).
ERROR_FIELDS = ("message", "hint", "file", "field", "log")
#: A progress event's fields: the stage, how many of its units are done, of how many.
PROGRESS_FIELDS = ("stage", "done", "total")
#: A rig job's (docs/design.md §17) ``progress``, ``artifact`` and ``warning`` events of one camera carry this field:
#: the camera's sensor name (``CAM_FRONT``); its ``done`` event lists the cameras (``cameras``) and counts ``frames``
#: over all of them.
CAMERA_FIELD = "camera"

#: How a batch item ended (its ``status``: ``python -m backend batch`` with or without ``--ray``, ``blender -c
#: scpainter batch``): done (or found up to date); failed (bad input, an explained failure, a bug, a worker that
#: died with no retry left); stopped by SIGTERM or Ctrl-C while it ran (its finished outputs kept); never started,
#: stopped (SIGTERM or Ctrl-C) before it began.
ITEM_OK, ITEM_FAILED, ITEM_STOPPED, ITEM_NOT_RUN = "ok", "failed", "stopped", "not run (SIGTERM)"
#: A batch's summary, its ``done`` event, printed in every ending (all done, some failed, SIGTERM, Ctrl-C):
#: ``command``, ``jobs`` (items), ``ok``, ``failed``, ``stopped``, ``not_run`` (items of each status above: a job
#: that never started is ``not_run``, never ``failed``), ``counts`` (``{status: items}``, in the order first met)
#: and ``items`` (one result per item, in order). ``core.batch_items.summary`` makes all but ``command`` and
#: ``items``.
BATCH_SUMMARY_FIELDS = ("command", "jobs", "ok", "failed", "stopped", "not_run", "counts", "items")


#: A progress event's ``stage`` while the renderer's numba kernels are compiled (the first run after an install,
#: ~15 s) or loaded from their cache: ``serve`` at its start, a one-shot ``render`` before its first frame when they
#: are not cached yet (``backend/render/warmup.py``). Its ``cached`` field says which.
COMPILE_STAGE = "compile"

#: ``python -m backend serve``: a warm backend (docs/design.md §12) that runs one request after another in one
#: process. It reads one JSON object per line on standard input: a request ``{"id": N, "argv": [...]}`` (what
#: follows ``python -m backend``; one of ``SERVED_COMMANDS``), ``{"cancel": N}`` (stop request N as SIGTERM stops a
#: one-shot command: its unit of work finishes, finished outputs are kept) or ``{"quit": true}`` (end after the
#: request in progress). A request's events are the command's own, followed by one ``served`` event.
SERVE = "serve"
SERVED_COMMANDS = ("render", "generate", "export")
REQUEST_ID, REQUEST_ARGV, REQUEST_CANCEL, REQUEST_QUIT = "id", "argv", "cancel", "quit"
#: The event that ends a request's events: ``id`` (the request's) and ``exit_code`` (what ``python -m backend
#: <argv>`` would have exited with).
SERVED = "served"
SERVED_FIELDS = ("id", "exit_code")
#: A request line is at most this many bytes (a render's argv is a few hundred); a longer one is refused, read
#: past in bounded pieces, never held whole. Its nesting and numbers have ``core.files.read_json``'s bounds.
MAX_REQUEST_BYTES = 2 ** 20
#: A malformed request line is answered by an ``error`` event whose ``file`` is this, whose ``field`` names what
#: is wrong (``id``, ``argv[2]``, ``(line)``) and whose ``id`` is the request's where it could be read (then a
#: ``served`` event with exit code ``EXIT_BAD_INPUT`` follows); the server goes on.
REQUEST_SOURCE = "(request)"


def request(request_id: int, argv) -> dict:
    """A warm backend's request line: run ``python -m backend <argv>`` as request ``request_id``."""
    return {REQUEST_ID: int(request_id), REQUEST_ARGV: [str(a) for a in argv]}


def cancel_request(request_id: int) -> dict:
    """A warm backend's request line: stop request ``request_id`` (running or waiting)."""
    return {REQUEST_CANCEL: int(request_id)}


def quit_request() -> dict:
    """A warm backend's request line: end the server once the request in progress (if any) has ended."""
    return {REQUEST_QUIT: True}


def served_marker(request_id: int) -> str:
    """The line a warm backend writes to standard error when request ``request_id`` has ended, before its
    ``served`` event: the client knows every stderr line of the request has arrived (two pipes keep no order
    between them)."""
    return f"scpainter-serve: request {int(request_id)} served"


#: The environment variables ``python -m backend`` sets for itself when they are missing (``backend/__init__.py``:
#: the OpenMP wait policy, numba's cache folder): a client that imported ``backend`` has them too, which says
#: nothing about the environment a backend it starts gets (``runs/warm_session.py`` leaves them out of its key).
BACKEND_SETS_ENV = ("OMP_WAIT_POLICY", "NUMBA_CACHE_DIR")


def event(kind: str, /, **fields) -> dict:
    """An event of ``kind`` (one of the kinds above) as the dict written on one line."""
    return {KIND: kind, **fields}


def error_event(message: str, /, hint: str | None = None, **fields) -> dict:
    """An ``error`` event: ``message``, ``hint`` and any of ``file``, ``field``, ``log`` (``ERROR_FIELDS``), plus
    what a failure says of itself (a ``CleanFailure``'s fields, e.g. ``stage``)."""
    return event(ERROR, message=message, hint=hint, **fields)


def kind_of(ev: dict) -> str | None:
    """The kind of a parsed event (None for a line that is not one)."""
    return ev.get(KIND) if isinstance(ev, dict) else None


#: What to do when the backend's Python lacks a package it needs (``doctor``'s report, *Check Backend*, the error
#: of any other command): the README's fix, for the interpreter named.
INSTALL_HINT = ("install the backend's packages into that Python: `{python} -m pip install -r requirements.txt` in "
                "the SCPainter folder (requirements-backend.txt for a Python without Blender, as on a GPU machine), "
                "or run `bash tools/setup.sh` there, which makes .venv with all of them "
                "(README, 'The two commands'), and choose its Python as Backend Python")


def install_hint(python: str) -> str:
    """``INSTALL_HINT`` for the interpreter ``python``."""
    return INSTALL_HINT.format(python=python)
