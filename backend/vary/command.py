"""``python -m backend vary BASE_JOB --out DIR``: variants of a job without Blender (``core.variation``), mesh
cars converted in this process (``backend.mesh``); ``python -m backend contact-sheet DIR``."""

from __future__ import annotations

from scpainter_blender.core.variation import spec as spec_mod, variants

from .. import events


def convert_mesh(mesh: str, out: str, count: int) -> None:
    """A library mesh into surface Gaussians at ``out``, as ``mesh-asset`` makes them."""
    from ..mesh import asset as mesh_asset

    mesh_asset.convert(mesh, out, count=count)


def vary(args) -> tuple:
    """Run the variation: progress events per variant, a warning event per unplaced variant and per warning of
    the run. The base job's paths are confined as ``render`` confines them (``--data-root``, ``--allow-outside``);
    the output folder is locked for the run (a second run: ``FolderBusyError``). Returns (the done event's fields,
    exit code: 1 when no variant could be placed)."""
    from scpainter_blender.core import outputs

    from ..errors import FolderBusyError

    spec = spec_mod.from_arguments(args)
    manifest = variants.make_variants(args.job, spec, args.out, convert_mesh=convert_mesh,
                                      progress=lambda d, n: events.progress("vary", d, n), skip_bad=args.skip_bad,
                                      allow_outside=args.allow_outside,
                                      data_roots=outputs.data_roots_option(args.data_root), busy=FolderBusyError)
    for w in variants.warnings(manifest):
        events.warning(**w)
    code = events.EXIT_OK if manifest["summary"]["placed"] else events.EXIT_FAILED
    return variants.done_fields(manifest, args.out), code
