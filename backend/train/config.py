"""The training configuration (``python -m backend train CONFIG``): a JSON file, schema ``scpainter.train/1``.

Paths are relative to the config file. Unknown keys are refused (a typo must not silently train with a default).
Every field and its default is below; docs/training.md explains them.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, fields

from scpainter_blender.core import batch_items as batch_mod
from scpainter_blender.core import errors, files, outputs
from scpainter_blender.core import job as job_mod

from .pairs import PairSettings

SCHEMA = "scpainter.train/1"
#: ``checkpointing_units``: the UNet's checkpointed units (backend/train/checkpointing.py says what each keeps)
CHECKPOINTING_UNITS = ("blocks", "diffusers")


class TrainConfigError(errors.InputError):
    """A training config that cannot be used: ``str()`` is "<file name>: <setting>: <message>"; ``field`` the
    setting (``pairs.width``), ``"(file)"`` for the file as a whole."""

    def __init__(self, path, field_name, message, hint=None):
        errors.InputError.__init__(self, path, field_name, message, hint)


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
    checkpointing_units: str = "blocks"  # blocks | diffusers: the UNet's checkpointed units (train/checkpointing.py)
    condition_chunk_frames: int = 1     # frames per condition-encoder chunk (one checkpointed unit each); 0: all
    encode_chunk_frames: int = 1        # frames per chunk of the frozen VAE's target encoding; 0: all
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
                out += batch_mod.read_list(p)
            else:
                out.append(p)
        return out

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("path")
        # as the job writes it (only the chosen outlier method's fields), resolved: a checkpoint's config says
        # what its pairs were cleaned with even after the defaults change (None, in code: both filters off)
        c = self.pairs.point_cleaning or job_mod.PointCleaning(None, None)
        d["pairs"]["point_cleaning"] = c.to_dict()
        return {"schema": SCHEMA, **d}


def _short(v) -> str:
    """A value for a message: its repr, cut (a setting can be a 100 MB list)."""
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def point_cleaning(value, path: str) -> job_mod.PointCleaning:
    """``pairs.point_cleaning``: read by the job's own reader (``job.PointCleaning.from_dict``: the same fields,
    bounds and defaults as a job's ``scene.point_cleaning``; absent fields take ``job.POINT_CLEANING``, ``null``
    turns a filter or both off), its errors raised as this file's, naming ``pairs.point_cleaning.<field>``."""
    try:
        return job_mod.PointCleaning.from_dict(value, path, "pairs.point_cleaning")
    except job_mod.JobError as e:
        raise TrainConfigError(e.path, e.field, e.message, e.hint) from None


#: Integers beyond this are refused: torch and the data loader take C ints, and no setting needs more.
MAX_INT = 2 ** 31 - 1


