"""COCO instances (the COCO data format, "Object Detection"; read with ``pycocotools`` in the tests only):

    annotations.json   {"info", "images", "annotations", "categories"}
    images/NNNNNN.png  the frames' images, NNNNNN sequential from 000000 in the job's frame order

``images``: id (from 1), file_name, width, height, plus ``frame`` (scene frame) and ``timestamp_s``.
``categories``: the classes of the exported objects, sorted, ids from 1. ``annotations`` (ids from 1), for each
object that shows (visible pixels, not removed) with ``EXTRA_KEYS`` (the fields ``core.labels`` says exports carry:
``track_id``, ``occlusion`` …) as extra keys and ``iscrowd`` 0:

- an inserted (synthetic) object: ``segmentation`` its visible mask (the instance layer == its track id) as
  compressed RLE, ``area`` the mask's pixel count, ``bbox`` [x, y, w, h] the mask's box;
- an object of the recording: only an estimate is known (``core.labels``: the depth test inside its projected
  box), so ``bbox`` is its ``bbox_visible``, ``segmentation`` that rectangle as a polygon and ``area`` its area —
  approximate, not the object's outline.

Pixel coordinates are ours (pixel (u, v) covers [u, u+1) x [v, v+1)), which are COCO's: pycocotools' ``toBbox``
gives x = the first column and w = the number of columns of a mask.

RLE (``rle_encode``): the mask read in column-major (Fortran) order as run lengths, starting with a run of
zeros (possibly empty); ``counts`` is the compressed string of pycocotools' ``maskApi.c`` ``rleToString``: each
count after the second stored as its difference from the count two before, then written 5 bits at a time, low
bits first, as characters 48 + (bits | 0x20 when more follow), the last group's bit 0x10 giving the sign.
"""

from __future__ import annotations

import json
import os

import numpy as np

from scpainter_blender.core import labels

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


def counts_string(counts) -> str:
    """pycocotools' compressed ``counts`` string of run lengths (``maskApi.c`` ``rleToString``)."""
    out = []
    for i, c in enumerate(counts):
        x = int(c) - (int(counts[i - 2]) if i > 2 else 0)
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5  # arithmetic shift: a negative difference keeps its sign
            more = x != -1 if ch & 0x10 else x != 0
            if more:
                ch |= 0x20
            out.append(chr(ch + 48))
    return "".join(out)


def rle_encode(mask) -> dict:
    """A (H, W) boolean mask as COCO's compressed RLE ``{"size": [H, W], "counts": str}``."""
    mask = np.asarray(mask, bool)
    return {"size": [int(mask.shape[0]), int(mask.shape[1])], "counts": counts_string(run_lengths(mask))}


def mask_bbox(mask) -> list:
    """[x, y, w, h] of the True pixels of a mask (COCO's box; our continuous pixel coordinates)."""
    ys, xs = np.nonzero(mask)
    return [float(xs.min()), float(ys.min()), float(xs.max() + 1 - xs.min()), float(ys.max() + 1 - ys.min())]


#: The extra keys of an annotation: the labels' carried identity, then their carried measures by name.
EXTRA_KEYS = labels.CARRIED_IDENTITY + tuple(sorted(labels.CARRIED_MEASURES))


def _extra(obj: dict) -> dict:
    return {k: obj[k] for k in EXTRA_KEYS}


def dataset(frames: list, file_names: list) -> dict:
    """The ``annotations.json`` content of ``frames`` (``common.ExportFrame`` with their instance layers), whose
    images are called ``file_names``."""
    shown = [[o for o in fr.labels["objects"] if common.exported(o)] for fr in frames]
    classes = sorted({o["class"] for objs in shown for o in objs})
    category = {c: i + 1 for i, c in enumerate(classes)}
    images, annotations = [], []
    for i, (fr, objs, name) in enumerate(zip(frames, shown, file_names)):
        lab = fr.labels
        W, H = lab["image_size"]
        images.append({"id": i + 1, "file_name": name, "width": W, "height": H, "frame": lab["frame"],
                       "timestamp_s": lab["timestamp_s"], **common.frame_quality(lab)})
        ids = None if fr.instance is None else np.rint(np.asarray(fr.instance)).astype(np.int64)
        for o in objs:
            ann = {"id": len(annotations) + 1, "image_id": i + 1, "category_id": category[o["class"]], "iscrowd": 0}
            if o["synthetic"]:
                mask = ids == o["track_id"]
                if not mask.any():  # the labels counted pixels the layer does not have: nothing to outline
                    continue
                ann.update(segmentation=rle_encode(mask), area=float(mask.sum()), bbox=mask_bbox(mask))
            else:
                x0, y0, x1, y1 = o["bbox_visible"]
                ann.update(segmentation=[[x0, y0, x1, y0, x1, y1, x0, y1]], area=float((x1 - x0) * (y1 - y0)),
                           bbox=[x0, y0, x1 - x0, y1 - y0])
            annotations.append({**ann, **_extra(o)})
    return {"info": {"description": "SCPainter export (COCO instances)", "version": "1.0"},
            "images": images, "annotations": annotations,
            "categories": [{"id": category[c], "name": c} for c in classes]}


def write(folder: str, frames: list, progress=None) -> dict:
    """The dataset into ``folder`` (existing, empty); ``progress(i)`` after each frame's image. Returns
    {"frames", "objects"} (objects: annotations)."""
    os.makedirs(os.path.join(folder, IMAGES))
    names = [common.index_name(i, ".png") for i in range(len(frames))]
    for i, (fr, name) in enumerate(zip(frames, names)):
        common.copy_image(fr.image, os.path.join(folder, IMAGES, name))
        if progress:
            progress(i)
    data = dataset(frames, names)
    with open(os.path.join(folder, ANNOTATIONS), "w", encoding="utf-8") as f:
        json.dump(data, f, allow_nan=False)
    return {"frames": len(frames), "objects": len(data["annotations"])}
