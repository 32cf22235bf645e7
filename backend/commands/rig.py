"""``python -m backend rig``: a single-camera job made a rig job (``core/rig_convert.py``; docs/design.md §17): the
base job's camera path becomes the ego path of a camera rig (a preset or a rig file) whose ``--follow`` camera
rides where the base camera was; the new job is written atomically, its paths valid from its own folder."""

from __future__ import annotations

import argparse

from .. import events

NAME = "rig"
ORDER = 125


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``rig``'s parser."""
    from scpainter_blender.core import rig as rig_mod
    from scpainter_blender.core.rig_convert import NO_LIDAR

    from . import options

    r = sub.add_parser(NAME, help="make a single-camera job a rig job (several cameras, and a LiDAR, on the ego "
                                  "vehicle following the job's camera path)")
    r.add_argument("job", help="the base job (job.json) with one camera")
    r.add_argument("--preset", required=True, metavar="NAME|RIG.json",
                   help=f"the rig: a preset ({', '.join(rig_mod.PRESETS)}) or a rig file (scpainter.rig/1)")
    r.add_argument("--follow", metavar="CAMERA",
                   help="the rig camera that rides on the base job's camera path (default: the rig's first)")
    r.add_argument("--scale", type=_number, default=1.0,
                   help="every camera's width and height times this (K scaled to match; default 1)")
    r.add_argument("--lidar", metavar="MODEL|none",
                   help=f"the rig's LiDAR model (a rig without one gets nuScenes' top mount), or {NO_LIDAR} "
                        "(default: the rig's own)")
    r.add_argument("--out", required=True, metavar="NEW_JOB.json",
                   help="the rig job to write; its folder is its output folder (give it a folder of its own); "
                        "an existing file is never overwritten")
    options.confinement_options(r)   # the base's paths confined as render confines them
    r.set_defaults(func=run)
    return r


def run(args: argparse.Namespace) -> int:
    """Write the rig job; a ``done`` event naming it, its cameras and LiDAR, and the folders a render of it needs
    as ``--data-root``."""
    from scpainter_blender.core import outputs, rig_convert

    rig = rig_convert.choose_rig(args.preset, args.scale, args.lidar)
    job, outside = rig_convert.make(args.job, rig, args.out, args.follow, args.allow_outside,
                                    outputs.data_roots_option(args.data_root))
    events.done(command=NAME, job=args.out, rig=rig.name, cameras=[c.name for c in rig.cameras],
                resolutions={c.name: list(c.resolution) for c in rig.cameras},
                lidar=None if rig.lidar is None else rig.lidar.name, follow=args.follow or rig.cameras[0].name,
                frames=len(job.frames), data_roots=outside)
    return events.EXIT_OK