def _check(cfg: TrainConfig, path: str) -> TrainConfig:
    """Every setting's type and range, naming the setting; a JSON value of the wrong type (a list for a number, a
    dict for a list) ends here, never as a TypeError in the middle of training."""
    def err(name, msg):
        raise TrainConfigError(path, name, msg)

    def integer(name, v, lo, hi=MAX_INT):
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            err(name, f"expected an integer in [{lo}, {hi}], got {_short(v)}")

    def number(name, v, lo=-math.inf, hi=math.inf, lo_open=False, hi_open=False, what=None):
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) and \
            (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
        if not ok:
            err(name, f"expected {what or 'a finite number'}, got {_short(v)}")

    for name in ("steps", "batch_size", "gradient_accumulation", "save_every", "keep_checkpoints", "log_every",
                 "sample_steps"):
        integer(name, getattr(cfg, name), 1)
    for name in ("warmup_steps", "sample_every", "num_workers", "seed", "condition_chunk_frames",
                 "encode_chunk_frames"):
        integer(name, getattr(cfg, name), 0)
    for name in ("drop_clip", "drop_condition", "ema_decay"):
        number(name, getattr(cfg, name), 0.0, 1.0, hi_open=True, what="a number in [0, 1)")
    number("learning_rate", cfg.learning_rate, 0.0, lo_open=True, what="a number > 0")
    number("adam_eps", cfg.adam_eps, 0.0, lo_open=True, what="a number > 0")
    number("weight_decay", cfg.weight_decay, 0.0, what="a number >= 0")
    number("max_grad_norm", cfg.max_grad_norm, 0.0, lo_open=True, what="a number > 0")
    number("p_mean", cfg.p_mean)
    number("p_std", cfg.p_std, 0.0, lo_open=True, what="a number > 0")
    betas = cfg.adam_betas
    if not isinstance(betas, (list, tuple)) or len(betas) != 2:
        err("adam_betas", f"expected two numbers [beta1, beta2] in [0, 1), got {_short(betas)}")
    for i, b in enumerate(betas):
        number(f"adam_betas[{i}]", b, 0.0, 1.0, hi_open=True, what="a number in [0, 1)")
    for name in ("gradient_checkpointing", "train_condition_encoder"):
        if not isinstance(getattr(cfg, name), bool):
            err(name, f"expected true or false, got {_short(getattr(cfg, name))}")
    if not isinstance(cfg.mixed_precision, str) or cfg.mixed_precision not in ("auto", "no", "bf16"):
        err("mixed_precision", f"expected auto, no or bf16, got {_short(cfg.mixed_precision)}")
    if not isinstance(cfg.checkpointing_units, str) or cfg.checkpointing_units not in CHECKPOINTING_UNITS:
        err("checkpointing_units", f"expected {' or '.join(CHECKPOINTING_UNITS)}, got {_short(cfg.checkpointing_units)}")
    if not isinstance(cfg.optimizer, str) or cfg.optimizer not in ("adamw", "adamw8bit"):
        err("optimizer", f"expected adamw or adamw8bit, got {_short(cfg.optimizer)}")
    for name in ("checkpoint", "output_dir"):
        v = getattr(cfg, name)
        if not isinstance(v, str) or not v or "\0" in v or len(v) > 4096:
            err(name, f"expected a folder path (a non-empty string), got {_short(v)}")
    if not isinstance(cfg.clips, list) or not cfg.clips:
        err("clips", "expected a non-empty list of clip folders (or list files)")
    for i, c in enumerate(cfg.clips):
        if not isinstance(c, str) or not c or "\0" in c or len(c) > 4096:
            err(f"clips[{i}]", f"expected a clip folder or list file path (a non-empty string), got {_short(c)}")
    p = cfg.pairs
    for name, lo, hi in (("width", 64, 16384), ("height", 64, 16384), ("frames", 1, 4096),
                         ("source_window", 1, 100_000), ("point_radius", 0, 64)):
        integer(f"pairs.{name}", getattr(p, name), lo, hi)
    if p.width % 64 or p.height % 64:
        err("pairs", f"width and height must be multiples of 64 (the VAE's 8 x the UNet's 8), got {p.width}x{p.height}")
    number("pairs.source_prob", p.source_prob, 0.0, 1.0, lo_open=True, what="a number in (0, 1]")
    number("pairs.asset_prob", p.asset_prob, 0.0, 1.0, what="a number in [0, 1]")
    number("pairs.grow_ratio", p.grow_ratio, 0.0, what="a number >= 0")
    number("pairs.grow_m", p.grow_m, 0.0, what="a number >= 0")
    number("pairs.confidence_percentile", p.confidence_percentile, 0.0, 100.0, what="a number in [0, 100]")
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
    if isinstance(pairs, dict) and "window" in pairs and "source_window" not in pairs:
        pairs = {("source_window" if k == "window" else k): v for k, v in pairs.items()}  # its name before 15
    pk = {f.name for f in fields(PairSettings)}
    if not isinstance(pairs, dict):
        raise TrainConfigError(path, "pairs", f"expected an object of pair settings ({', '.join(sorted(pk))}), got "
                                              f"{_short(pairs)}")
    if set(pairs) - pk:
        raise TrainConfigError(path, "pairs", f"unknown keys {sorted(set(pairs) - pk)} (known: "
                                              f"{', '.join(sorted(pk))})")
    if "point_cleaning" in pairs:  # checked here, whole (absent: PairSettings' default, the job's defaults)
        pairs = {**pairs, "point_cleaning": point_cleaning(pairs["point_cleaning"], path)}
    if isinstance(data.get("adam_betas"), list):  # JSON has no tuples; anything else is refused by _check
        data["adam_betas"] = tuple(data["adam_betas"])
    try:
        cfg = TrainConfig(**data, pairs=PairSettings(**pairs), path=os.path.abspath(path))
    except TypeError as e:
        raise TrainConfigError(path, "(top level)", str(e)) from None
    return _check(cfg, path)


def load(path: str) -> TrainConfig:
    # files.read_json: a regular file only (a FIFO is refused, not waited on), within size, depth and number limits
    return from_dict(files.read_json(path, error=TrainConfigError), path)


def save(path: str, cfg: TrainConfig) -> None:
    outputs.write_json(path, cfg.to_json())
