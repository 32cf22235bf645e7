"""Seeded fuzz cases for the backend's input files (issue 14), and the harness that runs and classifies them
(also the cases of issue 30's ``tests/fuzz_surfaces.py`` and issue 42's ``tests/fuzz_round3.py``).

Every case starts from a tiny valid job in its own folder and changes one thing::

    <case>/job/job.json              scpainter.job/2: 2 frames of 16 x 12, a scene, one asset, output_dir "out"
    <case>/job/predictions.npz       VGGT predictions, S = 2 frames of 16 x 12 (core.vggt.npz.save_predictions)
    <case>/job/car.ply               20 INRIA Gaussians, SH degree 1 (core.splats.inria.write_ply)
    <case>/job/out/                  the output folder
    <case>/outside/                  planted files that must never be touched (frame_000000.exr, backend.log,
                                     conditions/ with a stale job key, copies of the inputs, link targets)
    <case>/scpainter-ckpt/           checkpoint cases only: a copy of a tiny checkpoint (weights hard-linked)

Kinds (``CASES`` says how many of each; a case is reproducible from (kind, index, seed)):

* ``job``: structural (keys deleted, values replaced from a palette of hostile values, wrong-length lists),
  semantic (resolutions, frame numbers, source frames, generation settings, matrices), paths (output folders and
  inputs leading outside, symbolic links, FIFOs, directories, devices) and whole-file damage. Run with
  ``render job.json --device cpu``.
* ``npz``: byte- and array-level damage to predictions.npz (stored and deflated archives). ``render``.
* ``ply``: header and data damage to car.ply; content-preserving rewrites are also checked for a silent misread.
  ``render``.
* ``checkpoint``: scpainter.json, model_index.json, component folders and weight files of the checkpoint. Run with
  ``generate job.json --checkpoint <case>/scpainter-ckpt --device cpu --check``; on a backend without ``--check``
  (the "before" measurement) generate runs for real with ``--steps 1`` (on the same 2-frame job: SVD's temporal
  layers cannot take one frame), with a 60 s timeout.

Each case runs in-process through ``backend.__main__.main(argv)`` with standard output and error captured and a
timeout of ``TIMEOUT_S`` CPU seconds (SIGPROF), or ``WALL_FACTOR`` times that of wall-clock time (SIGALRM) for a case
blocked without using CPU; either handler raises, which also interrupts a blocking ``open`` of a FIFO. CPU time, so
that a busy machine does not turn a slow case into a hang. Outcome classes:

* ``accepted``  exit 0.
* ``clean``     exit 2 and an ``error`` event whose message names one of the case's files or folders as a word
                or a path's last part (job.json, predictions.npz, car.ply, scpainter.json, a planted file, a
                link's target, ...); its ``file`` and ``field`` keys are recorded.
* ``unclear``   exit 2 but no file named.
* ``traceback`` exit 1 (or any other code), "Traceback" on standard error, or an exception (SystemExit
                included) escaping ``main``; also a worker process that died during the case.
* ``hang``      the timeout fired (or the worker stopped answering and was killed).
* ``escape``    a file outside ``<case>/job/`` was created, modified or deleted (the case folder is snapshotted
                before and after: paths, sizes, mtimes, link targets; new names beside the case folder count too).
* ``misread``   a PLY rewritten without changing its Gaussians (a comment holding "end_header", ASCII, big endian,
                doubles, CRLF, ...) was accepted but ``core.splats.reader.read`` gives other values than the original.

``run()`` hands the cases to two worker processes (``python tests/fuzz_inputs.py --worker``, single-threaded,
each case in-process there), so that a hang no signal can interrupt, a crash or a runaway allocation (workers run
under a 4 GiB address-space and a 512 MiB file-size limit after their warm-up) costs one case, not the run; case
folders live in /dev/shm when it exists. The valid inputs are run first, untimed, and must be accepted. One case by
hand, in this process::

    .venv/bin/python -m tests.fuzz_inputs --kind job --index 17 [--seed 14] [--keep]
    .venv/bin/python -m tests.fuzz_inputs --list --kind ply
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import copy
import io
import json
import os
import random
import re
import select
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
import zlib
from dataclasses import dataclass

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (ROOT, HERE):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numpy as np  # noqa: E402

if __name__ == "__main__":   # a worker (python tests/fuzz_inputs.py --worker): fuzz_surfaces imports us by name
    sys.modules.setdefault("fuzz_inputs", sys.modules[__name__])
import fuzz_round3  # noqa: E402
import fuzz_surfaces  # noqa: E402

#: The input kinds of issue 14 (this module's mutations); issue 30's surfaces follow (``fuzz_surfaces.KINDS``),
#: then issue 42's (``fuzz_round3.KINDS``: links, races, lists, serve, numerics, names, diskfull, varykill).
INPUT_KINDS = ("job", "npz", "ply", "checkpoint")
#: The kinds whose cases another module makes and runs (``make_case``, ``run_case``, ``warm_up``).
SURFACE_KINDS = fuzz_surfaces.KINDS + fuzz_round3.KINDS
KINDS = INPUT_KINDS + SURFACE_KINDS
CASES = {"job": 480, "npz": 270, "ply": 270, "checkpoint": 130, **fuzz_surfaces.CASES, **fuzz_round3.CASES}
SEED = 14
TIMEOUT_S = 5.0                  # CPU seconds a case may use in its worker (a loaded machine does not make a hang)
WALL_FACTOR = 12.0               # ... and wall seconds, as many times that: a case blocked without using CPU
FALLBACK_TIMEOUT_S = 60.0        # checkpoint cases when generate runs for real (no --check): model load + 1 step
CLASSES = ("accepted", "clean", "unclear", "traceback", "hang", "escape", "misread")
FAILURES = ("unclear", "traceback", "hang", "escape", "misread")
MEMORY_HEADROOM = 4 << 30        # bytes of address space a worker may add after its warm-up
FILE_SIZE_LIMIT = 512 << 20      # the largest file a worker may write

W, H, S, N_GAUSSIANS = 16, 12, 2, 20
CKPT = "scpainter-ckpt"
STALE_KEY = "0" * 32


class Raw:
    """Text written verbatim into a JSON file (NaN, Infinity, a 5000-digit integer, 10000 nested lists)."""

    def __init__(self, text: str):
        self.text = text


def to_json(value) -> str:
    """JSON text of ``value``; ``Raw`` pieces are inserted as they are."""
    if isinstance(value, Raw):
        return value.text
    if isinstance(value, dict):
        return "{" + ", ".join(json.dumps(str(k)) + ": " + to_json(v) for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(to_json(v) for v in value) + "]"
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, int):
        return str(value)
    return json.dumps(float(value))  # NaN / Infinity for non-finite floats


# ---------------------------------------------------------------------------------------------- the valid base

class Base:
    """The valid inputs every case starts from (built once per session in ``folder``): the job, the predictions
    arrays and their archives, the PLY, and (on first use) a tiny checkpoint."""

    def __init__(self, folder: str):
        from scpainter_blender.core.geometry import cameras
        from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria, reader as splats_io
        from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io
        from vggt_cases import drive

        self.folder = folder
        os.makedirs(folder, exist_ok=True)
        arrays, w2c_vggt, intr = drive(S=S, H=H, W=W, seed=3)
        pred = os.path.join(folder, "predictions.npz")
        vggt_io.save_predictions(pred, **arrays)
        with np.load(pred) as z:
            self.arrays = {k: z[k] for k in z.files}          # exactly what the writer saved
        with open(pred, "rb") as f:
            self.npz_stored = f.read()
        buf = io.BytesIO()
        np.savez_compressed(buf, **self.arrays)
        self.npz_deflated = buf.getvalue()

        rng = np.random.default_rng(5)
        q = rng.normal(size=(N_GAUSSIANS, 4))
        g = splats.Gaussians(means=rng.uniform(-0.5, 0.5, (N_GAUSSIANS, 3)).astype(np.float32),
                             scales=rng.uniform(0.05, 0.2, (N_GAUSSIANS, 3)).astype(np.float32),
                             quats=(q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32),
                             opacities=rng.uniform(0.5, 0.9, N_GAUSSIANS).astype(np.float32),
                             sh=rng.normal(0, 0.3, (N_GAUSSIANS, 4, 3)).astype(np.float32))
        ply = os.path.join(folder, "car.ply")
        splats_inria.write_ply(ply, splats.encode(g))
        with open(ply, "rb") as f:
            self.ply = f.read()
        self.gaussians = splats_io.read(ply)
        end = self.ply.index(b"end_header\n") + len(b"end_header\n")
        self.ply_header = self.ply[:end].decode("ascii").splitlines()
        self.ply_data = self.ply[end:]
        self.ply_props = [line.split()[2] for line in self.ply_header if line.startswith("property")]
        self.ply_records = np.frombuffer(self.ply_data, dtype=[(p, "<f4") for p in self.ply_props])

        wfv = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])  # VGGT -> Z up, scale 1
        w2c = np.asarray(w2c_vggt, np.float64) @ cameras.rigid_inverse(wfv)
        K = vggt.vggt_K_to_ours(intr)
        c2w0 = cameras.rigid_inverse(w2c[0])
        ahead = c2w0[:3, 3] + 3.0 * c2w0[:3, 2]                 # 3 m in front of the first camera
        o2w = np.eye(4)
        o2w[:3, 3] = ahead
        frames = [{"frame": i + 1, "K": K[i].tolist(), "world_to_camera": w2c[i].tolist(), "source_frames": [0, 1]}
                  for i in range(S)]
        self.job = {"schema": "scpainter.job/2", "resolution": [W, H], "frames": frames,
                    "scene": {"predictions": "predictions.npz", "vggt_to_world": wfv.tolist(),
                              "confidence_percentile": 50.0},
                    "assets": [{"name": "car", "ply": "car.ply",
                                "object_to_world": {str(f["frame"]): o2w.tolist() for f in frames}}],
                    "output_dir": "out",
                    "generate": {"steps": 2, "window": 14, "overlap": 4, "seed": 0, "decode_chunk": 8, "fps": 7,
                                 "min_guidance": 1.0, "max_guidance": 3.0}}
        # generate needs two frames at least (SVD's temporal layers normalise over frames)
        self.checkpoint_job = dict(copy.deepcopy(self.job), generate={"steps": 1, "window": 14, "overlap": 4,
                                                                      "seed": 0})
        self._checkpoint = None

    def checkpoint(self) -> str:
        """A tiny SCPainter checkpoint (random weights; built once, then reused by later workers)."""
        if self._checkpoint is None:
            path = os.path.join(self.folder, "ckpt-base")
            if not os.path.isfile(os.path.join(path, "scpainter.json")):
                from backend.model import checkpoint_init, configs

                svd = os.path.join(self.folder, "svd-tiny")
                shutil.rmtree(svd, ignore_errors=True)
                shutil.rmtree(path, ignore_errors=True)
                configs.save_stock_svd(svd, "tiny", seed=0)
                checkpoint_init.init_checkpoint(svd, path)
            self._checkpoint = path
        return self._checkpoint


# ---------------------------------------------------------------------------------------------- one case

class CaseDir:
    """The files of one case; mutations change them (``job`` is written as job.json unless set to None)."""

    def __init__(self, root: str, base: Base, kind: str):
        self.root, self.base, self.kind = root, base, kind
        self.job_dir = os.path.join(root, "job")
        self.outside = os.path.join(root, "outside")
        self.job_json = os.path.join(self.job_dir, "job.json")
        self.predictions = os.path.join(self.job_dir, "predictions.npz")
        self.ply = os.path.join(self.job_dir, "car.ply")
        self.checkpoint = os.path.join(root, CKPT)
        self.job = copy.deepcopy(base.checkpoint_job if kind == "checkpoint" else base.job)
        self.names = set()         # more names a clean error may give (link targets, files an index names)

    def path(self, rel: str) -> str:
        return os.path.join(self.root, rel)

    def write(self, rel: str, data) -> str:
        """Write bytes or text at ``rel`` (relative to the case folder), replacing a file or hard link there."""
        p = self.path(rel)
        os.makedirs(os.path.dirname(p), exist_ok=True)
        if os.path.lexists(p) and not os.path.isdir(p):
            os.unlink(p)                  # never write through a hard link into the shared base checkpoint
        with open(p, "wb") as f:
            f.write(data.encode("utf-8") if isinstance(data, str) else data)
        return p

    def replace_with(self, rel: str, what: str, target: str = "") -> None:
        """Replace ``rel`` with: fifo, dir, missing, or a symbolic link to ``target``."""
        p = self.path(rel)
        if os.path.isdir(p) and not os.path.islink(p):
            shutil.rmtree(p)
        elif os.path.lexists(p):
            os.unlink(p)
        os.makedirs(os.path.dirname(p), exist_ok=True)
        if what == "fifo":
            os.mkfifo(p)
        elif what == "dir":
            os.makedirs(os.path.join(p, "inside"))
        elif what == "link":
            os.symlink(target, p)
            self.names.add(os.path.basename(target.rstrip("/")))


@dataclass
class Case:
    kind: str
    index: int
    seed: int
    description: str
    apply: object                      # function(CaseDir)
    names: tuple = ()                  # more file names a clean error may name
    same_gaussians: bool = False       # PLY rewritten without changing its Gaussians: check for a misread

    @property
    def family(self) -> str:
        return self.description.split(":")[0]


def prepare(case: Case, base: Base, root: str) -> CaseDir:
    """Build the case folder at ``root`` (removing an old one) and apply the mutation."""
    if os.path.lexists(root):
        shutil.rmtree(root)
    c = CaseDir(root, base, case.kind)
    os.makedirs(os.path.join(c.job_dir, "out"))
    os.makedirs(os.path.join(c.outside, "conditions"))
    os.makedirs(os.path.join(c.outside, "target"))
    with open(c.predictions, "wb") as f:
        f.write(base.npz_stored)
    with open(c.ply, "wb") as f:
        f.write(base.ply)
    plants = {"frame_000000.exr": b"planted exr", "preview_000000.png": b"planted png",
              "backend.log": b"planted log\n", "conditions/frame_000001.exr": b"planted exr",
              "conditions/preview_000001.png": b"planted png", "conditions/job_key.txt": STALE_KEY + "\n",
              "target/target.txt": b"planted target", "predictions.npz": base.npz_stored, "car.ply": base.ply,
              "job.json": to_json(base.job)}
    for rel, data in plants.items():
        c.write(os.path.join("outside", rel), data)
    if case.kind == "checkpoint":
        src = base.checkpoint()
        for dirpath, _, files in os.walk(src):
            dst = os.path.join(c.checkpoint, os.path.relpath(dirpath, src))
            os.makedirs(dst, exist_ok=True)
            for name in files:
                if name.endswith(".json"):
                    shutil.copyfile(os.path.join(dirpath, name), os.path.join(dst, name))
                else:
                    os.link(os.path.join(dirpath, name), os.path.join(dst, name))
    case.apply(c)
    if c.job is not None:
        c.write("job/job.json", to_json(c.job))
    return c


# ---------------------------------------------------------------------------------------------- mutations: job

_BIG_DIGITS = "9" * 5000
PALETTE = [
    ("null", None), ("true", True), ("-1", -1), ("0", 0), ("2**31", 2 ** 31), ("2**63", 2 ** 63),
    ("10**30", 10 ** 30), ("1e300", 1e300), ("-1e300", -1e300), ("0.5", 0.5), ("5e-324", 5e-324),
    ("a 5000-digit integer", Raw(_BIG_DIGITS)), ("NaN", Raw("NaN")), ("Infinity", Raw("Infinity")),
    ("-Infinity", Raw("-Infinity")), ("1e999", Raw("1e999")), ('""', ""), ('"x"', "x"),
    ("a 1 MB string", "x" * (1 << 20)), ("a lone surrogate", Raw('"\\ud800"')), ("[]", []), ("{}", {}),
    ("[1, 2, 3]", [1, 2, 3]), ("nested lists 10000 deep", Raw("[" * 10000 + "]" * 10000)),
]


def _tree_paths(node, prefix=()):
    for key, child in (node.items() if isinstance(node, dict) else enumerate(node)):
        yield prefix + (key,)
        if isinstance(child, (dict, list)):
            yield from _tree_paths(child, prefix + (key,))


def _get(tree, path):
    for k in path:
        tree = tree[k]
    return tree


def _fmt(path) -> str:
    out = ""
    for k in path:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out or "(top level)"


def _similar(shear=0.0, scale=1.0, det_sign=1.0):
    m = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
    m[:3, :3] *= scale
    m[0, 1] += shear
    m[0, 0] *= det_sign
    return m.tolist()


def _job_structural(kind):
    def plan(rng, base):
        paths = list(_tree_paths(base.job))
        if kind == "delete":
            p = rng.cycle([p for p in paths if isinstance(p[-1], str)])
            return f"delete key: {_fmt(p)}", lambda c: _get(c.job, p[:-1]).pop(p[-1])
        if kind == "leaf":
            p = rng.choice([p for p in paths if not isinstance(_get(base.job, p), (dict, list))])
        else:
            p = rng.choice([p for p in paths if isinstance(p[-1], str)])
        name, value = rng.cycle(PALETTE)

        def apply(c):
            _get(c.job, p[:-1])[p[-1]] = copy.deepcopy(value)
        return f"replace {'value' if kind == 'leaf' else 'field'}: {_fmt(p)} = {name}", apply
    return plan


def _job_wrong_length(rng, base):
    lists = [p for p in _tree_paths(base.job) if isinstance(_get(base.job, p), list)]
    p = rng.choice(lists)
    how = rng.choice(["one more entry", "one entry less", "empty", "doubled"])

    def apply(c):
        lst = _get(c.job, p)
        if how == "one more entry":
            lst.append(copy.deepcopy(lst[-1]) if lst else 0)
        elif how == "one entry less":
            lst[:] = lst[:-1]
        elif how == "empty":
            lst[:] = []
        else:
            lst[:] = lst + copy.deepcopy(lst)
    return f"wrong-length list: {_fmt(p)} {how}", apply


def _set(path, value):
    def apply(c):
        _get(c.job, path[:-1])[path[-1]] = copy.deepcopy(value)
    return apply


def _choice_plan(family, options):
    """A family whose cases go through ``options`` = [(detail, apply)] in turn (``Draw.cycle``); an option may
    also be a function ``(rng, base) -> (detail, apply)`` that draws its own details."""
    def plan(rng, base):
        option = rng.cycle(options)
        detail, apply = option(rng, base) if callable(option) else option
        return f"{family}: {detail}", apply
    return plan


def _frames_all(key, value):
    def apply(c):
        for fr in c.job["frames"]:
            fr[key] = copy.deepcopy(value)
    return apply


def _renumber(numbers):
    def apply(c):
        o2w = c.job["assets"][0]["object_to_world"]
        m = next(iter(o2w.values()))
        for fr, n in zip(c.job["frames"], numbers):
            fr["frame"] = n
        c.job["assets"][0]["object_to_world"] = {str(n) if not isinstance(n, Raw) else n.text: m for n in numbers}
    return apply


def _boxes(size, box_to_world=None, count=1):
    box = {"box_to_world": (np.eye(4) if box_to_world is None else box_to_world).tolist(), "size": size}
    return _set(("scene", "removal_boxes"), [box] * count)


def _asset_box(size=(1.9, 4.5, 1.6), box_to_file=None, **extra):
    box = {"box_to_file": (np.eye(4) if box_to_file is None else np.asarray(box_to_file)).tolist(),
           "size": list(size), **extra}
    return _set(("assets", 0, "box"), box)


def _recorded(boxes=None, size=(1.8, 4.4, 1.5), count=1, **extra):
    """``count`` recorded objects with ``boxes`` {frame key: matrix} (default: every frame, 10 m from the origin)."""
    def apply(c):
        frames = [str(f["frame"]) for f in c.job["frames"]]
        default = np.eye(4)
        default[:3, 3] = [0.0, 10.0, 0.8]
        b = boxes if boxes is not None else {f: default.tolist() for f in frames}
        c.job["scene"]["recorded_objects"] = [{"id": f"car{i}", "size": list(size), "boxes": copy.deepcopy(b),
                                               **extra} for i in range(count)]
    return apply


def _many_assets(n):
    def apply(c):
        c.job["assets"] = [dict(copy.deepcopy(c.job["assets"][0]), name=f"car{i}") for i in range(n)]
    return apply


def _matrix_in(path, fn):
    def apply(c):
        m = np.array(_get(c.job, path), np.float64)
        _get(c.job, path[:-1])[path[-1]] = fn(m)
    return apply


WFV = ("scene", "vggt_to_world")


def _set_cells(path, cells):
    """Set matrix entries {(i, j): value} (a value may be Raw)."""
    def apply(c):
        m = [list(row) for row in _get(c.job, path)]
        for (i, j), v in cells.items():
            m[i][j] = v
        _get(c.job, path[:-1])[path[-1]] = m
    return apply


def _linear(path, fn):
    """Replace the upper-left 3x3 of a 4x4 matrix with fn(it)."""
    def edit(m):
        m[:3, :3] = fn(m[:3, :3])
        return m.tolist()
    return _matrix_in(path, edit)


def _k_options(p):
    return [("zeros", _set(p, np.zeros((3, 3)).tolist())), ("NaN fx", _set_cells(p, {(0, 0): Raw("NaN")})),
            ("Infinity cx", _set_cells(p, {(0, 2): Raw("Infinity")})), ("fx -12", _set_cells(p, {(0, 0): -12.0})),
            ("fx 1e-30", _set_cells(p, {(0, 0): 1e-30})), ("fx 1e30", _set_cells(p, {(0, 0): 1e30})),
            ("fy 1e300", _set_cells(p, {(1, 1): 1e300})), ("cx 1e30", _set_cells(p, {(0, 2): 1e30})),
            ("cy -1e30", _set_cells(p, {(1, 2): -1e30})), ("skew 1e30", _set_cells(p, {(0, 1): 1e30})),
            ("last row [0, 0, 2]", _set_cells(p, {(2, 2): 2.0})), ("2x2", _matrix_in(p, lambda m: m[:2, :2].tolist())),
            ("fx 1e-300 and fy 1e300", _set_cells(p, {(0, 0): 1e-300, (1, 1): 1e300}))]


def _w2c_options(p):
    return [("scale 2", _linear(p, lambda r: 2 * r)), ("scale 1e-30", _linear(p, lambda r: 1e-30 * r)),
            ("translation 1e30", _set_cells(p, {(0, 3): 1e30})), ("translation 1e300", _set_cells(p, {(2, 3): 1e300})),
            ("translation 1e8", _set_cells(p, {(1, 3): 1e8})),
            ("shear 1e-6 (within tolerance)", _linear(p, lambda r: r + [[0, 1e-6, 0], [0, 0, 0], [0, 0, 0]])),
            ("reflection", _linear(p, lambda r: r * np.array([[-1.0], [1.0], [1.0]]))),
            ("zeros", _set(p, np.zeros((4, 4)).tolist())), ("NaN", _set_cells(p, {(0, 3): Raw("NaN")})),
            ("last row [0, 0, 0, 0]", _set_cells(p, {(3, 3): 0.0})),
            ("camera 2 m into the scene", _set_cells(p, {(0, 3): 0.0, (1, 3): 0.0, (2, 3): 2.0}))]


def _o2w_options(p):
    return [("singular (scale 0 on x)", _linear(p, lambda r: r * [0.0, 1.0, 1.0])),
            ("zeros", _set(p, np.zeros((4, 4)).tolist())), ("scale 1e-30", _linear(p, lambda r: 1e-30 * r)),
            ("scale 1e-5", _linear(p, lambda r: 1e-5 * r)), ("scale 1e30", _linear(p, lambda r: 1e30 * r)),
            ("scale 1e200", _linear(p, lambda r: 1e200 * r)), ("translation 1e30", _set_cells(p, {(0, 3): 1e30})),
            ("reflection", _linear(p, lambda r: r * [-1.0, 1.0, 1.0])), ("NaN", _set_cells(p, {(1, 1): Raw("NaN")})),
            ("shear 1e8", _set_cells(p, {(0, 1): 1e8})), ("last row [0, 0, 1, 1]", _set_cells(p, {(3, 2): 1.0})),
            ("non-uniform 1000 x 0.001 x 1", _linear(p, lambda r: r * [1000.0, 0.001, 1.0]))]



JOB_SEMANTIC = [
    ("resolution", [
        ("0 x 12", _set(("resolution",), [0, 12])), ("16 x 0", _set(("resolution",), [16, 0])),
        ("-16 x 12", _set(("resolution",), [-16, 12])), ("100000 x 100000", _set(("resolution",), [100000, 100000])),
        ("2**31 x 12", _set(("resolution",), [2 ** 31, 12])), ("16 x 10**9", _set(("resolution",), [16, 10 ** 9])),
        ("10**30 x 10**30", _set(("resolution",), [10 ** 30, 10 ** 30])),
        ("16.0 x 12.0", _set(("resolution",), [16.0, 12.0])),
        ("'16' x 12", _set(("resolution",), ["16", 12])), ("1 x 1", _set(("resolution",), [1, 1])),
        ("65536 x 1", _set(("resolution",), [65536, 1])), ("1 x 65536", _set(("resolution",), [1, 65536])),
        ("true x true", _set(("resolution",), [True, True])), ("16 x 12 x 3", _set(("resolution",), [16, 12, 3])),
        ("[16]", _set(("resolution",), [16])), ("16 x 12.5", _set(("resolution",), [16, 12.5])),
        ("2**63 x 2**63", _set(("resolution",), [2 ** 63, 2 ** 63])),
        ("20000 x 20000", _set(("resolution",), [20000, 20000])),
        ("a 5000-digit width", _set(("resolution",), [Raw(_BIG_DIGITS), 12])),
    ]),
    ("frame numbers", [
        ("10**12 and 10**12 + 1", _renumber([10 ** 12, 10 ** 12 + 1])),
        ("2**63 and 2**63 + 1", _renumber([2 ** 63, 2 ** 63 + 1])),
        ("10**30 and 10**30 + 1", _renumber([10 ** 30, 10 ** 30 + 1])), ("-5 and -4", _renumber([-5, -4])),
        ("-2**63 and 0", _renumber([-2 ** 63, 0])), ("duplicate 1 and 1", _renumber([1, 1])),
        ("1.0 and 2.0", _renumber([1.0, 2.0])), ("'1' and '2'", _renumber(["1", "2"])),
        ("999999 and 1000000 (7 digits)", _renumber([999999, 1000000])),
        ("frames list empty", _set(("frames",), [])),
        ("only the second frame", lambda c: c.job.__setitem__("frames", c.job["frames"][1:])),
        ("2**31 - 1 and 2**31", _renumber([2 ** 31 - 1, 2 ** 31])), ("true and false", _renumber([True, False])),
        ("null and 2", _renumber([None, 2])), ("0 and 10**6 (a gap)", _renumber([0, 10 ** 6])),
        ("the first frame 20 times with new numbers", lambda c: (c.job.__setitem__(
            "frames", [dict(c.job["frames"][0], frame=i) for i in range(20)]),
            c.job["assets"][0].__setitem__("object_to_world", {str(i): c.job["assets"][0]["object_to_world"]["1"]
                                                               for i in range(20)}))),
    ]),
    ("source frames", [
        ("[7] (S = 2)", _frames_all("source_frames", [7])), ("[2] (S = 2)", _frames_all("source_frames", [2])),
        ("[10**12]", _frames_all("source_frames", [10 ** 12])), ("[2**63]", _frames_all("source_frames", [2 ** 63])),
        ("[2**31]", _frames_all("source_frames", [2 ** 31])), ("[-1]", _frames_all("source_frames", [-1])),
        ("[]", _frames_all("source_frames", [])), ("[0] * 10000", _frames_all("source_frames", [0] * 10000)),
        ("[0.5]", _frames_all("source_frames", [0.5])), ("[true]", _frames_all("source_frames", [True])),
        ('"all"', _frames_all("source_frames", "all")), ("[0, 1, 7]", _frames_all("source_frames", [0, 1, 7])),
        ("missing", lambda c: [fr.pop("source_frames") for fr in c.job["frames"]]),
        ("[1, 0] (reversed)", _frames_all("source_frames", [1, 0])), ("[1]", _frames_all("source_frames", [1])),
        ("[0, 0]", _frames_all("source_frames", [0, 0])), ("null", _frames_all("source_frames", None)),
        ("[[0]]", _frames_all("source_frames", [[0]])),
    ]),
    ("generate settings", [(f"{k} = {name}", _set(("generate", k), v)) for k, vals in (
        ("steps", [("0", 0), ("-1", -1), ("10**9", 10 ** 9), ("10**30", 10 ** 30), ("2.5", 2.5)]),
        ("window", [("0", 0), ("-1", -1), ("10**9", 10 ** 9), ("2**63", 2 ** 63)]),
        ("overlap", [("14 (= window)", 14), ("-1", -1), ("10**9", 10 ** 9)]),
        ("decode_chunk", [("0", 0), ("10**12", 10 ** 12), ("-3", -3)]),
        ("seed", [("-1", -1), ("2**64", 2 ** 64), ("10**30", 10 ** 30), ("1.5", 1.5)]),
        ("fps", [("0", 0), ("-1", -1), ("1e300", 1e300), ("10**30", 10 ** 30), ("NaN", Raw("NaN"))]),
        ("min_guidance", [("-1", -1.0), ("1e300", 1e300), ("5 (> max 3)", 5.0), ("Infinity", Raw("Infinity"))]),
        ("max_guidance", [("0.5 (< min 1)", 0.5), ("1e300", 1e300), ("-1", -1.0)]),
        ("checkpoint", [('""', ""), ("123", 123), ('"../outside"', "../outside")]),
    ) for name, v in vals] + [("generate = []", _set(("generate",), [])),
                              ("generate = null", _set(("generate",), None))]),
    ("vggt_to_world", [
        ("1e-5 shear (slightly not a similarity)", _set(WFV, _similar(shear=1e-5))),
        ("1e-3 shear", _set(WFV, _similar(shear=1e-3))), ("singular (zeros)", _set(WFV, np.zeros((4, 4)).tolist())),
        ("scale 1e-30", _set(WFV, _similar(scale=1e-30))), ("scale 1e-10", _set(WFV, _similar(scale=1e-10))),
        ("scale 1e30", _set(WFV, _similar(scale=1e30))), ("scale 1e200", _set(WFV, _similar(scale=1e200))),
        ("scale -1", _set(WFV, _similar(scale=-1.0))), ("reflection", _set(WFV, _similar(det_sign=-1.0))),
        ("scale 1000", _set(WFV, _similar(scale=1000.0))), ("identity", _set(WFV, np.eye(4).tolist())),
        ("translation 1e30", _set_cells(WFV, {(0, 3): 1e30})), ("translation 1e300", _set_cells(WFV, {(2, 3): 1e300})),
        ("last row [0, 0, 0, 2]", _set_cells(WFV, {(3, 3): 2.0})),
        ("last row [1, 0, 0, 1]", _set_cells(WFV, {(3, 0): 1.0})),
        ("NaN entry", _set_cells(WFV, {(1, 2): Raw("NaN")})), ("3x4", _matrix_in(WFV, lambda m: m[:3].tolist())),
        ("5x5", _set(WFV, np.eye(5).tolist())),
        ("strings", _matrix_in(WFV, lambda m: [[str(v) for v in r] for r in m])),
    ]),
    ("K", [(f"frames[{f}] {d}", a) for f in (0, 1) for d, a in _k_options(("frames", f, "K"))]),
    ("world_to_camera", [(f"frames[{f}] {d}", a) for f in (0, 1)
                         for d, a in _w2c_options(("frames", f, "world_to_camera"))]),
    ("object_to_world", [(f"frame {k}: {d}", a) for k in ("1", "2")
                         for d, a in _o2w_options(("assets", 0, "object_to_world", k))] + [
        ("frame 2 missing", lambda c: c.job["assets"][0]["object_to_world"].pop("2")),
        ("extra frame '99'", lambda c: c.job["assets"][0]["object_to_world"].update({"99": np.eye(4).tolist()})),
        ("key 'x'", lambda c: c.job["assets"][0]["object_to_world"].update({"x": np.eye(4).tolist()})),
        ("a list instead of a mapping", lambda c: c.job["assets"][0].update(
            object_to_world=list(c.job["assets"][0]["object_to_world"].values()))),
        ("null", _set(("assets", 0, "object_to_world"), None)),
    ]),
    ("scene settings", [
        ("confidence_percentile 0", _set(("scene", "confidence_percentile"), 0.0)),
        ("confidence_percentile 100", _set(("scene", "confidence_percentile"), 100.0)),
        ("confidence_percentile -1", _set(("scene", "confidence_percentile"), -1.0)),
        ("confidence_percentile NaN", _set(("scene", "confidence_percentile"), Raw("NaN"))),
        ("crop [8, 0, 8, 0] (nothing left)", _set(("scene", "crop"), [8, 0, 8, 0])),
        ("crop [1, 1, 1, 1]", _set(("scene", "crop"), [1, 1, 1, 1])),
        ("crop [100000, 0, 0, 0]", _set(("scene", "crop"), [100000, 0, 0, 0])),
        ("crop [2**63, 0, 0, 0]", _set(("scene", "crop"), [2 ** 63, 0, 0, 0])),
        ('crop "auto"', _set(("scene", "crop"), "auto")),
        ('extrinsic_convention "camera_to_world"', _set(("scene", "extrinsic_convention"), "camera_to_world")),
        ('extrinsic_convention "auto"', _set(("scene", "extrinsic_convention"), "auto")),
        ("removal box size 0", _boxes([0, 0, 0])), ("removal box size 1e300", _boxes([1e300] * 3)),
        ("removal box covering everything", _boxes([1e6] * 3)), ("removal box NaN size", _boxes([Raw("NaN")] * 3)),
        ("removal box scaled matrix", _boxes([1, 1, 1], np.diag([2.0, 2, 2, 1]))),
        ("1000 removal boxes", _boxes([0.1, 0.1, 0.1], count=1000)),
        ("no scene", lambda c: c.job.pop("scene")),
    ]),
    ("labels", [
        ('class "a car" (a space)', _set(("assets", 0, "class"), "a car")),
        ('class ""', _set(("assets", 0, "class"), "")), ("class 123", _set(("assets", 0, "class"), 123)),
        ("class 100 characters", _set(("assets", 0, "class"), "c" * 100)),
        ('class "truck"', _set(("assets", 0, "class"), "truck")),
        ("box null", _set(("assets", 0, "box"), None)), ("box {}", _set(("assets", 0, "box"), {})),
        ("box size NaN", _asset_box(size=[Raw("NaN")] * 3)), ("box size 0", _asset_box(size=[0, 0, 0])),
        ("box size 1e300", _asset_box(size=[1e300] * 3)), ("box size [1, 2]", _asset_box(size=[1, 2])),
        ("box scaled matrix", _asset_box(box_to_file=np.diag([2.0, 2, 2, 1]))),
        ("box translation 1e300", _asset_box(box_to_file=np.array([[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                   [0, 0, 0, 1.0]]))),
        ("box an unknown field", _asset_box(front="+y")),
        ("fps 0", _set(("fps",), 0)), ("fps NaN", _set(("fps",), Raw("NaN"))), ("fps 1e300", _set(("fps",), 1e300)),
        ("fps 29.97", _set(("fps",), 29.97)), ('fps "24"', _set(("fps",), "24")),
        ("recorded_frames [5, 1]", _set(("scene", "recorded_frames"), [5, 1])),
        ("recorded_frames [0, 10**9]", _set(("scene", "recorded_frames"), [0, 10 ** 9])),
        ('recorded_frames "all"', _set(("scene", "recorded_frames"), "all")),
        ("recorded_frames [5, 9] (every frame outside)", _set(("scene", "recorded_frames"), [5, 9])),
        ("a recorded object", _recorded()), ("a recorded object without boxes", _recorded(boxes={})),
        ("a recorded object with frame key 'x'", _recorded(boxes={"x": np.eye(4).tolist()})),
        ("a recorded object of size -1", _recorded(size=(-1, 4, 1.5))),
        ("a recorded object with a NaN box", _recorded(boxes={"1": [[Raw("NaN")] * 4] * 4})),
        ("a recorded object 1e300 m away", _recorded(boxes={"1": [[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                  [0, 0, 0, 1]]})),
        ("a recorded object around the camera", _recorded(boxes={"1": np.eye(4).tolist()}, size=(1e6, 1e6, 1e6))),
        ("1000 recorded objects", _recorded(count=1000)),
        ("recorded objects with one id twice", _recorded(count=2, id="same")),
        ('a recorded object of class ""', _recorded(**{"class": ""})),
    ]),
    ("assets", [
        ("empty list", _set(("assets",), [])), ("no assets key", lambda c: c.job.pop("assets")),
        ("duplicate name", lambda c: c.job["assets"].append(copy.deepcopy(c.job["assets"][0]))),
        ('name ""', _set(("assets", 0, "name"), "")), ("name with a slash '../x'", _set(("assets", 0, "name"), "../x")),
        ("50 assets on the same PLY", _many_assets(50)),
        ('ply ""', _set(("assets", 0, "ply"), "")),
        ("name a lone surrogate", _set(("assets", 0, "name"), Raw('"\\udc80"'))),
        ("name 10000 characters", _set(("assets", 0, "name"), "n" * 10000)),
        ("name 123", _set(("assets", 0, "name"), 123)),
        ("two assets on one PLY", _many_assets(2)),
        ("assets = {}", _set(("assets",), {})), ("an asset = null", _set(("assets",), [None])),
        ("no object_to_world", lambda c: c.job["assets"][0].pop("object_to_world")),
        ("no ply", lambda c: c.job["assets"][0].pop("ply")), ("ply 123", _set(("assets", 0, "ply"), 123)),
        ("100 assets on the same PLY", _many_assets(100)),
    ]),
]


def _abs(rel):
    """output_dir / input path = an absolute path into the case folder (fixed at apply time)."""
    def apply(c, key):
        _get(c.job, key[:-1])[key[-1]] = c.path(rel)
    return apply


def _job_paths_plan():
    out = ("output_dir",)
    pred = ("scene", "predictions")
    ply = ("assets", 0, "ply")
    opts = [
        ('output_dir "../outside"', _set(out, "../outside")), ('output_dir "../../x"', _set(out, "../../x")),
        ('output_dir ".."', _set(out, "..")), ('output_dir "out/../../outside"', _set(out, "out/../../outside")),
        ('output_dir "../outside/conditions/.."', _set(out, "../outside/conditions/..")),
        ('output_dir "."', _set(out, ".")), ('output_dir "./out/"', _set(out, "./out/")),
        ("output_dir absolute, into outside/", lambda c: _abs("outside/abs")(c, out)),
        ("output_dir absolute, the job folder itself", lambda c: _abs("job")(c, out)),
        ('output_dir with a NUL byte', _set(out, "out\u0000x")),
        ('output_dir a lone surrogate', _set(out, Raw('"\\ud800"'))),
        ("output_dir 300 characters", _set(out, "o" * 300)),
        ("output_dir 5000 characters", _set(out, "/".join(["o" * 200] * 25))),
        ("output_dir is a file (car.ply)", _set(out, "car.ply")),
        ("out is a symlink to ../outside", lambda c: c.replace_with("job/out", "link", "../outside")),
        ("out is a symlink to an absolute outside/", lambda c: c.replace_with("job/out", "link", c.outside)),
        ("out/conditions is a symlink to ../../outside/conditions (stale frames there)",
         lambda c: c.replace_with("job/out/conditions", "link", "../../outside/conditions")),
        ("out/backend.log is a symlink to ../../outside/backend.log",
         lambda c: c.replace_with("job/out/backend.log", "link", "../../outside/backend.log")),
        ("out/conditions/job_key.txt.tmp is a symlink to outside/target/target.txt",
         lambda c: c.replace_with("job/out/conditions/job_key.txt.tmp", "link", "../../../outside/target/target.txt")),
        ("out/conditions/job_key.txt is a symlink to outside/conditions/job_key.txt",
         lambda c: c.replace_with("job/out/conditions/job_key.txt", "link", "../../../outside/conditions/job_key.txt")),
        ("out/conditions/frame_000001.exr.tmp is a symlink to outside/frame_000000.exr",
         lambda c: c.replace_with("job/out/conditions/frame_000001.exr.tmp", "link",
                                  "../../../outside/frame_000000.exr")),
        ("out/conditions/preview_000001.png is a symlink to outside/preview_000000.png",
         lambda c: c.replace_with("job/out/conditions/preview_000001.png", "link",
                                  "../../../outside/preview_000000.png")),
        ("out is a regular file", lambda c: (c.replace_with("job/out", "missing"), c.write("job/out", b"file"))),
        ("out/conditions is a FIFO", lambda c: c.replace_with("job/out/conditions", "fifo")),
    ]
    for what, key, fname in (("predictions", pred, "predictions.npz"), ("ply", ply, "car.ply")):
        rel = f"job/{fname}"
        opts += [
            (f"{what} is a FIFO", lambda c, rel=rel: c.replace_with(rel, "fifo")),
            (f"{what} is a directory", lambda c, rel=rel: c.replace_with(rel, "dir")),
            (f"{what} is /dev/zero", _set(key, "/dev/zero")),
            (f"{what} is /dev/null", _set(key, "/dev/null")),
            (f"{what} is a symlink to ../outside/{fname}",
             lambda c, rel=rel, fname=fname: c.replace_with(rel, "link", f"../outside/{fname}")),
            (f"{what} is a dangling symlink", lambda c, rel=rel: c.replace_with(rel, "link", "nowhere.bin")),
            (f"{what} is a symlink loop", lambda c, rel=rel: c.replace_with(rel, "link", os.path.basename(rel))),
            (f"{what} is missing", lambda c, rel=rel: c.replace_with(rel, "missing")),
            (f'{what} "../outside/{fname}"', _set(key, f"../outside/{fname}")),
            (f"{what} absolute, outside/{fname}", lambda c, key=key, fname=fname: _abs(f"outside/{fname}")(c, key)),
            (f'{what} "missing.bin"', _set(key, "missing.bin")),
            (f"{what} with a NUL byte", _set(key, fname + "\u0000")),
            (f"{what} 5000 characters", _set(key, "p" * 5000)),
            (f'{what} "." (the job folder)', _set(key, ".")),
            (f"{what} is job.json", _set(key, "job.json")),
        ]
    return _choice_plan("paths", opts)


def _whole_job_file():
    def text(c):
        return to_json(c.job)

    def raw(fn):
        def apply(c):
            data = fn(c)
            c.job = None
            c.write("job/job.json", data)
        return apply

    def truncated(rng, base):
        n = rng.randrange(0, len(to_json(base.job)))
        return f"truncated at byte {n}", raw(lambda c: text(c).encode()[:n])

    def random_bytes(rng, base):
        n = rng.choice([1, 7, 100, 4096])
        data = bytes(rng.randrange(256) for _ in range(n))
        return f"{n} random bytes ({zlib.crc32(data):08x})", raw(lambda c: data)

    def flipped(rng, base):
        k = rng.randrange(1, 6)
        seed = rng.randrange(2 ** 32)

        def fn(c):
            r = random.Random(seed)
            b = bytearray(text(c).encode())
            for _ in range(k):
                b[r.randrange(len(b))] = r.randrange(256)
            return bytes(b)
        return f"{k} random bytes overwritten", raw(fn)

    fixed = [
        ("empty", raw(lambda c: b"")), ("UTF-16 with BOM", raw(lambda c: text(c).encode("utf-16"))),
        ("UTF-8 with BOM", raw(lambda c: b"\xef\xbb\xbf" + text(c).encode())),
        ("not UTF-8 (latin-1 name)", raw(lambda c: text(c).replace('"car"', '"caf\u00e9"', 1).encode("latin-1"))),
        ("10 MB of '['", raw(lambda c: b"[" * (10 << 20))),
        ("10000 nested objects", raw(lambda c: b'{"a":' * 10000 + b"1" + b"}" * 10000)),
        ("a top-level list", raw(lambda c: b"[" + text(c).encode() + b"]")), ("null", raw(lambda c: b"null")),
        ("a number", raw(lambda c: b"42")), ("trailing garbage", raw(lambda c: text(c).encode() + b" }{ x")),
        ("1 MB of whitespace first", raw(lambda c: b" " * (1 << 20) + text(c).encode())),
        ("a NUL byte inside", raw(lambda c: text(c).encode().replace(b'"out"', b'"o\x00ut"'))),
        ("duplicate keys (the last wins)", raw(lambda c: text(c).encode()[:-1] + b', "output_dir": "out"}')),
        ("a FIFO", lambda c: (setattr(c, "job", None), c.replace_with("job/job.json", "fifo"))),
        ("a directory", lambda c: (setattr(c, "job", None), c.replace_with("job/job.json", "dir"))),
        ("missing", lambda c: (setattr(c, "job", None), c.replace_with("job/job.json", "missing"))),
        ("a symlink to ../outside/job.json", lambda c: (setattr(c, "job", None),
                                                        c.replace_with("job/job.json", "link", "../outside/job.json"))),
        ("the PLY's bytes", raw(lambda c: c.base.ply)), ("the npz's bytes", raw(lambda c: c.base.npz_stored)),
        ("steps 1e99999999 (beyond float64)",
         raw(lambda c: text(c).replace('"steps": 2', '"steps": 1e99999999').encode())),
    ]
    return _choice_plan("whole file", fixed + [truncated, random_bytes, flipped] * 3)


#: (plan, weight): a family with weight w gets w slots in every round of the schedule (see make_case)
JOB_FAMILIES = ([(_job_structural("delete"), 2), (_job_structural("leaf"), 2), (_job_structural("field"), 2),
                 (_job_wrong_length, 1)]
                + [(_choice_plan(name, opts), 2 if name == "labels" else 1) for name, opts in JOB_SEMANTIC]
                + [(_job_paths_plan(), 4), (_whole_job_file(), 2)])


# ---------------------------------------------------------------------------------------------- mutations: npz

def npy_bytes(a, allow_pickle=True) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asanyarray(a), allow_pickle=allow_pickle)
    return buf.getvalue()


def make_zip(members, deflate: bool) -> bytes:
    """A zip of [(name, bytes)] as numpy writes one (fixed dates; stored or deflated)."""
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, data in members:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            zf.writestr(info, data)
    return buf.getvalue()


def zip_members(data: bytes):
    """[(info, data offset)] of a zip's members."""
    out = []
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        for info in zf.infolist():
            name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26:info.header_offset + 30])
            out.append((info, info.header_offset + 30 + name_len + extra_len))
    return out


