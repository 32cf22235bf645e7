"""``python -m backend evaluate``: the paper's protocol on validation clips, and ground truth where a clip has it.

Per clip, the first ``frames`` frames at ``width`` x ``height``, as jobs (job.json) that go through the same
``render`` and ``generate`` code as users' jobs (so they resume and skip finished work):

* ``nvs_<shift>``: the recorded drive shifted laterally by each shift (metres, + left; paper §4.2: ±2, ±3 m),
  points of frames t ± source_window projected into frame t;
* ``insert``: re-insertion (paper §4.1): the clip's first tracked car with an asset has its points removed (grown
  box) and its Gaussian asset placed at its boxes, recorded cameras;
* ``insert_shift<s>``: both at once (paper §4.3), shifted by the first shift.

Each task has a *generated* video (with ``--checkpoint``), the *naive* baseline, its condition image I (points
and asset composited, holes black: the paper's "naive insertion"), and the *baseline*: I with its holes filled by
OpenCV inpainting (``backend/generate/baseline.py``, what ``generate`` makes without a checkpoint; also written as the
task's ``baseline.mp4``).

Every task's job is written first (``write_jobs``), then each is run and scored in turn. With ``--ray``
(``RayPool``) the jobs all run on a Ray cluster first (``run_jobs_on_pool``: ``batch_ray``'s scheduling, retries and
progress), a failed one ending the evaluation before any metric; the same loop then finds every output up to date
and only reads it, so the metrics are computed here exactly as without Ray. ``precision auto`` is resolved once for
the device the videos are made on (``generate.resolve_precision``), since a video's up-to-date key holds it.

Metrics (``evaluation.json``, and a table on standard error):

* FID / KID (Inception pool3 from ``--inception``, never downloaded) of every NVS task's frames against the
  recorded frames of all clips (paper Table 2), and of the combined task (Table 3, whole frames);
* FID-C / KID-C on car-centred crops (Table 1): generated and naive crops from the asset mask (its bounding box,
  squared and grown by ``crop_grow``), real crops from the tracked cars' boxes projected into the recorded frames;
* PSNR / SSIM against ground-truth views (``views`` in clip.json, e.g. the street's Cycles renders), per shift,
  over all pixels and over the pixels the condition covers (1 − hole).

With a handful of frames FID is dominated by its sample bias (it needs thousands of images); the numbers are
computed exactly as for a full validation set and reported with the image counts so nobody mistakes them.

Over ~400 lines because the protocol is one piece: its tasks, their jobs, the crops and the metrics loop must agree
(names, folders, frames), and reading them together is how that is checked.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from typing import TYPE_CHECKING

import numpy as np
import torch

from scpainter_blender.core import batch_items
from scpainter_blender.core import fields as fields_mod
from scpainter_blender.core import errors, outputs
from scpainter_blender.core.geometry import trajectory
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.output_layout import GENERATED_FRAME, OutputLayout

from ..batch import ray_pool as batch_ray
from .. import events
from ..errors import CleanFailure
from . import pictures
from ..train import clip as clip_mod
from ..train.pairs import load_clip_frames, load_resized
from ..train.view_settings import ViewSettings

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Iterable, Sequence


@dataclass(frozen=True)
class EvalSettings(ViewSettings):
    """The view (``ViewSettings``: resolution, frames, source window, removal-box growth as in training pairs,
    confidence), the tasks and the metrics."""

    clips: list
    output_dir: str
    checkpoint: str | None = None       # None: baselines only
    shifts: tuple = (2.0, -2.0, 3.0, -3.0)
    insertion: bool = True
    steps: int = job_mod.GENERATE_DEFAULTS["steps"]
    seed: int = job_mod.GENERATE_DEFAULTS["seed"]
    precision: str = "auto"
    inception: str | None = None
    crop_size: int = 128                # crops are resized to this square before the feature extractor
    crop_grow: float = 1.2
    crop_min_px: int = 16               # smaller cars (2D box side, pixels at the evaluation size) are left out
    inpaint: str = job_mod.BASELINE_DEFAULTS["inpaint"]             # the baseline's OpenCV method
    inpaint_radius: int = job_mod.BASELINE_DEFAULTS["inpaint_radius"]

    @classmethod
    def from_args(cls, a: argparse.Namespace) -> EvalSettings:
        """From ``python -m backend evaluate``'s arguments (backend/commands/evaluate.py): only the options given (their
        argparse default is None), the rest from this class and ``ViewSettings``, so a default is written once.
        Each value is checked: ``ArgumentError`` names the option. The bounds are the job's (``core.job``) plus
        what the metrics need: SSIM's 11 × 11 window fits the frames, and FID/KID get at least 2 frames per set."""
        # an option whose dest is a field's name is taken as given; --resolution W H and --no-insertion are mapped
        given = {f.name: getattr(a, f.name) for f in fields(cls) if getattr(a, f.name, None) is not None}
        if a.resolution is not None:
            given["width"], given["height"] = a.resolution
        if "shifts" in given:
            given["shifts"] = tuple(given["shifts"])
        if a.no_insertion:
            given["insertion"] = False
        s = cls(**given)

        def integer(value, option, lo, hi=None):
            return fields_mod.integer(value, errors.COMMAND_LINE, option, lo, hi,
                                      error=lambda p, f, m: errors.ArgumentError(f, m))

        W, H = (integer(v, "--resolution", 11, job_mod.MAX_SIDE) for v in (s.width, s.height))
        if W * H > job_mod.MAX_PIXELS:
            raise errors.ArgumentError("--resolution", f"{W} x {H} is more than {job_mod.MAX_PIXELS:,} pixels")
        integer(s.frames, "--frames", 2, job_mod.MAX_FRAMES)
        integer(s.source_window, "--source-window", 0, job_mod.MAX_SOURCE_FRAME)
        for key in ("steps", "seed"):
            integer(getattr(s, key), f"--{key}", *job_mod.GENERATE_INT_BOUNDS[key])
        integer(s.crop_min_px, "--crop-min-px", 0)
        for v in s.shifts:
            fields_mod.number(v, errors.COMMAND_LINE, "--shifts", -1000.0, 1000.0,
                              error=lambda p, f, m: errors.ArgumentError(f, m))
        return s


