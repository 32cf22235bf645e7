"""SCPainter checkpoint folders: found, checked without loading a model, and loaded with ``local_files_only``.

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
naming the file. Nothing is ever downloaded. ``check_svd_folder`` is the same check of a stock SVD snapshot.

``scpainter.json`` itself and ``CheckpointError`` are ``checkpoint_config``; making a folder from an SVD snapshot
is ``checkpoint_init``. Errors are ``CheckpointError`` (a ``errors.InputError``: ``path``, ``field``, ``message``,
``hint``); ``str()`` is ``"<full path>: <field>: <what is wrong>"``.
"""

from __future__ import annotations

import math
import os

from scpainter_blender.core import errors, files

from .checkpoint_config import CheckpointError, ScpainterConfig, json_object, show_value

#: OpenAI CLIP's input normalisation per RGB channel (of values in [0, 1]): the stock SVD feature extractor's
#: ``image_mean`` / ``image_std``, and the default when a checkpoint's ``preprocessor_config.json`` leaves them out.
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)

COMPONENTS = ("unet", "vae", "image_encoder", "feature_extractor", "scheduler")
# what from_pretrained(..., use_safetensors=True) reads in diffusers and transformers (no variant is passed)
DIFFUSERS_WEIGHTS = "diffusion_pytorch_model.safetensors"
TRANSFORMERS_WEIGHTS = "model.safetensors"
WEIGHTS = {"unet": DIFFUSERS_WEIGHTS, "vae": DIFFUSERS_WEIGHTS, "image_encoder": TRANSFORMERS_WEIGHTS}
CHECKPOINT_WEIGHTS = dict(WEIGHTS, condition_encoder=DIFFUSERS_WEIGHTS)
PICKLE_SUFFIXES = (".bin", ".pt", ".pth", ".ckpt", ".pkl", ".pickle")
JSON_FILES = {"feature_extractor": "preprocessor_config.json", "scheduler": "scheduler_config.json"}
PICKLED = "pickled weights are never loaded: convert to safetensors"


def no_checkpoint_message() -> str:
    return ("no SCPainter checkpoint is configured: make one from a Stable Video Diffusion img2vid(-xt) snapshot "
            "on disk with `python -m backend init-checkpoint --svd /path/to/stable-video-diffusion-img2vid-xt "
            "--out /path/to/scpainter-checkpoint`, then set generate.checkpoint in the job (or the add-on "
            "preferences), or pass --checkpoint")


INIT_HINT = "make a checkpoint with `python -m backend init-checkpoint --svd SVD_FOLDER --out CHECKPOINT_FOLDER`"


# ----------------------------------------------------------------------------------------- finding a folder

def resolve(path: str | None, source: str = errors.COMMAND_LINE, field: str = "--checkpoint") -> str:
    """The checkpoint folder ``path``, or CheckpointError saying how to make one. With no ``path``, the error
    names where one was expected: ``source`` and ``field``, the command line's ``--checkpoint`` by default, or
    the job file and ``generate.checkpoint`` (``generate.prepare``)."""
    if not path:
        raise CheckpointError(source, field, no_checkpoint_message(), hint=INIT_HINT)
    if not os.path.isdir(path):
        raise CheckpointError(os.path.abspath(path), "(folder)", "does not exist" if not os.path.exists(path) else
                              "is not a folder", hint="give the folder init-checkpoint or training wrote")
    if not os.path.isfile(os.path.join(path, "scpainter.json")):
        stock = os.path.isfile(os.path.join(path, "model_index.json"))
        hint = " (it looks like a stock SVD snapshot: run init-checkpoint on it first)" if stock else ""
        raise CheckpointError(path, "(folder)", f"not an SCPainter checkpoint (no scpainter.json){hint}; "
                              + no_checkpoint_message(), hint=INIT_HINT)
    return path


