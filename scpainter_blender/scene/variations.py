"""Variations from a Blender scene: the scene's job is the base (its points, recorded camera or camera path, cars,
boxes), ``core.variation`` makes the variants, library meshes go through the backend's ``mesh-asset``
(trimesh lives in the backend's Python). Shared by ``blender -c scpainter vary`` and *Make Variations*."""

from __future__ import annotations

import os

from ..core.output_layout import VariationLayout
from ..core.variation import variants
from ..runs.client import Invocation
from . import job_export


def mesh_converter(python: str = ""):
    """``convert_mesh(mesh, out_ply, count)`` running ``python -m backend mesh-asset`` with ``python``."""
    def convert(mesh: str, out: str, count: int) -> None:
        Invocation("mesh-asset", asset=mesh, out=out, count=int(count), python=python).run()
    return convert


def make_variations(context, spec, out: str, camera=None, python: str = "", progress=None,
                    skip_bad: bool = False) -> dict:
    """Export the scene's job seen from ``camera`` (None: the scene camera) as the base
    (``VariationLayout.base_job``) and write ``spec``'s variants into ``out`` (``skip_bad``: ``vary --skip-bad``,
    ``variants.make_variants``); returns the manifest. Errors:
    ``SceneError`` (no camera, no points), ``VariationError`` and the readers' ``InputError``s, a mesh's
    ``BackendError``."""
    out = os.path.abspath(out)
    layout = VariationLayout(out)
    variants.check_out(out, spec.variants, writes=(VariationLayout.BASE,))   # never over a user's files
    job_export.export_job(context, layout.base_job, output_dir=os.path.dirname(layout.base_job), camera=camera)
    # the add-on trusts the files the user imported (as it passes --allow-outside to every backend run)
    return variants.make_variants(layout.base_job, spec, out, convert_mesh=mesh_converter(python), progress=progress,
                                  skip_bad=skip_bad, allow_outside=True, own=(VariationLayout.BASE,))