@dataclass(frozen=True)
class RayPool:
    """``evaluate --ray``: the tasks' jobs run on a Ray cluster first (``run_jobs_on_pool``), with
    ``batch_ray.run_ray_batch``'s options; the metrics are then computed in this process, as without it."""

    address: str | None = None          # HOST:PORT of the head; None or "": RAY_ADDRESS, `ray start`'s, a new one
    device: str = "auto"                # the workers': cuda (one GPU per job) when the cluster has GPUs
    retries: int = batch_items.DEFAULT_RETRIES
    cpus_per_job: float = batch_items.DEFAULT_CPUS_PER_JOB     # on a cluster without GPUs

    def __post_init__(self):
        # batch --ray's check (run_ray_batch), made here too so evaluate refuses it before writing anything
        batch_items.check_ray_options(self.retries, self.cpus_per_job)

    @classmethod
    def from_args(cls, a: argparse.Namespace) -> RayPool | None:
        """From ``python -m backend evaluate``'s arguments: None without ``--ray``."""
        if a.ray is None:
            return None
        return cls(address=a.ray or None, device=a.device, retries=a.retries, cpus_per_job=a.cpus_per_job)


# ---------------------------------------------------------------------------------------------------------------
# Jobs
# ---------------------------------------------------------------------------------------------------------------

def insertion_car(clip: clip_mod.Clip, frames: range) -> int | None:
    """The first tracked car with an asset and a box in every evaluated frame."""
    for i, car in enumerate(clip.cars):
        if car.asset is not None and all(t in car.boxes for t in frames):
            return i
    return None


