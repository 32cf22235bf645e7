"""SCPainter checkpoint folders: made from a stock SVD snapshot on disk, loaded with ``local_files_only``.

Layout (a diffusers folder plus two entries)::

    scpainter.json            {"schema": "scpainter.checkpoint/1", ...} generation defaults and provenance
    model_index.json          the stock pipeline's index (kept so diffusers tools still open the folder)
    unet/ vae/ image_encoder/ feature_extractor/ scheduler/     the stock components, safetensors only
    condition_encoder/        ConditionEncoder (SVD's VAE encoder over I ‖ M_a), safetensors

Only safetensors are read or written: a snapshot that has only ``.bin`` weights (pickles) is refused with a
message naming the file. Nothing is ever downloaded.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import asdict, dataclass, field

SCHEMA = "scpainter.checkpoint/1"
COMPONENTS = ("unet", "vae", "image_encoder", "feature_extractor", "scheduler")
WEIGHTS = {"unet": "diffusion_pytorch_model.safetensors", "vae": "diffusion_pytorch_model.safetensors",
           "image_encoder": "model.safetensors"}


class CheckpointError(ValueError):
    """A checkpoint or SVD folder that cannot be used; the message names the path and what is wrong."""


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

    @classmethod
    def load(cls, path: str) -> ScpainterConfig:
        try:
            with open(path) as f:
                data = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise CheckpointError(f"{path}: cannot read the checkpoint config ({e})") from None
        if data.get("schema") != SCHEMA:
            raise CheckpointError(f"{path}: field 'schema' is {data.get('schema')!r}, expected {SCHEMA!r}")
        known = {k: v for k, v in data.items() if k in cls.__dataclass_fields__}
        return cls(**known)


def no_checkpoint_message() -> str:
    return ("no SCPainter checkpoint is configured: make one from a Stable Video Diffusion img2vid(-xt) snapshot "
            "on disk with `python -m backend init-checkpoint --svd /path/to/stable-video-diffusion-img2vid-xt "
            "--out /path/to/scpainter-checkpoint`, then set generate.checkpoint in the job (or the add-on "
            "preferences), or pass --checkpoint")


def check_svd_folder(path: str) -> None:
    """Raise CheckpointError unless ``path`` is a stock SVD img2vid snapshot with safetensors weights."""
    index = os.path.join(path, "model_index.json")
    if not os.path.isfile(index):
        raise CheckpointError(f"{path}: not a diffusers folder (no model_index.json)")
    try:
        with open(index) as f:
            cls = json.load(f).get("_class_name")
    except (OSError, json.JSONDecodeError) as e:
        raise CheckpointError(f"{index}: cannot read ({e})") from None
    if cls != "StableVideoDiffusionPipeline":
        raise CheckpointError(f"{index}: field '_class_name' is {cls!r}, expected 'StableVideoDiffusionPipeline'")
    for comp in COMPONENTS:
        if not os.path.isdir(os.path.join(path, comp)):
            raise CheckpointError(f"{path}: component folder '{comp}/' is missing")
    for comp, name in WEIGHTS.items():
        folder = os.path.join(path, comp)
        if not any(f.endswith(".safetensors") or f.endswith(".safetensors.index.json") for f in os.listdir(folder)):
            found = ", ".join(sorted(os.listdir(folder))) or "nothing"
            raise CheckpointError(f"{folder}: no safetensors weights (found {found}); pickled .bin weights are not "
                                  f"loaded: convert them to {name} first")


def _link_or_copy_tree(src: str, dst: str) -> None:
    """Hard-link files when the file system allows (multi-GB UNets), copy otherwise."""
    for root, _, files in os.walk(src):
        rel = os.path.relpath(root, src)
        os.makedirs(os.path.join(dst, rel), exist_ok=True)
        for f in files:
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
        raise CheckpointError(f"{out}: already exists; choose another --out or remove it")
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


def resolve(path: str | None) -> str:
    """The checkpoint folder, or CheckpointError saying how to make one."""
    if not path:
        raise CheckpointError(no_checkpoint_message())
    if not os.path.isfile(os.path.join(path, "scpainter.json")):
        hint = (" (it looks like a stock SVD snapshot: run init-checkpoint on it first)"
                if os.path.isfile(os.path.join(path, "model_index.json")) else "")
        raise CheckpointError(f"{path}: not an SCPainter checkpoint (no scpainter.json){hint}; "
                              + no_checkpoint_message())
    return path


def load(path: str, device="cpu", dtype=None) -> dict:
    """The checkpoint's components on ``device``: UNet and CLIP in ``dtype`` (float32 when None); the VAE and the
    condition encoder in ``dtype`` too, except float16 on a VAE that asks for upcasting (SVD's does)."""
    import torch
    from diffusers import AutoencoderKLTemporalDecoder, UNetSpatioTemporalConditionModel
    from transformers import CLIPVisionModelWithProjection

    from .condition import ConditionEncoder

    path = resolve(path)
    cfg = ScpainterConfig.load(os.path.join(path, "scpainter.json"))
    dtype = dtype or torch.float32
    try:
        with open(os.path.join(path, "vae", "config.json")) as f:
            upcast = json.load(f).get("force_upcast", True)
        vae_dtype = torch.float32 if (dtype == torch.float16 and upcast) else dtype
        unet = UNetSpatioTemporalConditionModel.from_pretrained(path, local_files_only=True, use_safetensors=True,
                                                                subfolder="unet", torch_dtype=dtype)
        vae = AutoencoderKLTemporalDecoder.from_pretrained(path, local_files_only=True, use_safetensors=True,
                                                           subfolder="vae", torch_dtype=vae_dtype)
        clip = CLIPVisionModelWithProjection.from_pretrained(os.path.join(path, "image_encoder"), local_files_only=True,
                                                             use_safetensors=True, dtype=dtype)
        cond = ConditionEncoder.from_pretrained(path, local_files_only=True, use_safetensors=True,
                                                subfolder="condition_encoder", torch_dtype=vae_dtype)
    except (OSError, ValueError) as e:
        raise CheckpointError(f"{path}: cannot load a component ({e})") from None
    for m in (unet, clip, vae, cond):
        m.to(device).eval().requires_grad_(False)
    with open(os.path.join(path, "feature_extractor", "preprocessor_config.json")) as f:
        fe = json.load(f)
    return {"unet": unet, "vae": vae, "image_encoder": clip, "condition_encoder": cond, "config": cfg,
            "clip_mean": fe.get("image_mean", [0.48145466, 0.4578275, 0.40821073]),
            "clip_std": fe.get("image_std", [0.26862954, 0.26130258, 0.27577711]), "path": path}
