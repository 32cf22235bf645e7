"""The training configuration (``python -m backend train CONFIG``): a JSON file, schema ``scpainter.train/1``.

Paths are relative to the config file. Unknown keys are refused (a typo must not silently train with a default).
Every field and its default is below; docs/training.md explains them.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field, fields

from scpainter_blender.core import job as job_mod

from .pairs import PairSettings

SCHEMA = "scpainter.train/1"


class TrainConfigError(ValueError):
    def __init__(self, path, field_name, message):
        super().__init__(f"{os.path.basename(str(path))}: {field_name}: {message}")


@dataclass
class TrainConfig:
    checkpoint: str                     # SCPainter checkpoint folder to start from (init-checkpoint's output)
    clips: list                         # clip folders / clip.json files, or one text file listing them
    output_dir: str                     # checkpoints/, logs/, train.log
    pairs: PairSettings = field(default_factory=PairSettings)
    steps: int = 30000                  # optimiser steps
    batch_size: int = 1                 # samples per process per micro-step
    gradient_accumulation: int = 1
    learning_rate: float = 1e-5
    warmup_steps: int = 500             # linear warm-up from 0
    adam_betas: tuple = (0.9, 0.999)
    adam_eps: float = 1e-8
    weight_decay: float = 1e-2
    max_grad_norm: float = 1.0
    p_mean: float = 0.7                 # log σ ~ N(p_mean, p_std²) (SVD fine-tuning recipe)
    p_std: float = 1.6
    drop_clip: float = 0.15             # probability of zeroing the CLIP embedding of a sample
    drop_condition: float = 0.15        # probability of zeroing the render-condition latent of a sample
    ema_decay: float = 0.9999           # 0: no EMA (checkpoints hold the raw weights)
    mixed_precision: str = "auto"       # auto (bf16 on CUDA, none on CPU) | no | bf16
    gradient_checkpointing: bool = False
    optimizer: str = "adamw"            # adamw | adamw8bit (bitsandbytes)
    train_condition_encoder: bool = True
    save_every: int = 1000
    keep_checkpoints: int = 3
    log_every: int = 10
    sample_every: int = 0               # 0: no sample videos
    sample_steps: int = 10
    num_workers: int = 2
    seed: int = 0
    path: str = ""                      # the config file (filled in by load)

    def resolve(self, p: str) -> str:
        return job_mod.resolve(self.path, p) if self.path else os.path.abspath(p)

    def clip_paths(self) -> list:
        out = []
        for c in self.clips:
            p = self.resolve(c)
            if os.path.isfile(p) and not p.endswith(".json"):
                out += job_mod.read_list(p)
            else:
                out.append(p)
        return out

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("path")
        return {"schema": SCHEMA, **d}


def _check(cfg: TrainConfig, path: str) -> TrainConfig:
    def err(name, msg):
        raise TrainConfigError(path, name, msg)

    for name in ("steps", "batch_size", "gradient_accumulation", "save_every", "keep_checkpoints", "log_every",
                 "sample_steps"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            err(name, f"expected an integer >= 1, got {v!r}")
    for name in ("warmup_steps", "sample_every", "num_workers", "seed"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            err(name, f"expected an integer >= 0, got {v!r}")
    for name in ("drop_clip", "drop_condition", "ema_decay"):
        v = getattr(cfg, name)
        if not isinstance(v, (int, float)) or not 0.0 <= v < 1.0:
            err(name, f"expected a number in [0, 1), got {v!r}")
    if not (isinstance(cfg.learning_rate, (int, float)) and cfg.learning_rate > 0):
        err("learning_rate", f"expected a number > 0, got {cfg.learning_rate!r}")
    if cfg.mixed_precision not in ("auto", "no", "bf16"):
        err("mixed_precision", f"expected auto, no or bf16, got {cfg.mixed_precision!r}")
    if cfg.optimizer not in ("adamw", "adamw8bit"):
        err("optimizer", f"expected adamw or adamw8bit, got {cfg.optimizer!r}")
    if not isinstance(cfg.clips, list) or not cfg.clips:
        err("clips", "expected a non-empty list of clip folders (or list files)")
    p = cfg.pairs
    if p.width % 64 or p.height % 64:
        err("pairs", f"width and height must be multiples of 64 (the VAE's 8 x the UNet's 8), got {p.width}x{p.height}")
    if p.frames < 1 or p.window < 1 or not 0 < p.source_prob <= 1 or not 0 <= p.asset_prob <= 1:
        err("pairs", "frames >= 1, window >= 1, source_prob in (0, 1], asset_prob in [0, 1]")
    return cfg


def from_dict(data: dict, path: str = "train.json") -> TrainConfig:
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise TrainConfigError(path, "schema", f"expected {SCHEMA!r}")
    data = {k: v for k, v in data.items() if k != "schema"}
    known = {f.name for f in fields(TrainConfig)} - {"path"}
    for k in data:
        if k not in known:
            raise TrainConfigError(path, k, f"unknown setting (known: {', '.join(sorted(known))})")
    for k in ("checkpoint", "clips", "output_dir"):
        if k not in data:
            raise TrainConfigError(path, k, "required")
    pairs = data.pop("pairs", {})
    pk = {f.name for f in fields(PairSettings)}
    if not isinstance(pairs, dict) or set(pairs) - pk:
        raise TrainConfigError(path, "pairs", f"unknown keys {sorted(set(pairs) - pk) if isinstance(pairs, dict) else pairs} "
                               f"(known: {', '.join(sorted(pk))})")
    if "adam_betas" in data:
        data["adam_betas"] = tuple(data["adam_betas"])
    try:
        cfg = TrainConfig(**data, pairs=PairSettings(**pairs), path=os.path.abspath(path))
    except TypeError as e:
        raise TrainConfigError(path, "(top level)", str(e)) from None
    return _check(cfg, path)


def load(path: str) -> TrainConfig:
    return from_dict(job_mod.read_json(path, TrainConfigError), path)


def save(path: str, cfg: TrainConfig) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(cfg.to_json(), f, indent=1)
        f.write("\n")
    os.replace(tmp, path)