def task_job(clip: clip_mod.Clip, s: EvalSettings, folder: str, shift: float, car: int | None) -> str:
    """Write ``folder/job.json`` for one task; returns its path."""
    frames = range(min(s.frames, clip.num_frames))
    if shift and not clip.metric:
        raise clip_mod.ClipError(clip.path, "poses", "lateral shifts in metres need metric poses (poses.npz)")
    w2c = trajectory.shift_trajectory(clip.world_to_camera, left_m=shift) if shift else clip.world_to_camera
    K = clip.K_for(s.width, s.height)
    S = clip.num_frames
    boxes, assets = [], []
    if car is not None:
        c = clip.cars[car]
        unique = {}
        for t in range(S):  # every box of the car, deduplicated: its points are gone from every source frame
            if t in c.boxes:
                unique.setdefault(np.round(c.boxes[t], 4).tobytes(), c.boxes[t])
        for b in unique.values():
            box_to_world, size = clip_mod.grown_box(b, c.size, s.grow_m, s.grow_ratio)
            boxes.append(job_mod.RemovalBox(box_to_world, size))
        a2b = clip_mod.asset_to_box(c)
        assets.append(job_mod.Asset(c.id, os.path.relpath(c.asset, folder), {t: c.boxes[t] @ a2b for t in frames}))
    # the clip's tracked cars travel with the job as recorded objects, so the task's frames are labelled (the
    # re-inserted car's own track lies in its removal boxes: listed as removed, its asset labelled instead)
    recorded = [job_mod.RecordedObject(str(c.id), c.size, {t: c.boxes[t] for t in frames if t in c.boxes})
                for c in clip.cars if any(t in c.boxes for t in frames)]
    scene = job_mod.Scene(os.path.relpath(clip.predictions.path, folder), clip.vggt_to_world,
                          confidence_percentile=s.confidence_percentile, removal_boxes=boxes,
                          recorded_frames=[0, S - 1], recorded_objects=recorded)
    job = job_mod.Job((s.width, s.height), [
        job_mod.Frame(t, K[t], w2c[t], list(range(max(0, t - s.source_window), min(S, t + s.source_window + 1))))
        for t in frames],
        output_dir=".", scene=scene, assets=assets, fps=float(clip.fps),
        generate=job_mod.GenerateSettings(steps=s.steps, seed=s.seed, fps=float(clip.fps)))
    os.makedirs(folder, exist_ok=True)
    path = OutputLayout(folder).job  # the task's output folder (output_dir ".")
    job_mod.save(path, job)
    return path


def tasks(clip: clip_mod.Clip, s: EvalSettings) -> list:
    """(name, shift, car) of the tasks this clip supports."""
    out = [(f"nvs_{shift:+g}m", shift, None) for shift in s.shifts]
    car = insertion_car(clip, range(min(s.frames, clip.num_frames))) if s.insertion else None
    if car is not None:
        out.append(("insert", 0.0, car))
        if s.shifts:
            out.append((f"insert_shift{s.shifts[0]:+g}m", s.shifts[0], car))
    return out


@dataclass(frozen=True)
class EvalTask:
    """One task of one clip, its job written (``write_jobs``); the job's folder holds the task's outputs."""

    clip: int                           # index into the settings' clips
    clip_name: str                      # "000_street": the clip's folder under the output folder
    name: str                           # nvs_+2m, insert, insert_shift+2m (``tasks``)
    shift: float                        # metres, + left
    car: int | None                     # the re-inserted car (index into clip.cars), None for NVS
    job: str                            # absolute path of the task's job.json

    @property
    def folder(self) -> str:
        return os.path.dirname(self.job)


def clip_name(index: int, clip: clip_mod.Clip) -> str:
    """The clip's folder under the output folder and its name in evaluation.json: "000_street"."""
    return f"{index:03d}_{os.path.basename(clip.folder)}"


def write_jobs(clips: list, s: EvalSettings, out_dir: str) -> list[EvalTask]:
    """Every task of every clip (``tasks``), its job written to ``out_dir/<clip_name>/<task>/job.json``, in the
    order the metrics visit them. ``ClipError`` (bad input) for a clip that cannot make a task."""
    work = []
    for ci, clip in enumerate(clips):
        folder = os.path.join(os.path.abspath(out_dir), clip_name(ci, clip))
        for name, shift, car in tasks(clip, s):
            job = task_job(clip, s, os.path.join(folder, name), shift, car)
            work.append(EvalTask(ci, clip_name(ci, clip), name, shift, car, job))
    return work


