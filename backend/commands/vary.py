"""``python -m backend vary``: variants of a job (camera shifts, lane changes, cars from a library placed on the
road), written as job folders with a batch list and a manifest (``backend/vary/command.py``; docs/design.md §16).
Its options are the variation spec's (``core.variation.spec.add_arguments``)."""

from __future__ import annotations

import argparse

from .. import events

NAME = "vary"
ORDER = 120


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``vary``'s parser."""
    from scpainter_blender.core.variation import spec as variation_spec  # (numpy only: the parser stays light)

    v = sub.add_parser(NAME, help="variants of a job (camera shifts, lane changes, cars from a library placed on "
                                  "the road), written as job folders with a batch list and a manifest")
    from . import options

    v.add_argument("job", help="the base job (job.json), e.g. as Blender exports it")
    variation_spec.add_arguments(v)
    options.confinement_options(v)   # the base's paths confined as render confines them
    v.set_defaults(func=run)
    return v


def run(args: argparse.Namespace) -> int:
    """Write the variants; a ``done`` event with what ``vary`` reports, and its exit code."""
    from ..vary import command

    fields, code = command.vary(args)
    events.done(command=NAME, **fields)
    return code
