"""The job contract (DESIGN §4.2): ``job.json``, schema ``scpainter.job/1``, validated on load and before saving.

One JSON file describes a render/generation: output resolution, per-frame cameras (our K, OpenCV
world_to_camera, the VGGT frames whose points project into it), the scene reconstruction with its
``world_from_vggt`` and removal boxes, Gaussian assets with a per-frame object_to_world (PLY file coordinates to
world metres), the output folder and generation settings. Paths are relative to the job file. ``scene`` and
``assets`` may be absent. Every error names the file and the field (``frames[3].K``), never a numpy traceback.

No bpy, no torch: numpy for the matrix checks only.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

SCHEMA = "scpainter.job/1"

#: ``scene.extrinsic_convention``: what the predictions' ``extrinsic`` holds (core.vggt.EXTRINSIC_CONVENTIONS).
EXTRINSIC_CONVENTIONS = ("world_to_camera", "camera_to_world")


class JobError(ValueError):
    def __init__(self, path, field, message):
        self.path, self.field = str(path), field
        super().__init__(f"{os.path.basename(self.path)}: {field}: {message}")


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


def _int(value, path, field, lo=None):
    if isinstance(value, bool) or not isinstance(value, int) or (lo is not None and value < lo):
        raise JobError(path, field, f"expected an integer{'' if lo is None else f' >= {lo}'}, got {value!r}")
    return value


def _number(value, path, field, lo=None, hi=None):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            (lo is not None and value < lo) or (hi is not None and value > hi):
        raise JobError(path, field, f"expected a number in [{lo}, {hi}], got {value!r}")
    return float(value)


def _str(value, path, field):
    if not isinstance(value, str) or not value:
        raise JobError(path, field, f"expected a non-empty string, got {value!r}")
    return value


def validate(job, path="job.json") -> dict:
    """Check every field of a job dict; returns it unchanged, raises JobError naming the field otherwise."""
    if not isinstance(job, dict):
        raise JobError(path, "(top level)", "expected a JSON object")
    if job.get("schema") != SCHEMA:
        raise JobError(path, "schema", f"expected {SCHEMA!r}, got {job.get('schema')!r}")
    res = job.get("resolution")
    if not isinstance(res, list) or len(res) != 2:
        raise JobError(path, "resolution", f"expected [width, height], got {res!r}")
    for i, v in enumerate(res):
        _int(v, path, f"resolution[{i}]", lo=1)
    frames = job.get("frames")
    if not isinstance(frames, list) or not frames:
        raise JobError(path, "frames", "expected a non-empty list")
    seen = set()
    for i, fr in enumerate(frames):
        where = f"frames[{i}]"
        if not isinstance(fr, dict):
            raise JobError(path, where, "expected an object")
        f = _int(fr.get("frame"), path, f"{where}.frame")
        if f in seen:
            raise JobError(path, f"{where}.frame", f"frame {f} appears twice")
        seen.add(f)
        K = _matrix(fr.get("K"), path, f"{where}.K", (3, 3))
        if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(K[2] != [0, 0, 1]) or K[1, 0] != 0:
            raise JobError(path, f"{where}.K", "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        _rigid(fr.get("world_to_camera"), path, f"{where}.world_to_camera")
        src = fr.get("source_frames", [])
        if not isinstance(src, list):
            raise JobError(path, f"{where}.source_frames", "expected a list of frame indices")
        for j, s in enumerate(src):
            _int(s, path, f"{where}.source_frames[{j}]", lo=0)
    if "scene" in job:
        sc = job["scene"]
        if not isinstance(sc, dict):
            raise JobError(path, "scene", "expected an object")
        _str(sc.get("predictions"), path, "scene.predictions")
        W = _matrix(sc.get("world_from_vggt"), path, "scene.world_from_vggt", (4, 4))
        A = W[:3, :3]
        s = np.cbrt(np.linalg.det(A))
        if not s > 0 or np.abs(A.T @ A / s ** 2 - np.eye(3)).max() > 1e-4 or np.any(W[3] != [0, 0, 0, 1]):
            raise JobError(path, "scene.world_from_vggt", "is not a similarity (uniform scale · rotation + shift)")
        _number(sc.get("confidence_percentile", 50.0), path, "scene.confidence_percentile", 0.0, 100.0)
        if sc.get("extrinsic_convention", "world_to_camera") not in EXTRINSIC_CONVENTIONS:
            raise JobError(path, "scene.extrinsic_convention", f"expected one of {list(EXTRINSIC_CONVENTIONS)}, "
                                                               f"got {sc['extrinsic_convention']!r}")
        crop = sc.get("crop", [0, 0, 0, 0])
        if not isinstance(crop, list) or len(crop) != 4:
            raise JobError(path, "scene.crop", f"expected [left, top, right, bottom] in pixels, got {crop!r}")
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
                raise JobError(path, f"{where}.size", f"expected [x, y, z] in metres, got {size!r}")
            for j, v in enumerate(size):
                _number(v, path, f"{where}.size[{j}]", lo=0.0)
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
        for key, lo in (("steps", 1), ("window", 1), ("overlap", 0), ("seed", 0), ("decode_chunk", 1)):
            if key in gen:
                _int(gen[key], path, f"generate.{key}", lo=lo)
        for key, lo in (("min_guidance", 0.0), ("max_guidance", 0.0), ("fps", 1.0)):
            if key in gen:
                _number(gen[key], path, f"generate.{key}", lo=lo)
        if gen.get("overlap", 0) >= gen.get("window", 14):
            raise JobError(path, "generate.overlap", "must be smaller than generate.window")
    return job


def read_json(path, error=JobError):
    """A JSON file's content; a missing or malformed file raises ``error(path, "(file)", message)``."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise error(path, "(file)", "not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise error(path, "(file)", f"not valid JSON: {e}") from None


def load(path) -> dict:
    """Read and validate a job file."""
    path = os.fspath(path)
    return validate(read_json(path), path)


def save(path, job: dict) -> None:
    """Validate, then write atomically (temp file, rename)."""
    path = os.fspath(path)
    validate(job, path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(job, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


def resolve(job_path, relative: str) -> str:
    """A path of the job, absolute (paths in a job are relative to the job file's folder)."""
    return os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(job_path)), relative))


def read_list(path) -> list:
    """Paths from a text file, one per line (blank lines and ``#`` comments skipped), relative ones taken from the
    file's folder: the ``--list`` of the batch commands."""
    path = os.fspath(path)
    base = os.path.dirname(os.path.abspath(path))
    try:
        with open(path, encoding="utf-8") as f:
            lines = [line.strip() for line in f]
    except OSError as e:
        raise ValueError(f"{path}: cannot read the list ({e.strerror})") from None
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