class TaskInputError(errors.InputError):
    """Bad input a task's job met on the pool: the job's file and field, and its message as the job wrote it
    (which already names them: ``str()`` does not put them in front again), followed by the task."""

    def __init__(self, path: str, field: str, text: str, hint: str | None = None) -> None:
        super().__init__(path, field, text, hint)
        self.args = (text,)


def run_jobs_on_pool(work: list[EvalTask], s: EvalSettings, pool: RayPool, stop: Sequence[object] = (),
                     log: Callable[[str], None] = events.log) -> list | None:
    """Every task's job on the Ray pool (``batch_ray.run_ray_batch``, progress stage ``evaluate-jobs``):
    ``generate`` with ``s.checkpoint`` (at ``s.precision``, resolved: ``generate.resolve_precision``), else
    ``render``. A job finished before is skipped by its own key, so a second evaluation only checks. Returns per
    task ``clip``, ``task``, ``worker`` (host:pid), ``attempts``, ``seconds``, ``skipped``; None when ``stop``
    (SIGTERM) ended it.

    Raises when a task failed, so no metric is computed from a partial evaluation: bad input (the job's result names
    a file and field) a ``TaskInputError`` naming them; anything else a ``CleanFailure`` naming the failed tasks with
    their errors and logs (``failed``)."""
    t0 = time.perf_counter()
    results = batch_ray.run_ray_batch(
        [t.job for t in work], "generate" if s.checkpoint else "render", pool.device,
        # absolute: a worker's working directory is not this process's
        os.path.abspath(s.checkpoint) if s.checkpoint else None,
        allow_outside=True,  # the protocol writes these jobs itself, pointing at the clip folders the user named
        half=None,  # as run_task's render: keep the precision of the frames already there (float32 when none)
        address=pool.address, retries=pool.retries, cpus_per_job=pool.cpus_per_job, stop=stop,
        precision=s.precision, stage="evaluate-jobs")
    if stop:
        return None
    failed = [(t, r) for t, r in zip(work, results) if r["status"] != "ok"]
    # bad input: an InputError's result (batch.failure) has its file and field; a CleanFailure's may name a file
    bad = [(t, r) for t, r in failed if r.get("field")]
    if bad:
        t, r = bad[0]
        others = f"; {len(failed) - 1} other task(s) failed too" if len(failed) > 1 else ""
        log(f"evaluate: task {t.clip_name}/{t.name} ({t.job}): bad input: {r['error']}{others}")
        raise TaskInputError(r["file"], r["field"], f"{r['error']} (evaluation task {t.clip_name}/{t.name}, job "
                                                    f"{t.job}{others})",
                             hint=r.get("hint") or "fix the file named, then run the same command again: finished "
                                                   "tasks are kept")
    if failed:
        listed = [{"clip": t.clip_name, "task": t.name, "job": t.job, "status": r["status"],
                   "error": r.get("error"), "log": r.get("log")} for t, r in failed]
        lines = "; ".join(f"{f['clip']}/{f['task']}: {f['error'] or f['status']}"
                          + (f" (log {f['log']})" if f["log"] else "") for f in listed)
        log(f"evaluate: {len(failed)} of {len(work)} tasks failed on the Ray pool: {lines}")
        raise CleanFailure(f"{len(failed)} of {len(work)} evaluation tasks failed on the Ray pool, so no metric was "
                           f"computed: {lines}",
                           hint="each task's error says what failed (a bug's traceback is in the log named); run "
                                "the same command again once fixed: finished tasks are kept", failed=listed)
    log(f"evaluate: {len(work)} jobs on the Ray pool in {time.perf_counter() - t0:.1f} s "
        f"({sum(bool(r.get('skipped')) for r in results)} already finished)")
    return [{"clip": t.clip_name, "task": t.name, "worker": r["worker"], "attempts": r["attempts"],
             "seconds": r["seconds"], "skipped": bool(r.get("skipped"))} for t, r in zip(work, results)]


# ---------------------------------------------------------------------------------------------------------------
# Crops
# ---------------------------------------------------------------------------------------------------------------

