"""The job contract (DESIGN §4.2): ``job.json``, schema ``scpainter.job/1``, validated on load and before saving.

One JSON file describes a render/generation: output resolution, per-frame cameras (our K, OpenCV
world_to_camera, the VGGT frames whose points project into it), the scene reconstruction with its
``world_from_vggt`` and removal boxes, Gaussian assets with a per-frame object_to_world (PLY file coordinates to
world metres), the output folder and generation settings. Paths are relative to the job file. ``scene`` and
``assets`` may be absent. Every error names the file and the field (``frames[3].K``), never a numpy traceback.

No bpy, no torch: numpy for the matrix checks only.
"""

from __future__ import annotations

import math
import os

import numpy as np

from . import cameras, files

SCHEMA = "scpainter.job/1"

#: Bounds that keep a job inside what the renderer and the model can do (validated, with the field named).
MAX_SIDE = 16384                   # pixels, each of width and height
MAX_PIXELS = 8192 * 8192           # width x height
MAX_FRAMES = 100_000               # output frames in one job
FRAME_RANGE = (-1048574, 1048574)  # Blender's MINAFRAME..MAXFRAME
MAX_SOURCE_FRAME = 1_000_000
MAX_SEED = 2 ** 63 - 1
#: ``generate`` settings: (low, high) of each; the checkpoint's own values obey the same (backend.model.checkpoint)
GENERATE_INT_BOUNDS = {"steps": (1, 1000), "window": (1, 256), "overlap": (0, 255), "seed": (0, MAX_SEED),
                       "decode_chunk": (1, 256)}
GENERATE_NUMBER_BOUNDS = {"min_guidance": (0.0, 100.0), "max_guidance": (0.0, 100.0), "fps": (1.0, 240.0)}

#: ``scene.extrinsic_convention``: what the predictions' ``extrinsic`` holds (core.vggt.EXTRINSIC_CONVENTIONS).
EXTRINSIC_CONVENTIONS = ("world_to_camera", "camera_to_world")


class JobError(files.InputError):
    """A job that cannot be run: ``str()`` is ``"<job file>: <field>: <what is wrong>"``."""


