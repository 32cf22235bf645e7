"""``python -m backend train``: fine-tune a checkpoint on clip folders (``backend/train/trainer.py``;
docs/training.md, docs/design.md §13). Run under ``accelerate launch`` / ``torchrun`` for several GPUs (one ``done``
event, from rank 0); it resumes from the newest checkpoint in the config's output_dir, and SIGTERM stops it with a
checkpoint saved.
"""

from __future__ import annotations

import argparse

from .. import events
from . import options

NAME = "train"
ORDER = 70


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``train``'s parser."""
    t = sub.add_parser(NAME, help="fine-tune a checkpoint on clip folders (run under accelerate launch/torchrun "
                                  "for several GPUs); resumes from the newest checkpoint in output_dir")
    t.add_argument("config", help="training config JSON (schema scpainter.train/1, docs/training.md)")
    options.device_option(t, None)
    t.add_argument("--max-steps", type=int, help="stop (with a checkpoint) after this step this time")
    t.set_defaults(func=run)
    return t


def run(args: argparse.Namespace) -> int:
    """Train; a ``done`` event (rank 0), else an error event when SIGTERM stopped it (exit 1)."""
    from ..train import config as train_config
    from ..train import trainer

    cfg = train_config.load(args.config)
    device = options.resolve_device(args.device)
    with events.stop_on_sigterm() as stop:
        result = trainer.train(cfg, device, stop, args.max_steps)
    result.pop("losses", None)
    if result.pop("stopped"):
        events.error(f"stopped by SIGTERM at step {result['step']}; checkpoint saved at {result['checkpoint']}",
                     hint="run the same command again to resume")
        return events.EXIT_FAILED
    from scpainter_blender.core.batch_items import ranks_from_env

    if ranks_from_env()[0] == 0:  # under torchrun / accelerate launch: one done event, from rank 0
        events.done(command=NAME, device=device, **result)
    return events.EXIT_OK