def square_box(x0: float, y0: float, x1: float, y1: float, grow: float, width: int, height: int) -> tuple[int, int, int,
               int] | None:
    """A square around the box (x0, y0)-(x1, y1) (pixels), side = grow × the longer side, moved to lie inside
    the image where it fits; None when the box is empty."""
    if x1 <= x0 or y1 <= y0:
        return None
    side = min(max(x1 - x0, y1 - y0) * grow, width, height)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    left = int(round(min(max(cx - side / 2, 0), width - side)))
    top = int(round(min(max(cy - side / 2, 0), height - side)))
    side = int(round(side))
    return left, top, left + side, top + side


def crop(image: torch.Tensor, box: tuple[int, int, int, int], size: int) -> torch.Tensor:
    """(3, size, size) from image (3, H, W) float in [0, 1] (bilinear, antialiased)."""
    x0, y0, x1, y1 = box
    c = image[:, y0:y1, x0:x1][None]
    return torch.nn.functional.interpolate(c, size=(size, size), mode="bilinear", antialias=True,
                                           align_corners=False)[0].clamp(0, 1)


def mask_crop_box(mask: np.ndarray, grow: float, min_px: int = 16) -> tuple[int, int, int, int] | None:
    """Square crop box around the pixels where the asset mask exceeds 0.5; None if their bounding box is smaller
    than min_px on a side."""
    ys, xs = np.nonzero(mask > 0.5)
    if len(xs) == 0 or xs.max() + 1 - xs.min() < min_px or ys.max() + 1 - ys.min() < min_px:
        return None
    H, W = mask.shape
    return square_box(xs.min(), ys.min(), xs.max() + 1, ys.max() + 1, grow, W, H)


def box_crop_box(box_to_world: np.ndarray, size: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, width: int,
                 height: int, grow: float, min_px: int = 16) -> tuple[int, int, int, int] | None:
    """Square crop box around a 3D box's projection (all 8 corners in front of the camera, at least half of its
    2D box inside the image, at least min_px on a side); None otherwise."""
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]) * size
    world = corners @ np.asarray(box_to_world)[:3, :3].T + np.asarray(box_to_world)[:3, 3]
    cam = world @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    if np.any(cam[:, 2] <= 0.1):
        return None
    uv = cam @ np.asarray(K).T
    uv = uv[:, :2] / uv[:, 2:]
    x0, y0 = uv.min(axis=0)
    x1, y1 = uv.max(axis=0)
    ix0, iy0, ix1, iy1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    if ix1 - ix0 < min_px or iy1 - iy0 < min_px or (ix1 - ix0) * (iy1 - iy0) < 0.5 * (x1 - x0) * (y1 - y0):
        return None
    return square_box(ix0, iy0, ix1, iy1, grow, width, height)


# ---------------------------------------------------------------------------------------------------------------
# Evaluation
# ---------------------------------------------------------------------------------------------------------------

@dataclass
class ImageSets:
    """Images (3, H, W) float in [0, 1] collected per set name, for FID/KID at the end."""

    sets: dict = field(default_factory=dict)

    def add(self, name: str, images: Iterable[torch.Tensor]) -> None:
        self.sets.setdefault(name, []).extend(list(images))


def _read_png(path: str, width: int, height: int) -> torch.Tensor:
    return load_resized(path, width, height).float() / 255.0


def run_task(job_path: str, device: str, s: EvalSettings, stop: Sequence[object]) -> dict:
    """Render (and generate, with a checkpoint) one task; returns its I, M_a, validity and generated frames."""
    from ..generate import command as gen_mod
    from ..render import command as render_cmd

    job = job_mod.load(job_path)
    out = {"generated": None}
    if s.checkpoint:
        # the protocol writes these jobs itself, pointing at the clip folders the user named: outside is allowed
        r = gen_mod.generate_job(job_path, job, device, s.checkpoint, s.precision, stop=stop, allow_outside=True)
        if r.get("stopped"):
            return {"stopped": True}
        out["generated"] = torch.stack([_read_png(os.path.join(r["frames_dir"], GENERATED_FRAME.name(e.frame)),
                                                  s.width, s.height) for e in job.frames])
    else:
        r = render_cmd.render_job(job_path, job, device, stop=stop, allow_outside=True)
        if r["stopped"]:
            return {"stopped": True}
    out["image"], out["asset_mask"], out["valid"] = gen_mod.load_conditions(job_path, job)
    out["frames"] = [e.frame for e in job.frames]
    return out