def _matrix(value, path, field, shape):
    try:
        m = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise JobError(path, field, f"expected a {shape[0]}x{shape[1]} matrix of numbers") from None
    if m.shape != shape:
        raise JobError(path, field, f"expected a {shape[0]}x{shape[1]} matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise JobError(path, field, "contains NaN or infinity")
    return m


def _rigid(value, path, field):
    m = _matrix(value, path, field, (4, 4))
    R = m[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0 or np.any(m[3] != [0, 0, 0, 1]):
        raise JobError(path, field, "is not a rotation + translation (no scale, shear or reflection)")
    return m


def _affine(value, path, field):
    m = _matrix(value, path, field, (4, 4))
    if np.any(m[3] != [0, 0, 0, 1]) or abs(np.linalg.det(m[:3, :3])) < 1e-12:
        raise JobError(path, field, "is not an invertible affine transform (last row [0, 0, 0, 1])")
    return m


def _int(value, path, field, lo=None, hi=None):
    if isinstance(value, bool) or not isinstance(value, int) or (lo is not None and value < lo) or \
            (hi is not None and value > hi):
        want = "" if lo is None and hi is None else f" >= {lo}" if hi is None else f" in [{lo}, {hi}]"
        raise JobError(path, field, f"expected an integer{want}, got {_short(value)}")
    return value


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _number(value, path, field, lo=None, hi=None):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            (lo is not None and value < lo) or (hi is not None and value > hi):
        raise JobError(path, field, f"expected a number in [{lo}, {hi}], got {_short(value)}")
    return float(value)


def _str(value, path, field):
    if not isinstance(value, str) or not value:
        raise JobError(path, field, f"expected a non-empty string, got {_short(value)}")
    if len(value) > 4096 or "\0" in value:
        raise JobError(path, field, "is not a usable path or name (longer than 4096 characters or a NUL byte)")
    return value


def validate(job, path="job.json") -> dict:
    """Check every field of a job dict; returns it unchanged, raises JobError naming the field otherwise."""
    if not isinstance(job, dict):
        raise JobError(path, "(top level)", "expected a JSON object")
    if job.get("schema") != SCHEMA:
        raise JobError(path, "schema", f"expected {SCHEMA!r}, got {job.get('schema')!r}")
    res = job.get("resolution")
    if not isinstance(res, list) or len(res) != 2:
        raise JobError(path, "resolution", f"expected [width, height], got {_short(res)}")
    for i, v in enumerate(res):
        _int(v, path, f"resolution[{i}]", lo=1, hi=MAX_SIDE)
    if res[0] * res[1] > MAX_PIXELS:
        raise JobError(path, "resolution", f"{res[0]} x {res[1]} is more than {MAX_PIXELS:,} pixels")
    frames = job.get("frames")
    if not isinstance(frames, list) or not frames:
        raise JobError(path, "frames", "expected a non-empty list")
    if len(frames) > MAX_FRAMES:
        raise JobError(path, "frames", f"{len(frames):,} frames: at most {MAX_FRAMES:,} in one job (split it)")
    seen = set()
    for i, fr in enumerate(frames):
        where = f"frames[{i}]"
        if not isinstance(fr, dict):
            raise JobError(path, where, "expected an object")
        f = _int(fr.get("frame"), path, f"{where}.frame", *FRAME_RANGE)
        if f in seen:
            raise JobError(path, f"{where}.frame", f"frame {f} appears twice")
        seen.add(f)
        K = _matrix(fr.get("K"), path, f"{where}.K", (3, 3))
        if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(K[2] != [0, 0, 1]) or K[1, 0] != 0 or np.abs(K).max() > 1e8:
            raise JobError(path, f"{where}.K", "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 "
                                               "(pixels, at most 1e8)")
        _rigid(fr.get("world_to_camera"), path, f"{where}.world_to_camera")
        src = fr.get("source_frames", [])
        if not isinstance(src, list):
            raise JobError(path, f"{where}.source_frames", "expected a list of frame indices")
        for j, s in enumerate(src):
            _int(s, path, f"{where}.source_frames[{j}]", lo=0, hi=MAX_SOURCE_FRAME)
    if "scene" in job:
        sc = job["scene"]
        if not isinstance(sc, dict):
            raise JobError(path, "scene", "expected an object")
        _str(sc.get("predictions"), path, "scene.predictions")
        W = _matrix(sc.get("world_from_vggt"), path, "scene.world_from_vggt", (4, 4))
        try:  # the loader's own rule (point_cloud decomposes it), so what validates also runs
            cameras.decompose_similarity(W)
        except ValueError as e:
            raise JobError(path, "scene.world_from_vggt", f"is not a similarity: {e}") from None
        _number(sc.get("confidence_percentile", 50.0), path, "scene.confidence_percentile", 0.0, 100.0)
        if sc.get("extrinsic_convention", "world_to_camera") not in EXTRINSIC_CONVENTIONS:
            raise JobError(path, "scene.extrinsic_convention", f"expected one of {list(EXTRINSIC_CONVENTIONS)}, "
                                                               f"got {sc['extrinsic_convention']!r}")
        crop = sc.get("crop", [0, 0, 0, 0])
        if not isinstance(crop, list) or len(crop) != 4:
            raise JobError(path, "scene.crop", f"expected [left, top, right, bottom] in pixels, got {_short(crop)}")
        for i, v in enumerate(crop):
            _int(v, path, f"scene.crop[{i}]", lo=0)
        boxes = sc.get("removal_boxes", [])
        if not isinstance(boxes, list):
            raise JobError(path, "scene.removal_boxes", "expected a list")
        for i, b in enumerate(boxes):
            where = f"scene.removal_boxes[{i}]"
            if not isinstance(b, dict):
                raise JobError(path, where, "expected an object")
            _rigid(b.get("box_to_world"), path, f"{where}.box_to_world")
            size = b.get("size")
            if not isinstance(size, list) or len(size) != 3:
                raise JobError(path, f"{where}.size", f"expected [x, y, z] in metres, got {_short(size)}")
            for j, v in enumerate(size):
                _number(v, path, f"{where}.size[{j}]", lo=0.0, hi=1e7)
    if "assets" in job:
        assets = job["assets"]
        if not isinstance(assets, list):
            raise JobError(path, "assets", "expected a list")
        names = set()
        for i, a in enumerate(assets):
            where = f"assets[{i}]"
            if not isinstance(a, dict):
                raise JobError(path, where, "expected an object")
            name = _str(a.get("name"), path, f"{where}.name")
            if name in names:
                raise JobError(path, f"{where}.name", f"{name!r} appears twice")
            names.add(name)
            _str(a.get("ply"), path, f"{where}.ply")
            o2w = a.get("object_to_world")
            if not isinstance(o2w, dict):
                raise JobError(path, f"{where}.object_to_world", "expected an object of frame -> 4x4 matrix")
            missing = [f for f in sorted(seen) if str(f) not in o2w]
            if missing:
                raise JobError(path, f"{where}.object_to_world", f"no transform for frames {missing[:5]}")
            for k, m in o2w.items():
                _affine(m, path, f"{where}.object_to_world[{k!r}]")
    _str(job.get("output_dir"), path, "output_dir")
    gen = job.get("generate")
    if gen is not None:
        if not isinstance(gen, dict):
            raise JobError(path, "generate", "expected an object")
        if "checkpoint" in gen:
            _str(gen["checkpoint"], path, "generate.checkpoint")
        check_generate_settings(gen, path)
    return job


def check_generate_settings(gen: dict, path="job.json", where: str = "generate") -> dict:
    """Bounds of the ``generate`` settings present in ``gen`` (job fields or command-line overrides, ``where``
    names them); ``overlap < window`` and ``min_guidance <= max_guidance`` when both are given. Returns ``gen``."""
    for key, (lo, hi) in GENERATE_INT_BOUNDS.items():
        if gen.get(key) is not None:
            _int(gen[key], path, f"{where}.{key}", lo, hi)
    for key, (lo, hi) in GENERATE_NUMBER_BOUNDS.items():
        if gen.get(key) is not None:
            _number(gen[key], path, f"{where}.{key}", lo, hi)
    if gen.get("overlap") is not None and gen.get("window") is not None and gen["overlap"] >= gen["window"]:
        raise JobError(path, f"{where}.overlap", f"{gen['overlap']} must be smaller than {where}.window "
                                                  f"({gen['window']})")
    if gen.get("min_guidance") is not None and gen.get("max_guidance") is not None and \
            gen["min_guidance"] > gen["max_guidance"]:
        raise JobError(path, f"{where}.min_guidance", "must not exceed max_guidance")
    return gen


def read_json(path, error=JobError):
    """A JSON file's content within ``files.read_json``'s limits; a missing, irregular, oversized or malformed
    file raises ``error(path, field, message)``."""
    return files.read_json(path, error)


def load(path) -> dict:
    """Read and validate a job file (structure and bounds; ``check_inputs`` checks what it points at)."""
    path = os.fspath(path)
    return validate(read_json(path), path)


def save(path, job: dict) -> None:
    """Validate, then write atomically (a unique temporary file, renamed)."""
    path = os.fspath(path)
    validate(job, path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    files.write_json(path, job)


def job_paths(job_path, job: dict, allow_outside: bool = False, checkpoint: bool = False) -> dict:
    """``{field: absolute path}`` of every path the job names (``output_dir``, ``scene.predictions``,
    ``assets[i].ply``, and ``generate.checkpoint`` with ``checkpoint``), relative ones taken from the job's folder.

    Unless ``allow_outside``, each must resolve inside the job's folder (no ``..``, no absolute path elsewhere, no
    symbolic link out): a job received from someone else reads and writes only its own folder. The user allows
    more with ``--allow-outside``; the add-on does, for the output folder the user chose. JobError names the
    field otherwise."""
    job_path = os.fspath(job_path)
    base = os.path.dirname(os.path.abspath(job_path))

    def confine(field, value):
        return files.confined(base, value, lambda f, m: JobError(job_path, f, m), field, allow_outside)

    out = {"output_dir": confine("output_dir", job["output_dir"])}
    if "scene" in job:
        out["scene.predictions"] = confine("scene.predictions", job["scene"]["predictions"])
    for i, a in enumerate(job.get("assets", [])):
        out[f"assets[{i}].ply"] = confine(f"assets[{i}].ply", a["ply"])
    if checkpoint and (job.get("generate") or {}).get("checkpoint"):
        out["generate.checkpoint"] = confine("generate.checkpoint", job["generate"]["checkpoint"])
    return out


def check_inputs(job_path, job: dict, allow_outside: bool = False) -> dict:
    """Everything about a validated job that can be checked before any work, from file headers: the paths
    (``job_paths``), that the predictions file is a readable ``.npz`` whose frames include every
    ``source_frames`` entry, and that each asset is a readable Gaussian file. Returns the paths plus
    ``num_source_frames``; raises an InputError (JobError, PredictionsError, SplatsError) naming file and field."""
    from . import splats, vggt

    paths = job_paths(job_path, job, allow_outside)
    if "scene" in job:
        pred = paths["scene.predictions"]
        shapes = files.npz_shapes(pred, ["extrinsic"], error=lambda p, k, m: vggt.PredictionsError(p, k, m))
        if "extrinsic" not in shapes:
            raise vggt.PredictionsError(pred, "extrinsic", "missing: the file has no camera poses")
        shape = shapes["extrinsic"]  # (S, 3, 4), a batch axis (1, S, 3, 4), or one squeezed frame (3, 4)
        S = shape[1] if len(shape) == 4 and shape[0] == 1 else 1 if len(shape) == 2 else shape[0]
        if S < 1:
            raise vggt.PredictionsError(pred, "extrinsic", f"holds no frames (shape {shape})")
        paths["num_source_frames"] = S
        for i, fr in enumerate(job["frames"]):
            bad = [s for s in fr.get("source_frames", []) if s >= S]
            if bad:
                raise JobError(job_path, f"frames[{i}].source_frames", f"frame(s) {bad[:5]} do not exist: "
                                                                       f"{os.path.basename(pred)} has {S} frames")
    for i, a in enumerate(job.get("assets", [])):
        splats.read(paths[f"assets[{i}].ply"])
    return paths


def resolve(job_path, relative: str) -> str:
    """A path of the job, absolute (paths in a job are relative to the job file's folder)."""
    return os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(job_path)), relative))