def with_npy_header(member: bytes, header_text: str, magic=b"\x93NUMPY", version=b"\x01\x00") -> bytes:
    """An .npy member with its header replaced (padded to 64 bytes as numpy does), the data kept."""
    hlen = struct.unpack("<H", member[8:10])[0]
    data = member[10 + hlen:]
    text = header_text.encode("latin-1")
    pad = (64 - (10 + len(text) + 1) % 64) % 64
    text = text + b" " * pad + b"\n"
    return magic + version + struct.pack("<H", len(text)) + text + data


def _header_dict(a) -> str:
    return repr({"descr": np.lib.format.dtype_to_descr(a.dtype), "fortran_order": False, "shape": a.shape})


class NpzCase:
    """What an npz mutation changes: arrays (re-saved with the case's compression) or the archive's bytes."""

    def __init__(self, base: Base, deflate: bool):
        self.base, self.deflate = base, deflate
        self.arrays = dict(base.arrays)

    def members(self, arrays=None):
        return [(f"{k}.npy", npy_bytes(v)) for k, v in (arrays or self.arrays).items()]

    def archive(self, arrays=None) -> bytes:
        return make_zip(self.members(arrays), self.deflate)

    def original(self) -> bytes:
        """The archive numpy itself wrote (np.savez / np.savez_compressed), for byte-level damage."""
        return self.base.npz_deflated if self.deflate else self.base.npz_stored