def baseline_video(task: dict, s: EvalSettings, folder: str, fps: float) -> torch.Tensor:
    """(T, 3, H, W) float in [0, 1]: the task's condition image with its holes inpainted (``baseline``, the same
    function ``generate`` uses without a checkpoint), also written as ``folder/baseline.mp4`` for people."""
    from ..generate import baseline
    from ..generate.video import write_mp4

    rgb = baseline.inpaint_video(task["image"].numpy(), 1.0 - task["valid"].numpy(), s.inpaint, s.inpaint_radius)
    write_mp4(OutputLayout(folder).eval_baseline, rgb, min(max(fps, 1.0), 240.0),
              metadata={"title": "SCPainter baseline", "comment": baseline.describe(s.inpaint, s.inpaint_radius)})
    return torch.from_numpy(rgb).permute(0, 3, 1, 2).float() / 255.0


def temporal_metrics(video: torch.Tensor | Sequence[torch.Tensor]) -> dict:
    """The flow-warping error (``temporal.warping_error``) of a video given as (T, 3, H, W) values in [0, 1] (a
    tensor or a list of (3, H, W) frames): ``warping_error`` and the mean fraction of pixels that ``counted``."""
    from .temporal import warping_error

    frames = torch.stack(list(video)) if not torch.is_tensor(video) else video
    r = warping_error(frames.permute(0, 2, 3, 1).float().cpu().numpy())
    return {"warping_error": r.mean, "counted": float(r.counted.mean()) if len(r.counted) else float("nan")}


def ground_truth_metrics(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor) -> dict:
    from .image_metrics import psnr, ssim

    covered = valid > 0.5
    return {"psnr": float(psnr(pred, gt).mean()), "ssim": float(ssim(pred, gt).mean()),
            "psnr_covered": float(psnr(pred, gt, mask=covered).mean()),
            "ssim_covered": float(ssim(pred, gt, mask=covered).mean())}


def feature_metrics(sets: dict, reference: str, net: Callable[[torch.Tensor], torch.Tensor] | None, device: str,
                    log: Callable[[str], None]) -> dict:
    """FID and KID of every set against ``reference`` (a key of ``sets``), with the feature extractor ``net``
    ((N, 3, H, W) in [0, 1] -> (N, D)); None: skipped."""
    if net is None:
        return {"skipped": "no --inception weights given (FID needs pt_inception-2015-12-05-6726825d.pth; "
                           "nothing is downloaded)"}
    from .fid import FeatureStats, fid, kid

    feats = {}
    for name, images in sets.items():
        st = FeatureStats(keep_features=True)
        for i in range(0, len(images), 16):
            with torch.no_grad():
                st.update(net(torch.stack(images[i:i + 16]).to(device)).cpu())
        feats[name] = st
        log(f"evaluate: features of {name}: {st.count} images")
    out = {}
    ref = feats[reference]
    for name, st in feats.items():
        if name == reference:
            continue
        k_mean, k_std = kid(ref.features(), st.features(), subsets=100, subset_size=min(1000, ref.count, st.count))
        out[name] = {"fid": fid(ref, st), "kid": k_mean, "kid_std": k_std, "images": st.count,
                     "reference_images": ref.count}
    return out


