"""``python -m backend splat-asset``: any Gaussian file the import reads (INRIA/TRELLIS PLY, SuperSplat compressed
PLY, .splat, SOG) as an INRIA-layout PLY, values as read (``backend/splat_asset.py``): what the import runs for the
formats Blender's Python cannot decode (docs/design.md §8)."""

from __future__ import annotations

import argparse

from .. import events

NAME = "splat-asset"
ORDER = 100


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``splat-asset``'s parser."""
    a = sub.add_parser(NAME, help="any Gaussian file the import reads (INRIA/TRELLIS PLY, SuperSplat "
                                  "compressed PLY, .splat, SOG) as an INRIA-layout PLY, values as read "
                                  "(what the import runs for formats Blender's Python cannot decode)")
    a.add_argument("splats", help="Gaussian file: a .sog bundle, a SOG's meta.json, or any other accepted file")
    a.add_argument("--out", required=True, help="Gaussian PLY to write (atomically)")
    a.set_defaults(func=run)
    return a


def run(args: argparse.Namespace) -> int:
    """Convert the file; an ``artifact`` event (the PLY) and a ``done`` event with the conversion's result."""
    from .. import splat_asset

    result = splat_asset.convert(args.splats, args.out)
    events.artifact(result["ply"], kind="gaussians")
    events.done(command=NAME, result=result)
    return events.EXIT_OK
