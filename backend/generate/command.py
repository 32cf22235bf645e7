"""The body of ``python -m backend generate``: conditions -> SCPainter video (docs/design.md §11), resumable,
stoppable. Without a checkpoint (or with ``--model baseline``) the video is the baseline's instead: the condition
image with its holes filled by OpenCV inpainting (``backend/generate/baseline.py``), marked as such in the manifest, the
events and the MP4's metadata.

Steps: render the condition layers that are missing (the render command's code); load I, M_a and the validity
1 − hole of every frame; pad them with holes to the model's size multiple; CLIP-embed the first source frame
(the recorded image; the first condition image when the job has no scene); sample the whole clip in overlapping
windows; decode in chunks; crop; write ``generated/frame_NNNNNN.png`` and ``generated.mp4``.

Resume: after every sampler step the latents are saved (atomically) to ``generate_state.safetensors`` with a key
hashing everything that determines the result (checkpoint, settings, conditions); a run with the same key
continues from the saved step and gives exactly the frames of an uninterrupted run (the sampler draws no noise
after the start). A finished run writes ``generated/manifest.json`` last; running again with the same key skips.
A run removes the previous manifest before it replaces the first frame (``_write_outputs``), so a run killed or
failing while it writes frames leaves a folder that is never called up to date (the model's and the baseline's).

(Just over 400 lines: the plan, the conditions' loading, the resume keys and the outputs' writing are the model's
and the baseline's alike; one module keeps the two generators on one path to the same files.)
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from scpainter_blender.core import errors, files, locking, outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import job_inputs
from scpainter_blender.core.output_layout import GENERATED_FRAME, OutputLayout

from . import baseline
from .. import events, png
from ..errors import FolderBusyError
from ..model import checkpoint as ckpt_mod
from ..render import command as render_cmd
from ..render import channels, rig_jobs

if TYPE_CHECKING:
    from collections.abc import Sequence

PRECISIONS = {"fp32": torch.float32, "bf16": torch.bfloat16, "fp16": torch.float16}
#: The settings that go to ``SCPainterPipeline.sample`` by name (``compile`` and ``gpu_tuning``: ``set_speed``).
SAMPLING = ("sampler", "feature_reuse", "guidance_sigma_min", "guidance_sigma_max")


@dataclass
class Plan:
    """What ``generate`` will do, known before anything is rendered or loaded (``prepare``)."""
    checkpoint: str | None  # None for the baseline
    settings: dict          # complete: GenerateSettings.resolve's (the model) or resolve_baseline's (the baseline)
    output_dir: str
    paths: dict
    model: str = "scpainter"   # "scpainter" or "baseline" (never "auto": prepare decides)

    def description(self) -> str:
        """What the video will be, in one line (logs, events, the manifest, the MP4's metadata)."""
        if self.model == "baseline":
            return baseline.describe(self.settings["inpaint"], self.settings["inpaint_radius"])
        return f"SCPainter model: checkpoint {self.checkpoint}"


#: How to get the model's video instead of the baseline's (events, the demo, the Blender report).
USE_CHECKPOINT_HINT = ("this is the inpainting baseline, not the model: for SCPainter's video pass --checkpoint DIR "
                       "(python -m backend init-checkpoint --svd SVD_SNAPSHOT --out DIR makes one from a Stable Video "
                       "Diffusion snapshot on disk) or set generate.checkpoint in the job")


def prepare(job_path: str, job: job_mod.Job, checkpoint: str | None, overrides: dict | None = None,
            allow_outside: bool = False, data_roots: Sequence[str] = ()) -> Plan:
    """Validate a generation before any work: the command-line overrides, the checkpoint (``checkpoint.check``:
    config field by field, safetensors only), the settings the job, overrides and checkpoint make together, and
    the job's input files (``job_inputs.check_inputs``; its paths confined to the job's folder and ``data_roots``
    unless ``allow_outside``). Raises an InputError naming the file (or "(command line)") and
    the field.

    The generator: ``overrides["model"]``, else the job's ``generate.model``, else ``auto`` — the model when a
    checkpoint is configured (``checkpoint`` or the job's ``generate.checkpoint``), the baseline otherwise. An
    explicit ``scpainter`` without a checkpoint is refused, saying how to make one; ``baseline`` ignores any
    checkpoint."""
    overrides = overrides or {}
    job_mod.check_generate_settings({k: v for k, v in overrides.items() if v is not None}, errors.COMMAND_LINE, "--")
    gen = job.generate or job_mod.GenerateSettings()
    model = gen.model_choice(overrides)
    if model == "auto":
        model = "scpainter" if checkpoint or gen.checkpoint else "baseline"
    if model == "baseline":
        paths = job_inputs.check_inputs(job_path, job, allow_outside, data_roots)
        outputs.check_output(paths["output_dir"], allow_outside)
        paths["allow_outside"] = allow_outside
        return Plan(None, gen.resolve_baseline(overrides), paths["output_dir"], paths, "baseline")
    if checkpoint:  # the command line's: the user's own choice, never confined
        ckpt = ckpt_mod.resolve(checkpoint)
    elif job.generate is None or not job.generate.checkpoint:
        ckpt = ckpt_mod.resolve(None, job_path, "generate.checkpoint")  # refused, naming the job file and field
    else:  # the job's own checkpoint path is relative to the job and confined like its other paths
        try:
            named = job_inputs.job_paths(job_path, job, allow_outside, checkpoint=True,
                                         data_roots=data_roots)["generate.checkpoint"]
        except job_mod.JobError as e:
            if e.field != "generate.checkpoint":
                raise
            raise job_mod.JobError(job_path, e.field, e.message, f"{e.hint}; or name the checkpoint on the command "
                                                                 "line with --checkpoint PATH") from None
        ckpt = ckpt_mod.resolve(named)
    config = ckpt_mod.check(ckpt)
    s = (job.generate or job_mod.GenerateSettings()).resolve(config, overrides, job_path)
    paths = job_inputs.check_inputs(job_path, job, allow_outside, data_roots)
    outputs.check_output(paths["output_dir"], allow_outside)
    paths["allow_outside"] = allow_outside
    return Plan(ckpt, s, paths["output_dir"], paths)


#: How far outside [0, 1] a value of I, M or M_a may lie and still be read (as the nearest of 0 and 1). The renderer
#: writes all three in [0, 1] (I clamped, M 0 or 1, M_a a coverage), and half floats keep them there (0 and 1 are
#: exact, rounding is monotonic); a compositor's lossy re-save does not: DWAA/DWAB ring up to 0.021 past an edge
#: (measured on a 50 % random mask). 1/16 takes that with margin and still refuses what is no condition layer (a
#: scene-linear image, a mask of 7 or -3).
VALUE_TOLERANCE = 1.0 / 16.0


def check_layer(path: str, layer: str, values: np.ndarray, job_path: str = "JOB") -> np.ndarray:
    """``values`` (H, W) float32 of the condition layer ``layer`` (a ``channels.CHANNELS`` key among I, M and M_a)
    of the EXR ``path``, clamped to [0, 1]; ExrError naming the file and the channel (``channels.FILE_NAMES``,
    e.g. ``image.R``), how many pixels, the first one (x, y) and what to do, for NaN/inf or a value outside
    [-``VALUE_TOLERANCE``, 1 + ``VALUE_TOLERANCE``]: the renderer never writes one, so the file was damaged or
    made by another tool, and the model would take it as a condition (NaN read as 0, a mask of 7 as a hole).
    ``job_path``: the job, for the hint."""
    hint = f"render the condition layers again: python -m backend render {job_path} --force"
    finite = np.isfinite(values)
    bad, what, why = ~finite, "NaN or infinite", ""
    if finite.all():
        bad = (values < -VALUE_TOLERANCE) | (values > 1.0 + VALUE_TOLERANCE)
        what = "outside [0, 1]"
        why = (f" (values from {float(values.min()):g} to {float(values.max()):g}; the renderer writes this layer in "
               f"[0, 1], {VALUE_TOLERANCE:g} beyond is allowed for a lossy re-save)")
    if bad.any():
        y, x = (int(v[0]) for v in np.nonzero(bad))
        raise channels.ExrError(path, channels.FILE_NAMES[layer], f"{int(bad.sum())} of its {bad.size} pixels are "
                                                                  f"{what}, the first at x={x}, y={y}{why}", hint=hint)
    return np.clip(values, 0.0, 1.0)


def load_conditions(job_path: str, job: job_mod.Job) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(image, asset_mask, valid): I (F, 3, H, W), M_a (F, 1, H, W) and validity 1 − hole (F, 1, H, W) float32
    tensors from the condition EXRs (``channels.read``: EXRs with the former channel name load too; one without
    these channels raises ``channels.ConditionsError``; a folder or FIFO in a frame's place, ``channels.ExrError``).
    Every frame must be the job's resolution (W x H): one of another size (re-saved by another tool) raises
    ``channels.ExrError`` naming it, its size and the job's, field ``dataWindow``, before anything is stacked.
    Every value of I, M and M_a must be finite and in [0, 1] up to ``VALUE_TOLERANCE`` (``check_layer``: an
    ExrError naming the file and the channel, e.g. ``image.R``); values within the tolerance are clamped."""
    image, asset_mask, valid = [], [], []
    need = (*channels.IMAGE, channels.HOLE, channels.ASSET_MASK)
    W, H = job.resolution
    for entry in job.frames:
        path = render_cmd.frame_paths(job_path, job, entry.frame)[0]
        layers = channels.read(path, required=need)
        h, w = layers[channels.HOLE].shape  # channels.read: every layer of a file has one size
        if (w, h) != (W, H):
            raise channels.ExrError(path, "dataWindow", f"is {w}x{h} pixels, the job's resolution is {W}x{H}",
                                    hint=f"render the condition layers again at the job's resolution: python -m "
                                         f"backend render {job_path} --force")
        layers = {c: check_layer(path, c, layers[c], job_path) for c in need}
        image.append(np.stack([layers[c] for c in channels.IMAGE]))
        asset_mask.append(layers[channels.ASSET_MASK][None])
        valid.append(1.0 - layers[channels.HOLE][None])
    t = lambda a: torch.from_numpy(np.ascontiguousarray(np.stack(a), dtype=np.float32))  # noqa: E731
    return t(image), t(asset_mask), t(valid)


def clip_source(job_path: str, job: job_mod.Job, first_condition: torch.Tensor) -> torch.Tensor:
    """(3, H, W) in [0, 1]: the recorded image of the first output frame's first source frame, if any."""
    scene, sources = job.scene, job.frames[0].source_frames
    if scene is not None and sources:
        from scpainter_blender.core.vggt import predictions as vggt

        path = job_mod.resolve(job_path, scene.predictions)
        images = files.read_npz(path, ["images"], error=vggt.PredictionsError)["images"]
        images = images[0] if images.ndim == 5 else images
        return torch.from_numpy(np.ascontiguousarray(images[sources[0]], dtype=np.float32))
    return first_condition


def conditions_key(identity: dict, image: torch.Tensor, asset_mask: torch.Tensor, valid: torch.Tensor) -> str:
    """A key for "the same video": ``identity`` (what made it: checkpoint, settings, ...) and the condition layers."""
    h = hashlib.sha256(json.dumps(identity, sort_keys=True).encode())
    for t in (image, asset_mask, valid):
        h.update(t.numpy().tobytes())
    return h.hexdigest()[:32]


def state_key(ckpt: str, s: dict, precision: str, image: torch.Tensor, asset_mask: torch.Tensor,
              valid: torch.Tensor) -> str:
    return conditions_key({"checkpoint": os.path.abspath(ckpt), "settings": s, "precision": precision},
                          image, asset_mask, valid)


HISTORY = "history."   # the prefix of the sampler's history tensors in a state file (DPM-Solver++(2M)'s x0_prev)


def save_state(path: str, latents: torch.Tensor, step: int, key: str, history: dict | None = None) -> None:
    """The latents after ``step`` and the sampler's ``history`` (what ``SCPainterPipeline.sample`` hands its
    ``on_step`` at a resume point), atomically, under ``key``."""
    from safetensors.torch import save_file

    tensors = {"latents": latents}
    tensors.update({HISTORY + k: v for k, v in (history or {}).items() if v is not None})
    with outputs.atomic_path(path) as tmp:
        save_file({k: v.detach().float().cpu().contiguous() for k, v in tensors.items()}, tmp,
                  metadata={"key": key, "step": str(step)})


def load_state(path: str, key: str, history: dict | None = None) -> tuple[torch.Tensor | None, int]:
    """(latents, step) saved under the same key, else (None, 0); the saved history goes into ``history`` (a dict
    the caller passes) when there is a state. A state with NaN/inf in any tensor is none."""
    from safetensors import safe_open

    if not os.path.isfile(path):
        return None, 0
    try:
        with safe_open(path, framework="pt") as f:
            meta = f.metadata() or {}
            if meta.get("key") != key:
                return None, 0
            latents, step = f.get_tensor("latents"), int(meta["step"])
            saved = {k[len(HISTORY):]: f.get_tensor(k) for k in f.keys() if k.startswith(HISTORY)}
    except Exception:  # a damaged state file only costs the steps it held
        return None, 0
    # never resumed from (or decoded): the sampler never saves one
    if not all(bool(torch.isfinite(t).all()) for t in (latents, *saved.values())):
        return None, 0
    if history is not None:
        history.update(saved)
    return latents, step


def resolve_precision(precision: str, device: str) -> str:
    """``precision`` with ``auto`` made concrete: bf16 on CUDA, fp32 on the CPU. A finished video's up-to-date key
    holds the concrete value, so whoever checks a video made on another device (``evaluate --ray``: GPU workers, a
    CPU driver) must resolve it for the device that made it."""
    if precision != "auto":
        return precision
    return "bf16" if device == "cuda" else "fp32"


def generate_job(job_path: str, job: job_mod.Job, device: str, checkpoint: str | None, precision: str = "auto",
                 force: bool = False, stop: Sequence[object] = (), overrides: dict | None = None,
                 allow_outside: bool = False, data_roots: Sequence[str] = ()) -> dict:
    """Render the missing condition layers and generate the video (see the module docstring); validated first
    (``prepare``, with ``allow_outside`` and ``data_roots``), one run per output folder (``locking.OutputLock``). A
    model producing NaN/inf raises ``errors.NonFiniteError`` and writes no frame, video or manifest.

    A rig job (docs/design.md §17) is generated camera by camera (``render.rig_jobs``): each camera job's video in
    ``<output_dir>/<camera>/``; the result's ``videos`` and ``frames_dirs`` are {camera: path}, ``frames`` counts
    over all cameras, ``skipped`` is true when every camera was up to date."""
    if job.rig is not None:
        return _generate_rig(job_path, job, device, checkpoint, precision, force, stop, overrides, allow_outside,
                             data_roots)
    plan = prepare(job_path, job, checkpoint, overrides, allow_outside, data_roots)
    outputs.make_folder(plan.output_dir, "output_dir", root=True)
    with locking.OutputLock(plan.output_dir, "generate", busy=FolderBusyError) as lock, events.log_scope():
        return _generate(job_path, job, device, plan, precision, force, stop, lock)


def _generate_rig(job_path, job, device, checkpoint, precision, force, stop, overrides, allow_outside,
                  data_roots) -> dict:
    # each camera job is prepared (checked) as it starts: the first finds any bad setting before any work
    root = job_inputs.job_paths(job_path, job, allow_outside, data_roots=data_roots)["output_dir"]
    results = rig_jobs.run_cameras(job, lambda cam, camera_job: generate_job(
        job_path, camera_job, device, checkpoint, precision, force, stop, overrides, allow_outside, data_roots), stop)
    out = rig_jobs.combined(job, results, root, ("frames",), stop)
    finished = [(name, r) for name, r in results if not r.get("stopped")]
    out.update(video=None, frames_dir=None, videos={name: r["video"] for name, r in finished},
               frames_dirs={name: r["frames_dir"] for name, r in finished},
               skipped=bool(results) and all(r.get("skipped") for _, r in results))
    stopped = [r for _, r in results if r.get("stopped")]
    if stopped:  # where the camera that stopped was
        out.update(stage=stopped[0]["stage"], steps_done=stopped[0]["steps_done"])
    elif out["stopped"]:  # stopped between two cameras
        out.update(stage="render", steps_done=0)
    return out


def torch_threads() -> int:
    """torch's CPU threads for the model: ``OMP_NUM_THREADS`` when it is a positive integer, else the CPUs this
    process may run on. Set explicitly before the model runs because numba's OpenMP layer (the CPU renderer) sets
    the OpenMP thread count of the thread it runs on, which torch's CPU kernels share: a ``generate`` that rendered
    its conditions first would otherwise sample with another thread count than one that found them rendered (or a
    warm server's next request), and a resumed run would differ from an uninterrupted one (by one level in 8-bit
    frames, measured with ``OMP_NUM_THREADS=1``)."""
    value = os.environ.get("OMP_NUM_THREADS", "")
    if value.isdigit() and int(value) > 0:
        return int(value)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _generate(job_path, job, device, plan: Plan, precision, force, stop, lock) -> dict:
    ckpt, s, out = plan.checkpoint, plan.settings, plan.output_dir
    precision = resolve_precision(precision, device)
    dtype = PRECISIONS[precision]
    layout = OutputLayout(out)
    log = events.FileLog(layout.log)
    if lock.stale:
        log(f"generate: {lock.took_over()}")
    t0 = time.perf_counter()
    outputs.remove_temporaries(out, [OutputLayout.VIDEO, OutputLayout.STATE])  # left by a killed run
    outputs.remove_temporaries(layout.generated, [OutputLayout.MANIFEST] + [
        GENERATED_FRAME.name(e.frame) for e in job.frames])
    r = render_cmd.render_job(job_path, job, device, stop=stop, log=log, allow_outside=plan.paths["allow_outside"],
                              lock=False, checked=plan.paths)  # prepare() checked the inputs; the lock is held
    if r["stopped"]:
        return {"stopped": True, "stage": "render", "steps_done": 0}
    image, asset_mask, valid = load_conditions(job_path, job)
    frames_n, _, H, W = image.shape
    gen_dir, mp4 = layout.generated, layout.video
    if plan.model == "baseline":
        key = conditions_key({"model": "baseline", "settings": s}, image, asset_mask, valid)
        if not force and _up_to_date(gen_dir, mp4, key, playback_fps(job, plan), video_ticks(job)):
            log(f"generate: {mp4} is up to date (the same baseline settings and conditions)")
            return {**_result(job, plan, mp4, gen_dir, frames_n, skipped=True), **s}
        return _baseline(job, plan, image, valid, key, stop, log, t0)
    key = state_key(ckpt, s, precision, image, asset_mask, valid)
    if not force and _up_to_date(gen_dir, mp4, key, playback_fps(job, plan), video_ticks(job)):
        log(f"generate: {mp4} is up to date (same checkpoint, settings and conditions)")
        return _result(job, plan, mp4, gen_dir, frames_n, skipped=True)

    from ..model.pipeline import SCPainterPipeline, pad_to_multiple

    torch.set_num_threads(torch_threads())
    log(f"generate {job_path}: {frames_n} frames {W}x{H}, {s['steps']} steps, window {s['window']} overlap "
        f"{s['overlap']}, {precision} on {device}, checkpoint {ckpt}")
    pipe = SCPainterPipeline.from_checkpoint(ckpt, device, dtype)
    m = pipe.pixel_multiple
    cond = pipe.condition_latents(pad_to_multiple(image, m), pad_to_multiple(asset_mask, m),
                                  pad_to_multiple(valid, m, 0.0), seed=s["seed"])
    clip = pipe.clip_embedding(clip_source(job_path, job, image[0]))
    pipe.release_encoders()   # CLIP and the condition encoder are done: their memory goes before the UNet runs
    pipe.set_speed(s["compile"], s["gpu_tuning"])
    state_path = layout.state
    history: dict = {}
    latents, start = (None, 0) if force else load_state(state_path, key, history)
    if start:
        log(f"generate: resuming after step {start} of {s['steps']}")
    stopped_at = []

    def on_step(i, n, x, state):
        if state is not None:   # a resume point: the latents and the sampler's history are all the next step needs
            save_state(state_path, x, i, key, state)
        events.progress("generate", i, n)
        if stop and i < n:
            stopped_at.append(i)
            return True
        return False

    x = latents
    if start < s["steps"]:
        x = pipe.sample(cond, clip, steps=s["steps"], seed=s["seed"], window=s["window"], overlap=s["overlap"],
                        min_guidance=s["min_guidance"], max_guidance=s["max_guidance"], latents=latents,
                        start_step=start, on_step=on_step, history=history, **{k: s[k] for k in SAMPLING})
    if stopped_at:
        return {"stopped": True, "stage": "generate", "steps_done": stopped_at[-1], "steps": s["steps"]}
    video = pipe.decode(x, chunk=s["decode_chunk"])[:, :, :H, :W]
    rgb = baseline.to_uint8(video.permute(0, 2, 3, 1).numpy())
    _write_outputs(job, plan, rgb, mp4, {"key": key, "checkpoint": ckpt, "settings": s, "precision": precision})
    if os.path.exists(state_path):
        os.remove(state_path)
    log(f"generate: {mp4} in {time.perf_counter() - t0:.1f} s")
    return {**_result(job, plan, mp4, gen_dir, frames_n), "precision": precision, **s}


def _baseline(job, plan: Plan, image, valid, key, stop, log, t0) -> dict:
    """The baseline's frames, one at a time (a stop keeps nothing: the whole video takes seconds to a minute)."""
    s, layout = plan.settings, OutputLayout(plan.output_dir)
    log(f"generate: {plan.description()}; {len(job.frames)} frames")
    events.log(f"generate: {USE_CHECKPOINT_HINT}")

    def on_frame(i, frame):
        events.progress("generate", i + 1, len(job.frames), model="baseline")
        return bool(stop) and i + 1 < len(job.frames)

    rgb = baseline.inpaint_video(image.numpy(), 1.0 - valid.numpy(), s["inpaint"], s["inpaint_radius"], on_frame)
    if len(rgb) < len(job.frames):
        log(f"generate: stopped after {len(rgb)} of {len(job.frames)} baseline frames (not kept: it starts again)")
        return {"stopped": True, "stage": "generate", "steps_done": len(rgb), "steps": len(job.frames)}
    mp4 = layout.video
    _write_outputs(job, plan, rgb, mp4, {"key": key, "checkpoint": None, "settings": s})
    log(f"generate: {mp4} (baseline) in {time.perf_counter() - t0:.1f} s")
    return {**_result(job, plan, mp4, layout.generated, len(rgb)), **s}


def playback_fps(job: job_mod.Job, plan: Plan) -> float:
    """The rate the MP4 plays at: the job's frame rate (the scene's, which the labels' timestamps use) when it
    has one, else the generation's ``fps`` setting (the baseline's default or the checkpoint's)."""
    return float(job.fps) if job.fps is not None else float(plan.settings["fps"])


def video_ticks(job: job_mod.Job) -> list:
    """When the MP4 shows each output frame, in frames of 1/``playback_fps``: the job's ``frame_ticks`` (its scene
    frames' offsets, so a Frame Step 2 job plays at the times its labels say), or 0, 1, … for a hand-written job
    whose frames do not increase (it plays in its own order)."""
    ticks = job.frame_ticks()
    return ticks if all(b > a for a, b in zip(ticks, ticks[1:])) else list(range(len(ticks)))


def _up_to_date(gen_dir: str, mp4: str, key: str, fps: float, ticks: list | None = None) -> bool:
    """A finished run with the same key left the video and its manifest, at the same playback rate (a manifest
    written before the rate was recorded played at the generation's ``fps``, which is then what ``fps`` is) and the
    same frame times (``video_ticks``; a manifest without them played its frames one tick apart)."""
    manifest = os.path.join(gen_dir, OutputLayout.MANIFEST)
    if not (os.path.isfile(manifest) and os.path.isfile(mp4)):
        return False
    try:
        m = files.read_json(manifest)
        written = m.get("playback_fps", m.get("settings", {}).get("fps"))
        written_ticks = m.get("video_ticks", list(range(len(m.get("frames", [])))))
        return (m.get("key") == key and (written is None or abs(float(written) - fps) < 1e-9)
                and (ticks is None or written_ticks == ticks))
    except (errors.InputError, AttributeError, TypeError, ValueError):  # unreadable: generate again
        return False


def _result(job: job_mod.Job, plan: Plan, mp4: str, gen_dir: str, frames: int, skipped: bool = False) -> dict:
    """The ``done`` event's fields every generation shares; the baseline's say what it is and how to get the model."""
    r = {"stopped": False, "skipped": skipped, "output_dir": plan.output_dir, "video": mp4, "frames_dir": gen_dir,
         "frames": frames, "model": plan.model, "description": plan.description(),
         "playback_fps": playback_fps(job, plan)}  # the MP4's rate ("fps" is the generation's setting)
    if plan.model == "baseline":
        r["hint"] = USE_CHECKPOINT_HINT
    return r


def _write_outputs(job, plan: Plan, rgb: np.ndarray, mp4: str, manifest: dict) -> None:
    """``generated/frame_NNNNNN.png`` per output frame, ``generated.mp4`` and ``generated/manifest.json`` (written
    last: it marks the run finished; a previous run's is removed before the first frame is written, so a folder
    holding frames of two runs is never up to date). rgb: (F, H, W, 3) uint8. The manifest and the MP4's metadata
    say which generator made them (``model``, ``description``), so a baseline video is not taken for the model's."""
    from .video import write_mp4

    gen_dir = outputs.output_folder(plan.output_dir, OutputLayout.GENERATED, plan.paths.get("allow_outside", False))
    # a finished run's manifest goes before its first frame is replaced: a run killed (or failing) from here on
    # leaves a folder that no run calls up to date, however its frames are mixed (the next run writes them all)
    outputs.remove_listed(gen_dir, [OutputLayout.MANIFEST])
    for entry, frame in zip(job.frames, rgb):
        path = os.path.join(gen_dir, GENERATED_FRAME.name(entry.frame))
        png.write_png(path, frame)
        events.artifact(path, frame=entry.frame, kind="generated", model=plan.model)
    fps = playback_fps(job, plan)
    write_mp4(mp4, rgb, fps, metadata={"title": f"SCPainter {plan.model}", "comment": plan.description()},
              ticks=video_ticks(job))
    events.artifact(mp4, kind="video", model=plan.model)
    outputs.write_json(os.path.join(gen_dir, OutputLayout.MANIFEST),
                       {**manifest, "model": plan.model, "description": plan.description(), "playback_fps": fps,
                        "frames": [e.frame for e in job.frames], "video_ticks": video_ticks(job)})