# ----------------------------------------------------------------------------------------- checking a folder

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
    data = json_object(index)
    wmap = data.get("weight_map")
    if not isinstance(wmap, dict) or not wmap:
        raise CheckpointError(index, "weight_map", f"expected an object of parameter name -> shard file, got "
                                                   f"{show_value(wmap)}")
    folder, seen = os.path.dirname(index), set()
    for param, shard in wmap.items():
        where = f"weight_map.{param}"
        if not isinstance(shard, str) or not shard:
            raise CheckpointError(index, where, f"expected a shard file name, got {show_value(shard)}")
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
            raise CheckpointError(cfg_path, "transformers_weights", f"is {show_value(explicit)}: only a .safetensors "
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
        config = json_object(os.path.join(folder, "config.json"))
        _check_weights(folder, name, config)
        if comp == "vae":
            upcast = config.get("force_upcast", True)
            if not isinstance(upcast, bool):
                raise CheckpointError(os.path.join(folder, "config.json"), "force_upcast",
                                      f"expected true or false, got {show_value(upcast)}")
            info["force_upcast"] = upcast
    for comp, name in JSON_FILES.items():
        _folder(os.path.join(root, comp))
        data = json_object(os.path.join(root, comp, name))
        if comp == "scheduler":
            from .edm import Schedule   # here, not at the top: edm imports torch, which finding a folder needs not

            info["schedule"] = Schedule.from_config(data, os.path.join(root, comp, name))
        if comp == "feature_extractor":
            for key, default in (("image_mean", list(CLIP_MEAN)), ("image_std", list(CLIP_STD))):
                v = data.get(key, default)
                ok = isinstance(v, list) and len(v) == 3 and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
                if ok and key == "image_std" and not all(x > 0 for x in v):
                    ok = False
                if not ok:
                    raise CheckpointError(os.path.join(root, comp, name), key,
                                          f"expected 3 finite numbers{' > 0' if key == 'image_std' else ''} (one "
                                          f"per RGB channel), got {show_value(v) if not isinstance(v, list) else v}")
                info["clip_mean" if key == "image_mean" else "clip_std"] = [float(x) for x in v]
    return info


def _check(path: str) -> dict:
    cfg = ScpainterConfig.load(os.path.join(path, "scpainter.json"))
    json_object(os.path.join(path, "model_index.json"))
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
    cls = json_object(index).get("_class_name")
    if cls != "StableVideoDiffusionPipeline":
        raise CheckpointError(index, "_class_name", f"is {show_value(cls)}, expected 'StableVideoDiffusionPipeline'")
    for comp in COMPONENTS:
        _folder(os.path.join(path, comp))
    _check_components(path, WEIGHTS)


# -------------------------------------------------------------------------------------------------- loading

def load(path: str, device="cpu", dtype=None) -> dict:
    """The checkpoint's components on ``device``: UNet and CLIP in ``dtype`` (float32 when None); the VAE (which only
    decodes at inference) in ``pipeline.decode_dtype`` (fp16 for a 16-bit model on CUDA, as stock SVD decodes); the
    condition encoder in ``dtype`` too, except float32 for float16 when the VAE asks for upcasting (SVD's does:
    stock SVD encodes in float32); ``config``
    (ScpainterConfig), ``clip_mean``/``clip_std``, ``schedule`` (``edm.Schedule`` from
    ``scheduler/scheduler_config.json``: what the pipeline samples with and training's denoiser holds) and
    ``path``. The folder passes ``check`` first, so only safetensors are ever read."""
    import torch
    from diffusers import AutoencoderKLTemporalDecoder, UNetSpatioTemporalConditionModel
    from transformers import CLIPVisionModelWithProjection

    from .condition import ConditionEncoder
    from .pipeline import decode_dtype

    path = resolve(path)
    info = _check(path)
    dtype = dtype or torch.float32
    encoder_dtype = torch.float32 if (dtype == torch.float16 and info["force_upcast"]) else dtype
    loaders = {
        "unet": lambda: UNetSpatioTemporalConditionModel.from_pretrained(
            path, local_files_only=True, use_safetensors=True, subfolder="unet", torch_dtype=dtype),
        "vae": lambda: AutoencoderKLTemporalDecoder.from_pretrained(
            path, local_files_only=True, use_safetensors=True, subfolder="vae",
            torch_dtype=decode_dtype(dtype, device)),
        "image_encoder": lambda: CLIPVisionModelWithProjection.from_pretrained(
            os.path.join(path, "image_encoder"), local_files_only=True, use_safetensors=True, dtype=dtype),
        "condition_encoder": lambda: ConditionEncoder.from_pretrained(
            path, local_files_only=True, use_safetensors=True, subfolder="condition_encoder", torch_dtype=encoder_dtype),
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
