"""SCPainter checkpoint folders: made from a stock SVD snapshot on disk, loaded with ``local_files_only``.

Layout (a diffusers folder plus two entries)::

    scpainter.json            {"schema": "scpainter.checkpoint/1", ...} generation defaults and provenance
    model_index.json          the stock pipeline's index (kept so diffusers tools still open the folder)
    unet/ vae/ image_encoder/ feature_extractor/ scheduler/     the stock components, safetensors only
    condition_encoder/        ConditionEncoder (SVD's VAE encoder over I ‖ M_a), safetensors

Only safetensors are read or written. ``check(path)`` validates a checkpoint folder without loading a model, and
``load`` runs it first, so diffusers/transformers never meet a pickle to fall back to ``torch.load`` on: each
weighted component must have the safetensors file the library reads (``diffusion_pytorch_model.safetensors`` /
``model.safetensors``) or its ``*.safetensors.index.json``, whose shards must all be ``.safetensors`` files in the
component's folder. A component with only ``.bin``/``.pt`` weights, or an index naming such a shard, is refused
naming the file. Nothing is ever downloaded.

Errors are ``CheckpointError`` (a ``files.InputError``: ``path``, ``field``, ``message``, ``hint``); ``str()`` is
``"<full path>: <field>: <what is wrong>"``, e.g. ``/models/ckpt/scpainter.json: fps: expected an integer in
[1, 240], got 300``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import asdict, dataclass, field
from typing import ClassVar

from scpainter_blender.core import files
from scpainter_blender.core import job as job_mod

SCHEMA = "scpainter.checkpoint/1"
COMPONENTS = ("unet", "vae", "image_encoder", "feature_extractor", "scheduler")
# what from_pretrained(..., use_safetensors=True) reads in diffusers and transformers (no variant is passed)
DIFFUSERS_WEIGHTS = "diffusion_pytorch_model.safetensors"
TRANSFORMERS_WEIGHTS = "model.safetensors"
WEIGHTS = {"unet": DIFFUSERS_WEIGHTS, "vae": DIFFUSERS_WEIGHTS, "image_encoder": TRANSFORMERS_WEIGHTS}
CHECKPOINT_WEIGHTS = dict(WEIGHTS, condition_encoder=DIFFUSERS_WEIGHTS)
PICKLE_SUFFIXES = (".bin", ".pt", ".pth", ".ckpt", ".pkl", ".pickle")
JSON_FILES = {"feature_extractor": "preprocessor_config.json", "scheduler": "scheduler_config.json"}
PICKLED = "pickled weights are never loaded: convert to safetensors"

# Bounds of scpainter.json's numeric fields, shared with the generate command's overrides (window, fps, guidance):
# field -> (kind, low, high), both ends inclusive, high None: unbounded. "int" accepts an integral number (7.0).
# fps, guidance and window are the job's own generate bounds (core.job), so a value valid in one is valid in both
BOUNDS = {
    "trained_steps": ("int", 0, 2 ** 63 - 1),
    "fps": ("int", *map(int, job_mod.GENERATE_NUMBER_BOUNDS["fps"])),
    "motion_bucket_id": ("int", 0, 1023),
    "noise_aug_strength": ("float", 0.0, 10.0),
    "min_guidance": ("float", *job_mod.GENERATE_NUMBER_BOUNDS["min_guidance"]),
    "max_guidance": ("float", *job_mod.GENERATE_NUMBER_BOUNDS["max_guidance"]),
    "window": ("int", *job_mod.GENERATE_INT_BOUNDS["window"]),
}
LATENT_VALIDITY = ("area",)   # the rules backend.model.condition implements (latent_validity: area average)


class CheckpointError(files.InputError):
    """A checkpoint or SVD folder that cannot be used: ``path`` (the file or folder), ``field`` (the key;
    ``"(file)"`` / ``"(folder)"`` for the whole), ``message``, ``hint``. ``str()`` is ``"<path>: <field>:
    <message>"`` with the full path (``config.json`` alone would not say which component); without a path (no
    checkpoint configured) ``"<field>: <message>"``."""

    def __init__(self, path, field, message, hint=None):
        super().__init__(path or "", field, message, hint)
        self.args = (f"{self.path}: {self.field}: {message}" if self.path else f"{self.field}: {message}",)

    def __reduce__(self):  # picklable (worker processes): rebuilt from its parts, not from the formatted message
        return type(self), (self.path, self.field, self.message, self.hint)


def _show(value) -> str:
    """A JSON value as a message quotes it."""
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if value is None:
        return "null"
    if isinstance(value, str):
        return f"{value[:60]!r} (a string)"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, int) and len(str(abs(value))) > 24:
        return f"an integer of {len(str(abs(value)))} digits"
    return repr(value)


def check_field(name: str, value):
    """``value`` for the bounded field ``name`` (see ``BOUNDS``), an integral float as int and an int as float
    where the field is a float; ``ValueError("expected …, got …")`` (no file or field in the message: the caller
    wraps it with its own) for a wrong type, a boolean, NaN/infinity or a value out of range."""
    kind, low, high = BOUNDS[name]
    rng = f"in [{low:g}, {high:g}]" if high is not None and high < 2 ** 53 else f"≥ {low:g}"
    if kind == "int":
        want = f"expected an integer {rng}"
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            value = int(value)
        if not isinstance(value, int) or isinstance(value, bool):
            raise ValueError(f"{want}, got {_show(value)}")
    else:
        want = f"expected a finite number {rng}"
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ValueError(f"{want}, got {_show(value)}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{want}, got {value}")
    if value < low or (high is not None and value > high):
        raise ValueError(f"{want}, got {_show(value)}")
    return value if kind == "int" else float(value)


def check_guidance(min_guidance: float, max_guidance: float) -> None:
    """``ValueError`` unless min ≤ max (both already passed ``check_field``)."""
    if min_guidance > max_guidance:
        raise ValueError(f"is {min_guidance:g}, greater than max_guidance {max_guidance:g}: guidance rises from "
                         "min_guidance to max_guidance over each window")


FIELD_HINT = "correct the field in scpainter.json (init-checkpoint and training write valid ones)"


@dataclass
class ScpainterConfig:
    schema: str = SCHEMA
    base: str = ""                    # the SVD snapshot this checkpoint was made from
    trained_steps: int = 0            # 0: not fine-tuned yet (the condition encoder's mask channel is zero)
    fps: int = 7                      # SVD conditions on fps - 1
    motion_bucket_id: int = 127
    noise_aug_strength: float = 0.02
    min_guidance: float = 1.0
    max_guidance: float = 3.0
    window: int = 14                  # frames the UNet denoises together
    latent_validity: str = "area"     # see backend.model.condition
    extra: dict = field(default_factory=dict)

    BOUNDS: ClassVar[dict] = BOUNDS
    LATENT_VALIDITY: ClassVar[tuple] = LATENT_VALIDITY

    @classmethod
    def load(cls, path: str) -> ScpainterConfig:
        """Read and validate ``scpainter.json``, field by field: ``schema`` exactly ``SCHEMA``; ``base`` a string;
        the numbers within ``BOUNDS`` (no booleans, NaN or infinity), ``min_guidance`` ≤ ``max_guidance``;
        ``latent_validity`` one of ``LATENT_VALIDITY``; ``extra`` an object. A missing field (other than
        ``schema``) takes its default; unknown keys are ignored (a newer writer's additions). CheckpointError
        naming the file and the field otherwise."""
        data = files.read_json(path, error=CheckpointError)
        if not isinstance(data, dict):
            raise CheckpointError(path, "(file)", f"expected a JSON object, got {_show(data)}")
        if data.get("schema") != SCHEMA:
            got = f"is {_show(data['schema'])}" if "schema" in data else "is missing"
            raise CheckpointError(path, "schema", f"{got}, expected {SCHEMA!r}: not an SCPainter checkpoint of "
                                                  "this version")
        values = {}
        for name in cls.__dataclass_fields__:
            if name == "schema" or name not in data:
                continue
            v, problem = data[name], None
            if name in BOUNDS:
                try:
                    v = check_field(name, v)
                except ValueError as e:
                    problem = str(e)
            elif name == "base" and not isinstance(v, str):
                problem = f"expected a string (the SVD snapshot's folder), got {_show(v)}"
            elif name == "latent_validity" and (not isinstance(v, str) or v not in LATENT_VALIDITY):
                problem = f"expected one of {', '.join(map(repr, LATENT_VALIDITY))}, got {_show(v)}"
            elif name == "extra" and not isinstance(v, dict):
                problem = f"expected an object, got {_show(v)}"
            if problem:
                raise CheckpointError(path, name, problem, hint=FIELD_HINT)
            values[name] = v
        cfg = cls(**values)
        try:
            check_guidance(cfg.min_guidance, cfg.max_guidance)
        except ValueError as e:
            raise CheckpointError(path, "min_guidance", str(e), hint=FIELD_HINT) from None
        return cfg


def no_checkpoint_message() -> str:
    return ("no SCPainter checkpoint is configured: make one from a Stable Video Diffusion img2vid(-xt) snapshot "
            "on disk with `python -m backend init-checkpoint --svd /path/to/stable-video-diffusion-img2vid-xt "
            "--out /path/to/scpainter-checkpoint`, then set generate.checkpoint in the job (or the add-on "
            "preferences), or pass --checkpoint")


INIT_HINT = "make a checkpoint with `python -m backend init-checkpoint --svd SVD_FOLDER --out CHECKPOINT_FOLDER`"


# ----------------------------------------------------------------------------------------- checking a folder

def _json_object(path: str) -> dict:
    data = files.read_json(path, error=CheckpointError)
    if not isinstance(data, dict):
        raise CheckpointError(path, "(file)", f"expected a JSON object, got {_show(data)}")
    return data


def _folder(path: str) -> None:
    if not os.path.isdir(path):
        what = "is not a folder" if os.path.exists(path) else "is missing"
        raise CheckpointError(path, "(folder)", f"component folder {what}")


def _safetensors_header(path: str) -> None:
    """CheckpointError unless ``path`` is a regular file that starts like safetensors (an 8-byte header length, a
    JSON header that fits in the file). Reads 9 bytes; never unpickles."""
    with files.open_regular(path, CheckpointError) as f:
        head = f.read(9)
        size = os.fstat(f.fileno()).st_size
    n = int.from_bytes(head[:8], "little") if len(head) == 9 else -1
    if n < 2 or n > min(size - 8, 100 * 2 ** 20) or head[8:9] != b"{":
        raise CheckpointError(path, "(file)", "is not a safetensors file (no valid header): truncated, or pickled "
                                              "weights renamed? " + PICKLED)


def _check_index(index: str) -> None:
    """A ``*.safetensors.index.json``: its ``weight_map`` names only ``.safetensors`` files beside it."""
    data = _json_object(index)
    wmap = data.get("weight_map")
    if not isinstance(wmap, dict) or not wmap:
        raise CheckpointError(index, "weight_map", f"expected an object of parameter name -> shard file, got "
                                                   f"{_show(wmap)}")
    folder, seen = os.path.dirname(index), set()
    for param, shard in wmap.items():
        where = f"weight_map.{param}"
        if not isinstance(shard, str) or not shard:
            raise CheckpointError(index, where, f"expected a shard file name, got {_show(shard)}")
        if shard in seen:
            continue
        seen.add(shard)
        if os.path.basename(shard) != shard or shard in (".", "..") or "\\" in shard:
            raise CheckpointError(index, where, f"names shard {shard!r}: shards must be files in the index's own "
                                                "folder")
        if not shard.endswith(".safetensors"):
            raise CheckpointError(index, where, f"names shard {shard!r}, which is not a .safetensors file: {PICKLED}",
                                  hint="convert the shards to safetensors (save_pretrained(..., "
                                       "safe_serialization=True)) and rewrite the index")
        _safetensors_header(os.path.join(folder, shard))


def _check_weights(folder: str, name: str, config: dict) -> None:
    """The weights ``from_pretrained(folder, use_safetensors=True)`` will read: ``name`` and/or
    ``name.index.json`` (diffusers prefers the index, transformers the single file: every one present is
    checked), or for transformers the file ``config.json``'s ``transformers_weights`` names."""
    index = name + ".index.json"
    candidates = [name, index]
    if name == TRANSFORMERS_WEIGHTS and "transformers_weights" in config:
        explicit = config["transformers_weights"]
        cfg_path = os.path.join(folder, "config.json")
        if not isinstance(explicit, str) or os.path.basename(explicit) != explicit or explicit in (".", "..") or \
                not (explicit.endswith(".safetensors") or explicit.endswith(".safetensors.index.json")):
            raise CheckpointError(cfg_path, "transformers_weights", f"is {_show(explicit)}: only a .safetensors "
                                  f"file (or its .safetensors.index.json) in this folder is loaded; {PICKLED}")
        candidates = [explicit]
    try:
        entries = sorted(os.listdir(folder))
    except OSError as e:
        raise CheckpointError(folder, "(folder)", f"cannot be listed: {e.strerror or e}") from None
    present = [c for c in candidates if c in entries]
    for c in present:
        p = os.path.join(folder, c)
        _check_index(p) if c.endswith(".index.json") else _safetensors_header(p)
    if present:
        return
    pickled = [f for f in entries if f.endswith(PICKLE_SUFFIXES) or f.endswith(".bin.index.json")]
    if pickled:
        raise CheckpointError(os.path.join(folder, pickled[0]), "(file)", f"{PICKLED} ({name})",
                              hint=f"save the component with save_pretrained(..., safe_serialization=True), which "
                                   f"writes {name}")
    others = [f for f in entries if f.endswith(".safetensors") or f.endswith(".safetensors.index.json")]
    found = ", ".join(entries) or "nothing"
    extra = (f"; a variant ({', '.join(others)}) is not loaded: rename it to {name}" if others else "")
    raise CheckpointError(folder, "(folder)", f"no safetensors weights: expected {' or '.join(candidates)}, found "
                                              f"{found}{extra}")


def _check_components(root: str, weighted) -> dict:
    """Each of ``weighted`` (component -> weights name): its ``config.json`` and safetensors weights; the feature
    extractor's and the scheduler's configs. Returns what ``load`` reads from them: ``force_upcast`` (VAE),
    ``clip_mean``, ``clip_std``, ``schedule`` (``edm.Schedule`` of the scheduler config, SVD's EDM kind only)."""
    info = {}
    for comp, name in weighted.items():
        folder = os.path.join(root, comp)
        _folder(folder)
        config = _json_object(os.path.join(folder, "config.json"))
        _check_weights(folder, name, config)
        if comp == "vae":
            upcast = config.get("force_upcast", True)
            if not isinstance(upcast, bool):
                raise CheckpointError(os.path.join(folder, "config.json"), "force_upcast",
                                      f"expected true or false, got {_show(upcast)}")
            info["force_upcast"] = upcast
    for comp, name in JSON_FILES.items():
        _folder(os.path.join(root, comp))
        data = _json_object(os.path.join(root, comp, name))
        if comp == "scheduler":
            from .edm import Schedule   # here, not at the top: edm imports this module (and torch)

            info["schedule"] = Schedule.from_config(data, os.path.join(root, comp, name))
        if comp == "feature_extractor":
            for key, default in (("image_mean", [0.48145466, 0.4578275, 0.40821073]),
                                 ("image_std", [0.26862954, 0.26130258, 0.27577711])):
                v = data.get(key, default)
                ok = isinstance(v, list) and len(v) == 3 and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
                if ok and key == "image_std" and not all(x > 0 for x in v):
                    ok = False
                if not ok:
                    raise CheckpointError(os.path.join(root, comp, name), key,
                                          f"expected 3 finite numbers{' > 0' if key == 'image_std' else ''} (one "
                                          f"per RGB channel), got {_show(v) if not isinstance(v, list) else v}")
                info["clip_mean" if key == "image_mean" else "clip_std"] = [float(x) for x in v]
    return info


def _check(path: str) -> dict:
    cfg = ScpainterConfig.load(os.path.join(path, "scpainter.json"))
    _json_object(os.path.join(path, "model_index.json"))
    info = _check_components(path, CHECKPOINT_WEIGHTS)
    info["config"] = cfg
    return info


def check(path: str) -> ScpainterConfig:
    """Validate the SCPainter checkpoint folder ``path`` without loading a model and return its config.

    Checks: ``scpainter.json`` field by field (``ScpainterConfig.load``); ``model_index.json`` a JSON object; each
    of unet, vae, image_encoder, condition_encoder a folder with ``config.json`` and safetensors weights (see
    ``_check_weights``: the file the library reads, or an index whose shards are all ``.safetensors`` files in the
    folder; a component with only ``.bin``/``.pt``/``.pth``/``.ckpt`` weights, or an index naming one, is
    refused naming that file); the VAE's ``force_upcast`` a boolean; ``feature_extractor/preprocessor_config.json``
    with ``image_mean``/``image_std`` three finite numbers each; ``scheduler/scheduler_config.json`` SVD's EDM
    scheduler (``edm.Schedule.from_config``: v prediction, continuous timesteps, Karras sigmas between its
    ``sigma_min`` and ``sigma_max``). Every file must be a regular file (a FIFO or device is refused before it
    is read). CheckpointError naming the file and field otherwise; ``resolve`` errors (no checkpoint, no
    scpainter.json) first."""
    return _check(resolve(path))["config"]


def check_svd_folder(path: str) -> None:
    """Raise CheckpointError unless ``path`` is a stock SVD img2vid snapshot with safetensors weights (the same
    per-component checks as ``check``, without the SCPainter entries)."""
    index = os.path.join(path, "model_index.json")
    if not os.path.isfile(index):
        raise CheckpointError(path, "(folder)", "not a diffusers folder (no model_index.json)",
                              hint="pass the folder of a Stable Video Diffusion img2vid(-xt) snapshot")
    cls = _json_object(index).get("_class_name")
    if cls != "StableVideoDiffusionPipeline":
        raise CheckpointError(index, "_class_name", f"is {_show(cls)}, expected 'StableVideoDiffusionPipeline'")
    for comp in COMPONENTS:
        _folder(os.path.join(path, comp))
    _check_components(path, WEIGHTS)


# ----------------------------------------------------------------------------------------- making a folder

def _link_or_copy_tree(src: str, dst: str) -> None:
    """Hard-link files when the file system allows (multi-GB UNets), copy otherwise."""
    for root, _, names in os.walk(src):
        rel = os.path.relpath(root, src)
        os.makedirs(os.path.join(dst, rel), exist_ok=True)
        for f in names:
            s, d = os.path.join(root, f), os.path.join(dst, rel, f)
            try:
                os.link(s, d)
            except OSError:
                shutil.copy2(s, d)


def link_components(src: str, dst: str, components=COMPONENTS, log=lambda m: None) -> None:
    """Hard-link (or copy) ``components`` and model_index.json of the diffusers folder ``src`` into ``dst``."""
    for comp in components:
        log(f"{comp}")
        _link_or_copy_tree(os.path.join(src, comp), os.path.join(dst, comp))
    shutil.copy2(os.path.join(src, "model_index.json"), os.path.join(dst, "model_index.json"))


def init_checkpoint(svd: str, out: str, log=lambda m: None) -> str:
    """Turn a stock SVD snapshot into an SCPainter checkpoint folder at ``out`` (written beside it under a
    temporary name, renamed when complete). Returns ``out``."""
    from diffusers import AutoencoderKLTemporalDecoder

    from .condition import ConditionEncoder

    svd, out = os.path.abspath(svd), os.path.abspath(out)
    check_svd_folder(svd)
    if os.path.exists(out):
        raise CheckpointError(out, "(folder)", "already exists; choose another --out or remove it")
    parent = os.path.dirname(out)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=".scpainter-ckpt-", dir=parent)
    try:
        link_components(svd, tmp, log=lambda m: log(f"init-checkpoint: {m}"))
        vae = AutoencoderKLTemporalDecoder.from_pretrained(svd, subfolder="vae", local_files_only=True,
                                                           use_safetensors=True)
        log("init-checkpoint: condition encoder (SVD's VAE encoder, mask channel zero)")
        ConditionEncoder.from_vae(vae).save_pretrained(os.path.join(tmp, "condition_encoder"),
                                                       safe_serialization=True)
        with open(os.path.join(tmp, "scpainter.json"), "w") as f:
            json.dump(asdict(ScpainterConfig(base=svd)), f, indent=1)
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


