"""Seeded fuzz cases for issue 42's surfaces (round three), run by ``tests/fuzz_inputs.py``'s harness (its worker
processes, timeouts, folder snapshots, outcome classes and result records).

Every case starts from ``fuzz_inputs.prepare``'s folder (``job/`` with the tiny job, its inputs and ``out/``;
``outside/`` with planted files that must never be touched); the kinds that run ``vary`` add a *road base* in
``job/road/`` (a drive of 5 cameras over a flat road, ``RoadBase``), a one-car library in ``job/cars/`` and
a spec in ``job/spec.json`` (2 variants of 16 x 12, one parked car each; a run takes ~0.5 s).

Kinds (``CASES`` says how many of each; a case is reproducible from (kind, index, seed)):

* ``links``: a symbolic link (absolute, relative, or dangling into ``outside/``) or a hard link to a file of
  ``outside/`` planted where ``render``, ``generate``, ``export`` or ``vary`` writes (``backend.log``,
  ``conditions/`` and its files, the lock, ``generated/``, the video, ``export/``, ``export/kitti``, a vary
  folder's ``v0000``, ``library``, ``variants.txt``, ``variation.json``), in a fresh output folder or after a
  first run; ``escape`` if anything outside ``job/`` is created, changed or deleted.
* ``races``: the product's own file calls hooked in-process (``os.open``, ``open``, ``io.open``, ``os.mkdir``):
  right after the first open of an input (car.ply, predictions.npz, job.json, the road's predictions, the
  library's car) it is swapped for a link into ``outside/``; right after an output folder is made
  (``conditions/``, ``generated/``, ``export/``, the first folder made in ``export/``, ``v0000``, ``library``,
  or ``out/`` and ``out/vary`` themselves after their first file) it is moved aside and a link into ``outside/``
  put in its place. No timing: the swap happens at that call. ``escape``: a file outside ``job/`` created,
  changed or deleted, or opened by a run that then succeeded (the hooks see every open: a run that opened the
  swapped file and refused it used nothing). ``swapped`` in the result says the swap happened (a case whose hook
  never fired proves nothing: the CI test asserts every one did).
* ``lists``: (a) ``batch --list`` files with Unicode line breaks that are not newlines (CR, VT, FF, FS, GS, RS,
  NEL, LS, PS) hiding a ``data-root:`` line in a path or a root, NUL bytes, control characters, non-UTF-8 bytes,
  5000-character lines, CRLF and a BOM (valid); the list's job, if the injected root were honoured, writes into
  ``outside/`` (``escape``). (b) ``vary`` on a base whose recording, library or output folder name holds such a
  break followed by ``data-root: <a folder replicating outside/'s path>``: accepted only if ``variants.txt`` read
  back (``core.batch_items.read_job_list``) declares exactly the run's own folder, the recording's and the
  library's roots and lists exactly the placed variants (else ``misread``: the list's meaning changed).
  (c) ``contact-sheet`` on a vary folder whose manifest holds hostile fields (ids with breaks, NUL or ``..``,
  100,000 variants, resolutions, wrong types).
* ``serve``: one real ``python -m backend serve`` process per worker; a case sends one malformed request line
  (non-integer ids, NaN, 5000-digit integers, 100,000-deep nesting, wrong types for ``cancel`` and ``argv``,
  invalid UTF-8, a 4 MiB line, not an object) and then a valid ``render --check`` request. ``clean``: an
  ``error`` event came for the malformed line (or it ran as a request, ``accepted``) and the valid request was
  served with exit 0; ``unclear``: it was served but the malformed line got no error event (silently ignored);
  ``hang``: the valid request got no answer within ``SERVE_WAIT_S``; ``traceback``: the server died. A server
  that hangs or dies is replaced for the next case.
* ``numerics``: every numeric field of the job (each leaf; three cells of each matrix) and of a variation spec
  (``core.variation.spec.FIELDS``), and ``vary``'s ``--variants``/``--seed``, set to hostile values (310-digit
  integers, 1e308, -0, 2**64, -2**63-1, bool, strings, 1e-320) through ``render --check`` / ``vary``.
* ``names``: 255-byte (valid) and 256-byte names, a 4,200-byte path, non-UTF-8 bytes, NUL, newline, CR, ESC,
  emoji, spaces and dots, for the predictions, the asset, the output folder, the job's folder, ``export --out``,
  ``vary --out`` and a vary library.
* ``diskfull`` (root only: ``can_mount``; skipped otherwise): the output folder is a tmpfs of 8-256 KiB (``mount
  -t tmpfs``, always unmounted), sometimes half filled first, for ``render``, ``generate``, ``export`` and
  ``vary``: a run that fails must exit with an error event naming the folder or a file in it, not a traceback or
  "an internal error" (else ``traceback``); any ``.<name>.<random>.tmp`` or empty file left is ``misread``.
* ``varykill``: ``vary`` (forked from ``fuzz_surfaces.ForkServer``, stopped at each atomic rename until the
  harness lets it on: ``fuzz_surfaces._gate_renames``) killed with SIGKILL or SIGTERM before a seeded rename,
  after a finished run of another spec or on a fresh folder, then a re-run (the folder must then be exactly the
  re-run's: list and jobs, no temporary) or no re-run (the list, read back, must be wholly one run's, or refused
  by ``batch --list``);
  or two ``vary`` runs at once on one folder, their renames interleaved by the gates (one is refused by the lock,
  or the list is wholly one run's). A mixed list is ``misread``.

Outcome classes are ``fuzz_inputs``' (accepted, clean, unclear, traceback, hang, escape, misread); exit 1 with
neither a traceback nor "an internal error" is a failure the command explains (``backend.errors.CleanFailure``:
a busy folder, a batch with a failed job) and is classified as exit 2 (``_lenient``); argparse's usage error
naming an option is exit 2 naming that option. One case by hand:
``.venv/bin/python -m tests.fuzz_inputs --kind links --index 7 [--keep]``.
"""

from __future__ import annotations

import builtins
import contextlib
import copy
import io
import json
import os
import random
import select
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (ROOT, HERE):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numpy as np  # noqa: E402

KINDS = ("links", "races", "lists", "serve", "numerics", "names", "diskfull", "varykill")
CASES = {"links": 60, "races": 40, "lists": 60, "serve": 120, "numerics": 180, "names": 60, "diskfull": 30,
         "varykill": 10}
#: The wall-clock seconds a serve case waits for the valid request's ``served`` event.
SERVE_WAIT_S = 10.0
#: How long a new serve process may take to answer its first request (imports, kernels).
SERVE_START_S = 180.0
#: The spec of a vary case (``RoadBase``): small and quick, every variant placed on the road base.
VARY_SPEC = {"variants": 2, "seed": 1, "resolution": [16, 12], "cars": {"count": [1, 1], "moving_probability": 0.0}}
#: vary's killed runs (``varykill``): spec A, then spec B killed, or the other way round.
VARY_A = dict(VARY_SPEC, variants=3, seed=1)
VARY_B = dict(VARY_SPEC, variants=2, seed=2)
#: How many atomic renames a vary run of spec A / B makes on a fresh folder (``_gate_renames``; measured): a kill
#: lands before one of them.
VARY_RENAMES = {"A": 7, "B": 6}


@dataclass
class Case:
    kind: str
    index: int
    seed: int
    description: str
    apply: object          # the case's plan: a dict its runner reads

    @property
    def family(self) -> str:
        return self.description.split(":")[0]


class Draw(random.Random):
    turn = 0

    def cycle(self, options):
        order = random.Random(len(options)).sample(range(len(options)), len(options))
        return options[order[self.turn % len(options)]]


