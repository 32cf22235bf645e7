"""COCO instances (the COCO data format, "Object Detection"; read with ``pycocotools`` and torchvision's
``CocoDetection`` + ``wrap_dataset_for_transforms_v2`` in the tests only):

    annotations.json   {"info", "images", "annotations", "categories"}
    images/NNNNNN.png  the frames' images, NNNNNN sequential from 000000 in the job's frame order

``images``: id (sequential from 1: unique within the file), file_name, width, height, plus ``frame`` (scene frame),
``timestamp_s`` and the frame's quality (``common.frame_quality``). ``categories``: the whole fixed class table
``core.categories.CATEGORIES`` (id, name, supercategory), whatever classes the frames show, so every export of
every job agrees on the ids; an object whose class the table lacks is an ``InputError`` naming it.
``annotations`` (ids from 1), with ``EXTRA_KEYS`` (the fields ``core.labels`` says exports carry: ``track_id``,
``occlusion`` …) as extra keys:

- each object exported as a label (``common.exported``: visible pixels, not removed, not ignored), ``iscrowd`` 0:
  ``segmentation`` its visible mask — an inserted car: the instance layer's pixels with its track id; a recorded
  object: the pixels of its ``bbox_visible`` rectangle (the box of the pixels ``core.labels`` found showing its
  points; the layer holds only inserted cars, so the outline itself is not written), approximate;
- each ignore region (``core.labels.ignore_region``: an object seen but not labelled), ``iscrowd`` 1:
  ``segmentation`` the pixels of the region's rectangle, ``category_id`` its class's.

``area`` is the mask's pixel count and ``bbox`` [x, y, w, h] the mask's box. Masks are **uncompressed** RLE
(``rle``: ``{"size": [H, W], "counts": [run lengths]}``), exact for any mask and what ``pycocotools.mask.
frPyObjects`` accepts for ``iscrowd`` 0 as well as 1 (torchvision's wrapper turns every ``segmentation`` into a
mask with it; a compressed ``counts`` string raises there for ``iscrowd`` 0).

Pixel coordinates are ours (pixel (u, v) covers [u, u+1) x [v, v+1)), which are COCO's: pycocotools' ``toBbox``
gives x = the first column and w = the number of columns of a mask. RLE: the mask read in column-major (Fortran)
order as run lengths, starting with a run of zeros (possibly empty) — pycocotools' ``maskApi.c`` convention.
"""

from __future__ import annotations

import json
import os

import numpy as np

from scpainter_blender.core import categories, labels, outputs

from . import common

IMAGES, ANNOTATIONS = "images", "annotations.json"
#: Whether ``write`` reads the frames' instance layers (``command.FORMATS``): the synthetic objects' masks.
NEEDS_INSTANCE = True


def run_lengths(mask) -> list:
    """Column-major run lengths of a (H, W) boolean mask, the first a run of zeros (0 when it starts with one)."""
    flat = np.asarray(mask, bool).ravel(order="F")
    if flat.size == 0:
        return []
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    edges = np.concatenate([[0], change, [flat.size]])
    runs = np.diff(edges).tolist()
    return ([0] + runs) if flat[0] else runs


def rle(mask) -> dict:
    """A (H, W) boolean mask as COCO's uncompressed RLE ``{"size": [H, W], "counts": [int, …]}``."""
    mask = np.asarray(mask, bool)
    return {"size": [int(mask.shape[0]), int(mask.shape[1])], "counts": [int(c) for c in run_lengths(mask)]}


def rectangle_mask(box, width: int, height: int) -> np.ndarray:
    """(H, W) mask of the pixels a box [x0, y0, x1, y1] (continuous pixel coordinates) touches, clipped to the
    image."""
    x0, y0, x1, y1 = box
    c0, r0 = max(int(np.floor(x0)), 0), max(int(np.floor(y0)), 0)
    c1, r1 = min(int(np.ceil(x1)), width), min(int(np.ceil(y1)), height)
    mask = np.zeros((height, width), bool)
    mask[r0:r1, c0:c1] = True
    return mask


def mask_bbox(mask) -> list:
    """[x, y, w, h] of the True pixels of a mask (COCO's box; our continuous pixel coordinates)."""
    ys, xs = np.nonzero(mask)
    return [float(xs.min()), float(ys.min()), float(xs.max() + 1 - xs.min()), float(ys.max() + 1 - ys.min())]


#: The extra keys of an annotation: the labels' carried identity, then their carried measures by name.
EXTRA_KEYS = common.CARRIED_KEYS


def _mask(o: dict, ids, width: int, height: int):
    """The visible mask of an object exported as a label (see the module's docstring); None when an inserted car's
    pixels are missing from the layer (the labels counted pixels the layer does not have: nothing to outline)."""
    if not o["synthetic"]:
        return rectangle_mask(o["bbox_visible"], width, height)
    if ids is None:
        return None
    mask = ids == o["track_id"]
    return mask if mask.any() else None


def categories_table() -> list:
    """The ``categories`` of every export: the whole fixed table, in its order."""
    return [{"id": c.id, "name": c.name, "supercategory": c.supercategory} for c in categories.CATEGORIES]


def dataset(frames: list, file_names: list) -> dict:
    """The ``annotations.json`` content of ``frames`` (``common.ExportFrame`` with their instance layers), whose
    images are called ``file_names``."""
    images, annotations = [], []
    for i, (fr, name) in enumerate(zip(frames, file_names)):
        lab = fr.labels
        W, H = lab["image_size"]
        images.append({"id": i + 1, "file_name": name, "width": W, "height": H, "frame": lab["frame"],
                       "timestamp_s": lab["timestamp_s"], **common.frame_quality(lab)})
        ids = None if fr.instance is None else np.rint(np.asarray(fr.instance)).astype(np.int64)
        for k, o in enumerate(lab["objects"]):
            region = labels.ignore_region(o)
            if region is None and not common.exported(o):
                continue
            category = common.category(lab, k)
            mask = rectangle_mask(region, W, H) if region is not None else _mask(o, ids, W, H)
            if mask is None or not mask.any():
                continue
            annotations.append({"id": len(annotations) + 1, "image_id": i + 1, "category_id": category.id,
                                "iscrowd": int(region is not None), "segmentation": rle(mask),
                                "area": float(mask.sum()), "bbox": mask_bbox(mask), **common.carried(o)})
    return {"info": {"description": "SCPainter export (COCO instances)", "version": "2.0"},
            "images": images, "annotations": annotations, "categories": categories_table()}


def write(folder: str, frames: list, progress=None) -> dict:
    """The dataset into ``folder`` (existing, empty); ``progress(i)`` after each frame's image. Returns
    {"frames", "objects", "ignore_regions"} (objects: the ``iscrowd`` 0 annotations; ignore_regions: the
    ``iscrowd`` 1 ones)."""
    outputs.make_folder(os.path.join(folder, IMAGES))
    names = [common.index_name(i, ".png") for i in range(len(frames))]
    for i, (fr, name) in enumerate(zip(frames, names)):
        common.copy_image(fr.image, os.path.join(folder, IMAGES, name))
        if progress:
            progress(i)
    data = dataset(frames, names)
    with outputs.atomic_write(os.path.join(folder, ANNOTATIONS), "w") as f:
        json.dump(data, f, allow_nan=False)
    crowd = sum(a["iscrowd"] for a in data["annotations"])
    return {"frames": len(frames), "objects": len(data["annotations"]) - crowd, "ignore_regions": crowd}
