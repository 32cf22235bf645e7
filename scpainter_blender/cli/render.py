"""``blender -c scpainter render``: a .blend's condition layers. The .blend is opened (never written), its job seen
by the scene camera (``--camera NAME``: that camera object) written into the camera's output folder, ``<scene
output folder>/<camera>/`` (``props.camera_output_dir``; the scene output folder is ``--output`` or the scene's),
and ``python -m backend render`` run there, blocking (``common.run_scene``)."""

from __future__ import annotations

import argparse

from . import common

NAME = "render"
ORDER = 20


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``render BLEND``, the scene options, the common options, ``--checkpoint`` (the job names it)."""
    c = sub.add_parser(NAME, help="render a .blend's condition layers")
    c.add_argument("blend", help="the scene (.blend)")
    common.scene_options(c)
    common.common_options(c)
    common.checkpoint_option(c)
    common.proposals_option(c)
    c.set_defaults(func=run)
    return c


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """The scene's render; the summary (its outputs, camera, warnings) and exit code 0."""
    return common.run_scene(args, NAME, proposals=args.proposals)