def can_mount() -> bool:
    """Whether this process may mount a tmpfs (root, and the ``mount`` command works here): the ``diskfull``
    kind runs only then."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    import tempfile
    d = tempfile.mkdtemp(prefix="scpainter-mount-probe-")
    try:
        ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", d], capture_output=True).returncode == 0
        if ok:
            subprocess.run(["umount", d], capture_output=True)
        return ok
    finally:
        with contextlib.suppress(OSError):
            os.rmdir(d)


def ci_kinds() -> tuple:
    """The kinds CI runs here: all, ``diskfull`` only where a tmpfs can be mounted."""
    return tuple(k for k in KINDS if k != "diskfull" or can_mount())


# ---------------------------------------------------------------------------------------------- the road base

class RoadBase:
    """A job ``vary`` can place cars for, built once per worker: 5 cameras 1.5 m above a flat road, pitched 45°
    down, 4 m apart, 126° wide (VGGT frame: Y down, Z forward; the job's world Z up as ``fuzz_inputs.Base``),
    160 x 64 depth maps of the road, and a library of one procedural car (4.4 x 1.8 m)."""

    def __init__(self, folder: str):
        from scpainter_blender.core import shapes
        from scpainter_blender.core.geometry import cameras
        from scpainter_blender.core.vggt import npz as vggt_io, predictions as vggt

        os.makedirs(folder, exist_ok=True)
        S, H, W, f, a, step, height = 5, 64, 160, 40.0, np.radians(45.0), 4.0, 1.5
        R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        w2c = np.tile(np.eye(4), (S, 1, 1))
        intr = np.tile(np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]]), (S, 1, 1))
        u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        dw = np.stack([(u - W / 2) / f, (v - H / 2) / f, np.ones_like(u)], -1) @ R   # ray directions, VGGT world
        t = height / dw[..., 1]                                                       # camera z where it hits y = h
        wp = np.zeros((S, H, W, 3), np.float32)
        for i in range(S):
            c = np.array([0.0, 0.0, step * i])
            w2c[i, :3, :3], w2c[i, :3, 3] = R, -R @ c
            wp[i] = c + dw * t[..., None]
        rng = np.random.default_rng(0)
        path = os.path.join(folder, "predictions.npz")
        vggt_io.save_predictions(path, images=rng.random((S, H, W, 3), dtype=np.float32),
                                 depth=np.tile(t.astype(np.float32), (S, 1, 1)),
                                 depth_conf=np.full((S, H, W), 5.0, np.float32), extrinsic=w2c, intrinsic_vggt=intr,
                                 world_points=wp, world_points_conf=np.full((S, H, W), 5.0, np.float32))
        with open(path, "rb") as fh:
            self.predictions = fh.read()
        wfv = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
        w2c_w = w2c @ cameras.rigid_inverse(wfv)
        K = vggt.vggt_K_to_ours(intr)
        self.job = {"schema": "scpainter.job/2", "resolution": [W, H],
                    "frames": [{"frame": i + 1, "K": K[i].tolist(), "world_to_camera": w2c_w[i].tolist(),
                                "source_frames": list(range(S))} for i in range(S)],
                    "scene": {"predictions": "predictions.npz", "vggt_to_world": wfv.tolist(),
                              "confidence_percentile": 0.0},
                    "assets": [], "output_dir": "out"}
        car = os.path.join(folder, "car.ply")
        shapes.save_as_amodal3r(car, shapes.procedural_car_gaussians(count=1500, seed=7))
        with open(car, "rb") as fh:
            self.car = fh.read()


_ROAD = {}


def road(base) -> RoadBase:
    if "road" not in _ROAD:
        _ROAD["road"] = RoadBase(os.path.join(base.folder, "road-base"))
    return _ROAD["road"]


def add_road(c, base, spec=None, road_rel="job/road", cars_rel="job/cars") -> None:
    """The road base into the case folder ``c``: ``road_rel``/job.json and predictions.npz, ``cars_rel``/car.ply,
    job/spec.json; sets ``c.road_job``, ``c.cars``, ``c.spec``, ``c.vary_out`` (job/out/vary)."""
    r = road(base)
    c.write(os.path.join(road_rel, "predictions.npz"), r.predictions)
    c.write(os.path.join(road_rel, "job.json"), json.dumps(r.job))
    c.write(os.path.join(cars_rel, "car.ply"), r.car)
    c.write("job/spec.json", json.dumps(spec if spec is not None else VARY_SPEC))
    c.road_job, c.cars = c.path(os.path.join(road_rel, "job.json")), c.path(cars_rel)
    c.spec, c.vary_out = c.path("job/spec.json"), c.path("job/out/vary")


def vary_argv(c, out=None, spec=None) -> list:
    return ["vary", c.road_job, "--out", out or c.vary_out, "--spec", spec or c.spec, "--library", c.cars]


# ---------------------------------------------------------------------------------------------- running

def _folder(case, base, root):
    import fuzz_inputs as F
    c = F.prepare(F.Case("job", case.index, case.seed, case.description, lambda c: None), base, root)
    c.write("job/job.json", F.to_json(c.job))
    return c


#: What the commands write (a clean error may name any of them: a full disk, a planted link).
OUTPUT_NAMES = {"out", "conditions", "generated", "generated.mp4", "export", "kitti", "backend.log", "record.json",
                ".scpainter.lock", "variants.txt", "variation.json", "vary", "library", "v0000", "v0001",
                "contact_sheet.png"} | {f"{p}_{f:06d}.{e}" for f in (1, 2) for p, e in
                                        (("frame", "exr"), ("preview", "png"), ("labels", "json"),
                                         ("labelled", "png"), ("frame", "png"))}


#: The options a case gives a path or number with (an ArgumentError naming one is a clean refusal).
OPTION_NAMES = {"--out", "--library", "--spec", "--list", "--data-root", "--variants", "--seed"}


def _names(c, extra=()) -> set:
    """The names a clean error may give: the case's files and folders (``fuzz_inputs._case_names``, everything
    under the case folder now), what the commands write (``OUTPUT_NAMES``) and ``extra``."""
    import fuzz_inputs as F
    names = F._case_names(c, F.Case("job", 0, 0, "", None)) | {"spec.json", "road", "cars", "list.txt"} | \
        OUTPUT_NAMES | OPTION_NAMES
    for _, dirnames, filenames in os.walk(c.root):
        names.update(dirnames + filenames)
    names.update(extra)
    return {n for n in names if n}


def _lenient(ran: dict) -> dict:
    """A run's record with exit 1 read as 2 when it printed no traceback and no "internal error": batch (a job
    failed), vary (nothing placed) and a full disk end 1 with a clean error event; a batch's failed items (its
    ``done`` event's ``items[].error``) count as error events."""
    import fuzz_inputs as F
    items = [{"event": "error", "message": i.get("error", ""), "field": i.get("field") or "(job)"}
             for e in F.parse_events(ran["stdout"]) if e.get("event") == "done" and e.get("command") == "batch"
             for i in (e.get("items") or []) if isinstance(i, dict) and i.get("error")]
    if items:
        ran = dict(ran, stdout=ran["stdout"] + "".join(json.dumps(i) + "\n" for i in items))
    text = ran["stdout"] + ran["stderr"]
    if ran["rc"] == 1 and ran["exc"] is None and "Traceback" not in ran["stderr"] and "internal error" not in text \
            and "please report" not in text:
        return dict(ran, rc=2)
    return ran


def _run(case, c, root, workdir, argv, timeout, names=(), lenient=True, hooks=None) -> tuple:
    """Run ``argv`` in-process with the snapshot of the case folder around it; (result, outcome, ran). Exit 1
    without a traceback or "an internal error" is a failure the command explains (``backend.errors.CleanFailure``:
    a busy folder, a full disk, a batch with a failed job), classified as exit 2 would be (``_lenient``)."""
    import fuzz_inputs as F
    names = _names(c, names)
    before, top_before = F.snapshot(root, c.job_dir), set(os.listdir(workdir))
    with (hooks if hooks is not None else contextlib.nullcontext()):
        ran = F.invoke(argv, timeout)
    usage = [ln for ln in ran["stderr"].splitlines() if ": error: argument " in ln]
    if (ran["exc"] or "").startswith("SystemExit(2)") and usage:   # argparse's usage error: exit 2 naming the option
        opt = usage[-1].split(": error: argument ", 1)[1].split(":")[0].split("/")[0]
        ran = dict(ran, exc=None, rc=2, stdout=ran["stdout"] + json.dumps(
            {"event": "error", "message": f"{opt}: {usage[-1]}", "field": opt}) + "\n")
    escapes = F._changed(before, F.snapshot(root, c.job_dir))
    escapes += [f"created ../{n}" for n in sorted(set(os.listdir(workdir)) - top_before)]
    names |= _names(c)   # and what the run made
    if hooks is not None and ran["rc"] == 0:   # opened, then refused: nothing of it was used
        escapes += [f"read {os.path.relpath(p, root)}" for p in dict.fromkeys(hooks.read_outside)]
    result = _record(case, ran)
    outcome = F.classify(result, _lenient(ran) if lenient else ran, escapes, names, timeout)
    return result, outcome, ran


def _record(case, ran=None) -> dict:
    return {"kind": case.kind, "index": case.index, "seed": case.seed, "description": case.description,
            "family": case.family, "rc": ran["rc"] if ran else None,
            "seconds": round(ran["seconds"], 4) if ran else 0.0, "message": "", "file": None, "field": None}


def _untimed(argv) -> dict:
    import fuzz_inputs as F
    r = F.invoke(argv, 600)
    if r["rc"] != 0:
        raise RuntimeError(f"setup run {argv[:1]} failed (exit {r['rc']}): {r['stdout'][-400:]} {r['stderr'][-400:]}"
                           f" {r['exc'] or ''}")
    return r