def evaluate(s: EvalSettings, device: str, stop: Sequence[object] = (),
             extractor: Callable[[torch.Tensor], torch.Tensor] | None = None, pool: RayPool | None = None) -> dict:
    """Run every task of every clip and write ``evaluation.json``; returns its path, ``seconds`` and the ground-truth
    rows, or ``{"stopped": True}`` when ``stop`` (SIGTERM) ended it. ``device``: this process's (the metrics, and
    any job not finished yet). ``pool``: every task's job runs on a Ray pool first (``run_jobs_on_pool``; its
    failures raise before any metric), and evaluation.json lists where each ran (``jobs``); the tasks' loop then
    finds every output up to date and only reads it. ``extractor`` replaces the Inception network given by
    ``s.inception`` (tests use a tiny random one; FID's statistics do not depend on the extractor)."""
    if extractor is None and s.inception:
        from .inception import load_inception

        extractor = load_inception(s.inception, device)  # fail fast: before hours of generation
    # precision auto resolved once, for the device the videos are made on (the pool's workers when there is one),
    # and asked for by the pool and this process alike: it is part of a video's up-to-date key
    from ..generate.command import resolve_precision

    s = replace(s, precision=resolve_precision(s.precision, batch_ray.job_device(pool.device, pool.address)
                                                if pool is not None else device))
    out_dir = os.path.abspath(s.output_dir)
    os.makedirs(out_dir, exist_ok=True)
    log = events.FileLog(os.path.join(out_dir, "evaluate.log"))
    t0 = time.perf_counter()
    clips = [clip_mod.load(p) for p in s.clips]
    work = write_jobs(clips, s, out_dir)
    jobs = None
    if pool is not None:
        jobs = run_jobs_on_pool(work, s, pool, stop, log)
        if jobs is None:
            return {"stopped": True}
    whole, crops = ImageSets(), ImageSets()
    gt_rows, temporal_rows = [], []
    for ci, clip in enumerate(clips):
        frames = range(min(s.frames, clip.num_frames))
        K = clip.K_for(s.width, s.height)
        # undistorted (clip.json's distortion) and resized as training's targets are; a video clip decoded once
        real = list(load_clip_frames(clip, s.width, s.height, list(frames)).float() / 255.0)
        whole.add("real", real)
        temporal_rows.append({"clip": clip_name(ci, clip), "task": "recorded", "shift_m": 0.0, "output": "real",
                              **temporal_metrics(real)})
        for car in clip.cars:  # real car crops for FID-C, from the boxes on the recorded frames
            for t in frames:
                if t in car.boxes:
                    b = box_crop_box(car.boxes[t], car.size, K[t], clip.world_to_camera[t], s.width, s.height,
                                     s.crop_grow, s.crop_min_px)
                    if b is not None:
                        crops.add("real", [crop(real[t], b, s.crop_size)])
        for n, task in ((n, t) for n, t in enumerate(work, 1) if t.clip == ci):
            if stop:
                return {"stopped": True}
            name, shift, car = task.clip_name, task.shift, task.car
            log(f"evaluate: {name} {task.name}")
            r = run_task(task.job, device, s, stop)
            if r.get("stopped"):
                return {"stopped": True}
            events.progress("evaluate", n, len(work), clip=name, task=task.name)
            kinds = {"naive": r["image"], "baseline": baseline_video(r, s, task.folder, clip.fps)}
            if r["generated"] is not None:
                kinds["generated"] = r["generated"]
            for kind, video in kinds.items():
                temporal_rows.append({"clip": name, "task": task.name, "shift_m": shift, "output": kind,
                                      **temporal_metrics(video)})
                whole.add(f"{task.name}/{kind}", video)
                if car is not None:
                    for f, asset_mask in zip(video, r["asset_mask"]):
                        b = mask_crop_box(asset_mask[0].numpy(), s.crop_grow, s.crop_min_px)
                        if b is not None:
                            crops.add(f"{task.name}/{kind}", [crop(f, b, s.crop_size)])
            sheet = {"condition I": r["image"], "baseline": kinds["baseline"],
                     **({"generated": r["generated"]} if r["generated"] is not None else {})}
            if car is None and shift in clip.views:
                gt = load_clip_frames(clip, s.width, s.height, list(frames), view=shift).float() / 255.0
                sheet["ground truth"] = gt
                temporal_rows.append({"clip": name, "task": task.name, "shift_m": shift, "output": "ground_truth",
                                      **temporal_metrics(gt)})  # the floor: real motion the flow cannot explain
                for kind, video in kinds.items():
                    gt_rows.append({"clip": name, "task": task.name, "shift_m": shift, "output": kind,
                                    "frames": len(frames), "hole_fraction": float(1 - r["valid"].mean()),
                                    **ground_truth_metrics(video, gt, r["valid"])})
            pictures.contact_sheet(OutputLayout(task.folder).eval_sheet, sheet)
    result = {"settings": asdict(s), "seconds": None, "ground_truth": gt_rows, "temporal": temporal_rows,
              "fid": feature_metrics(whole.sets, "real", extractor, device, log),
              "fid_c": (feature_metrics(crops.sets, "real", extractor, device, log)
                        if (skip_c := crops_skipped(crops.sets, s, work)) is None else {"skipped": skip_c}),
              "counts": {"whole": {k: len(v) for k, v in whole.sets.items()},
                         "crops": {k: len(v) for k, v in crops.sets.items()}}}
    if not gt_rows:  # say why the table is empty rather than print an empty one
        result["ground_truth_skipped"] = ground_truth_skipped(clips, s)
    if jobs is not None:  # where each task's job ran on the pool, and how long it took there
        result["jobs"] = jobs
    result["seconds"] = time.perf_counter() - t0
    pictures.metrics_plot(os.path.join(out_dir, "metrics.png"), gt_rows, temporal_rows)
    path = os.path.join(out_dir, "evaluation.json")
    outputs.write_json(path, events.json_safe(result))  # strict JSON: a NaN/inf metric (e.g. no covered pixel) is null
    log(format_table(result))
    events.artifact(path, kind="evaluation")
    return {"evaluation": path, "seconds": result["seconds"], "ground_truth": gt_rows}


