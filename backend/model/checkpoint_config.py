"""``scpainter.json``, an SCPainter checkpoint's config: generation defaults and provenance, read field by field.

``ScpainterConfig.load`` validates the file (schema, types, ``BOUNDS``, ``min_guidance`` ≤ ``max_guidance``) with
``check_field`` and ``check_guidance``. ``CheckpointError`` is the error of everything about a checkpoint folder
(``checkpoint``: finding, checking and loading one; ``checkpoint_init``: making one). stdlib and core only.

Errors are ``CheckpointError`` (a ``errors.InputError``: ``path``, ``field``, ``message``, ``hint``); ``str()`` is
``"<full path>: <field>: <what is wrong>"``, e.g. ``/models/ckpt/scpainter.json: fps: expected an integer in
[1, 240], got 300``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from scpainter_blender.core import errors, files
from scpainter_blender.core import job as job_mod

SCHEMA = "scpainter.checkpoint/1"

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


class CheckpointError(errors.InputError):
    """A checkpoint or SVD folder that cannot be used: ``path`` (the file or folder; ``errors.COMMAND_LINE`` or the
    job file when no checkpoint is given, see ``checkpoint.resolve``), ``field`` (the key; ``"(file)"`` /
    ``"(folder)"`` for the whole), ``message``, ``hint``. ``str()`` is ``"<path>: <field>: <message>"`` with the
    full path (``config.json`` alone would not say which component)."""

    def __init__(self, path, field, message, hint=None):
        super().__init__(path, field, message, hint)
        self.args = (f"{self.path}: {self.field}: {message}",)

    def __reduce__(self):  # picklable (worker processes): rebuilt from its parts, not from the formatted message
        return type(self), (self.path, self.field, self.message, self.hint)


def show_value(value) -> str:
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


def json_object(path: str) -> dict:
    """A checkpoint's JSON file that must hold an object (``files.read_json``'s limits), or CheckpointError."""
    data = files.read_json(path, error=CheckpointError)
    if not isinstance(data, dict):
        raise CheckpointError(path, "(file)", f"expected a JSON object, got {show_value(data)}")
    return data


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
            raise ValueError(f"{want}, got {show_value(value)}")
    else:
        want = f"expected a finite number {rng}"
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ValueError(f"{want}, got {show_value(value)}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{want}, got {value}")
    if value < low or (high is not None and value > high):
        raise ValueError(f"{want}, got {show_value(value)}")
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
        data = json_object(path)
        if data.get("schema") != SCHEMA:
            got = f"is {show_value(data['schema'])}" if "schema" in data else "is missing"
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
                problem = f"expected a string (the SVD snapshot's folder), got {show_value(v)}"
            elif name == "latent_validity" and (not isinstance(v, str) or v not in LATENT_VALIDITY):
                problem = f"expected one of {', '.join(map(repr, LATENT_VALIDITY))}, got {show_value(v)}"
            elif name == "extra" and not isinstance(v, dict):
                problem = f"expected an object, got {show_value(v)}"
            if problem:
                raise CheckpointError(path, name, problem, hint=FIELD_HINT)
            values[name] = v
        cfg = cls(**values)
        try:
            check_guidance(cfg.min_guidance, cfg.max_guidance)
        except ValueError as e:
            raise CheckpointError(path, "min_guidance", str(e), hint=FIELD_HINT) from None
        return cfg
