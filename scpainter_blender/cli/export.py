"""``blender -c scpainter export``: a .blend's labels as a dataset. The .blend's job is written as ``render`` writes
it (``--camera`` too) and ``python -m backend export`` run on it (``common.run_scene``; missing frames rendered
first; the dataset in ``--out``, default ``<camera's output folder>/export/<format>``; docs/design.md §15)."""

from __future__ import annotations

import argparse
import os

from ..core import backend_protocol as protocol
from . import common

NAME = "export"
ORDER = 60


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``export BLEND --format F``, ``--out``, the scene options, the common options."""
    x = sub.add_parser(NAME, help=f"a .blend's labels as a dataset ({protocol.export_format_labels()}), rendering "
                                  "missing frames first")
    x.add_argument("blend", help="the scene (.blend)")
    x.add_argument("--format", required=True, choices=protocol.EXPORT_FORMAT_NAMES)
    x.add_argument("--out", help="destination folder, written whole (default: <output folder>/export/<format>); an "
                                 "existing one must be empty or a previous export")
    common.scene_options(x)
    common.common_options(x)
    common.proposals_option(x)
    x.set_defaults(func=run)
    return x


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """The scene's dataset; the summary (its outputs: ``format``, ``out``, ``objects``, ``images``; camera,
    warnings) and exit code 0."""
    return common.run_scene(args, NAME, export_format=args.format,
                            out=os.path.abspath(args.out) if args.out else None, proposals=args.proposals)
