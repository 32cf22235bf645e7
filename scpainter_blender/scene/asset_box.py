"""A Gaussian asset's 3D box and class, for labels: estimated at import, shown as a child cube empty the artist
edits, written to the job (``assets[].box``, ``assets[].class``).

Box convention (core/geometry/boxes.py): the box frame is centred on the box, x across the width, y along the
length with +y the front, z up; ``size`` = (width, length, height).

* The box object (kind ``ASSET_BOX``, ``kinds.asset_box(asset)``) is a cube empty of display size
  ``DISPLAY_SIZE`` = 0.5, so its own unit cube [−0.5, 0.5]³ is the box (``placement.cube_matrix``), parented to
  the asset with an identity parent inverse: its ``matrix_basis`` = box_to_data · diag(size) is the box in the
  asset's *data frame* (Z up, data units: before the asset's scale). It follows the asset; the artist moves, turns
  and scales it in the viewport.
* A single-arrow empty (kind ``ASSET_FRONT``, ``kinds.asset_front(box)``), the box's child, marks the front: it
  starts at the centre of the front face and points along +y, ``FRONT_LENGTH`` of the box's length long; it is not
  selectable (it follows the box).
* The asset's class is its custom property ``CLASS_PROPERTY`` (``scpainter_class``), ``core.job.DEFAULT_CLASS``
  at import.

In the job the box is in the PLY file's coordinates (``job_box``): the box in the data frame mapped back through
``scpainter_file_to_data`` (any affine: the nearest rigid box, ``boxes.rigid_box``), so the backend places it with
the asset's own object_to_world.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..core import job as job_mod
from ..core.geometry import boxes
from . import keys, kinds, placement, props

DISPLAY_SIZE = 0.5        # a cube empty draws [−size, size]³: 0.5 draws the unit cube
FRONT_LENGTH = 0.25       # the front arrow's length, a fraction of the box's length (it scales with the box)
CLASS_PROPERTY = keys.CLASS
#: The front arrow in the box's unit frame: at the front face's centre (y = +0.5), its z (the arrow) along +y.
_FRONT_BASIS = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.5], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
#: 180° about the box's own z: its front becomes its back (exact, unlike a rotation by float π).
_FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])


def data_points(asset) -> np.ndarray:
    """(N, 3) float64: the asset's Gaussian means in its data frame (its mesh's vertex positions)."""
    n = len(asset.data.vertices)
    pos = np.empty(n * 3, np.float32)
    if n:
        asset.data.attributes["position"].data.foreach_get("vector", pos)
    return pos.reshape(-1, 3).astype(np.float64)


def estimate(asset, points=None):
    """Estimate the asset's box and (re)make its box object: ``boxes.estimate_box`` of ``points`` (N, 3) in its
    data frame (default: its Gaussian means), upright in the data frame's Z. Replaces a box the artist edited.
    Returns the box object, or None (and removes the old box) when fewer than 4 finite points make no box: the
    backend then estimates it when it makes labels."""
    P = data_points(asset) if points is None else np.asarray(points, np.float64).reshape(-1, 3)
    if np.count_nonzero(np.isfinite(P).all(axis=1)) < 4:
        remove(asset)
        return None
    box_to_data, size = boxes.estimate_box(P, up=(0.0, 0.0, 1.0))
    return make(asset, box_to_data, size)


def make(asset, box_to_data, size):
    """The asset's box object for the box ``box_to_data`` (4, 4 rigid, data frame) of ``size`` (width, length,
    height; data units), with its front arrow; an existing box is replaced."""
    remove(asset)
    box = _empty(f"{asset.name} box", "CUBE", DISPLAY_SIZE, kinds.ASSET_BOX, asset)
    unit = np.asarray(box_to_data, np.float64) @ np.diag([*np.asarray(size, np.float64), 1.0])
    box.matrix_basis = Matrix(unit.tolist())
    front = _empty(f"{asset.name} front", "SINGLE_ARROW", FRONT_LENGTH, kinds.ASSET_FRONT, box)
    front.matrix_basis = Matrix(_FRONT_BASIS.tolist())
    front.hide_select = True
    return box


def _empty(name, display_type, display_size, kind, parent):
    obj = bpy.data.objects.new(name, None)
    obj.empty_display_type = display_type
    obj.empty_display_size = display_size
    kinds.mark(obj, kind)
    for coll in parent.users_collection:
        coll.objects.link(obj)
    obj.parent = parent
    obj.matrix_parent_inverse = Matrix.Identity(4)  # its matrix_basis is in the parent's own frame
    return obj


def remove(asset) -> None:
    """Delete the asset's box object and its front arrow (no box: nothing happens)."""
    box = kinds.asset_box(asset)
    if box is None:
        return
    for obj in [*box.children, box]:
        bpy.data.objects.remove(obj, do_unlink=True)


def flip(asset) -> bool:
    """Turn the asset's box 180° about its own z (its front becomes its back; centre and size kept). False when
    the asset has no box."""
    box = kinds.asset_box(asset)
    if box is None:
        return False
    box.matrix_basis = Matrix((np.array(box.matrix_basis, np.float64) @ _FLIP).tolist())
    return True


def box_to_data(asset, box) -> np.ndarray:
    """The affine (4, 4) mapping the unit cube onto ``box`` in the asset's data frame: its parent inverse ·
    ``matrix_basis`` when it is the asset's child (float64 from the stored transform: Blender's world matrices are
    float32), else inverse(asset.matrix_world) · its matrix_world; through ``placement.cube_matrix``."""
    if box.parent == asset:
        M = np.array(box.matrix_parent_inverse, np.float64) @ np.array(box.matrix_basis, np.float64)
    else:
        M = np.linalg.inv(np.array(asset.matrix_world, np.float64)) @ np.array(box.matrix_world, np.float64)
    return placement.cube_matrix(box, M)


def job_box(asset) -> job_mod.AssetBox | None:
    """The job's ``AssetBox`` of an asset, in its PLY file's coordinates: the nearest rigid box (``rigid_box``) of
    inverse(file_to_data) · ``box_to_data``; None when it has no box object (the backend then estimates one)."""
    box = kinds.asset_box(asset)
    if box is None:
        return None
    file_to_data = props.matrix_property(asset, keys.FILE_TO_DATA)
    T, size = boxes.rigid_box(np.linalg.inv(file_to_data) @ box_to_data(asset, box))
    return job_mod.AssetBox(T, size)


def category(asset) -> str:
    """The asset's class for labels: ``CLASS_PROPERTY``, else ``core.job.DEFAULT_CLASS`` (an asset imported before
    classes existed). Checked by the job's own rule when the job is saved."""
    return str(asset.get(CLASS_PROPERTY, job_mod.DEFAULT_CLASS)).strip() or job_mod.DEFAULT_CLASS


def assets_among(objects) -> list:
    """The Gaussian assets ``objects`` stand for (an asset, or its box or front arrow: ``kinds.owning_asset``),
    each once, in order; None entries are skipped."""
    out = []
    for obj in objects:
        asset = kinds.owning_asset(obj)
        if asset is not None and asset not in out:
            out.append(asset)
    return out
