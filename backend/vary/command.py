"""``python -m backend vary BASE_JOB --out DIR``: variants of a job without Blender (``core.variation``), mesh
cars converted in this process (``backend.mesh``); ``python -m backend contact-sheet DIR``."""

from __future__ import annotations

import os

from scpainter_blender.core.variation import spec as spec_mod, variants

from .. import events


def convert_mesh(mesh: str, out: str, count: int) -> None:
    """A library mesh into surface Gaussians at ``out``, as ``mesh-asset`` makes them."""
    from ..mesh import asset as mesh_asset

    mesh_asset.convert(mesh, out, count=count)


def vary(args) -> dict:
    """Run the variation; progress events per variant; returns the done event's fields."""
    spec = spec_mod.from_arguments(args)
    manifest = variants.make_variants(args.job, spec, args.out, convert_mesh=convert_mesh,
                                      progress=lambda d, n: events.progress("vary", d, n))
    return done_fields(args.out, manifest)


def done_fields(out: str, manifest: dict) -> dict:
    """What ``vary``'s done event carries (both CLIs): the folder, the list, the manifest and the summary."""
    from scpainter_blender.core.output_layout import VariationLayout

    layout = VariationLayout(os.path.abspath(out))
    for e in manifest["variants"]:
        if e["outcome"] != "placed":
            events.warning(variants.unplaced_text(e), variants.UNPLACED, rejections=e["unplaced"]["rejections"])
    return {"output_dir": layout.root, "list": layout.list, "manifest": layout.manifest,
            "summary": manifest["summary"], "timings": manifest["timings"]}