def _npz_plan(family, make):
    """``make(rng, n: NpzCase) -> (detail, fn(n) -> bytes)``; the bytes become predictions.npz."""
    def plan(rng, base):
        deflate = rng.random() < 0.5
        detail, fn = make(rng, NpzCase(base, deflate))

        def apply(c):
            c.write("job/predictions.npz", fn(NpzCase(c.base, deflate)))
        return f"{family}: {detail} ({'deflated' if deflate else 'stored'})", apply
    return plan


KEYS = ("images", "depth", "depth_conf", "extrinsic", "intrinsic", "world_points", "world_points_conf")


def _npz_rename(rng, n):
    key = rng.choice(KEYS)
    new = rng.choice([key, key + ".npz", key.upper() + ".npy", key + ".NPY", key + ".npy.npy", "dir/" + key + ".npy",
                      "../" + key + ".npy", "/" + key + ".npy", key + ".npy\u00e9"])
    return f"member {key}.npy renamed {new!r}", lambda n: make_zip(
        [(new if name == key + ".npy" else name, d) for name, d in n.members()], n.deflate)


def _npz_flip(rng, n):
    key = rng.choice(KEYS)
    info, start = next((i, s) for i, s in zip_members(n.original()) if i.filename == key + ".npy")
    lo = start if n.deflate else start + 128          # stored: flip data bytes, not the .npy header
    flips = sorted((rng.randrange(lo, start + info.compress_size), 1 + rng.randrange(255))
                   for _ in range(rng.randrange(1, 9)))

    def fn(n):
        data = bytearray(n.original())
        for at, x in flips:
            data[at] ^= x
        return bytes(data)
    return f"{len(flips)} bytes flipped in {key}.npy at {[a - start for a, _ in flips]} (CRC not fixed)", fn


