"""``blender -c scpainter generate``: a .blend's video, run as ``render`` runs (the job in the camera's output
folder, ``common.run_scene``) with ``python -m backend generate``. Without a checkpoint (``--checkpoint`` or the
preference) it makes the baseline, OpenCV inpainting of the condition holes (no model; ``--inpaint`` for this run,
else the scene's Baseline Inpainting); each output says which (``model``: "scpainter" or "baseline", and
``description``)."""

from __future__ import annotations

import argparse

from . import common

NAME = "generate"
ORDER = 30


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``generate BLEND``, the scene options, the common options, ``--checkpoint``, ``--inpaint``."""
    c = sub.add_parser(NAME, help="generate a .blend's video")
    c.add_argument("blend", help="the scene (.blend)")
    common.scene_options(c)
    common.common_options(c)
    common.checkpoint_option(c)
    common.inpaint_option(c)
    c.set_defaults(func=run)
    return c


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """The scene's video; the summary (its outputs, ``model``, camera, warnings) and exit code 0."""
    return common.run_scene(args, NAME)