# ------------------------------------------------------------------------------------------------- loading

def resolve(path: str | None) -> str:
    """The checkpoint folder, or CheckpointError saying how to make one."""
    if not path:
        raise CheckpointError(None, "generate.checkpoint", no_checkpoint_message(), hint=INIT_HINT)
    if not os.path.isdir(path):
        raise CheckpointError(os.path.abspath(path), "(folder)", "does not exist" if not os.path.exists(path) else
                              "is not a folder", hint="give the folder init-checkpoint or training wrote")
    if not os.path.isfile(os.path.join(path, "scpainter.json")):
        stock = os.path.isfile(os.path.join(path, "model_index.json"))
        hint = " (it looks like a stock SVD snapshot: run init-checkpoint on it first)" if stock else ""
        raise CheckpointError(path, "(folder)", f"not an SCPainter checkpoint (no scpainter.json){hint}; "
                              + no_checkpoint_message(), hint=INIT_HINT)
    return path


def load(path: str, device="cpu", dtype=None) -> dict:
    """The checkpoint's components on ``device``: UNet and CLIP in ``dtype`` (float32 when None); the VAE and the
    condition encoder in ``dtype`` too, except float16 on a VAE that asks for upcasting (SVD's does); ``config``
    (ScpainterConfig), ``clip_mean``/``clip_std``, ``schedule`` (``edm.Schedule`` from
    ``scheduler/scheduler_config.json``: what the pipeline samples with and training's denoiser holds) and
    ``path``. The folder passes ``check`` first, so only safetensors are ever read."""
    import torch
    from diffusers import AutoencoderKLTemporalDecoder, UNetSpatioTemporalConditionModel
    from transformers import CLIPVisionModelWithProjection

    from .condition import ConditionEncoder

    path = resolve(path)
    info = _check(path)
    dtype = dtype or torch.float32
    vae_dtype = torch.float32 if (dtype == torch.float16 and info["force_upcast"]) else dtype
    loaders = {
        "unet": lambda: UNetSpatioTemporalConditionModel.from_pretrained(
            path, local_files_only=True, use_safetensors=True, subfolder="unet", torch_dtype=dtype),
        "vae": lambda: AutoencoderKLTemporalDecoder.from_pretrained(
            path, local_files_only=True, use_safetensors=True, subfolder="vae", torch_dtype=vae_dtype),
        "image_encoder": lambda: CLIPVisionModelWithProjection.from_pretrained(
            os.path.join(path, "image_encoder"), local_files_only=True, use_safetensors=True, dtype=dtype),
        "condition_encoder": lambda: ConditionEncoder.from_pretrained(
            path, local_files_only=True, use_safetensors=True, subfolder="condition_encoder", torch_dtype=vae_dtype),
    }
    models = {}
    for comp, make in loaders.items():
        try:
            models[comp] = make()
        except (OSError, ValueError) as e:
            raise CheckpointError(os.path.join(path, comp), "(folder)", f"cannot load the component ({e})") from None
    for m in models.values():
        m.to(device).eval().requires_grad_(False)
    return {**models, "config": info["config"], "clip_mean": info["clip_mean"], "clip_std": info["clip_std"],
            "schedule": info["schedule"], "path": path}