def _npz_header(rng, n):
    key = rng.choice(KEYS)
    a = n.arrays[key]
    d = _header_dict(a)
    variants = [
        ("garbage dict", lambda m: with_npy_header(m, "{'descr': 'xyz', 'what': [1, 2")),
        ("not a dict", lambda m: with_npy_header(m, "hello world")),
        ("wrong magic", lambda m: with_npy_header(m, d, magic=b"\x93NUMPX")),
        ("version 9.9", lambda m: with_npy_header(m, d, version=b"\x09\x09")),
        ("version 0.0", lambda m: with_npy_header(m, d, version=b"\x00\x00")),
        ("version 3.0 with a v1 header", lambda m: with_npy_header(m, d, version=b"\x03\x00")),
        ("header length past the member", lambda m: m[:8] + struct.pack("<H", 65535) + m[10:]),
        ("no 'shape'", lambda m: with_npy_header(m, repr({"descr": "<f4", "fortran_order": False}))),
        ("descr '<x9'", lambda m: with_npy_header(m, d.replace("'<f4'", "'<x9'"))),
        ("descr '<f8' (twice the bytes)", lambda m: with_npy_header(m, d.replace("'<f4'", "'<f8'"))),
        ("descr '|O' (pickle)", lambda m: with_npy_header(m, d.replace("'<f4'", "'|O'"))),
        ("descr '<c8'", lambda m: with_npy_header(m, d.replace("'<f4'", "'<c8'"))),
        ("negative shape", lambda m: with_npy_header(m, repr({"descr": "<f4", "fortran_order": False,
                                                              "shape": (-1,) + a.shape[1:]}))),
        ("fortran_order True", lambda m: with_npy_header(m, d.replace("False", "True"))),
        ("fortran_order 'x'", lambda m: with_npy_header(m, d.replace("False", "'x'"))),
        ("shape of strings", lambda m: with_npy_header(m, repr({"descr": "<f4", "fortran_order": False,
                                                                "shape": ("2", "3")}))),
        ("header only (no data)", lambda m: with_npy_header(m, d)[:128]),
    ]
    detail, f = rng.cycle(variants)

    def fn(n):
        return make_zip([(name, f(m) if name == key + ".npy" else m) for name, m in n.members()], n.deflate)
    return f"{key}.npy {detail}", fn


def _npz_claims_more(rng, n):
    key = rng.choice(KEYS)
    a = n.arrays[key]
    if not n.deflate and rng.random() < 0.5:
        # numpy's own stored archive, the shape patched in place (same length: every digit of the first axis a 9):
        # the member's CRC no longer matches either
        old = repr(a.shape)
        first = old[1:].split(",")[0]
        new = "(" + "9" * len(first) + old[1 + len(first):]

        def fn(n):
            data = bytearray(n.original())
            info, start = next((i, s) for i, s in zip_members(bytes(data)) if i.filename == key + ".npy")
            head = bytes(data[start:start + 128])
            at = head.index(old.encode())
            data[start + at:start + at + len(old)] = new.encode()
            return bytes(data)
        return f"{key}.npy shape {new} for {a.shape} patched in place (CRC not fixed)", fn
    axis = rng.randrange(a.ndim)
    factor = rng.cycle([2, 1000, 10 ** 6, 10 ** 15])
    shape = list(a.shape)
    shape[axis] = shape[axis] * factor if factor < 10 ** 15 else factor
    text = repr({"descr": np.lib.format.dtype_to_descr(a.dtype), "fortran_order": False, "shape": tuple(shape)})
    return f"{key}.npy shape {tuple(shape)} for {a.shape} (CRC fixed)", lambda n: make_zip(
        [(name, with_npy_header(m, text) if name == key + ".npy" else m) for name, m in n.members()], n.deflate)


def _npz_claims_less(rng, n):
    key = rng.choice(KEYS)
    a = n.arrays[key]
    shape = (1,) + a.shape[1:]
    text = repr({"descr": np.lib.format.dtype_to_descr(a.dtype), "fortran_order": False, "shape": shape})
    return f"{key}.npy shape {shape}, data for {a.shape}", lambda n: make_zip(
        [(name, with_npy_header(m, text) if name == key + ".npy" else m) for name, m in n.members()], n.deflate)


def _npz_arrays(family, variants):
    """variants: [(detail, fn(arrays dict) -> arrays dict)]."""
    def make(rng, n):
        detail, f = rng.cycle(variants)
        return detail, lambda n: n.archive(f(dict(n.arrays)))
    return _npz_plan(family, make)


def _set_key(key, fn):
    def f(arrays):
        arrays[key] = fn(arrays[key])
        return arrays
    return f


def _zero_frames(arrays):
    return {k: v[:0] for k, v in arrays.items()}


def _nan_variants():
    out = []
    for key in KEYS:
        for what, val in (("NaN", np.nan), ("inf", np.inf), ("-inf", -np.inf)):
            for where in ("one value", "frame 0", "everything"):
                def fn(a, val=val, where=where):
                    a = np.array(a, np.float32)
                    if where == "one value":
                        a.flat[a.size // 2] = val
                    elif where == "frame 0":
                        a[0] = val
                    else:
                        a[...] = val
                    return a
                out.append((f"{key} {what} in {where}", _set_key(key, fn)))
    return out


def _dtype_variants():
    out = []
    for key in KEYS:
        for name, fn in (
                ("object", lambda a: np.array(a.tolist(), dtype=object)),
                ("complex64", lambda a: a.astype(np.complex64)), ("<U8 strings", lambda a: a.astype("<U8")),
                ("bytes S4", lambda a: a.astype("S4")), ("bool", lambda a: a.astype(bool)),
                ("int8", lambda a: a.astype(np.int8)),
                ("uint8 0-255", lambda a: (np.clip(a, 0, 1) * 255).astype(np.uint8)),
                ("float16", lambda a: a.astype(np.float16)), ("float64", lambda a: a.astype(np.float64)),
                ("int64", lambda a: a.astype(np.int64)), ("big-endian >f4", lambda a: a.astype(">f4")),
                ("datetime64", lambda a: a.astype(np.int64).astype("datetime64[s]")),
                ("void V4", lambda a: np.ascontiguousarray(a).view("V4")),
                ("structured", lambda a: np.ascontiguousarray(a).view([("v", "<f4")])),
                ("timedelta64", lambda a: a.astype(np.int64).astype("timedelta64[s]"))):
            out.append((f"{key} as {name}", _set_key(key, fn)))
    return out


def _shape_variants():
    out = []
    for key in KEYS:
        for name, fn in (
                ("one axis more", lambda a: a[None]), ("one axis less", lambda a: a[0]),
                ("flattened", lambda a: a.reshape(-1)), ("a scalar", lambda a: np.float32(1.0)),
                ("transposed", lambda a: np.ascontiguousarray(a.T)),
                ("one more frame", lambda a: np.concatenate([a, a[:1]])),
                ("one frame less", lambda a: a[:1]), ("width 1", lambda a: a[..., :1] if a.ndim >= 3 else a),
                ("an empty (0,) array", lambda a: np.zeros((0,), np.float32)),
                ("5 batch axes", lambda a: a.reshape((1,) * 5 + a.shape)),
                ("100 frames", lambda a: np.repeat(a[:1], 100, axis=0))):
            out.append((f"{key} {name}", _set_key(key, fn)))
    return out


def _value_variants():
    def rot_scale(a):
        a = np.array(a)
        a[:, :3, :3] *= 2
        return a

    def intr(fx):
        def fn(a):
            a = np.array(a)
            a[:, 0, 0] = fx
            return a
        return fn
    return [
        ("depth all zero", _set_key("depth", np.zeros_like)), ("depth negative", _set_key("depth", lambda a: -a)),
        ("depth 1e30", _set_key("depth", lambda a: np.full_like(a, 1e30))),
        ("depth 3e38", _set_key("depth", lambda a: np.full_like(a, 3e38))),
        ("depth 1e-30", _set_key("depth", lambda a: np.full_like(a, 1e-30))),
        ("depth_conf negative", _set_key("depth_conf", lambda a: -a)),
        ("depth_conf all equal", _set_key("depth_conf", np.ones_like)),
        ("images 0-255", _set_key("images", lambda a: a * 255)), ("images negative", _set_key("images", lambda a: -a)),
        ("extrinsic scaled rotation", _set_key("extrinsic", rot_scale)),
        ("extrinsic zeros", _set_key("extrinsic", np.zeros_like)),
        ("extrinsic translation 1e30",
         _set_key("extrinsic", lambda a: np.concatenate([a[..., :3], np.full_like(a[..., 3:], 1e30)], -1))),
        ("intrinsic zero focal", _set_key("intrinsic", intr(0.0))),
        ("intrinsic negative focal", _set_key("intrinsic", intr(-30.0))),
        ("intrinsic focal 1e-30", _set_key("intrinsic", intr(1e-30))),
        ("intrinsic focal 1e30", _set_key("intrinsic", intr(1e30))),
        ("intrinsic zeros", _set_key("intrinsic", np.zeros_like)),
        ("world_points 1e30", _set_key("world_points", lambda a: np.full_like(a, 1e30))),
        ("extrinsic of 3 frames, images of 2", _set_key("extrinsic", lambda a: np.concatenate([a, a[:1]]))),
        ("one frame, squeezed (S = 1, no frame axis)", lambda arr: {k: v[0] for k, v in arr.items()}),
        ("one frame (S = 1)", lambda arr: {k: v[:1] for k, v in arr.items()}),
        ("images (S, H, W, 3) layout", _set_key("images", lambda a: np.ascontiguousarray(np.moveaxis(a, 1, -1)))),
        ("images with 4 channels", _set_key("images", lambda a: np.concatenate([a, a[:, :1]], 1))),
        ("images 1 channel", _set_key("images", lambda a: a[:, :1])),
    ]


def _npz_keys(rng, n):
    extras = [("foo", np.zeros(3)), ("images_2", np.zeros((2, 2))), ("pickle", np.array([{}], dtype=object)),
              ("big", np.zeros((64, 64, 64), np.float32))]
    options = ([(f"key {k} missing", lambda n, k=k: n.archive({x: v for x, v in n.arrays.items() if x != k}))
                for k in KEYS]
               + [(f"extra key {name!r}",
                   lambda n, name=name, a=a: make_zip(n.members() + [(name + ".npy", npy_bytes(a))], n.deflate))
                  for name, a in extras]
               + [(f"member {k}.npy twice (the second empty)", lambda n, k=k: make_zip(
                   n.members() + [(k + ".npy", npy_bytes(np.zeros((0,), np.float32)))], n.deflate)) for k in KEYS[:4]]
               + [("only world_points and world_points_conf", lambda n: n.archive(
                   {k: v for k, v in n.arrays.items() if k.startswith("world")})),
                  ("no members at all", lambda n: make_zip([], n.deflate)),
                  ("every key upper case", lambda n: n.archive({k.upper(): v for k, v in n.arrays.items()}))])
    return rng.cycle(options)


def _npz_whole(rng, n):
    pick = rng.randrange(12)
    if pick < 4:
        cut = rng.random()
        return f"truncated at {cut:.3f} of its length", lambda n: (lambda b: b[:int(len(b) * cut)])(n.original())
    options = [
        ("a single .npy (images)", lambda n: npy_bytes(n.arrays["images"])),
        ("empty", lambda n: b""), ("1000 random bytes", lambda n: random.Random(7).randbytes(1000)),
        ("a zip with one text member", lambda n: make_zip([("readme.txt", b"hello")], n.deflate)),
        ("the PLY's bytes", lambda n: n.base.ply),
        ("a pickle", lambda n: b"\x80\x04\x95\x05\x00\x00\x00\x00\x00\x00\x00K\x01."),
        ("zip end record only", lambda n: n.original()[-22:]),
        ("two archives concatenated", lambda n: n.original() + n.original()),
    ]
    detail, fn = rng.cycle(options)
    return detail, fn


def _central_record(data: bytes, name: str) -> int:
    """Offset of ``name``'s central-directory record."""
    pos = data.find(b"PK\x01\x02")
    while pos >= 0:
        nlen = struct.unpack("<H", data[pos + 28:pos + 30])[0]
        if data[pos + 46:pos + 46 + nlen] == name.encode():
            return pos
        pos = data.find(b"PK\x01\x02", pos + 4)
    raise KeyError(name)


def _npz_zip_flags(rng, n):
    key = rng.choice(KEYS)
    what = rng.cycle(["encrypted flag", "compression method 99", "compression method 12 (bzip2)",
                      "compression method 14 (lzma)", "size 0 in the central directory",
                      "local header offset past the end"])

    def fn(n):
        data = bytearray(n.original())
        info, _ = next((i, s) for i, s in zip_members(bytes(data)) if i.filename == key + ".npy")
        local, cd = info.header_offset, _central_record(bytes(data), key + ".npy")
        if what == "encrypted flag":
            data[local + 6] |= 1
            data[cd + 8] |= 1
        elif what.startswith("compression method"):
            method = int(what.split()[2])
            data[local + 8:local + 10] = struct.pack("<H", method)
            data[cd + 10:cd + 12] = struct.pack("<H", method)
        elif what.startswith("size 0"):
            data[cd + 20:cd + 28] = struct.pack("<II", 0, 0)
        else:
            data[cd + 42:cd + 46] = struct.pack("<I", 0x7FFFFFF0)
        return bytes(data)
    return f"{key}.npy {what}", fn


def _npz_special(rng, base):
    p = "job/predictions.npz"
    options = [
        ("a FIFO", lambda c: c.replace_with(p, "fifo")), ("a directory", lambda c: c.replace_with(p, "dir")),
        ("an empty directory", lambda c: (c.replace_with(p, "missing"), os.makedirs(c.path(p)))),
        ("a symlink to ../outside/predictions.npz", lambda c: c.replace_with(p, "link", "../outside/predictions.npz")),
        ("a symlink to /dev/zero", lambda c: c.replace_with(p, "link", "/dev/zero")),
        ("a symlink to /dev/urandom", lambda c: c.replace_with(p, "link", "/dev/urandom")),
        ("a symlink to a directory", lambda c: c.replace_with(p, "link", "../outside/target")),
        ("a symlink loop", lambda c: c.replace_with(p, "link", "predictions.npz")),
        ("a dangling symlink", lambda c: c.replace_with(p, "link", "nowhere.npz")),
        ("a symlink to car.ply", lambda c: c.replace_with(p, "link", "car.ply")),
        ("a hard link to ../outside/predictions.npz",
         lambda c: (c.replace_with(p, "missing"), os.link(c.path("outside/predictions.npz"), c.path(p)))),
        ("missing", lambda c: c.replace_with(p, "missing")),
        ("a FIFO inside a symlinked folder", lambda c: (os.mkfifo(c.path("outside/target/p.npz")),
                                                        c.replace_with(p, "link", "../outside/target/p.npz"))),
    ]
    detail, apply = rng.cycle(options)
    return f"special file: {detail}", apply


NPZ_FAMILIES = [
    (_npz_plan("member renamed", _npz_rename), 1), (_npz_plan("corrupt member data", _npz_flip), 2),
    (_npz_plan("broken .npy header", _npz_header), 2), (_npz_plan("header claims more", _npz_claims_more), 2),
    (_npz_plan("header claims less", _npz_claims_less), 1),
    (_npz_arrays("dtype", _dtype_variants()), 2), (_npz_arrays("NaN/inf", _nan_variants()), 2),
    (_npz_arrays("shape", _shape_variants() + [("S = 0 in every array", _zero_frames)] * 3), 2),
    (_npz_arrays("values", _value_variants()), 2),
    (_npz_plan("keys", _npz_keys), 1), (_npz_plan("whole file", _npz_whole), 1),
    (_npz_plan("zip header", _npz_zip_flags), 1), (_npz_special, 1),
]


# ---------------------------------------------------------------------------------------------- mutations: PLY

def ply_bytes(lines, data: bytes, newline="\n") -> bytes:
    return (newline.join(lines) + newline).encode("utf-8") + data


def _ply_end_header_comment(rng, base):
    text = rng.cycle(["comment written by x end_header y", "comment end_header", "obj_info end_header",
                       "comment xend_headerx", "comment end_header\x0bz", "comment  end_header  ",
                       "comment made by tool v1 (writes end_header after the properties)"])
    # a comment usually sits near the top; one after the properties is what a reader that looks for the first
    # "end_header" misreads without noticing
    where = rng.choice([2, 3, rng.randrange(4, len(base.ply_header) - 1)] + [len(base.ply_header) - 1] * 3)
    lines = base.ply_header[:where] + [text] + base.ply_header[where:]
    return f"{text!r} at header line {where + 1}", lambda b: ply_bytes(lines, b.ply_data)


def _ply_truncated(rng, base):
    n = rng.randrange(0, len(base.ply))
    return f"truncated at byte {n} of {len(base.ply)}", lambda b: b.ply[:n]


def _ply_count(rng, base):
    count = rng.cycle([N_GAUSSIANS + 1, N_GAUSSIANS - 1, 2 * N_GAUSSIANS, 0, N_GAUSSIANS + 1000, 10 ** 15,
                        10 ** 14, 999999999999999, 10 ** 16, 2 ** 63, -1, "1e3", "0x14", "20.0", "",
                        2 ** 31, 2 ** 32, 2 ** 64, "+20", "020", "20 20", "٢٠ (Arabic-Indic digits)"])
    lines = [f"element vertex {count}" if line.startswith("element vertex") else line for line in base.ply_header]
    return f"element vertex {count} ({N_GAUSSIANS} in the data)", lambda b: ply_bytes(lines, b.ply_data)


_PLY_NP = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4",
           "double": "f8", "float32": "f4", "float64": "f8", "int8": "i1", "uint8": "u1"}


