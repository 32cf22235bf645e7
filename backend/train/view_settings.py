"""The view settings training and evaluation share: one home for their values and defaults.

A training pair (``pairs.PairSettings``) and an evaluation task (``evaluate.protocol.EvalSettings``) are rendered
the same way: ``frames`` consecutive frames at ``width`` x ``height`` pixels, the points of the frames within
±``source_window`` of frame t projected into it, a re-inserted car's points removed inside its box grown by
``grow_ratio`` and ``grow_m``, the reconstruction's points kept above ``confidence_percentile`` as a job keeps
them. Both settings classes derive from ``ViewSettings``, so these fields (flat, as train.json's ``pairs`` and
evaluation.json's ``settings`` hold them) and their defaults are written here only; ``python -m backend evaluate``'s
options default to None and take these defaults from the dataclass.

It lives in ``backend/train`` because evaluation already reads its clips and frames through the training side
(``train.clip``, ``train.pairs``); it imports neither torch nor bpy, so the command line reads it at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass

from scpainter_blender.core.geometry import point_cloud


@dataclass(frozen=True, kw_only=True)
class ViewSettings:
    """Keyword-only fields, so a subclass may declare fields without defaults before them."""

    width: int = 576                    # pixels: SVD's 576 x 320 (latents 1/8 of it)
    height: int = 320
    frames: int = 14                    # consecutive frames of a sample or an evaluated clip (SVD's window)
    source_window: int = 8              # the points of frames t − source_window .. t + source_window project into t
    grow_ratio: float = 0.1             # a removal box = the car's size · (1 + grow_ratio) + 2 · grow_m (metres)
    grow_m: float = 0.2
    # points kept above this percentile of VGGT's confidence: the import's and the job's default, so both keep what
    # a job does
    confidence_percentile: float = point_cloud.CONFIDENCE_PERCENTILE