def crops_skipped(sets: dict, s: EvalSettings, work: list) -> str | None:
    """Why FID-C / KID-C cannot be computed from the car crops ``sets`` (ImageSets.sets), or None when they can."""
    if not any(t.car is not None for t in work):
        return ("no insertion task (--no-insertion)" if not s.insertion else
                "no insertion task: no clip has a tracked car with an asset in its first frames")
    if "real" not in sets:
        return "no real car crops (no tracked car's box in view on the recorded frames)"
    if len(sets) == 1:
        return "no inserted car in view (its asset mask is empty on every frame)"
    return None


def ground_truth_skipped(clips: list, s: EvalSettings) -> str:
    """Why no task was compared with a ground-truth view: the shifts asked and the views the clips have."""
    have = sorted({float(v) for c in clips for v in c.views})
    if not have:
        return "no clip has ground-truth views (clip.json's \"views\")"
    return (f"no ground-truth view at the shifts asked ({', '.join(f'{x:+g}' for x in s.shifts) or 'none'} m); "
            f"the clips have views at {', '.join(f'{x:+g}' for x in have)} m (--shifts)")


def format_table(result: dict) -> str:
    lines = ["ground truth (PSNR dB / SSIM; all pixels | covered pixels):",
             f"{'task':<16}{'output':<11}{'holes':>7}{'PSNR':>8}{'SSIM':>7}{'PSNR cov':>10}{'SSIM cov':>9}"]
    if "ground_truth_skipped" in result:
        lines[1:] = [f"  skipped: {result['ground_truth_skipped']}"]
    for r in result["ground_truth"]:
        r = {k: float("nan") if v is None else v for k, v in r.items()}  # evaluation.json holds NaN/inf as null
        lines.append(f"{r['task']:<16}{r['output']:<11}{r['hole_fraction']:>7.3f}{r['psnr']:>8.2f}{r['ssim']:>7.3f}"
                     f"{r['psnr_covered']:>10.2f}{r['ssim_covered']:>9.3f}")
    lines.append("temporal consistency (flow-warping error, lower is steadier; counted = pixels the flows agree on):")
    for r in result.get("temporal", []):
        r = {k: float("nan") if v is None else v for k, v in r.items()}
        lines.append(f"  {r['task']:<16}{r['output']:<13}{r['warping_error']:>10.5f}  counted {r['counted']:.2f}")
    for key in ("fid", "fid_c"):
        m = result[key]
        if "skipped" in m:
            lines.append(f"{key}: skipped: {m['skipped']}")
            continue
        lines.append(f"{key} (against real; images):")
        for name, v in m.items():
            lines.append(f"  {name:<30} FID {v['fid']:8.2f}  KID {v['kid']:.4f} ± {v['kid_std']:.4f}  "
                         f"({v['images']} vs {v['reference_images']})")
    return "\n".join(lines)