def leftovers(folder) -> list:
    """Temporaries (``.<name>.<random>.tmp``) and empty files under ``folder``: outputs are written whole or not at
    all (the lock and ``backend.log``, appended line by line, excepted)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(folder):
        for n in dirnames + filenames:
            p = os.path.join(dirpath, n)
            if (n.startswith(".") and ".tmp" in n) or (n in filenames and n not in (".scpainter.lock", "backend.log")
                                                         and not os.path.islink(p) and os.path.getsize(p) == 0):
                out.append(os.path.relpath(p, folder))
    return out


# ---------------------------------------------------------------------------------------------- links

#: (command, path under job/out, "file" or "dir", outside target for a hard link or an existing file)
LINK_SITES = [
    ("render", "backend.log", "file", "backend.log"),
    ("render", "conditions", "dir", ""),
    ("render", "conditions/frame_000001.exr", "file", "frame_000000.exr"),
    ("render", "conditions/preview_000001.png", "file", "preview_000000.png"),
    ("render", "conditions/record.json", "file", "target/target.txt"),
    ("render", "conditions/labels_000001.json", "file", "target/target.txt"),
    ("render", ".scpainter.lock", "file", "target/target.txt"),
    ("generate", "generated", "dir", ""),
    ("generate", "generated.mp4", "file", "target/target.txt"),
    ("generate", "generated/frame_000001.png", "file", "preview_000000.png"),
    ("export", "export", "dir", ""),
    ("export", "export/kitti", "dir", ""),
    ("export", "export/kitti/label_2", "dir", ""),
    ("export", "export/kitti/export.json", "file", "job.json"),
    ("vary", "vary/v0000", "dir", ""),
    ("vary", "vary/library", "dir", ""),
    ("vary", "vary/variants.txt", "file", "target/target.txt"),
    ("vary", "vary/variation.json", "file", "job.json"),
    ("vary", "vary/v0000/job.json", "file", "job.json"),
    ("vary", "vary/backend.log", "file", "backend.log"),
]


def _links_plan(rng):
    command, site, what, target = rng.cycle(LINK_SITES)
    styles = ["absolute symlink", "relative symlink", "dangling symlink"] + (["hard link"] if what == "file" else [])
    style = styles[(rng.turn // len(LINK_SITES)) % len(styles)]
    after = bool(rng.turn // len(LINK_SITES) // len(styles) % 2) or rng.random() < 0.3
    return (f"{command}: out/{site} {'an' if style[0] in 'ah' else 'a'} {style} into outside/"
            f"{'(new)' if style == 'dangling symlink' else (target or 'target')}"
            f"{' after a first run' if after else ''}",
            {"command": command, "site": site, "what": what, "target": target, "style": style, "after": after})


def _argv_for(command, c) -> list:
    return {"render": ["render", c.job_json, "--device", "cpu"],
            "generate": ["generate", c.job_json, "--device", "cpu"],
            "export": ["export", c.job_json, "--format", "kitti", "--device", "cpu"]}.get(command) or vary_argv(c)


def plant(c, site_path, what, target, style) -> str:
    """Put a link at ``site_path`` (removing what is there) into ``outside/``; returns its target."""
    if os.path.isdir(site_path) and not os.path.islink(site_path):
        shutil.rmtree(site_path)
    elif os.path.lexists(site_path):
        os.unlink(site_path)
    os.makedirs(os.path.dirname(site_path), exist_ok=True)
    dest = os.path.join(c.outside, "new-" + os.path.basename(site_path)) if style == "dangling symlink" else \
        os.path.join(c.outside, target or "target")
    if style == "hard link":
        os.link(dest, site_path)
    else:
        os.symlink(os.path.relpath(dest, os.path.dirname(site_path)) if style == "relative symlink" else dest,
                   site_path)
    return dest


def _run_links(case, base, root, workdir, timeout):
    p = case.apply
    c = _folder(case, base, root)
    if p["command"] == "vary":
        add_road(c, base)
    argv = _argv_for(p["command"], c)
    if p["after"]:
        _untimed(argv)
    dest = plant(c, os.path.join(c.job_dir, "out", p["site"]), p["what"], p["target"], p["style"])
    return c, _run(case, c, root, workdir, argv, timeout, names={os.path.basename(dest), os.path.basename(p["site"])})


# ---------------------------------------------------------------------------------------------- races

class Hooks:
    """``os.open``, ``open``/``io.open`` and ``os.mkdir`` wrapped for one run: every path they open that resolves
    into ``outside`` is recorded (``read_outside``); after the first successful call on ``trigger`` (an open of a
    file, a mkdir of a folder, or with ``under`` any open or mkdir inside that folder; with ``staging`` the mkdir
    of the folder ``outputs.atomic_folder`` builds ``trigger`` in, ``.<name>.<random>.tmp`` beside it) ``swap(path)``
    runs once (``fired``: that path)."""

    def __init__(self, outside, trigger, op, swap, under=False, staging=False):
        self.outside = os.path.realpath(outside)
        self.trigger, self.op, self.swap, self.under = os.path.abspath(trigger), op, swap, under
        self.staging = staging
        self.read_outside, self.fired = [], False

    @staticmethod
    def _abs(path, dir_fd=None):
        if isinstance(path, int):
            return None
        p = os.fsdecode(os.fspath(path))
        if dir_fd is not None and not os.path.isabs(p):
            with contextlib.suppress(OSError):
                return os.path.join(os.readlink(f"/proc/self/fd/{dir_fd}"), p)
        return os.path.abspath(p)

    def _seen(self, op, path, dir_fd=None):
        p = self._abs(path, dir_fd)
        if p is None:
            return
        with contextlib.suppress(OSError, ValueError):
            real = os.path.realpath(p)
            if real == self.outside or real.startswith(self.outside + os.sep):
                self.read_outside.append(real)
        folder, name = os.path.split(self.trigger)
        hit = (p.startswith(self.trigger + os.sep) if self.under else
               os.path.dirname(p) == folder and os.path.basename(p).startswith(f".{name}.") if self.staging else
               p == self.trigger)
        if not self.fired and op == self.op and hit:
            self.fired = p
            self.swap(p)

    def __enter__(self):
        self.saved = (os.open, builtins.open, io.open, os.mkdir)
        real_os_open, real_open, real_mkdir = os.open, builtins.open, os.mkdir
        hooks = self

        def os_open(path, flags, mode=0o777, *, dir_fd=None):
            fd = real_os_open(path, flags, mode, dir_fd=dir_fd)
            hooks._seen("open", path, dir_fd)
            return fd

        def py_open(file, *args, **kwargs):
            f = real_open(file, *args, **kwargs)
            hooks._seen("open", file)
            return f

        def mkdir(path, mode=0o777, *, dir_fd=None):
            real_mkdir(path, mode, dir_fd=dir_fd)
            hooks._seen("mkdir", path, dir_fd)

        os.open, builtins.open, io.open, os.mkdir = os_open, py_open, py_open, mkdir
        return self

    def __exit__(self, *exc):
        os.open, builtins.open, io.open, os.mkdir = self.saved
        return False


#: (command, trigger path under job/, "open" / "mkdir" / "under", outside target, what is swapped)
RACE_SITES = [
    ("render", "car.ply", "open", "car.ply", "file"),
    ("render", "predictions.npz", "open", "predictions.npz", "file"),
    ("render", "job.json", "open", "job.json", "file"),
    ("render", "out/conditions", "mkdir", "conditions", "dir"),
    ("render --force", "out/conditions/record.json", "open", "conditions", "conditions"),
    ("render", "out", "under", "target", "dir"),
    ("generate", "out/generated", "mkdir", "target", "dir"),
    ("export", "out/export", "mkdir", "target", "dir"),
    ("export", "out/export", "mkdir-under", "target", "made"),
    ("vary", "out/vary/v0000", "mkdir-staging", "target", "made"),   # built under .v0000.*.tmp, renamed whole
    ("vary", "out/vary/library", "mkdir", "target", "dir"),
    ("vary", "road/predictions.npz", "open", "predictions.npz", "file"),
    ("vary", "cars/car.ply", "open", "car.ply", "file"),
    ("vary", "out/vary", "under", "target", "dir"),
]


def _races_plan(rng):
    command, trigger, op, target, what = rng.cycle(RACE_SITES)
    style = ("absolute", "relative")[rng.turn // len(RACE_SITES) % 2]
    when = {"open": "after its first open", "mkdir": "after it was made", "under": "after its first file",
            "mkdir-under": "after it was made", "mkdir-staging": "after it was made"}[op]
    swapped = ("out/conditions" if what == "conditions" else f"job/{trigger}/(the first folder made in it)"
               if op == "mkdir-under" else f"job/{trigger}'s staging folder (.{os.path.basename(trigger)}.*.tmp)"
               if op == "mkdir-staging" else f"job/{trigger}")
    return (f"{command.split()[0]}: {swapped} swapped for {'an' if style[0] == 'a' else 'a'} {style} link to "
            f"outside/{target} {when}"
            + (" (a second run)" if what == "conditions" else ""),
            {"command": command, "trigger": trigger, "op": op, "target": target, "what": what, "style": style})


def _run_races(case, base, root, workdir, timeout):
    p = case.apply
    c = _folder(case, base, root)
    command = p["command"].split()[0]
    if command == "vary":
        add_road(c, base)
    argv = _argv_for(command, c)
    if p["what"] == "conditions":
        _untimed(argv)
        argv = argv + ["--force"]
    victim = c.path("job/out/conditions") if p["what"] == "conditions" else c.path("job/" + p["trigger"])
    dest = os.path.join(c.outside, p["target"])
    aside = iter(range(100))

    def swap(fired):
        made = fired if p["what"] == "made" else victim
        moved = os.path.join(c.job_dir, f".aside-{next(aside)}-{os.path.basename(made)}")
        os.rename(made, moved)
        os.symlink(dest if p["style"] == "absolute" else os.path.relpath(dest, os.path.dirname(made)), made)

    op = {"under": "open", "mkdir-under": "mkdir", "mkdir-staging": "mkdir"}.get(p["op"], p["op"])
    hooks = Hooks(c.outside, c.path("job/" + p["trigger"]), op, swap, under=p["op"] in ("under", "mkdir-under"),
                  staging=p["op"] == "mkdir-staging")
    c_res = _run(case, c, root, workdir, argv, timeout, names={p["target"], os.path.basename(victim)}, hooks=hooks)
    c_res[0]["swapped"] = bool(hooks.fired)
    return c, c_res


# ---------------------------------------------------------------------------------------------- lists

#: Line breaks of ``str.splitlines`` that no list writer means as one (a name may hold them).
BREAKS = [("CR", "\r"), ("VT", "\x0b"), ("FF", "\x0c"), ("FS", "\x1c"), ("GS", "\x1d"), ("RS", "\x1e"),
          ("NEL", "\x85"), ("LS", "\u2028"), ("PS", "\u2029")]


def _evil_job(c):
    """job/evil/job.json: the base job writing into outside/target/evil-out (allowed only with a data root there)."""
    import fuzz_inputs as F
    job = copy.deepcopy(c.job)
    job["output_dir"] = "../../outside/target/evil-out"
    c.write("job/evil/job.json", F.to_json(job))
    shutil.copyfile(c.predictions, c.path("job/evil/predictions.npz"))
    shutil.copyfile(c.ply, c.path("job/evil/car.ply"))
    os.makedirs(c.path("job/road"), exist_ok=True)


def _list_direct(rng):
    name, br = rng.cycle(BREAKS)
    forms = [
        ("a break in a data-root line hides data-root: ../outside",
         lambda c: f"data-root: road{br}data-root: ../outside\nevil/job.json\n".encode()),
        ("a break in the first path hides data-root: ../outside",
         lambda c: f"road/x.json{br}data-root: ../outside\nevil/job.json\n".encode()),
        ("lines separated by the break only",
         lambda c: f"data-root: ../outside{br}evil/job.json{br}".encode()),
    ]
    form, make = forms[(rng.turn // len(BREAKS)) % len(forms)]
    return f"batch list: {form} ({name})", {"list": make}


def _list_bytes(rng):
    forms = [
        ("a NUL byte in a path", lambda c: b"job.json\x00evil/job.json\n"),
        ("a NUL byte in a data-root line", lambda c: b"data-root: ../outside\x00\nevil/job.json\n"),
        ("non-UTF-8 bytes in a path", lambda c: b"jo\xffb.json\n"),
        ("non-UTF-8 bytes in a data-root line", lambda c: b"data-root: r\xe9\nevil/job.json\n"),
        ("a 5000-character path", lambda c: ("x" * 5000 + "/job.json\n").encode()),
        ("ESC and BEL in a path", lambda c: b"job\x1b[2J\x07.json\n"),
        ("a data-root line after the path", lambda c: b"evil/job.json\ndata-root: ../outside\n"),
        ("data-root: with nothing after", lambda c: b"data-root:\nevil/job.json\n"),
        ("CRLF and a BOM (valid)", lambda c: b"\xef\xbb\xbfjob.json\r\n"),
        ("UTF-16 text", lambda c: "job.json\n".encode("utf-16")),
        ("a path with a tab", lambda c: b"job.json\tevil/job.json\n"),
    ]
    form, make = rng.cycle(forms)
    return f"batch list: {form}", {"list": make}


def _chain(c, first: str) -> str:
    """A folder job/<first><outside's absolute path as nested folders>: its absolute path, written as one line,
    reads as ``...<first>`` then ``<outside's path>``."""
    return os.path.join(c.job_dir, first + c.outside)


