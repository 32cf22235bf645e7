"""The condition EXR's channels, named once: the writer (``render``) and every reader (``generate``, ``evaluate``,
training pairs, benchmarks, tools) go through this module.

Channels of ``conditions/frame_NNNNNN.exr``, float32 (H, W) each:

    R G B        the condition image I, display-referred, [0, 1]
    hole         1 where the pixel has no point and the asset mask is below 1/255 (the hole mask M), else 0
    asset_mask   M_a = 1 − the transmittance of the assets' Gaussians, [0, 1]
    Z            depth (metres along the optical axis) of what the pixel shows: where the asset's opacity first
                 reaches 0.5 if nearer than the point, else the point; +inf where empty

The dict ``frames.render_frame`` returns has exactly these keys. Condition EXRs written before the asset mask had
one name call its channel ``asset``; ``read`` gives it the current name, so earlier output folders still load
(their record's job key is unchanged, so a resumed render keeps them).

Only numpy and the EXR module: tools that just read the layers do not import torch.
"""

from __future__ import annotations

import os

from scpainter_blender.core import files

from . import exr

IMAGE = ("R", "G", "B")
HOLE = "hole"
ASSET_MASK = "asset_mask"
DEPTH = "Z"
CHANNELS = (*IMAGE, HOLE, ASSET_MASK, DEPTH)

#: Former channel names -> current ones (condition EXRs written before the rename).
FORMER_NAMES = {"asset": ASSET_MASK}


class ConditionsError(files.InputError):
    """A condition EXR without the channels this reader needs (``field`` = ``channels``)."""


def write(path, layers: dict) -> None:
    """One frame's layers (``CHANNELS`` -> (H, W) arrays, as ``frames.render_frame`` returns them) as a condition
    EXR, atomically (``exr.write``). ValueError (a programming error, not input) for any other set of keys."""
    if set(layers) != set(CHANNELS):
        raise ValueError(f"condition layers must be {list(CHANNELS)}, got {sorted(layers)}")
    exr.write(path, layers)


def read(path, required=CHANNELS) -> dict:
    """The channels {name: (H, W) float32} of a condition EXR, former names (``FORMER_NAMES``) renamed to the
    current ones. ``required``: the channels the caller needs; ConditionsError naming the missing ones, with a
    hint to render the frame again."""
    layers = exr.read(path)
    for old, new in FORMER_NAMES.items():
        if old in layers and new not in layers:
            layers[new] = layers.pop(old)
    missing = [c for c in required if c not in layers]
    if missing:
        raise ConditionsError(os.fspath(path), "channels",
                              f"condition layers {missing} are missing (the file has {sorted(layers)})",
                              hint="render the conditions again: python -m backend render JOB --force")
    return layers