def _retyped(base, types: dict, order="<"):
    """Header lines and data with some properties stored as other PLY types (values cast)."""
    lines = []
    for line in base.ply_header:
        w = line.split()
        if w[0] == "property" and w[2] in types:
            line = f"property {types[w[2]]} {w[2]}"
        lines.append(line)
    dt = np.dtype([(p, order + _PLY_NP[types.get(p, "float")]) for p in base.ply_props])
    rec = np.empty(len(base.ply_records), dt)
    with np.errstate(all="ignore"):
        for p in base.ply_props:
            rec[p] = base.ply_records[p]
    return lines, rec.tobytes()


def _ply_retype(rng, base):
    t = rng.cycle(["uchar", "char", "short", "ushort", "int", "uint", "double", "float64", "uint8"])
    props = rng.choice([[rng.choice(base.ply_props)], base.ply_props])
    lines, data = _retyped(base, {p: t for p in props})
    what = props[0] if len(props) == 1 else "every property"
    return f"{what} stored as {t}", lambda b: ply_bytes(lines, data), t in ("double", "float64")


def _ply_list(rng, base):
    p = rng.choice(base.ply_props)
    lines = [f"property list uchar float {p}" if line.split()[-1] == p and line.startswith("property") else line
             for line in base.ply_header]
    i = base.ply_props.index(p)
    dt = np.dtype([(q, "<f4") for q in base.ply_props[:i]] + [("n", "u1"), (p, "<f4")]
                  + [(q, "<f4") for q in base.ply_props[i + 1:]])
    rec = np.empty(len(base.ply_records), dt)
    rec["n"] = 1
    for q in base.ply_props:
        rec[q] = base.ply_records[q]
    return f"{p} a list property (one float each)", lambda b: ply_bytes(lines, rec.tobytes())


