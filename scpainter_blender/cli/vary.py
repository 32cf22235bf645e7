"""``blender -c scpainter vary``: variants of a scene (camera shifts, lane changes, cars from a library placed on
the road) as job folders with a batch list and a manifest (``scene/variations.py``, docs/design.md §16). The source
is a .blend, opened, or VGGT predictions (.npz) imported into an empty scene with the import options; its job seen
from ``--camera`` is the base."""

from __future__ import annotations

import argparse
import json
import sys

import bpy

from ..core import backend_protocol as protocol
from ..core import errors, import_options
from ..core.variation import spec as variation_spec, variants as vary_mod
from ..runs import preferences
from ..scene import importer, props, variations
from . import common

NAME = "vary"
ORDER = 50


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``vary SOURCE``, the variation options (``core.variation.spec``), ``--camera``, the import options,
    ``--backend-python``."""
    v = sub.add_parser(NAME, help="variants of a scene (camera shifts, lane changes, cars from a library placed on "
                                  "the road) as job folders with a batch list and a manifest")
    v.add_argument("source", help="the scene (.blend), or VGGT predictions (.npz) imported with the import options")
    variation_spec.add_arguments(v)
    v.add_argument("--camera", help="the camera the variants start from (default: the scene camera)")
    import_options.add_arguments(v)
    v.add_argument("--backend-python", help="interpreter for mesh conversions (default: the add-on preference)")
    v.set_defaults(func=run)
    return v


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """The .blend opened (or the predictions imported into an empty scene with the import options), its job seen
    from ``--camera`` the base, the variants written (``scene/variations.py``): the summary and exit code 0; exit 1
    when none could be placed (the summary says why). Import options with a .blend source are bad input."""
    spec = variation_spec.from_arguments(args)  # checked before a scene is opened
    if args.source.lower().endswith(".npz"):
        bpy.ops.wm.read_homefile(use_empty=True)
        importer.import_vggt(bpy.context, args.source, import_options.from_arguments(args))
    else:
        given = import_options.given(args)
        if given:  # a .blend's points were imported already: the options would change nothing
            raise errors.ArgumentError(given[0], "is an import option: it applies to a predictions (.npz) source, "
                                                 f"not to the scene {args.source}",
                                       hint="leave it out, or give the predictions file instead of the .blend")
        common.open_blend(args.source, args)
    camera = props.named_camera(bpy.context.scene, args.camera, args.source)
    python = args.backend_python or preferences.python(preferences.get(bpy.context))

    def progress(done: int, total: int) -> None:
        print(f"scpainter: vary {done}/{total}", file=sys.stderr, flush=True)

    manifest = variations.make_variations(bpy.context, spec, args.out, camera, python, progress, args.skip_bad)
    for w in vary_mod.warnings(manifest):
        print(json.dumps(protocol.event(protocol.WARNING, **w)), flush=True)
    code = protocol.EXIT_OK if manifest["summary"]["placed"] else protocol.EXIT_FAILED
    return vary_mod.done_fields(manifest, args.out), code