def read_list(path) -> list:
    """Paths from a text file, one per line (blank lines and ``#`` comments skipped), relative ones taken from the
    file's folder: the ``--list`` of the batch commands."""
    path = os.fspath(path)
    base = os.path.dirname(os.path.abspath(path))
    with files.open_regular(path) as f:
        data = f.read(files.MAX_JSON_BYTES + 1)
    if len(data) > files.MAX_JSON_BYTES:
        raise files.InputError(path, "(file)", "is too large for a list of job paths")
    try:
        lines = [line.strip() for line in data.decode("utf-8-sig").splitlines()]
    except UnicodeDecodeError as e:
        raise files.InputError(path, "(file)", f"is not UTF-8 text (byte {e.start})") from None
    return [p if os.path.isabs(p) else os.path.join(base, p) for p in lines if p and not p.startswith("#")]


def shard(items: list, rank: int, world: int) -> list:
    """The items of one rank of a batch: every ``world``-th, starting at ``rank`` (deterministic, order kept)."""
    if not 0 <= rank < world:
        raise ValueError(f"rank {rank} is not in [0, {world})")
    return items[rank::world]


def ranks_from_env() -> tuple[int, int, int]:
    """(rank, world size, local rank) from torchrun/accelerate's environment; (0, 1, 0) without it."""
    def get(name, default):
        value = os.environ.get(name, "")
        return int(value) if value.strip() else default
    return get("RANK", 0), get("WORLD_SIZE", 1), get("LOCAL_RANK", 0)