def _ply_rewrite(rng, base):
    """The same Gaussians written another valid way: a reader must give exactly the original values."""
    hdr, rec = base.ply_header, base.ply_records

    def fmt(name):
        return [("format " + name + " 1.0" if x.startswith("format") else x) for x in hdr]

    def ascii_rows(f, nl="\n"):
        return (nl.join(" ".join(f(float(v)) for v in r) for r in rec.tolist()) + nl).encode()

    def shuffled(r):
        order = list(base.ply_props)
        r.shuffle(order)
        lines = hdr[:3] + [f"property float {p}" for p in order] + ["end_header"]
        data = np.empty(len(rec), [(p, "<f4") for p in order])
        for p in order:
            data[p] = rec[p]
        return f"properties in the order {' '.join(order[:4])} ...", (lambda b: ply_bytes(lines, data.tobytes()))

    def with_extras():
        lines = hdr[:3] + ["property float nx", "property float ny", "property float nz"] + hdr[3:-1] + \
            ["property uchar label", "end_header"]
        dt = [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")] + [(p, "<f4") for p in base.ply_props] + [("label", "u1")]
        data = np.zeros(len(rec), dt)
        for p in base.ply_props:
            data[p] = rec[p]
        return "normals and a uchar label as extra properties", (lambda b: ply_bytes(lines, data.tobytes()))

    big = rec.astype(rec.dtype.newbyteorder(">")).tobytes()
    doubles_be = _retyped(base, {p: "double" for p in base.ply_props}, ">")
    options = [
        ("ASCII (repr)", lambda b: ply_bytes(fmt("ascii"), ascii_rows(repr))),
        ("ASCII (%.9e)", lambda b: ply_bytes(fmt("ascii"), ascii_rows(lambda v: f"{v:.9e}"))),
        ("ASCII with CRLF", lambda b: ply_bytes(fmt("ascii"), ascii_rows(repr, "\r\n"), "\r\n")),
        ("big-endian", lambda b: ply_bytes(fmt("binary_big_endian"), big)),
        ("big-endian doubles", lambda b: ply_bytes([x.replace("binary_little_endian", "binary_big_endian")
                                                    for x in doubles_be[0]], doubles_be[1])),
        ("obj_info and comment lines between the properties",
         lambda b: ply_bytes(hdr[:5] + ["obj_info made by hand", "comment between"] + hdr[5:], b.ply_data)),
        ("format version 1.1", lambda b: ply_bytes([x.replace(" 1.0", " 1.1") for x in hdr], b.ply_data)),
        ("trailing spaces on every header line", lambda b: ply_bytes([x + "  " for x in hdr], b.ply_data)),
        with_extras(), lambda r: shuffled(r), lambda r: shuffled(r),
    ]
    got = rng.cycle(options)
    detail, fn = got(rng) if callable(got) else got
    return detail, fn, True


def _ply_header_bytes(rng, base):
    end = base.ply.index(b"end_header")
    changes = sorted((rng.randrange(end + 10), rng.randrange(256)) for _ in range(rng.randrange(1, 6)))

    def fn(b):
        data = bytearray(b.ply)
        for at, value in changes:
            data[at] = value
        return bytes(data)
    return f"{len(changes)} header bytes overwritten: {', '.join(f'{a}={v:#04x}' for a, v in changes)}", fn


def _ply_line_endings(rng, base):
    which = rng.cycle(["no newline after end_header", "CRLF line endings", "CR line endings",
                        "'end_header ' with a trailing space", "tabs between words", "double spaces between words",
                        "a blank line in the header", "CRLF only after end_header", "leading spaces on every line",
                        "a form feed in a comment", "LF CR line endings"])
    lines = list(base.ply_header)
    if which == "no newline after end_header":
        return which, (lambda b: ("\n".join(lines)).encode() + b.ply_data), True
    if which == "CRLF line endings":
        return which, (lambda b: ply_bytes(lines, b.ply_data, "\r\n")), True
    if which == "CR line endings":
        return which, (lambda b: ply_bytes(lines, b.ply_data, "\r")), True
    if which == "LF CR line endings":   # the CR after end_header's LF is a data byte: not the same Gaussians
        return which, (lambda b: ply_bytes(lines, b.ply_data, "\n\r")), False
    if which == "CRLF only after end_header":
        return which, (lambda b: ply_bytes(lines[:-1], b"") + b"end_header\r\n" + b.ply_data), True
    if which == "leading spaces on every line":
        return which, (lambda b: ply_bytes([" " + x for x in lines], b.ply_data)), True
    if which == "a form feed in a comment":
        return which, (lambda b: ply_bytes(lines[:2] + ["comment a\x0cb"] + lines[2:], b.ply_data)), True
    if which.startswith("'end_header '"):
        lines[-1] = "end_header "
    elif which == "tabs between words":
        lines = [line.replace(" ", "\t") for line in lines]
    elif which == "double spaces between words":
        lines = [line.replace(" ", "  ") for line in lines]
    else:
        lines.insert(2, "")
    return which, (lambda b: ply_bytes(lines, b.ply_data)), True


def _ply_many_comments(rng, base):
    n = rng.cycle([100, 300, 1000, 1500, 1900, 2000, 3000, 5000, 20000, 50000, 100000])
    lines = base.ply_header[:2] + [f"comment line {i:06d} of a long header" for i in range(n)] + base.ply_header[2:]
    return f"{n} comment lines (~{n * 34 // 1024} KB header)", lambda b: ply_bytes(lines, b.ply_data), True


def _ply_values(rng, base):
    col = rng.choice(["x", "opacity", "scale_0", "rot_0", "f_dc_0", "f_rest_3", "all rot", "all scale"])
    val = rng.cycle([("NaN", np.nan), ("inf", np.inf), ("-inf", -np.inf), ("0", 0.0), ("1e30", 1e30),
                      ("100", 100.0), ("-100", -100.0), ("3e38", 3e38), ("1e-45", 1e-45)])
    rows = rng.choice(["row 0", "every row"])

    def fn(b):
        rec = b.ply_records.copy()
        groups = {"all rot": [f"rot_{i}" for i in range(4)], "all scale": [f"scale_{i}" for i in range(3)]}
        cols = groups.get(col, [col])
        for cname in cols:
            if rows == "row 0":
                rec[cname][0] = val[1]
            else:
                rec[cname][:] = val[1]
        return ply_bytes(b.ply_header, rec.tobytes())
    return f"{col} = {val[0]} in {rows}", fn


def _ply_duplicate(rng, base):
    p = rng.choice(base.ply_props)
    lines = list(base.ply_header)
    i = next(j for j, line in enumerate(lines) if line.startswith("property") and line.split()[2] == p)
    lines.insert(i + 1, lines[i])
    dt = np.dtype([(f"c{j}", "<f4") for j in range(len(base.ply_props) + 1)])
    rec = np.empty(len(base.ply_records), dt)
    i = base.ply_props.index(p)
    for j, q in enumerate(base.ply_props[:i + 1] + [p] + base.ply_props[i + 1:]):
        rec[f"c{j}"] = base.ply_records[q]
    return f"property {p} twice", lambda b: ply_bytes(lines, rec.tobytes())


def _ply_missing_prop(rng, base):
    p = rng.choice(base.ply_props)
    keep = [q for q in base.ply_props if q != p]
    lines = [line for line in base.ply_header if not (line.startswith("property") and line.split()[2] == p)]
    rec = np.empty(len(base.ply_records), [(q, "<f4") for q in keep])
    for q in keep:
        rec[q] = base.ply_records[q]
    return f"property {p} missing", lambda b: ply_bytes(lines, rec.tobytes())


def _line(start, new):
    """Header lines with the line that starts with ``start`` replaced by ``new``."""
    return lambda lines: [(new if x.startswith(start) else x) for x in lines]


def _ply_malformed_line(rng, base):
    options = [
        ("'property float' (no name)", lambda lines: lines[:3] + ["property float"] + lines[3:]),
        ("'element vertex' (no count)", _line("element vertex", "element vertex")),
        ("'format binary_little_endian' (no version)", _line("format", "format binary_little_endian")),
        ("format version 2.0", _line("format", "format binary_little_endian 2.0")),
        ("format 'binary_middle_endian'", _line("format", "format binary_middle_endian 1.0")),
        ("no format line", lambda lines: [x for x in lines if not x.startswith("format")]),
        ("two format lines", lambda lines: lines[:2] + ["format binary_big_endian 1.0"] + lines[2:]),
        ("unknown keyword 'foo bar'", lambda lines: lines[:2] + ["foo bar"] + lines[2:]),
        ("property before any element", lambda lines: lines[:2] + ["property float q"] + lines[2:]),
        ("type 'float128'", lambda lines: [x.replace("property float x", "property float128 x") for x in lines]),
        ("type 'half'", lambda lines: [x.replace("property float opacity", "property half opacity") for x in lines]),
        ("a non-ASCII comment", lambda lines: lines[:2] + ["comment caf\u00e9"] + lines[2:]),
        ("a NUL in a comment", lambda lines: lines[:2] + ["comment a\u0000b"] + lines[2:]),
        ("'PLY' upper case", lambda lines: ["PLY"] + lines[1:]),
        ("'ply ' with a trailing space", lambda lines: ["ply "] + lines[1:]),
        ("property name 'end_header_x' (extra)", lambda lines: lines),
        ("'element vertex 20 20'", lambda lines: [(x + " 20" if x.startswith("element vertex") else x) for x in lines]),
        ("'property float x y'", _line("property float x", "property float x y")),
        ("'property list uchar' (short)", lambda lines: lines[:-1] + ["property list uchar", "end_header"]),
        ("'comment' alone", lambda lines: lines[:2] + ["comment"] + lines[2:]),
        ("'obj_info' alone", lambda lines: lines[:2] + ["obj_info"] + lines[2:]),
        ("end_header twice", lambda lines: lines + ["end_header"]),
        ("format ascii with binary data", _line("format", "format ascii 1.0")),
    ]
    detail, fn = rng.cycle(options)
    if detail.startswith("property name"):
        lines = base.ply_header[:-1] + ["property float end_header_x", "end_header"]
        rec = np.empty(len(base.ply_records), [(q, "<f4") for q in base.ply_props] + [("e", "<f4")])
        for q in base.ply_props:
            rec[q] = base.ply_records[q]
        rec["e"] = 1.0
        return detail, (lambda b: ply_bytes(lines, rec.tobytes())), True
    lines = fn(list(base.ply_header))
    same = detail in ("format version 2.0", "a non-ASCII comment", "a NUL in a comment", "'ply ' with a trailing space",
                      "'comment' alone", "'obj_info' alone")
    return detail, (lambda b: ply_bytes(lines, b.ply_data)), same


def _ply_elements(rng, base):
    options = [
        ("an empty face element after the vertices (same Gaussians)", "after0"),
        ("a face element of 5 triangles before the vertices", "before"),
        ("a face element after the vertices, data for it", "after5"),
        ("a second vertex element", "second"),
        ("no vertex element (renamed 'point')", "point"),
        ("a compressed-PLY chunk element with garbage", "chunk"),
        ("a mesh: x y z and faces only", "mesh"),
        ("f_rest_8 missing (8 f_rest)", "rest8"), ("f_rest numbered with a gap", "gap"),
        ("element vertex 0 and no data", "zero"),
        ("an element of 3 rows without properties before the vertices (same Gaussians)", "noprops"),
        ("an element of 2 float rows before the vertices (same Gaussians)", "skip2"),
        ("a face element of 10**9 triangles after the vertices, no data", "faces_huge"),
        ("a face element of 10**9 triangles before the vertices, no data", "faces_huge_before"),
        ("an element of 10**15 float rows before the vertices", "skip_huge"),
        ("a vertex element of 20 rows of 2000 float properties", "wide"),
    ]
    detail, how = rng.cycle(options)
    faces = np.empty(5, [("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, [[0, 1, 2]] * 5
    hdr, data = list(base.ply_header), base.ply_data
    if how == "noprops":
        return detail, (lambda b: ply_bytes(hdr[:2] + ["element extra 3"] + hdr[2:], data)), True
    if how == "skip2":
        extra = np.arange(2, dtype="<f4").tobytes()
        lines = hdr[:2] + ["element extra 2", "property float a"] + hdr[2:]
        return detail, (lambda b: ply_bytes(lines, extra + data)), True
    if how in ("faces_huge", "faces_huge_before"):
        face = ["element face 1000000000", "property list uchar int vertex_indices"]
        lines = hdr[:-1] + face + ["end_header"] if how == "faces_huge" else hdr[:2] + face + hdr[2:]
        return detail, (lambda b: ply_bytes(lines, data)), how == "faces_huge"
    if how == "skip_huge":
        return detail, (lambda b: ply_bytes(hdr[:2] + ["element extra 1000000000000000", "property float a"] + hdr[2:],
                                            data)), False
    if how == "wide":
        lines = hdr[:3] + [f"property float p{i}" for i in range(2000)] + ["end_header"]
        return detail, (lambda b: ply_bytes(lines, bytes(N_GAUSSIANS * 8000))), False
    if how == "after0":
        return detail, (lambda b: ply_bytes(hdr[:-1] + ["element face 0", "property list uchar int vertex_indices",
                                                       "end_header"], data)), True
    if how == "before":
        lines = hdr[:2] + ["element face 5", "property list uchar int vertex_indices"] + hdr[2:]
        return detail, (lambda b: ply_bytes(lines, faces.tobytes() + data)), False
    if how == "after5":
        lines = hdr[:-1] + ["element face 5", "property list uchar int vertex_indices", "end_header"]
        return detail, (lambda b: ply_bytes(lines, data + faces.tobytes())), True
    if how == "second":
        vlines = [x for x in hdr if x.startswith(("element vertex", "property"))]
        return detail, (lambda b: ply_bytes(hdr[:-1] + vlines + ["end_header"], data + data)), False
    if how == "point":
        lines = [x.replace("element vertex", "element point") for x in hdr]
        return detail, (lambda b: ply_bytes(lines, data)), False
    if how == "chunk":
        lines = hdr[:2] + ["element chunk 1"] + [f"property float {p}" for p in ("min_x", "min_y", "min_z")] + \
            [f"element vertex {N_GAUSSIANS}", "property uint packed_position", "property uint packed_rotation",
             "property uint packed_scale", "property uint packed_color", "end_header"]
        return detail, (lambda b: ply_bytes(lines, random.Random(3).randbytes(12 + 16 * N_GAUSSIANS))), False
    if how == "mesh":
        lines = hdr[:2] + [f"element vertex {N_GAUSSIANS}", "property float x", "property float y", "property float z",
                           "element face 5", "property list uchar int vertex_indices", "end_header"]
        xyz = np.ascontiguousarray(np.stack([base.ply_records[k] for k in "xyz"], 1), "<f4")
        return detail, (lambda b: ply_bytes(lines, xyz.tobytes() + faces.tobytes())), False
    if how in ("rest8", "gap"):
        drop = "f_rest_8" if how == "rest8" else "f_rest_4"
        keep = [q for q in base.ply_props if q != drop]
        lines = [x for x in hdr if not (x.startswith("property") and x.split()[2] == drop)]
        if how == "gap":
            lines = [x.replace("f_rest_8", "f_rest_9") for x in lines]
        rec = np.empty(len(base.ply_records), [(q, "<f4") for q in keep])
        for q in keep:
            rec[q] = base.ply_records[q]
        return detail, (lambda b: ply_bytes(lines, rec.tobytes())), False
    lines = [("element vertex 0" if x.startswith("element vertex") else x) for x in hdr]
    return detail, (lambda b: ply_bytes(lines, b"")), False


def _ply_special(rng, base):
    options = [
        ("a FIFO", lambda c: c.replace_with("job/car.ply", "fifo")),
        ("a directory", lambda c: c.replace_with("job/car.ply", "dir")),
        ("empty", lambda c: c.write("job/car.ply", b"")), ("just 'ply'", lambda c: c.write("job/car.ply", b"ply")),
        ("just 'ply\\n'", lambda c: c.write("job/car.ply", b"ply\n")),
        ("'ply' and end_header only",
         lambda c: c.write("job/car.ply", b"ply\nformat binary_little_endian 1.0\nend_header\n")),
        ("a symlink to /dev/zero", lambda c: c.replace_with("job/car.ply", "link", "/dev/zero")),
        ("a symlink to ../outside/car.ply", lambda c: c.replace_with("job/car.ply", "link", "../outside/car.ply")),
        ("missing", lambda c: c.replace_with("job/car.ply", "missing")),
        ("'ply' then 1 MB of zeros", lambda c: c.write("job/car.ply", b"ply\n" + bytes(1 << 20))),
        ("'ply' then 70 KB without end_header", lambda c: c.write("job/car.ply", b"ply\n" + b"comment x\n" * 7000)),
        ("the npz's bytes", lambda c: c.write("job/car.ply", c.base.npz_stored)),
        ("a symlink loop", lambda c: c.replace_with("job/car.ply", "link", "car.ply")),
        ("a dangling symlink", lambda c: c.replace_with("job/car.ply", "link", "nowhere.ply")),
        ("a symlink to /dev/urandom", lambda c: c.replace_with("job/car.ply", "link", "/dev/urandom")),
        ("'ply' then 100 KB of newlines", lambda c: c.write("job/car.ply", b"ply\n" + b"\n" * 100000)),
        ("a header with end_header but no format or element",
         lambda c: c.write("job/car.ply", b"ply\nend_header\n" + c.base.ply_data)),
        ("a hard link to ../outside/car.ply",
         lambda c: (c.replace_with("job/car.ply", "missing"), os.link(c.path("outside/car.ply"), c.ply))),
    ]
    detail, apply = rng.cycle(options)
    return f"special file: {detail}", apply, False


def _ply3(family, make):
    """A family whose ``make`` returns (detail, fn[, same])."""
    def plan(rng, base):
        got = make(rng, base)
        detail, fn = got[0], got[1]
        same = got[2] if len(got) > 2 else False

        def apply(c):
            c.write("job/car.ply", fn(c.base))
        return f"{family}: {detail}", apply, same
    return plan


PLY_FAMILIES = [
    (_ply3("end_header in a comment", lambda r, b: (*_ply_end_header_comment(r, b), True)), 2),
    (_ply3("truncated", _ply_truncated), 2), (_ply3("vertex count", _ply_count), 2),
    (_ply3("property type", _ply_retype), 2), (_ply3("list property", _ply_list), 1),
    (_ply3("same Gaussians rewritten", _ply_rewrite), 2), (_ply3("header bytes", _ply_header_bytes), 2),
    (_ply3("line endings", _ply_line_endings), 1), (_ply3("many comments", _ply_many_comments), 1),
    (_ply3("data values", _ply_values), 2), (_ply3("duplicate property", _ply_duplicate), 1),
    (_ply3("missing property", _ply_missing_prop), 1), (_ply3("malformed header line", _ply_malformed_line), 2),
    (_ply3("elements", _ply_elements), 2), (_ply_special, 2),
]


# ---------------------------------------------------------------------------------------------- mutations: checkpoint

CONFIG_FIELDS = ("schema", "base", "trained_steps", "fps", "motion_bucket_id", "noise_aug_strength", "min_guidance",
                 "max_guidance", "window", "latent_validity", "extra")
CONFIG_VALUES = {
    "fps": [("0", 0), ("-1", -1), ("1e300", 1e300), ("10**30", 10 ** 30), ("2.5", 2.5)],
    "window": [("0", 0), ("-1", -1), ("10**9", 10 ** 9), ("1", 1), ("2**63", 2 ** 63)],
    "latent_validity": [('"foo"', "foo"), ('""', ""), ("1", 1)],
    "min_guidance": [("5 (> max 3)", 5.0), ("-1", -1.0), ("1e300", 1e300)],
    "max_guidance": [("0.5 (< min 1)", 0.5), ("1e300", 1e300), ("-3", -3.0)],
    "noise_aug_strength": [("-1", -1.0), ("1e300", 1e300), ("100", 100.0)],
    "motion_bucket_id": [("-1", -1), ("10**9", 10 ** 9), ("1e300", 1e300)],
    "trained_steps": [("-1", -1), ("10**30", 10 ** 30)],
    "schema": [('"scpainter.checkpoint/2"', "scpainter.checkpoint/2"), ("null", None)],
    "base": [("123", 123), ('"/nonexistent"', "/nonexistent")],
    "extra": [('"x"', "x"), ("[]", [])],
}
GENERIC = [("null", None), ("true", True), ('"7"', "7"), ("[]", []), ("{}", {}), ("NaN", Raw("NaN")),
           ("Infinity", Raw("Infinity")), ("a 5000-digit integer", Raw(_BIG_DIGITS)), ("-1e300", -1e300)]


def _config_text(c) -> dict:
    with open(os.path.join(c.checkpoint, "scpainter.json")) as f:
        return json.load(f)


def _write_config(c, cfg) -> None:
    c.write(f"{CKPT}/scpainter.json", to_json(cfg))


def _ckpt_field(rng, base):
    key = rng.choice(CONFIG_FIELDS)
    name, value = rng.choice(CONFIG_VALUES.get(key, []) + GENERIC)

    def apply(c):
        cfg = _config_text(c)
        cfg[key] = copy.deepcopy(value)
        _write_config(c, cfg)
    return f"config field: scpainter.json {key} = {name}", apply


def _ckpt_semantic(rng, base):
    key, name, value = rng.cycle([(k, n, v) for k, vals in CONFIG_VALUES.items() for n, v in vals])

    def apply(c):
        cfg = _config_text(c)
        cfg[key] = copy.deepcopy(value)
        _write_config(c, cfg)
    return f"config range: scpainter.json {key} = {name}", apply


def _ckpt_missing_extra(rng, base):
    def without(key):
        return lambda c: _write_config(c, {k: v for k, v in _config_text(c).items() if k != key})

    def extra(key, value):
        def apply(c):
            cfg = _config_text(c)
            if value is None:
                cfg.update({f"k{i}": i for i in range(1000)})
            else:
                cfg[key] = value
            _write_config(c, cfg)
        return apply
    options = ([(f"scpainter.json without {k}", without(k)) for k in CONFIG_FIELDS]
               + [("scpainter.json with an extra 'foo'", extra("foo", 1)),
                  ("scpainter.json with an extra '__class__'", extra("__class__", "x")),
                  ("scpainter.json with 1000 unknown keys", extra("", None))])
    detail, apply = rng.cycle(options)
    return f"config keys: {detail}", apply


def _ckpt_config_file(rng, base):
    def raw(fn):
        return lambda c: c.write(f"{CKPT}/scpainter.json", fn(c))
    options = [
        ("not JSON", raw(lambda c: b"this is not json")), ("empty", raw(lambda c: b"")),
        ("truncated", raw(lambda c: to_json(_config_text(c)).encode()[:40])),
        ("a top-level list", raw(lambda c: b"[1, 2]")), ("null", raw(lambda c: b"null")),
        ("UTF-16", raw(lambda c: to_json(_config_text(c)).encode("utf-16"))),
        ("not UTF-8", raw(lambda c: b'{"schema": "scpainter.checkpoint/1", "base": "caf\xe9"}')),
        ("nested 10000 deep", raw(lambda c: b"[" * 10000 + b"]" * 10000)),
        ("10 MB (a long 'extra' string)",
         raw(lambda c: to_json(dict(_config_text(c), extra={"junk": "x" * (10 << 20)})).encode())),
        ("10 MB of '['", raw(lambda c: b"[" * (10 << 20))),
        ("NaN at the top level", raw(lambda c: b"NaN")),
        ("a directory", lambda c: c.replace_with(f"{CKPT}/scpainter.json", "dir")),
        ("a FIFO", lambda c: c.replace_with(f"{CKPT}/scpainter.json", "fifo")),
        ("missing", lambda c: c.replace_with(f"{CKPT}/scpainter.json", "missing")),
        ("a symlink to /dev/zero", lambda c: c.replace_with(f"{CKPT}/scpainter.json", "link", "/dev/zero")),
        ("a symlink loop", lambda c: c.replace_with(f"{CKPT}/scpainter.json", "link", "scpainter.json")),
        ("a JSON string", raw(lambda c: b'"scpainter.checkpoint/1"')),
        ("trailing garbage", raw(lambda c: to_json(_config_text(c)).encode() + b" }{")),
        ("10 MB of whitespace, then the config", raw(lambda c: b" " * (10 << 20) + to_json(_config_text(c)).encode())),
        ("a lone surrogate in 'base'", raw(lambda c: to_json(dict(_config_text(c), base=Raw('"\\ud800"'))).encode())),
    ]
    detail, apply = rng.cycle(options)
    return f"config file: scpainter.json {detail}", apply


WEIGHT_FILES = {"unet": "diffusion_pytorch_model.safetensors", "vae": "diffusion_pytorch_model.safetensors",
                "image_encoder": "model.safetensors", "condition_encoder": "diffusion_pytorch_model.safetensors"}


def _ckpt_index_bin(rng, base):
    comp = rng.choice(list(WEIGHT_FILES))
    stem = WEIGHT_FILES[comp].replace(".safetensors", "")
    shard = rng.cycle([f"{stem}-00001-of-00001.bin", f"{stem}-00001-of-00001.safetensors",
                       "../../outside/x.safetensors",
                        "/dev/zero"])
    keep = rng.random() < 0.3

    def apply(c):
        folder = f"{CKPT}/{comp}"
        if not keep:
            c.replace_with(f"{folder}/{WEIGHT_FILES[comp]}", "missing")
        c.write(f"{folder}/{WEIGHT_FILES[comp]}.index.json",
                to_json({"metadata": {"total_size": 1}, "weight_map": {"conv_in.weight": shard}}))
        c.names.add(os.path.basename(shard))
        if shard.endswith(".bin"):
            c.write(f"{folder}/{shard}", b"not a pickle")
    return (f"sharded index: {comp}/{WEIGHT_FILES[comp]}.index.json names {shard!r}"
            f"{' (the safetensors file kept)' if keep else ''}"), apply


def _ckpt_bin_only(rng, base):
    comp = rng.choice(list(WEIGHT_FILES))
    name = rng.choice(["diffusion_pytorch_model.bin", "pytorch_model.bin", "model.pt", "model.ckpt"])

    def apply(c):
        c.replace_with(f"{CKPT}/{comp}/{WEIGHT_FILES[comp]}", "missing")
        c.write(f"{CKPT}/{comp}/{name}", b"not a pickle")
    return f"pickled weights only: {comp}/ holds {name} and no safetensors", apply


def _ckpt_missing_component(rng, base):
    comp, how = rng.cycle([(c, h) for h in ("missing", "a file", "empty", "a symlink to ../outside/target")
                           for c in ("unet", "vae", "image_encoder", "feature_extractor", "scheduler",
                                     "condition_encoder")])

    def apply(c):
        rel = f"{CKPT}/{comp}"
        if how == "missing":
            c.replace_with(rel, "missing")
        elif how == "a file":
            c.replace_with(rel, "missing")
            c.write(rel, b"x")
        elif how == "empty":
            c.replace_with(rel, "missing")
            os.makedirs(c.path(rel))
        else:
            c.replace_with(rel, "link", "../outside/target")
    return f"component folder: {comp}/ {how}", apply


def _ckpt_model_index(rng, base):
    def edit(fn):
        def apply(c):
            p = os.path.join(c.checkpoint, "model_index.json")
            with open(p) as f:
                data = json.load(f)
            c.write(f"{CKPT}/model_index.json", fn(data))
        return apply
    options = [
        ("not JSON", edit(lambda d: "{{{")), ("empty", edit(lambda d: "")),
        ("_class_name 'Foo'", edit(lambda d: to_json(dict(d, _class_name="Foo")))),
        ("without _class_name", edit(lambda d: to_json({k: v for k, v in d.items() if k != "_class_name"}))),
        ("unet = ['os', 'system']", edit(lambda d: to_json(dict(d, unet=["os", "system"])))),
        ("unet = null", edit(lambda d: to_json(dict(d, unet=None)))),
        ("a list", edit(lambda d: "[]")),
        ("missing", lambda c: c.replace_with(f"{CKPT}/model_index.json", "missing")),
        ("a FIFO", lambda c: c.replace_with(f"{CKPT}/model_index.json", "fifo")),
    ]
    detail, apply = rng.cycle(options)
    return f"model_index.json: {detail}", apply


COMPONENT_CONFIGS = ["unet/config.json", "vae/config.json", "image_encoder/config.json",
                     "condition_encoder/config.json",
                     "scheduler/scheduler_config.json", "feature_extractor/preprocessor_config.json"]


def _ckpt_component_config(rng, base):
    rel = rng.choice(COMPONENT_CONFIGS)
    how = rng.cycle(["not JSON", "missing", "empty object", "a FIFO", "in_channels 3", "block_out_channels []",
                      "sample_size -1", "image_mean null", "10000 nested lists"])

    def apply(c):
        p = f"{CKPT}/{rel}"
        if how == "missing":
            c.replace_with(p, "missing")
        elif how == "a FIFO":
            c.replace_with(p, "fifo")
        elif how == "not JSON":
            c.write(p, b"garbage{")
        elif how == "empty object":
            c.write(p, b"{}")
        elif how == "10000 nested lists":
            c.write(p, b"[" * 10000 + b"]" * 10000)
        else:
            with open(c.path(p)) as f:
                data = json.load(f)
            key, value = {"in_channels 3": ("in_channels", 3), "block_out_channels []": ("block_out_channels", []),
                          "sample_size -1": ("sample_size", -1), "image_mean null": ("image_mean", None)}[how]
            data[key] = value
            c.write(p, to_json(data))
    return f"component config: {rel} {how}", apply


def _ckpt_weights(rng, base):
    comp = rng.choice(list(WEIGHT_FILES))
    how = rng.cycle(["truncated to 100 bytes", "random bytes", "empty", "header length 2**63", "a FIFO",
                      "a directory"])

    def apply(c):
        rel = f"{CKPT}/{comp}/{WEIGHT_FILES[comp]}"
        if how == "a FIFO":
            c.replace_with(rel, "fifo")
        elif how == "a directory":
            c.replace_with(rel, "dir")
        else:
            with open(c.path(rel), "rb") as f:
                data = f.read()
            data = {"truncated to 100 bytes": data[:100], "random bytes": random.Random(1).randbytes(4096),
                    "empty": b"", "header length 2**63": struct.pack("<Q", 2 ** 63) + data[8:]}[how]
            c.write(rel, data)                       # unlinks the hard link first
    return f"weights: {comp}/{WEIGHT_FILES[comp]} {how}", apply


def _ckpt_folder(rng, base):
    options = [
        ("a file", lambda c: (shutil.rmtree(c.checkpoint), c.write(CKPT, b"x"))),
        ("missing", lambda c: shutil.rmtree(c.checkpoint)),
        ("a symlink to outside/target",
         lambda c: (shutil.rmtree(c.checkpoint), os.symlink("outside/target", c.checkpoint))),
        ("a stock SVD snapshot (no scpainter.json)", lambda c: c.replace_with(f"{CKPT}/scpainter.json", "missing")),
        ("an empty folder", lambda c: (shutil.rmtree(c.checkpoint), os.makedirs(c.checkpoint))),
        ("a FIFO", lambda c: (shutil.rmtree(c.checkpoint), os.mkfifo(c.checkpoint))),
        ("only scpainter.json", lambda c: [c.replace_with(f"{CKPT}/{d}", "missing") for d in os.listdir(c.checkpoint)
                                           if d != "scpainter.json"]),
        ("a symlink to the job folder", lambda c: (shutil.rmtree(c.checkpoint), os.symlink("job", c.checkpoint))),
        ("a dangling symlink", lambda c: (shutil.rmtree(c.checkpoint), os.symlink("nowhere", c.checkpoint))),
    ]
    detail, apply = rng.cycle(options)
    return f"checkpoint folder: {detail}", apply


CHECKPOINT_FAMILIES = [(_ckpt_field, 2), (_ckpt_semantic, 2), (_ckpt_missing_extra, 1), (_ckpt_config_file, 2),
                       (_ckpt_index_bin, 1), (_ckpt_bin_only, 1), (_ckpt_missing_component, 1),
                       (_ckpt_model_index, 1), (_ckpt_component_config, 1), (_ckpt_weights, 1), (_ckpt_folder, 1)]

FAMILIES = {"job": JOB_FAMILIES, "npz": NPZ_FAMILIES, "ply": PLY_FAMILIES, "checkpoint": CHECKPOINT_FAMILIES}


class Draw(random.Random):
    """The random choices of one case, seeded by (seed, kind, index). ``turn`` counts the cases of the same family
    before this one: ``cycle`` walks a family's main list of variants in a fixed shuffled order with it, so every
    variant is covered once before any repeats."""

    turn = 0

    def cycle(self, options):
        order = random.Random(len(options)).sample(range(len(options)), len(options))
        return options[order[self.turn % len(options)]]


def _schedule(families) -> list:
    return [j for j, (_, weight) in enumerate(families) for _ in range(weight)]


def make_case(kind: str, index: int, seed: int, base: Base) -> Case:
    """Case ``index`` of ``kind``. The families' slots (weight each) repeat in rounds: ``index`` picks the slot,
    the family's ``turn`` is how many of its cases came before, and every other choice comes from a Random seeded
    by (seed, kind, index), so a case is the same on every run and machine."""
    if kind in fuzz_surfaces.KINDS:
        return fuzz_surfaces.make_case(kind, index, seed)
    if kind in fuzz_round3.KINDS:
        return fuzz_round3.make_case(kind, index, seed)
    families = FAMILIES[kind]
    slots = _schedule(families)
    slot = index % len(slots)
    j = slots[slot]
    rng = Draw(f"{seed}/{kind}/{index}")
    rng.turn = (index // len(slots)) * families[j][1] + slots[:slot].count(j)
    got = families[j][0](rng, base)
    description, apply = got[0], got[1]
    same = bool(got[2]) if len(got) > 2 else False
    return Case(kind, index, seed, description, apply, same_gaussians=same)


# ---------------------------------------------------------------------------------------------- running a case

class Hang(BaseException):
    """Raised by the SIGALRM / SIGPROF handler; a BaseException so no ``except Exception`` in the backend swallows
    it."""


@contextlib.contextmanager
def alarm(seconds: float, cpu: bool = False):
    """Raise ``Hang`` in this thread after ``seconds`` of wall-clock time; with ``cpu``, after ``seconds`` of this
    process's CPU time (ITIMER_PROF: user + system, all threads) or ``WALL_FACTOR`` times that of wall-clock time,
    whichever comes first. A case is timed by the CPU it uses, so one other busy process on the machine (which
    stretches wall-clock time, not CPU time) does not turn a slow case into a "hang"; the wall-clock bound still
    ends a case blocked without using CPU (a FIFO opened for reading, a lock waited on)."""
    def handler(signum, frame):
        raise Hang()
    old = signal.signal(signal.SIGALRM, handler)
    old_prof = signal.signal(signal.SIGPROF, handler) if cpu else None
    signal.setitimer(signal.ITIMER_REAL, seconds * (WALL_FACTOR if cpu else 1.0))
    if cpu:
        signal.setitimer(signal.ITIMER_PROF, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        if cpu:
            signal.setitimer(signal.ITIMER_PROF, 0)
            signal.signal(signal.SIGPROF, old_prof)


def snapshot(root: str, skip: str) -> dict:
    """{relative path: (type, size, mtime_ns, link target)} of everything under ``root`` except the ``skip``
    folder's contents; links are recorded, never followed."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        if os.path.abspath(dirpath) == os.path.abspath(skip):
            dirnames[:] = []
            continue
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            rel = os.path.relpath(p, root)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            if os.path.islink(p):
                out[rel] = ("link", 0, 0, os.readlink(p))
            elif os.path.isdir(p) and not os.path.islink(p):
                out[rel] = ("dir", 0, 0, "")
            else:
                out[rel] = ("file", st.st_size, st.st_mtime_ns, "")
    return out


def _changed(before: dict, after: dict) -> list:
    out = []
    for rel in sorted(set(before) | set(after)):
        if rel == "job" or rel.startswith("job" + os.sep):
            continue
        if rel not in after:
            out.append(f"deleted {rel}")
        elif rel not in before:
            out.append(f"created {rel}")
        elif before[rel] != after[rel]:
            out.append(f"modified {rel}")
    return out


def has_check_option() -> bool:
    """Whether this backend's generate knows ``--check`` (added with issue 14)."""
    from backend.__main__ import build_parser

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            build_parser().parse_args(["generate", "job.json", "--check"])
        return True
    except SystemExit:
        return False


def command(case: Case, c: CaseDir, check: bool) -> list:
    if case.kind == "checkpoint":
        argv = ["generate", c.job_json, "--checkpoint", c.checkpoint, "--device", "cpu"]
        return argv + (["--check"] if check else ["--steps", "1"])
    return ["render", c.job_json, "--device", "cpu"]


def _case_names(c: CaseDir, case: Case) -> set:
    names = {"job.json", "predictions.npz", "car.ply", CKPT} | c.names
    for folder in (c.job_dir, c.outside, c.checkpoint):
        for dirpath, dirnames, filenames in os.walk(folder):
            names.update(dirnames + filenames)
    if case.kind == "checkpoint":
        names.update(["scpainter.json", "model_index.json"] + [f"{d}/" for d in
                                                             ("unet", "vae", "image_encoder", "feature_extractor",
                                                              "scheduler", "condition_encoder")])
        names.update(d for d in ("unet", "vae", "image_encoder", "feature_extractor", "scheduler",
                                 "condition_encoder") if f"{d}/" in case.description)
        names.update(os.path.basename(p) for p in COMPONENT_CONFIGS)
    # names a mutation put into the job (a path to a missing file, a renamed input)
    if isinstance(c.job, dict):
        for key in (("scene", "predictions"), ("assets", 0, "ply"), ("output_dir",)):
            try:
                v = _get(c.job, key)
            except (KeyError, IndexError, TypeError):
                continue
            if isinstance(v, str) and v and "\0" not in v:
                names.add(os.path.basename(os.path.normpath(os.path.join(c.job_dir, v))))
    names.update(case.names)
    return {n.strip("/") for n in names if n.strip("/")}


def names_a_file(message: str, names) -> bool:
    """Whether ``message`` names one of ``names`` as a word or as the last part of a path ("job.json: frames: ...",
    "'/tmp/x/car.ply' is ...", "unet/: ..."); a name inside another word does not count."""
    for token in re.split(r"[\s'\"`:,;()\[\]{}<>=]+", message or ""):
        token = token.rstrip("/.")
        if token and (token in names or token.rsplit("/", 1)[-1] in names):
            return True
    return False


def _first_line(text: str, limit: int = 220) -> str:
    text = (text or "").strip()
    line = text.splitlines()[0] if text else ""
    return line[:limit] + ("…" if len(line) > limit else "")


def _last_exception(tb: str) -> str:
    """The "SomeError: message" line of the last exception in a traceback."""
    lines = [x for x in (tb or "").strip().splitlines() if x.strip()]
    for line in reversed(lines):
        if re.match(r"^[A-Za-z_][\w.]*(Error|Exception|Exit|Interrupt|Warning|error)\b", line):
            return _first_line(line)
    return _first_line(lines[-1]) if lines else ""


def _gaussians_equal(a, b) -> bool:
    keys = ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot")
    return all(getattr(a, k).shape == getattr(b, k).shape and np.array_equal(getattr(a, k), getattr(b, k),
                                                                             equal_nan=True) for k in keys)


def invoke(argv, timeout: float) -> dict:
    """Run ``backend.__main__.main(argv)`` in this process with standard output and error captured and a timeout
    (``alarm``: ``timeout`` CPU seconds, ``WALL_FACTOR`` times that of wall-clock time): {rc, exc (a traceback or a
    SystemExit line, None), hang, stdout, stderr, seconds}."""
    from backend.__main__ import main

    out, err = io.StringIO(), io.StringIO()
    rc, exc, hang = None, None, False
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), alarm(timeout, cpu=True):
            rc = main(argv)
    except Hang:
        hang = True
    except SystemExit as e:
        last = err.getvalue().strip().splitlines()[-1:] or [""]
        exc = f"SystemExit({e.code}) escaped main(): {_first_line(last[0])}"
    except BaseException:  # noqa: BLE001 - an exception escaping main() is what we count
        exc = traceback.format_exc()
    return {"rc": rc, "exc": exc, "hang": hang, "stdout": out.getvalue(), "stderr": err.getvalue(),
            "seconds": time.perf_counter() - t0}


def parse_events(stdout: str) -> list:
    """The JSON event lines of a run's standard output (a line that is not JSON as a "(not JSON)" event)."""
    events = []
    for line in stdout.splitlines():
        try:
            events.append(json.loads(line))
        except ValueError:
            events.append({"event": "(not JSON)", "message": line[:200]})
    return [e if isinstance(e, dict) else {"event": "(not JSON)", "message": str(e)[:200]} for e in events]


def classify(result: dict, ran: dict, escapes: list, names, timeout: float) -> str:
    """The outcome class of a run (``invoke``'s dict) by the rules of the module docstring, before any misread
    check; fills ``result``'s message, file, field (and traceback, escaped)."""
    rc, exc, stderr = ran["rc"], ran["exc"], ran["stderr"]
    errors = [e for e in parse_events(ran["stdout"]) if e.get("event") == "error"]
    if errors:
        result["message"] = _first_line(str(errors[-1].get("message", "")))
        result["file"], result["field"] = errors[-1].get("file"), errors[-1].get("field")
    if escapes:
        result["escaped"] = escapes[:6]
        result["message"] = "; ".join(escapes[:3]) + (f" (rc {rc}: {result['message']})" if result["message"] else
                                                      f" (rc {rc})")
        return "escape"
    if ran["hang"]:
        result["message"] = f"no answer within {timeout:g} CPU s or {timeout * WALL_FACTOR:g} s" + (f" (last log: {_first_line(stderr.splitlines()[-1])})"
                                                                 if stderr.strip() else "")
        return "hang"
    if exc is not None or rc not in (0, 2) or "Traceback" in stderr:
        tb = exc if exc is not None else stderr
        if exc is not None or not result["message"]:   # else the error event's "SomeError: message" says it
            result["message"] = (_last_exception(tb) if "Traceback" in (tb or "") else _first_line(tb)) or \
                f"exit code {rc}"
        result["traceback"] = (tb or "")[-3000:]
        return "traceback"
    if rc == 0:
        return "accepted"
    named = [e for e in errors if names_a_file(str(e.get("message", "")), names)]
    if not errors:
        result["message"] = _first_line(stderr) or "exit 2 without an error event"
    return "clean" if named else "unclear"


def run_case(case: Case, base: Base, workdir: str, timeout: float = TIMEOUT_S, check: bool = True,
             keep: bool = False) -> dict:
    """Build, run and classify one case in this process; returns a JSON-able result."""
    if case.kind in fuzz_surfaces.KINDS:
        return fuzz_surfaces.run_case(case, base, workdir, timeout, keep)
    if case.kind in fuzz_round3.KINDS:
        return fuzz_round3.run_case(case, base, workdir, timeout, keep)
    root = os.path.join(workdir, f"{case.kind}-{case.index:04d}")
    c = prepare(case, base, root)
    argv = command(case, c, check)
    names = _case_names(c, case)
    if case.kind == "checkpoint" and not check:
        timeout = max(timeout, FALLBACK_TIMEOUT_S)
    before, top_before = snapshot(root, c.job_dir), set(os.listdir(workdir))
    ran = invoke(argv, timeout)
    escapes = _changed(before, snapshot(root, c.job_dir))
    escapes += [f"created ../{n}" for n in sorted(set(os.listdir(workdir)) - top_before)]
    result = {"kind": case.kind, "index": case.index, "seed": case.seed, "description": case.description,
              "family": case.family, "rc": ran["rc"], "seconds": round(ran["seconds"], 4), "message": "",
              "file": None, "field": None}
    outcome = classify(result, ran, escapes, names, timeout)
    if outcome == "accepted" and case.kind == "ply" and case.same_gaussians:
        from scpainter_blender.core.splats import reader as splats_io
        try:
            with alarm(timeout, cpu=True):
                same = _gaussians_equal(splats_io.read(c.ply), base.gaussians)
            why = "" if same else "core.splats.reader.read gives other values than the original file"
        except BaseException as e:  # noqa: BLE001
            same, why = False, f"accepted, but core.splats.reader.read fails: {type(e).__name__}: {e}"
        if not same:
            outcome = "misread"
            result["message"] = _first_line(why)
    return finish(result, outcome, ran, root, keep)


def finish(result: dict, outcome: str, ran: dict, root: str, keep: bool) -> dict:
    """``result`` with its ``outcome``; with ``keep`` also the case folder and the run's output tails, else the
    case folder removed."""
    result["outcome"] = outcome
    if keep:
        result["folder"] = root
        result["stdout"], result["stderr"] = ran["stdout"][-4000:], ran["stderr"][-4000:]
    else:
        shutil.rmtree(root, ignore_errors=True)
    return result


def base_case(kind: str, seed: int = SEED) -> Case:
    """The valid input itself (render job, or the checkpoint job): must be accepted."""
    return Case(kind, -1, seed, "base: the valid input, unchanged", lambda c: None)


# ---------------------------------------------------------------------------------------------- workers

def _limit_resources() -> None:
    import resource

    try:
        with open("/proc/self/statm") as f:
            vm = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        resource.setrlimit(resource.RLIMIT_AS, (vm + MEMORY_HEADROOM, resource.RLIM_INFINITY))
    except (OSError, ValueError):
        pass
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # a too-large write fails with EFBIG instead of killing us
    try:
        resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_SIZE_LIMIT, resource.RLIM_INFINITY))
    except (OSError, ValueError):
        pass


def worker(fd: int, slot: int, seed: int, timeout: float, workdir: str, checkpoint: bool, surfaces=()) -> None:
    """Run the cases the parent sends on standard input ("kind index" lines) in this process, reporting JSON lines
    on ``fd``: ready (with the valid inputs' outcomes), then start and result per case."""
    out = os.fdopen(fd, "w", buffering=1)
    import numba
    import torch

    base = Base(os.path.join(workdir, f"base-{slot}"))
    if {"kill", "varykill"} & set(surfaces):   # forked before numba's threading layer is launched here (fuzz_surfaces.ForkServer)
        fuzz_surfaces.start_fork_server(base, os.path.join(workdir, f"w{slot}"))
    torch.set_num_threads(1)       # tiny cases: threads only cost time, more so on a shared 2-core machine
    numba.set_num_threads(1)
    check = has_check_option()
    warm = {}
    for kind in ("job", "checkpoint") if checkpoint else ("job",):   # warm-up outside the timeouts
        r = run_case(base_case(kind, seed), base, os.path.join(workdir, f"w{slot}"), timeout=600, check=check)
        warm[kind] = {"outcome": r["outcome"], "seconds": r["seconds"], "message": r["message"]}
    for kind in surfaces:     # issue 30's and 42's kinds: their valid inputs, the references misreads are judged by
        r = (fuzz_round3 if kind in fuzz_round3.KINDS else fuzz_surfaces).warm_up(kind, base,
                                                                                 os.path.join(workdir, f"w{slot}"), seed)
        warm[kind] = {"outcome": r["outcome"], "seconds": r["seconds"], "message": r["message"]}
    _limit_resources()
    import backend

    ready = {"check": check, "base": warm, "backend": os.path.dirname(backend.__file__)}
    out.write(json.dumps({"ready": ready}) + "\n")
    cases = os.path.join(workdir, f"w{slot}")
    for line in iter(sys.stdin.readline, ""):
        kind, index = line.split()
        index = int(index)
        out.write(json.dumps({"start": [kind, index]}) + "\n")
        try:
            r = run_case(make_case(kind, index, seed, base), base, cases, timeout, check)
        except BaseException as e:  # noqa: BLE001 - a harness failure on one case is reported, not fatal
            r = {"kind": kind, "index": index, "seed": seed, "description": "(harness error)", "family": "(harness)",
                 "rc": None, "seconds": 0.0, "message": f"harness: {type(e).__name__}: {e}", "file": None,
                 "field": None, "outcome": "traceback", "traceback": traceback.format_exc()[-3000:]}
        out.write(json.dumps({"result": r}) + "\n")


class _Worker:
    """A worker process (``worker``): cases go in on its standard input, messages come back on a pipe."""

    def __init__(self, slot, seed, timeout, workdir, checkpoint, n, surfaces=()):
        r, w = os.pipe()
        os.makedirs(os.path.join(workdir, f"w{slot}"), exist_ok=True)
        self.slot, self.ready, self.current, self.deadline = slot, False, None, None
        self.log_path = os.path.join(workdir, f"worker-{n}.log")
        self.log = open(self.log_path, "wb")
        env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
        self.proc = subprocess.Popen(
            [sys.executable, os.path.abspath(__file__), "--worker", "--fd", str(w), "--slot", str(slot), "--seed",
             str(seed), "--timeout", str(timeout), "--workdir", workdir]
            + (["--with-checkpoint"] if checkpoint else []) + (["--surfaces", *surfaces] if surfaces else []),
            cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=self.log, stderr=subprocess.STDOUT, pass_fds=(w,))
        os.close(w)
        self.fd, self.buf, self.eof = r, b"", False

    def send(self, case) -> None:
        self.current = tuple(case)
        with contextlib.suppress(BrokenPipeError):   # a worker that died is noticed at the end of its messages
            self.proc.stdin.write(f"{case[0]} {case[1]}\n".encode())
            self.proc.stdin.flush()

    def finish(self) -> None:
        """No more cases: the worker exits when it reads the end of its input."""
        if not self.proc.stdin.closed:
            self.proc.stdin.close()

    def messages(self) -> list:
        """The complete messages that have arrived (call when the pipe is readable); sets ``eof``."""
        chunk = os.read(self.fd, 1 << 16)
        if not chunk:
            self.eof = True
        self.buf += chunk
        *lines, self.buf = self.buf.split(b"\n")
        return [json.loads(line) for line in lines if line.strip()]

    def tail(self) -> str:
        with open(self.log_path, "rb") as f:
            return f.read()[-3000:].decode("utf-8", "replace")

    def close(self, kill: bool = False) -> int:
        if kill and self.proc.poll() is None:
            self.proc.kill()
        with contextlib.suppress(OSError):
            self.finish()
        rc = self.proc.wait()
        os.close(self.fd)
        self.log.close()
        return rc


def _scratch_parent():
    """A RAM-backed folder for the case folders when there is one (creating and removing ~10,000 small files is
    much faster there), else the default temporary folder."""
    shm = "/dev/shm"
    try:
        st = os.statvfs(shm)
        if os.path.isdir(shm) and os.access(shm, os.W_OK) and st.f_bavail * st.f_frsize > (2 << 30):
            return shm
    except OSError:
        pass
    return None


class _Pool:
    """The parent side of ``run``: worker processes, the queues of cases, the results."""

    def __init__(self, todo, seed, timeout, workdir, workers, startup_timeout, on_result):
        self.todo, self.seed, self.timeout, self.workdir = todo, seed, timeout, workdir
        self.startup_timeout, self.on_result = startup_timeout, on_result
        self.ckpt = collections.deque(x for x in todo if x[0] == "checkpoint")
        self.other = collections.deque(x for x in todo if x[0] != "checkpoint")
        self.results, self.live, self.started = {}, {}, 0
        self.meta = {"base": {}, "check": None, "backend": None}
        # a kill case runs several backend processes in turn, each under its own (longer) timeout
        self.case_wait = WALL_FACTOR * timeout + 15 + (fuzz_surfaces.KILL_TIMEOUT_S * 4 if any(x[0] in ("kill", "varykill")
                                                                                                for x in todo)
                                             else 0)
        self.slots = [0] + ([1] if workers > 1 and self.other else [])
        self.surfaces = tuple(k for k in SURFACE_KINDS if any(x[0] == k for x in todo))

    def start(self, slot) -> None:
        self.started += 1
        w = _Worker(slot, self.seed, self.timeout, self.workdir, slot == 0 and bool(self.ckpt), self.started,
                    self.surfaces)
        w.started_by = time.monotonic() + self.startup_timeout
        self.live[slot] = w

    def restart(self, slot) -> None:
        if (self.ckpt or self.other) if slot == 0 else self.other:  # worker 1 takes no checkpoint case
            self.start(slot)

    def assign(self, w) -> None:
        queue = self.ckpt if (w.slot == 0 and self.ckpt) else self.other
        if queue:
            w.send(queue.popleft())
            w.deadline = time.monotonic() + self.case_wait
        else:
            w.current, w.deadline = None, None
            w.finish()

    def record(self, r) -> None:
        self.results[(r["kind"], r["index"])] = r
        if self.on_result:
            self.on_result(r)

    def lost(self, w, outcome, why) -> None:
        """The case ``w`` was running when it died or was killed."""
        kind, index = w.current
        self.record({"kind": kind, "index": index, "seed": self.seed, "family": "", "description": "", "rc": None,
                     "seconds": None, "file": None, "field": None, "outcome": outcome, "message": why,
                     **({"traceback": w.tail()} if outcome == "traceback" else {})})

    def on_message(self, w, msg) -> None:
        if "ready" in msg:
            w.ready = True
            ready = msg["ready"]
            self.meta.update(check=ready["check"], backend=ready["backend"])
            self.meta["base"].update(ready["base"])
            if not ready["check"] and any(k == "checkpoint" for k, _ in self.todo):
                self.case_wait = WALL_FACTOR * max(self.timeout, FALLBACK_TIMEOUT_S) + 15
            self.assign(w)
        elif "result" in msg:
            self.record(msg["result"])
            self.assign(w)

    def loop(self) -> None:
        for slot in self.slots:
            self.start(slot)
        while self.live:
            now = time.monotonic()
            waits = [(w.deadline if w.ready else w.started_by) - now for w in self.live.values()
                     if w.current is not None or not w.ready]
            fds = [w.fd for w in self.live.values()]
            readable, _, _ = select.select(fds, [], [], max(0.0, min(waits, default=60.0)))
            for w in list(self.live.values()):
                if w.fd in readable:
                    for msg in w.messages():
                        self.on_message(w, msg)
                    if w.eof:
                        del self.live[w.slot]
                        if not w.ready:
                            tail = w.tail()
                            w.close(kill=True)
                            raise RuntimeError(f"fuzz worker {w.slot} ended before it was ready:\n{tail}")
                        rc = w.close()
                        if w.current is not None:
                            self.lost(w, "traceback", f"the worker process died during the case (exit {rc})")
                        self.restart(w.slot)
                        continue
                now = time.monotonic()
                if w.ready and w.current is not None and now > w.deadline:
                    del self.live[w.slot]
                    w.close(kill=True)
                    self.lost(w, "hang", f"the worker did not answer within {self.case_wait:.0f} s (the timeout "
                                         "could not interrupt it); killed")
                    self.restart(w.slot)
                elif not w.ready and now > w.started_by:
                    del self.live[w.slot]
                    tail = w.tail()
                    w.close(kill=True)
                    raise RuntimeError(f"fuzz worker {w.slot} was not ready within {self.startup_timeout:g} s:\n"
                                       f"{tail}")

    def close(self) -> None:
        for w in self.live.values():     # only after an error: a finished loop has no live worker
            w.close(kill=True)
        self.live.clear()


def run(kinds=KINDS, seed: int = SEED, timeout: float = TIMEOUT_S, indices=None, on_result=None, workers: int = 2,
        startup_timeout: float = 900.0) -> dict:
    """Run the cases of ``kinds`` (or only ``indices`` = [(kind, index)]) in ``workers`` worker processes.

    Cases are handed out one at a time; worker 0 takes the checkpoint cases first (it alone builds the tiny
    checkpoint), then helps with the rest. A case a worker does not answer within 2 × timeout + 15 s is a hang
    (the worker is killed and a new one takes its place); a worker that dies during a case gives that case a
    traceback. Returns {"results": [...] in case order, "check": bool, "base": {kind: outcome of the valid
    input}, "backend": the backend package's folder, "workers": processes started, "seconds": s}."""
    t0 = time.perf_counter()
    todo = [tuple(x) for x in indices] if indices is not None else [(k, i) for k in kinds for i in range(CASES[k])]
    with tempfile.TemporaryDirectory(prefix="scpainter-fuzz-", dir=_scratch_parent()) as workdir:
        pool = _Pool(todo, seed, timeout, workdir, workers, startup_timeout, on_result)
        try:
            pool.loop()
        finally:
            pool.close()
        results = pool.results
        missing = [x for x in todo if x not in results]
        if missing:
            raise RuntimeError(f"the fuzz run ended without results for {missing[:5]}")
        for r in results.values():  # descriptions of the cases whose worker died
            if not r.get("description"):
                case = make_case(r["kind"], r["index"], seed, _planning_base(workdir))
                r["description"], r["family"] = case.description, case.family
    return {"results": [results[x] for x in todo], "check": pool.meta["check"], "base": pool.meta["base"],
            "backend": pool.meta["backend"], "workers": pool.started, "seconds": round(time.perf_counter() - t0, 1)}


_PLANNING = {}


def _planning_base(workdir: str) -> Base:
    if "base" not in _PLANNING:
        _PLANNING["base"] = Base(os.path.join(workdir, "plan"))
    return _PLANNING["base"]


# ---------------------------------------------------------------------------------------------- tables

def summarize(results) -> dict:
    """{kind: {cases, accepted, clean, unclear, traceback, hang, escape, misread}} plus "total"."""
    table = {}
    for r in results:
        row = table.setdefault(r["kind"], dict({"cases": 0}, **{c: 0 for c in CLASSES}))
        row["cases"] += 1
        row[r["outcome"]] += 1
    total = dict({"cases": 0}, **{c: 0 for c in CLASSES})
    for row in table.values():
        for k in total:
            total[k] += row[k]
    ordered = {k: table[k] for k in KINDS if k in table}
    ordered["total"] = total
    return ordered


def format_table(summary: dict) -> str:
    cols = ("cases", "accepted", "clean", "unclear", "traceback", "hang", "escape", "misread")
    heads = ("input kind", "cases", "accepted", "clean errors", "unclear", "tracebacks", "hangs", "escapes",
             "misreads")
    rows = [[k] + [str(v[c]) for c in cols] for k, v in summary.items()]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(heads)]
    line = lambda cells: "| " + " | ".join(c.ljust(w) if i == 0 else c.rjust(w)  # noqa: E731
                                           for i, (c, w) in enumerate(zip(cells, widths))) + " |"
    return "\n".join([line(heads), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [line(r) for r in rows])


def format_failures(results, limit: int = 200) -> str:
    bad = [r for r in results if r["outcome"] in FAILURES]
    lines = [f"{r['kind']:<10} {r['index']:>4}  {r['outcome']:<9}  {r['description'][:70]:<70}  {r['message'][:150]}"
             for r in bad[:limit]]
    if len(bad) > limit:
        lines.append(f"... and {len(bad) - limit} more")
    if bad:
        lines.append("reproduce one: .venv/bin/python -m tests.fuzz_inputs --kind KIND --index N [--keep]")
    return "\n".join(lines)


def families(results) -> list:
    """[(kind, family, outcome, count, example message)] of the failing outcomes, largest first."""
    groups = {}
    for r in results:
        if r["outcome"] in FAILURES:
            key = (r["kind"], r["family"], r["outcome"])
            g = groups.setdefault(key, [0, r])
            g[0] += 1
    return sorted(((k[0], k[1], k[2], g[0], f"#{g[1]['index']} {g[1]['description']}: {g[1]['message']}")
                   for k, g in groups.items()), key=lambda x: (KINDS.index(x[0]), -x[3]))


def failure_classes(results) -> list:
    """[(kind, outcome, message pattern, count, an example "#index description")] of the failing outcomes: the
    message with paths, hex keys and numbers blanked, so one defect is one line, largest first."""
    groups = {}
    for r in results:
        if r["outcome"] not in FAILURES:
            continue
        msg = re.sub(r"(/[^\s'\":,;()]+)+", "<path>", r.get("message") or "")
        msg = re.sub(r"\b[0-9a-f]{8,}\b", "<key>", msg)
        msg = re.sub(r"\d+", "N", msg)[:120]
        g = groups.setdefault((r["kind"], r["outcome"], msg), [0, r])
        g[0] += 1
    return sorted(((k[0], k[1], k[2], g[0], f"#{g[1]['index']} {g[1]['description'][:100]}")
                   for k, g in groups.items()), key=lambda x: (KINDS.index(x[0]), -x[3]))


# ---------------------------------------------------------------------------------------------- command line

def _cli(argv=None) -> int:
    p = argparse.ArgumentParser(description="Run one fuzz case in this process (or list the cases).")
    p.add_argument("--kind", choices=KINDS)
    p.add_argument("--index", type=int)
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--timeout", type=float, default=TIMEOUT_S)
    p.add_argument("--keep", action="store_true", help="keep the case folder and print its path")
    p.add_argument("--list", action="store_true", help="print every case's description")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--fd", type=int, help=argparse.SUPPRESS)
    p.add_argument("--slot", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--with-checkpoint", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--workdir", help=argparse.SUPPRESS)
    p.add_argument("--surfaces", nargs="*", default=(), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        worker(a.fd, a.slot, a.seed, a.timeout, a.workdir, a.with_checkpoint, tuple(a.surfaces))
        return 0
    workdir = tempfile.mkdtemp(prefix="scpainter-fuzz-case-")
    base = Base(os.path.join(workdir, "base"))
    if a.list:
        for kind in ([a.kind] if a.kind else KINDS):
            for i in range(CASES[kind]):
                print(f"{kind:<10} {i:>4}  {make_case(kind, i, a.seed, base).description}")
        shutil.rmtree(workdir)
        return 0
    if a.kind is None or a.index is None:
        p.error("give --kind and --index (or --list)")
    if a.kind in ("kill", "varykill"):   # before the warm-up below launches numba's threading layer in this process
        fuzz_surfaces.start_fork_server(base, workdir)
    check = has_check_option()
    warm = run_case(base_case(a.kind if a.kind == "checkpoint" else "job", a.seed), base, workdir, 600, check)
    print(f"warm-up (the valid input): {warm['outcome']} in {warm['seconds']:.2f} s {warm['message']}")
    if a.kind in SURFACE_KINDS:
        warm = (fuzz_round3 if a.kind in fuzz_round3.KINDS else fuzz_surfaces).warm_up(a.kind, base, workdir, a.seed)
        print(f"warm-up ({a.kind}): {warm['outcome']} in {warm['seconds']:.2f} s {warm['message']}")
    case = make_case(a.kind, a.index, a.seed, base)
    r = run_case(case, base, workdir, a.timeout, check, keep=a.keep)
    for key in ("stdout", "stderr", "traceback"):
        if r.get(key):
            print(f"--- {key}\n{r.pop(key).rstrip()}")
    print(json.dumps(r, indent=1))
    if not a.keep:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0 if r["outcome"] in ("accepted", "clean") else 1


if __name__ == "__main__":
    sys.exit(_cli())
