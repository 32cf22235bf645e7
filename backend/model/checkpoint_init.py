"""Making an SCPainter checkpoint folder from a stock SVD img2vid snapshot on disk (``python -m backend
init-checkpoint``), and linking a snapshot's components into a folder (what training's checkpoints share with
their base). The folder's layout and checks are ``checkpoint``; ``scpainter.json`` is ``checkpoint_config``.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import asdict

from scpainter_blender.core import outputs

from .checkpoint import COMPONENTS, check_svd_folder
from .checkpoint_config import CheckpointError, ScpainterConfig


def link_components(src: str, dst: str, components=COMPONENTS, log=lambda m: None) -> None:
    """Hard-link (or copy) ``components`` and model_index.json of the diffusers folder ``src`` into ``dst``."""
    for comp in components:
        log(f"{comp}")
        outputs.link_or_copy_tree(os.path.join(src, comp), os.path.join(dst, comp))
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
    with outputs.atomic_folder(out) as tmp:
        link_components(svd, tmp, log=lambda m: log(f"init-checkpoint: {m}"))
        vae = AutoencoderKLTemporalDecoder.from_pretrained(svd, subfolder="vae", local_files_only=True,
                                                           use_safetensors=True)
        log("init-checkpoint: condition encoder (SVD's VAE encoder, mask channel zero)")
        ConditionEncoder.from_vae(vae).save_pretrained(os.path.join(tmp, "condition_encoder"),
                                                       safe_serialization=True)
        outputs.write_json(os.path.join(tmp, "scpainter.json"), asdict(ScpainterConfig(base=svd)))
    return out
