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


def spec_of(args) -> spec_mod.VariationSpec:
    """The spec file's settings (or the defaults) with the command line's ``--variants``, ``--seed``,
    ``--library``."""
    spec = spec_mod.load(args.spec) if args.spec else spec_mod.VariationSpec()
    library = os.path.abspath(args.library) if args.library else None
    return spec.with_overrides(variants=args.variants, seed=args.seed, library=library)


def vary(args) -> dict:
    """Run the variation; progress events per variant; returns the done event's fields."""
    spec = spec_of(args)
    manifest = variants.make_variants(args.job, spec, args.out, convert_mesh=convert_mesh,
                                      progress=lambda d, n: events.progress("vary", d, n))
    return done_fields(args.out, manifest)


def done_fields(out: str, manifest: dict) -> dict:
    """What ``vary``'s done event carries (both CLIs): the folder, the list, the manifest and the summary."""
    from scpainter_blender.core.output_layout import VariationLayout

    layout = VariationLayout(os.path.abspath(out))
    for e in manifest["variants"]:
        if e["outcome"] != "placed":
            events.warning(f"{e['id']} could not be placed: car {e['unplaced']['car'] + 1} "
                           f"({e['unplaced']['asset']}, {e['unplaced']['mode']}) found no place in "
                           f"{e['unplaced']['tries']} tries", "variant_unplaced",
                           rejections=e["unplaced"]["rejections"])
    return {"output_dir": layout.root, "list": layout.list, "manifest": layout.manifest,
            "summary": manifest["summary"], "timings": manifest["timings"]}
