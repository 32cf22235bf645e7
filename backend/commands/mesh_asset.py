"""``python -m backend mesh-asset``: a car mesh (GLB, glTF, OBJ, PLY, STL, OFF) as flat surface Gaussians, written
as an INRIA-layout PLY, Z up, in the mesh's units (``backend/mesh/asset.py``; docs/design.md §8)."""

from __future__ import annotations

import argparse

from .. import events

NAME = "mesh-asset"
ORDER = 90


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``mesh-asset``'s parser."""
    m = sub.add_parser(NAME, help="a car mesh (GLB, glTF, OBJ, PLY, STL, OFF) as flat surface Gaussians "
                                  "(an INRIA-layout PLY, Z up, the mesh's units)")
    m.add_argument("mesh", help="mesh file; glTF/GLB/OBJ are read Y up, PLY/STL/OFF Z up (see --up)")
    m.add_argument("--out", required=True, help="Gaussian PLY to write (atomically)")
    m.add_argument("--count", type=int, default=200_000, help="number of Gaussians (default 200000)")
    m.add_argument("--up", choices=["auto", "y", "z"], default="auto", help="the file's up axis (default: by format)")
    m.add_argument("--seed", type=int, default=0)
    m.set_defaults(func=run)
    return m


def run(args: argparse.Namespace) -> int:
    """Convert the mesh; an ``artifact`` event (the PLY) and a ``done`` event with the conversion's result."""
    from ..mesh import asset as mesh_asset

    result = mesh_asset.convert(args.mesh, args.out, count=args.count, up=args.up, seed=args.seed,
                                progress=events.progress)
    events.artifact(result["ply"], kind="gaussians")
    events.done(command=NAME, result=result)
    return events.EXIT_OK