def _list_vary(rng):
    forms = [("the recording's folder", "recording"), ("the library's folder", "library"),
             ("the output folder", "out")]
    form, where = forms[rng.turn % len(forms)]
    name, br = BREAKS[(rng.turn // len(forms) * 4 + rng.turn % len(forms)) % len(BREAKS)]
    return (f"vary list: {form} named 'x{name}data-root: <outside>'",
            {"vary": where, "break": br})


def _manifest_case(rng):
    forms = [
        ("an id with a newline", lambda m: m["variants"][0].update(id="v0000\ndata-root: /")),
        ("an id with ../", lambda m: m["variants"][0].update(id="../../../outside/target")),
        ("an id with a NUL", lambda m: m["variants"][0].update(id="v00\x0000")),
        ("an id that is a number", lambda m: m["variants"][0].update(id=7)),
        ("100000 variants", lambda m: m.update(variants=[dict(m["variants"][-1], id=f"v{i:04d}", outcome="unplaced")
                                                         for i in range(100000)])),
        ("spec.resolution 100000 x 100000", lambda m: m["spec"].update(resolution=[100000, 100000])),
        ("spec.resolution a 310-digit integer", lambda m: m["spec"].update(resolution=[int("9" * 310), 12])),
        ("variants a string", lambda m: m.update(variants="v0000")),
        ("a variant null", lambda m: m["variants"].__setitem__(0, None)),
        ("outcome a list", lambda m: m["variants"][0].update(outcome=["placed"])),
        ("schema missing", lambda m: m.pop("schema")),
        ("spec missing", lambda m: m.pop("spec")),
    ]
    form, fn = rng.cycle(forms)
    return f"contact-sheet manifest: {form}", {"manifest": fn}


def _weighted(families, rng, *args):
    """A plan of ``families`` = [(plan, weight)]: slots by weight in rounds (as ``fuzz_inputs.make_case``); the
    chosen plan's ``turn`` becomes how many of its cases came before, so each walks its own variants in order."""
    slots = [j for j, (_, w) in enumerate(families) for _ in range(w)]
    slot = rng.turn % len(slots)
    j = slots[slot]
    rng.turn = (rng.turn // len(slots)) * families[j][1] + slots[:slot].count(j)
    return families[j][0](rng, *args)


def _lists_plan(rng):
    return _weighted([(_list_direct, 2), (_list_bytes, 1), (_list_vary, 1), (_manifest_case, 1)], rng)


def _run_lists(case, base, root, workdir, timeout):
    import fuzz_inputs as F
    p = case.apply
    c = _folder(case, base, root)
    if "list" in p:
        _evil_job(c)
        data = p["list"](c)
        c.write("job/list.txt", data)
        argv = ["batch", "--list", c.path("job/list.txt"), "--command", "render", "--device", "cpu"]
        return c, _run(case, c, root, workdir, argv, timeout, names={"list.txt"})
    if "manifest" in p:
        add_road(c, base)
        _untimed(vary_argv(c))
        mpath = os.path.join(c.vary_out, "variation.json")
        with open(mpath) as fh:
            m = json.load(fh)
        p["manifest"](m)
        c.write("job/out/vary/variation.json", F.to_json(m))
        return c, _run(case, c, root, workdir, ["contact-sheet", c.vary_out], timeout)
    # vary with a hostile folder name
    br, where = p["break"], p["vary"]
    odd = "x" + br + "data-root: "
    os.makedirs(c.path("job/x"), exist_ok=True)   # so the line's first half names a folder too
    if where == "recording":
        add_road(c, base, road_rel=os.path.relpath(_chain(c, odd), c.root))
        out = c.vary_out
    elif where == "library":
        add_road(c, base, cars_rel=os.path.relpath(_chain(c, odd), c.root))
        out = c.vary_out
    else:
        add_road(c, base)
        out = _chain(c, "out/" + odd)
    result, outcome, ran = _run(case, c, root, workdir, vary_argv(c, out=out), timeout)
    if outcome == "accepted":
        why = _list_meaning(out, {out, os.path.dirname(c.road_job), c.cars})
        if why:
            outcome, result["message"] = "misread", why
    return c, (result, outcome, ran)


def _list_meaning(out, roots) -> str:
    """Why ``out``/variants.txt read back is not the run's list (other data roots or jobs than the run's), or ""."""
    from scpainter_blender.core import batch_items
    from scpainter_blender.core.errors import InputError
    try:
        jl = batch_items.read_job_list(os.path.join(out, "variants.txt"))
    except InputError:
        return ""     # refused when read: batch will not run it
    with open(os.path.join(out, "variation.json")) as fh:
        m = json.load(fh)
    want = {os.path.realpath(os.path.join(out, v["id"], "job.json")) for v in m["variants"]
            if v.get("outcome") == "placed"}
    real_roots = {os.path.realpath(r) for r in roots}
    extra_roots = [r for r in jl.data_roots if os.path.realpath(r) not in real_roots]
    got = {os.path.realpath(x) for x in jl.paths}
    if extra_roots:
        return f"variants.txt read back declares data roots the run never meant: {extra_roots[:2]}"
    if got != want:
        return f"variants.txt read back lists {sorted(got - want)[:2]} / misses {sorted(want - got)[:2]}"
    return ""


# ---------------------------------------------------------------------------------------------- serve

def _raw(text):
    return text.encode("utf-8", "surrogatepass") if isinstance(text, str) else text


_ARGV = '["render", "JOB", "--check", "--device", "cpu"]'
SERVE_LINES = [
    ("id a string", '{"id": "1", "argv": ARGV}'),
    ("id a float", '{"id": 1.5, "argv": ARGV}'),
    ("id null", '{"id": null, "argv": ARGV}'),
    ("id a list", '{"id": [1], "argv": ARGV}'),
    ("id an object", '{"id": {}, "argv": ARGV}'),
    ("id true", '{"id": true, "argv": ARGV}'),
    ("id 1e308", '{"id": 1e308, "argv": ARGV}'),
    ("id NaN", '{"id": NaN, "argv": ARGV}'),
    ("id Infinity", '{"id": Infinity, "argv": ARGV}'),
    ("id a 5000-digit integer", '{"id": ' + "9" * 5000 + ', "argv": ARGV}'),
    ("id a 310-digit integer", '{"id": ' + "9" * 310 + ', "argv": ARGV}'),
    ("id 2**64", '{"id": 18446744073709551616, "argv": ARGV}'),
    ("id missing", '{"argv": ARGV}'),
    ("id a lone surrogate", '{"id": "\\ud800", "argv": ARGV}'),
    ("argv 100000 deep", '{"id": 5, "argv": ' + "[" * 100000 + "]" * 100000 + '}'),
    ("a list 100000 deep", "[" * 100000 + "]" * 100000),
    ("objects 50000 deep", '{"a": ' * 50000 + "1" + "}" * 50000),
    ("cancel a list", '{"cancel": [1]}'),
    ("cancel an object", '{"cancel": {}}'),
    ("cancel a string", '{"cancel": "1"}'),
    ("cancel null", '{"cancel": null}'),
    ("cancel a float", '{"cancel": 1.5}'),
    ("cancel a 5000-digit integer", '{"cancel": ' + "9" * 5000 + '}'),
    ("cancel NaN", '{"cancel": NaN}'),
    ("invalid UTF-8 in argv", b'{"id": 6, "argv": ["render", "\xff\xfe"]}'),
    ("invalid UTF-8 alone", b"\xff\xfe\xfd"),
    ("an overlong UTF-8 encoding", b'{"id": 6\xc0\xae}'),
    ("a UTF-8 encoded surrogate", b'{"id": 6, "argv": ["\xed\xa0\x80"]}'),
    ("a 4 MiB line", '{"id": 7, "argv": ["render", "' + "x" * (4 << 20) + '"]}'),
    ("argv a string", '{"id": 8, "argv": "render JOB"}'),
    ("argv numbers", '{"id": 8, "argv": [1, 2]}'),
    ("argv an object", '{"id": 8, "argv": {}}'),
    ("argv empty", '{"id": 8, "argv": []}'),
    ("argv null", '{"id": 8, "argv": null}'),
    ("argv missing", '{"id": 8}'),
    ("argv with null", '{"id": 8, "argv": ["render", null]}'),
    ("argv with a NUL", '{"id": 8, "argv": ["render", "JOB\\u0000x", "--check"]}'),
    ("argv serve", '{"id": 8, "argv": ["serve"]}'),
    ("argv 100000 strings", '{"id": 8, "argv": ["render"' + ', "x"' * 100000 + ']}'),
    ("not an object: a list", '[1, 2]'),
    ("not an object: a number", '12'),
    ("not an object: a string", '"render"'),
    ("not an object: null", 'null'),
    ("not JSON", 'render job.json'),
    ("a truncated object", '{"id": 9, "argv": ["render"'),
]


def _serve_plan(rng):
    name, line = rng.cycle(SERVE_LINES)
    return f"serve: {name}", {"line": line}


class ServeProcess:
    """A ``python -m backend serve`` process of this worker, with its standard output read line by line."""

    def __init__(self, workdir):
        self.log_path = os.path.join(workdir, "serve.log")
        self.log = open(self.log_path, "ab")
        self.proc = subprocess.Popen([sys.executable, "-m", "backend", "serve", "--device", "cpu", "--idle-timeout",
                                      "900"], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.log, env=dict(os.environ, OMP_NUM_THREADS="1"))
        self.buf, self.next_id = b"", 1000

    def send(self, data: bytes) -> bool:
        try:
            self.proc.stdin.write(data + b"\n")
            self.proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError):
            return False

    def events_until(self, rid, wait) -> tuple:
        """The events up to the ``served`` event of ``rid``: (events, "served" | "hang" | "died")."""
        seen, deadline, fd = [], time.monotonic() + wait, self.proc.stdout.fileno()
        while True:
            while b"\n" in self.buf:
                line, self.buf = self.buf.split(b"\n", 1)
                try:
                    e = json.loads(line)
                except ValueError:
                    e = {"event": "(not JSON)", "message": line[:200].decode("utf-8", "replace")}
                seen.append(e if isinstance(e, dict) else {"event": "(not JSON)"})
                if isinstance(e, dict) and e.get("event") == "served" and e.get("id") == rid:
                    return seen, "served"
            left = deadline - time.monotonic()
            if left <= 0:
                return seen, "hang"
            if not select.select([fd], [], [], left)[0]:
                return seen, "hang"
            chunk = os.read(fd, 1 << 16)
            if not chunk:
                return seen, "died"
            self.buf += chunk

    def valid(self, job, wait) -> tuple:
        self.next_id += 1
        rid = self.next_id
        req = {"id": rid, "argv": ["render", job, "--check", "--device", "cpu"]}
        if not self.send(json.dumps(req).encode()):
            return [], "died", rid
        seen, how = self.events_until(rid, wait)
        return seen, how, rid

    def stderr_tail(self) -> str:
        with open(self.log_path, "rb") as fh:
            return fh.read()[-2000:].decode("utf-8", "replace")

    def close(self):
        with contextlib.suppress(Exception):
            self.proc.kill()
            self.proc.wait(10)
        self.log.close()


_SERVE: dict = {}


def _server(workdir, base):
    s = _SERVE.get("proc")
    if s is not None and s.proc.poll() is None:
        return s
    if s is not None:
        s.close()
    folder = os.path.join(workdir, "serve-job")
    if "job" not in _SERVE:
        import fuzz_inputs as F
        c = F.prepare(F.Case("job", -1, 0, "serve", lambda c: None), base, folder)
        c.write("job/job.json", F.to_json(c.job))
        _SERVE["job"] = c.job_json
    s = ServeProcess(workdir)
    _SERVE["proc"] = s
    _, how, _ = s.valid(_SERVE["job"], SERVE_START_S)
    if how != "served":
        raise RuntimeError(f"the serve process did not answer its first request ({how}): {s.stderr_tail()[-800:]}")
    return s


def _run_serve(case, base, root, workdir, timeout):
    import fuzz_inputs as F
    result = _record(case)
    s = _server(workdir, base)
    line = case.apply["line"]
    line = _raw(line.replace("ARGV", _ARGV).replace("JOB", _SERVE["job"]) if isinstance(line, str) else line)
    t0 = time.perf_counter()
    sent = s.send(line)
    seen, how, rid = s.valid(_SERVE["job"], SERVE_WAIT_S) if sent else ([], "died", None)
    result["seconds"] = round(time.perf_counter() - t0, 4)
    errors = [e for e in seen if e.get("event") == "error"]
    others = [e for e in seen if e.get("event") == "served" and e.get("id") != rid]
    mine = [e for e in seen if e.get("event") == "served" and e.get("id") == rid]
    if errors:
        result["message"] = F._first_line(str(errors[0].get("message", "")))
        result["file"], result["field"] = errors[0].get("file"), errors[0].get("field") or "(request)"
    if how == "died" or s.proc.poll() is not None:
        with contextlib.suppress(Exception):
            s.proc.wait(5)
        outcome = "traceback"
        last = (s.stderr_tail().strip().splitlines() or [""])[-1]
        result["message"] = f"the server ended (exit {s.proc.returncode}): {F._first_line(last)}"
        s.close()
        _SERVE.pop("proc", None)
    elif how == "hang":
        outcome = "hang"
        result["message"] = (f"no answer to a valid request within {SERVE_WAIT_S:g} s after it (last log: "
                             f"{F._first_line((s.stderr_tail().strip().splitlines() or [''])[-1])})")
        s.close()
        _SERVE.pop("proc", None)
    elif mine and mine[0].get("exit_code") != 0:
        outcome, result["message"] = "traceback", f"the valid request after it exited {mine[0].get('exit_code')}"
    elif errors:
        outcome = "clean"
    elif others:
        outcome, result["rc"] = "accepted", others[0].get("exit_code")
    else:
        outcome = "unclear"
        result["message"] = "no error event: the line was ignored silently (" + F._first_line(
            (s.stderr_tail().strip().splitlines() or [""])[-1]) + ")"
    result["outcome"] = outcome
    return result


# ---------------------------------------------------------------------------------------------- numerics

_D310 = "9" * 310
NUMBERS = [("a 310-digit integer", "R:" + _D310), ("minus a 310-digit integer", "R:-" + _D310),
           ("1e308", 1e308), ("-1e308", -1e308), ("-0", "R:-0"), ("-0.0", "R:-0.0"), ("2**64", 2 ** 64),
           ("-2**63-1", -2 ** 63 - 1), ("true", True), ("false", False), ('"1"', "1"), ("1e-320", "R:1e-320"),
           ("1e309 as an integer", "R:1" + "0" * 309), ("0.1", 0.1)]


def _value(v):
    import fuzz_inputs as F
    return F.Raw(v[2:]) if isinstance(v, str) and v.startswith("R:") else v


def job_number_paths(job) -> list:
    """Every numeric leaf of ``job`` (a 4x4 matrix or 3x3 K: cells [0][0], [0][3] or [0][2], [3][3] or [2][2])."""
    import fuzz_inputs as F
    out = []
    for p in F._tree_paths(job):
        v = F._get(job, p)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        if len(p) >= 2 and isinstance(p[-1], int) and isinstance(p[-2], int):
            n = len(F._get(job, p[:-2]))
            if (p[-2], p[-1]) not in ((0, 0), (0, n - 1), (n - 1, n - 1)):
                continue
        out.append(p)
    return out


def spec_number_fields() -> list:
    """[(dotted field, index or None)] of every numeric setting of a variation spec (``spec.FIELDS``)."""
    from scpainter_blender.core.variation import spec as spec_mod
    out = []
    for name, _, kind, _, _ in spec_mod.FIELDS:
        if kind in ("int", "number"):
            out.append((name, None))
        elif kind in ("pair", "int_pair", "range", "int_range", "choices", "shifts"):
            out += [(name, 0), (name, 1)] if kind != "choices" and kind != "shifts" else [(name, 0)]
    return out


def _num_job(rng, base):
    paths = job_number_paths(base.job)
    combos = [(p, v) for p in paths for v in NUMBERS]
    p, (vname, v) = rng.cycle(combos)
    import fuzz_inputs as F
    return f"job number: {F._fmt(p)} = {vname}", {"job_path": p, "value": v}


def _num_spec(rng, base):
    combos = [(f, v) for f in spec_number_fields() for v in NUMBERS]
    (field, i), (vname, v) = rng.cycle(combos)
    return (f"spec number: {field}{'' if i is None else f'[{i}]'} = {vname}",
            {"spec_field": field, "spec_index": i, "value": v})


def _num_cli(rng, base):
    options = [("--variants", x) for x in (_D310, "1e308", "-0", "0x10", "1_0", "nan", "true", " 2", "100001")] + \
              [("--seed", x) for x in (_D310, "-" + _D310, "1e308", "-0", "-1", str(2 ** 64), "nan", "1.5")]
    opt, val = rng.cycle(options)
    return f"vary option: {opt} {val[:20]}{'...' if len(val) > 20 else ''}", {"option": opt, "arg": val}


def _numerics_plan(rng, base):
    return _weighted([(_num_job, 6), (_num_spec, 3), (_num_cli, 1)], rng, base)


def _set_spec(spec, field, i, value):
    """``spec``'s dotted ``field`` (its element ``i`` when given: the rest from the defaults, ``spec.to_file``)
    set to ``value``."""
    from scpainter_blender.core.variation import spec as spec_mod
    keys = field.split(".")
    node, default = spec, spec_mod.to_file(spec_mod.VariationSpec())
    for k in keys[:-1]:
        node, default = node.setdefault(k, {}), default.get(k, {})
    if i is None:
        node[keys[-1]] = value
    else:
        cur = list(node.get(keys[-1]) or default.get(keys[-1]) or [16, 12])
        cur[i] = value
        node[keys[-1]] = cur


def _run_numerics(case, base, root, workdir, timeout):
    import fuzz_inputs as F
    p = case.apply
    c = _folder(case, base, root)
    if "job_path" in p:
        path = p["job_path"]
        F._get(c.job, path[:-1])[path[-1]] = _value(p["value"])
        c.write("job/job.json", F.to_json(c.job))
        return c, _run(case, c, root, workdir, ["render", c.job_json, "--check", "--device", "cpu"], timeout)
    add_road(c, base)
    if "spec_field" in p:
        spec = copy.deepcopy(VARY_SPEC)
        _set_spec(spec, p["spec_field"], p["spec_index"], _value(p["value"]))
        c.write("job/spec.json", F.to_json(spec))
        argv = vary_argv(c)
    else:
        argv = vary_argv(c) + [p["option"], p["arg"]]
    return c, _run(case, c, root, workdir, argv, timeout, names={"--variants", "--seed"})


# ---------------------------------------------------------------------------------------------- names

NAME_STYLES = [
    ("255 bytes", lambda stem: ("n" * 255).encode()),
    ("256 bytes", lambda stem: ("n" * 256).encode()),
    ("255 bytes of 2-byte characters", lambda stem: ("é" * 127 + "n").encode()),
    ("a 4200-byte path", None),
    ("non-UTF-8 bytes", lambda stem: stem.encode() + b"\xff\xfe"),
    ("a NUL byte", lambda stem: stem.encode() + b"\x00x"),
    ("a newline", lambda stem: stem.encode() + b"\nx"),
    ("a carriage return", lambda stem: stem.encode() + b"\rx"),
    ("ESC", lambda stem: stem.encode() + b"\x1b[31m"),
    ("an emoji", lambda stem: stem.encode() + "🚗".encode()),
    ("spaces and dots", lambda stem: b" " + stem.encode() + b" ..."),
]
NAME_TARGETS = ["scene.predictions", "assets[0].ply", "output_dir", "the job's folder", "export --out",
                "vary --out", "vary --library"]


def _names_plan(rng):
    combos = [(t, s) for t in NAME_TARGETS for s in range(len(NAME_STYLES))]
    target, s = rng.cycle(combos)
    return f"names: {target} with {NAME_STYLES[s][0]}", {"target": target, "style": s}


def _hostile_name(style, stem) -> bytes:
    make = NAME_STYLES[style][1]
    if make is None:   # nested 200-byte folders, 4200 bytes in all
        return b"/".join([b"d" * 200] * 21)
    return make(stem)


def _mk_path(parent: str, name: bytes) -> bytes:
    """``parent``/``name`` as bytes (the name may be a relative path of several parts)."""
    return os.path.join(os.fsencode(parent), name)


def _run_names(case, base, root, workdir, timeout):
    import fuzz_inputs as F
    p = case.apply
    target, style = p["target"], p["style"]
    c = _folder(case, base, root)
    stem = {"scene.predictions": "pred", "assets[0].ply": "car", "output_dir": "out"}.get(target, "dir")
    name = _hostile_name(style, stem)
    makeable = b"\x00" not in name and len(name) < 3000 and all(len(part) <= 255 for part in name.split(b"/"))
    names = {stem}

    if target in ("scene.predictions", "assets[0].ply"):
        ext = b".npz" if stem == "pred" else b".ply"
        # a file name of exactly the style's length, its extension included
        label = NAME_STYLES[style][0]
        full = (("é" * 125 + "n").encode() + ext if label.startswith("255 bytes of") else
                name[:len(name) - len(ext)] + ext if label.startswith(("255", "256")) else name + ext)
        makeable = b"\x00" not in full and len(full) < 3000 and all(len(x) <= 255 for x in full.split(b"/"))
        if makeable:
            dst = _mk_path(c.job_dir, full)
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            os.rename(os.fsencode(c.predictions if stem == "pred" else c.ply), dst)
        if stem == "pred":
            c.job["scene"]["predictions"] = os.fsdecode(full)
        else:
            c.job["assets"][0]["ply"] = os.fsdecode(full)
        c.write("job/job.json", F.to_json(c.job))
        argv = ["render", c.job_json, "--device", "cpu"]
    elif target == "output_dir":
        c.job["output_dir"] = os.fsdecode(name)
        c.write("job/job.json", F.to_json(c.job))
        argv = ["render", c.job_json, "--device", "cpu"]
    elif target == "the job's folder":
        folder = _mk_path(c.job_dir, name)
        if makeable:
            os.makedirs(folder, exist_ok=True)
            job = copy.deepcopy(c.job)
            depth = name.count(b"/") + 1
            job["scene"]["predictions"] = "../" * depth + "predictions.npz"
            job["assets"][0]["ply"] = "../" * depth + "car.ply"
            with open(os.path.join(folder, b"job.json"), "w") as fh:
                fh.write(F.to_json(job))
        argv = ["render", os.fsdecode(os.path.join(folder, b"job.json")), "--device", "cpu", "--data-root",
                c.job_dir]
    elif target == "export --out":
        argv = ["export", c.job_json, "--format", "kitti", "--device", "cpu", "--out",
                os.fsdecode(_mk_path(os.path.join(c.job_dir, "out"), name))]
    else:
        add_road(c, base)
        if target == "vary --out":
            argv = vary_argv(c, out=os.fsdecode(_mk_path(os.path.join(c.job_dir, "out"), name)))
        else:
            lib = _mk_path(c.job_dir, name)
            if makeable:
                os.makedirs(lib, exist_ok=True)
                shutil.copyfile(os.path.join(c.cars, "car.ply"), os.path.join(lib, b"car.ply"))
            argv = vary_argv(c)
            argv[argv.index("--library") + 1] = os.fsdecode(lib)
    names.update(os.fsdecode(x) for x in name.split(b"/") if x)
    return c, _run(case, c, root, workdir, argv, timeout, names=names)


# ---------------------------------------------------------------------------------------------- disk full

DISK_SIZES_K = (8, 12, 16, 24, 32, 48, 64, 96, 128, 256)


def _diskfull_plan(rng):
    command = rng.cycle(["render", "generate", "export", "vary"])
    size = DISK_SIZES_K[(rng.turn // 4) % len(DISK_SIZES_K)]
    fill = rng.choice([0, 0, 50])
    return (f"{command}: the output folder a {size} KiB tmpfs{f', {fill}% filled first' if fill else ''}",
            {"command": command, "size_k": size, "fill": fill})


def _mount(path, size_k):
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_k}k", "tmpfs", path], capture_output=True)
    if r.returncode != 0:
        raise RuntimeError(f"mount failed: {r.stderr.decode(errors='replace')[:200]}")


def _umount(path):
    if subprocess.run(["umount", path], capture_output=True).returncode != 0:
        subprocess.run(["umount", "-l", path], capture_output=True)


def _run_diskfull(case, base, root, workdir, timeout):
    import fuzz_inputs as F
    p = case.apply
    c = _folder(case, base, root)
    if p["command"] == "vary":
        add_road(c, base)
    argv = _argv_for(p["command"], c)
    out = os.path.join(c.job_dir, "out")
    _mount(out, p["size_k"])
    try:
        if p["fill"]:
            st = os.statvfs(out)
            with open(os.path.join(out, "filler.bin"), "wb") as fh:
                fh.write(b"\0" * (st.f_bavail * st.f_frsize * p["fill"] // 100))
        result, outcome, ran = _run(case, c, root, workdir, argv, timeout, names={"out", "filler.bin"})
        text = ran["stdout"] + ran["stderr"]
        if outcome in ("clean", "unclear") and ("internal error" in text or "please report" in text):
            outcome = "traceback"
        elif outcome == "unclear" and out + os.sep in result["message"]:   # names a path inside the full folder
            outcome = "clean"
        left = [x for x in leftovers(out) if x != "filler.bin"]
        if outcome in ("accepted", "clean", "unclear") and left:
            outcome, result["message"] = "misread", f"left behind: {left[:4]} ({result['message'][:100]})"
    finally:
        _umount(out)
    return c, (result, outcome, ran)


# ---------------------------------------------------------------------------------------------- vary killed

VARYKILL_SCENARIOS = ["B killed after a finished A, then B again", "B killed after a finished A, then A again",
                      "B killed after a finished A, no re-run", "A killed on a fresh folder, then A again",
                      "A and B at once"]


def _varykill_plan(rng):
    sc = rng.cycle(VARYKILL_SCENARIOS)
    sig = ("SIGKILL", "SIGTERM")[rng.turn // len(VARYKILL_SCENARIOS) % 2]
    killed = "A" if sc.startswith("A killed") else "B"
    point = rng.randrange(1, VARY_RENAMES[killed] + 1) if "at once" not in sc else 0
    return (f"vary: {sc}" + (f", {sig} before rename {point}" if point else ""),
            {"scenario": sc, "signal": sig if point else "", "point": point})


def _vary_folder(F, base, root):
    c = F.prepare(F.Case("job", -1, 0, "varykill", lambda c: None), base, root)
    c.write("job/job.json", F.to_json(c.job))
    add_road(c, base, spec=VARY_A)
    c.write("job/spec_b.json", json.dumps(VARY_B))
    return c


def _normal(data: bytes, c) -> bytes:
    """A list's or job's bytes with the case's folder as <JOB> and a library file's key (``asset_frame.file_key``:
    its identity on this disk) as <KEY>."""
    import re
    return re.sub(rb"\.[0-9a-f]{10}\.hue", b".<KEY>.hue", data.replace(os.fsencode(c.job_dir), b"<JOB>"))


def _vary_state(c, out) -> dict | None:
    """{relative path: ``_normal`` bytes} of variants.txt and every job it lists; None when there is no
    variants.txt."""
    p = os.path.join(out, "variants.txt")
    if not os.path.exists(p):
        return None
    # its lines sorted: the data-root lines come in set order (PYTHONHASHSEED), which changes nothing
    state = {"variants.txt": b"\n".join(sorted(_normal(open(p, "rb").read(), c).splitlines()))}
    from scpainter_blender.core import batch_items
    from scpainter_blender.core.errors import InputError
    try:
        jl = batch_items.read_job_list(p)
    except InputError:
        return {"(refused)": b""}
    for job in jl.paths:
        rel = os.path.relpath(job, out)
        try:
            state[rel] = _normal(open(job, "rb").read(), c)
        except OSError as e:
            state[rel] = f"({type(e).__name__})".encode()
    return state


_VARY_REFS: dict = {}


def varykill_references(base, workdir) -> None:
    """The lists and jobs of finished vary runs of spec A and B on a fresh folder (in forked children, as the
    cases run), and how many renames each makes."""
    import fuzz_inputs as F
    import fuzz_surfaces as FS
    if _VARY_REFS:
        return
    for name in ("A", "B"):
        c = _vary_folder(F, base, os.path.join(workdir, f"varykill-ref-{name}"))
        spec = c.spec if name == "A" else c.path("job/spec_b.json")
        ch = FS._Child(vary_argv(c, spec=spec), os.path.join(workdir, f"varykill-ref-{name}.log"), gated=True)
        renames = 0
        while True:
            got = ch.read(120)
            if not got:
                break
            for ln in got:
                if ln.startswith(FS.GATE):
                    renames += 1
                    ch.step()
        if not ch.wait(time.monotonic() + 120) or ch.rc != 0:
            raise RuntimeError(f"varykill reference {name}: exit {ch.rc}: {ch.stderr()[-600:]}")
        _VARY_REFS[name] = _vary_state(c, c.vary_out)
        _VARY_REFS["renames " + name] = renames
        shutil.rmtree(c.root, ignore_errors=True)


def run_varykill(case, base, root, workdir, keep) -> dict:
    """One varykill case in this process (a fork server's case runner: backend children forked from here)."""
    import fuzz_inputs as F
    import fuzz_surfaces as FS
    varykill_references(base, workdir)
    result = _record(case)
    p = case.apply
    c = _vary_folder(F, base, root)
    specs = {"A": c.spec, "B": c.path("job/spec_b.json")}
    logs = iter(range(100))
    before, top_before = F.snapshot(root, c.job_dir), set(os.listdir(workdir))
    problems, hang, gates = [], [], []
    t0 = time.perf_counter()

    def child(name, gated=False):
        return FS._Child(vary_argv(c, spec=specs[name]),
                         os.path.join(workdir, f"varykill-{case.index}-{next(logs)}.log"), gated=gated)

    def judge(ch, label):
        o, m = FS._judge(F, ch, label)
        # vary ends 1 when it refuses a busy folder: FS._judge counts that as the lock respected
        if o:
            problems.append((o, m))

    def run(name, kill_at=None, sig=""):
        ch = child(name, gated=kill_at is not None)
        deadline = time.monotonic() + FS.KILL_TIMEOUT_S
        if kill_at is not None:
            seen = 0
            while time.monotonic() < deadline and ch.ack is not None:
                got = ch.read(max(0.0, deadline - time.monotonic()))
                if not got:
                    break
                for ln in got:
                    if not ln.startswith(FS.GATE):
                        continue
                    seen += 1
                    gates.append(os.path.relpath(ln[len(FS.GATE):], c.job_dir))
                    if seen == kill_at:
                        ch.signal(sig)
                        ch.open()
                        break
                    ch.step()
        if not ch.wait(deadline):
            hang.append(f"vary {name} did not end within {FS.KILL_TIMEOUT_S:g} s")
        else:
            judge(ch, f"vary {name}")
        return ch

    def together():
        a, b = child("A", gated=True), child("B", gated=True)
        deadline = time.monotonic() + FS.KILL_TIMEOUT_S
        live = [a, b]
        while live and time.monotonic() < deadline:   # one rename each in turn: the runs interleave
            for ch in list(live):
                got = ch.read(max(0.0, deadline - time.monotonic()))
                if got == []:
                    live.remove(ch)
                    continue
                if any(ln.startswith(FS.GATE) for ln in got or []):
                    ch.step()
        for ch, name in ((a, "A"), (b, "B")):
            if not ch.wait(deadline):
                hang.append(f"vary {name} (at once) did not end within {FS.KILL_TIMEOUT_S:g} s")
            else:
                judge(ch, f"vary {name} (at once)")

    sc, sig, point = p["scenario"], p["signal"], p["point"]
    final = None
    try:
        with F.alarm(FS.KILL_TIMEOUT_S * 4):
            if sc.startswith("B killed"):
                run("A")
                run("B", point, sig)
                if sc.endswith("B again"):
                    run("B")
                    final = "B"
                elif sc.endswith("A again"):
                    run("A")
                    final = "A"
            elif sc.startswith("A killed"):
                run("A", point, sig)
                run("A")
                final = "A"
            else:
                together()
    except F.Hang:
        hang.append("the case did not end")
    result["seconds"] = round(time.perf_counter() - t0, 3)
    if sig:
        result["killed_before"] = gates[point - 1] if len(gates) >= point else f"(the run ended: {len(gates)} renames)"
    escapes = F._changed(before, F.snapshot(root, c.job_dir))
    escapes += [f"created ../{n}" for n in sorted(set(os.listdir(workdir)) - top_before)
                if not n.startswith(f"varykill-{case.index}-")]
    if escapes:
        outcome, result["message"], result["escaped"] = "escape", "; ".join(escapes[:3]), escapes[:6]
    elif hang:
        outcome, result["message"] = "hang", hang[0]
    elif problems:
        outcome, result["message"] = problems[0]
    else:
        state = _vary_state(c, c.vary_out)
        why = []
        if final is not None:
            if state != _VARY_REFS[final]:
                why.append(f"after the re-run of {final} the folder's list and jobs are not that run's "
                           f"({_diff(state, _VARY_REFS[final])})")
            left = leftovers(c.vary_out)
            if left:
                why.append(f"temporaries left after the re-run: {left[:3]}")
        elif state is not None and "(refused)" not in state:
            whole = [n for n in ("A", "B") if state == _VARY_REFS[n]]
            # mixed: only a batch that refuses the list (however the folder says it is unfinished) is right
            if not whole and _batch_takes(c.vary_out, os.path.join(workdir, f"varykill-{case.index}-batch.log")):
                why.append("variants.txt and the jobs it lists are neither wholly A's nor B's, and batch --list "
                           "takes them: " + _diff(state, _VARY_REFS["A"]) + " / " + _diff(state, _VARY_REFS["B"]))
        outcome = "misread" if why else "accepted"
        result["message"] = "; ".join(why)
        result["rc"] = 0
    return FS.finish_case(result, outcome, workdir, f"varykill-{case.index}-", root, keep)


def _batch_takes(out, log) -> bool:
    """Whether ``batch --list out/variants.txt --command render`` runs the list (exit 0) rather than refusing it;
    in a forked child, as the case's vary runs (``fuzz_surfaces._Child``)."""
    import fuzz_surfaces as FS
    ch = FS._Child(["batch", "--list", os.path.join(out, "variants.txt"), "--command", "render", "--device", "cpu"],
                   log)
    ended = ch.wait(time.monotonic() + FS.KILL_TIMEOUT_S)
    return not ended or ch.rc == 0   # a batch that never ends has not refused the list either


def _diff(got, want) -> str:
    if got is None:
        return "no variants.txt"
    differ = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))
    return "differ: " + ", ".join(differ[:4])


# ---------------------------------------------------------------------------------------------- cases

FAMILIES = {"links": _links_plan, "races": _races_plan, "lists": _lists_plan, "serve": _serve_plan,
            "numerics": _numerics_plan, "names": _names_plan, "diskfull": _diskfull_plan,
            "varykill": _varykill_plan}
_NEEDS_BASE = ("numerics",)
_PLAN_BASE: dict = {}


def _plan_job() -> object:
    """What the numerics plans enumerate: ``fuzz_inputs.Base`` (its job's fields), built once in a temporary
    folder."""
    if "job" not in _PLAN_BASE:
        import tempfile

        import fuzz_inputs as F
        d = tempfile.mkdtemp(prefix="scpainter-fuzz-plan-")
        try:
            _PLAN_BASE["job"] = F.Base(d)
        finally:
            shutil.rmtree(d, ignore_errors=True)
    return _PLAN_BASE["job"]


def make_case(kind: str, index: int, seed: int) -> Case:
    """Case ``index`` of ``kind``: the family's plan cycles through its variants (``Draw.cycle`` with ``turn`` =
    index), every other choice seeded by (seed, kind, index)."""
    rng = Draw(f"{seed}/{kind}/{index}")
    rng.turn = index
    plan = FAMILIES[kind]
    description, spec = plan(rng, _plan_job()) if kind in _NEEDS_BASE else plan(rng)
    return Case(kind, index, seed, description, spec)


def run_case(case: Case, base, workdir: str, timeout: float, keep: bool = False) -> dict:
    """Build, run and classify one case of this module's kinds in this process (``fuzz_inputs.run_case``)."""
    import fuzz_inputs as F
    import fuzz_surfaces as FS
    if case.kind == "serve":
        return _run_serve(case, base, None, workdir, timeout)
    if case.kind == "varykill":
        if FS._SERVER:
            got = FS._SERVER[0].case(case.index, case.seed, workdir, keep, kind="varykill")
            if got is None:
                r = _record(case)
                r.update(outcome="hang", message="the case did not end in time")
                return r
            return got
        return run_varykill(case, base, os.path.join(workdir, f"{case.kind}-{case.index:04d}"), workdir, keep)
    root = os.path.join(workdir, f"{case.kind}-{case.index:04d}")
    runner = {"links": _run_links, "races": _run_races, "lists": _run_lists, "numerics": _run_numerics,
              "names": _run_names, "diskfull": _run_diskfull}[case.kind]
    _, (result, outcome, ran) = runner(case, base, root, workdir, timeout)
    return F.finish(result, outcome, ran, root, keep)


def warm_up(kind: str, base, workdir: str, seed: int) -> dict:
    """The valid input of ``kind`` run once (untimed): a vary on the road base must place its variants, the
    serve process must answer, the varykill references be built."""
    import fuzz_inputs as F
    import fuzz_surfaces as FS
    t0 = time.perf_counter()
    outcome, message = "accepted", ""
    try:
        if kind == "serve":
            _server(workdir, base)
        elif kind == "varykill":
            got = FS.start_fork_server(base, workdir).warm(kind="varykill")
            outcome, message = got["outcome"], got["message"]
        elif "road" in _ROAD and "checked" in _ROAD:   # the road base was tried for another kind already
            outcome, message = _ROAD["checked"]
        elif kind in ("links", "races", "lists", "numerics", "names", "diskfull"):
            case = Case(kind, -1, seed, "base: the valid input", {})
            c = _folder(case, base, os.path.join(workdir, f"{kind}-base"))
            add_road(c, base)
            r = F.invoke(vary_argv(c), 600)
            if r["rc"] != 0:
                outcome, message = "traceback", f"vary on the road base: exit {r['rc']}: {r['stdout'][-300:]}"
            else:
                with open(os.path.join(c.vary_out, "variation.json")) as fh:
                    placed = json.load(fh)["summary"]["placed"]
                if placed != VARY_SPEC["variants"]:
                    outcome, message = "unclear", f"vary placed {placed} of {VARY_SPEC['variants']} on the road base"
            shutil.rmtree(c.root, ignore_errors=True)
            _ROAD["checked"] = (outcome, message)
    except Exception as e:  # noqa: BLE001
        outcome, message = "traceback", f"{type(e).__name__}: {e}"[:400]
    return {"outcome": outcome, "seconds": round(time.perf_counter() - t0, 3), "message": message}
