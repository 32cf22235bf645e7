"""``python -m backend init-checkpoint``: make an SCPainter checkpoint folder from a stock SVD snapshot
(``backend/model/checkpoint_init.py``; docs/design.md §11)."""

from __future__ import annotations

import argparse

from .. import events

NAME = "init-checkpoint"
ORDER = 60


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``init-checkpoint``'s parser."""
    c = sub.add_parser(NAME, help="make an SCPainter checkpoint folder from a stock SVD snapshot")
    c.add_argument("--svd", required=True, help="local stable-video-diffusion-img2vid(-xt) diffusers folder")
    c.add_argument("--out", required=True, help="new checkpoint folder")
    c.set_defaults(func=run)
    return c


def run(args: argparse.Namespace) -> int:
    """Write the checkpoint; a ``done`` event naming it."""
    from ..model import checkpoint_init

    out = checkpoint_init.init_checkpoint(args.svd, args.out, log=events.log)
    events.done(command=NAME, checkpoint=out)
    return events.EXIT_OK
