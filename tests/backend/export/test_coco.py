"""COCO export read back with the loaders teams train with (test-only tools): pycocotools' ``COCO`` and
torchvision's ``CocoDetection`` + ``wrap_dataset_for_transforms_v2``: masks equal to the instance pass, boxes,
the fixed category table, ignore regions as ``iscrowd`` 1."""

import json
import os
import sys

import numpy as np
import pytest
import torch
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from tests.backend.export import export_fixtures as F
from backend.export import coco
from scpainter_blender.core import categories, errors, labels

#: Kept alive while the tests run: see ``_torchvision``.
_SCHEMAS = []


def _torchvision():
    """torchvision (requirements.txt's test-only pin). PyPI's torchvision wheel is built against PyPI's CUDA torch;
    beside a CPU build of the same torch release (this project's machines install torch 2.13.0+cpu) its compiled
    operators do not load, and its import then fails declaring a fake kernel for ``torchvision::nms`` ("operator
    torchvision::nms does not exist"). The loaders tested here are pure Python (the masks come from pycocotools),
    so in that case the two operators' schemas are declared, without kernels, and the import retried."""
    try:
        import torchvision
    except RuntimeError as e:
        if "torchvision::nms" not in str(e):
            raise
        for name in [n for n in sys.modules if n == "torchvision" or n.startswith("torchvision.")]:
            del sys.modules[name]
        lib = torch.library.Library("torchvision", "DEF")
        for op in ("nms", "qnms"):
            lib.define(f"{op}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
        _SCHEMAS.append(lib)
        import torchvision
    return torchvision


@pytest.mark.parametrize("seed", range(40))
def test_rle_matches_pycocotools(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 300, 2)
    mask = rng.random((h, w)) < rng.random()
    if seed == 0:
        mask[:] = False
    elif seed == 1:
        mask[:] = True
    elif seed == 2:  # long runs of every size
        mask[:] = False
        mask[: h // 2, : w // 3] = True
        mask[-1, -1] = True
    ours = coco.rle(mask)
    assert ours["size"] == [h, w] and all(isinstance(c, int) for c in ours["counts"])
    compressed = mask_utils.frPyObjects(ours, int(h), int(w))      # what the loaders do with it
    theirs = mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))
    assert compressed["counts"] == theirs["counts"]
    assert np.array_equal(mask_utils.decode(compressed), mask)
    if mask.any():
        assert coco.mask_bbox(mask) == list(mask_utils.toBbox(theirs))


def test_rectangle_mask_covers_the_touched_pixels():
    m = coco.rectangle_mask([1.5, 2.0, 4.0, 3.2], 6, 5)
    assert m.sum() == 3 * 2 and m[2:4, 1:4].all()
    assert coco.rectangle_mask([-3.0, -1.0, 99.0, 1.0], 6, 5).sum() == 6


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    return F.write_dataset(tmp_path_factory, coco, "coco")


def _expected_masks(fr) -> dict:
    """track id -> (iscrowd, the mask the annotation must decode to): an inserted car's instance pixels, a recorded
    object's visible-box rectangle, an ignore region's rectangle."""
    out = {}
    for o in fr.labels["objects"]:
        region = labels.ignore_region(o)
        if region is not None:
            out[o["track_id"]] = (1, coco.rectangle_mask(region, F.W, F.H))
        elif o["synthetic"]:
            out[o["track_id"]] = (0, np.rint(fr.instance) == o["track_id"])
        else:
            out[o["track_id"]] = (0, coco.rectangle_mask(o["bbox_visible"], F.W, F.H))
    return out


def test_pycocotools_reads_it_back(exported):
    out, frames, counts = exported
    assert sorted(os.listdir(out)) == ["annotations.json", "images"]
    api = COCO(str(out / "annotations.json"))
    cats = api.loadCats(api.getCatIds())
    assert [(c["id"], c["name"], c["supercategory"]) for c in cats] == \
        [(c.id, c.name, c.supercategory) for c in categories.CATEGORIES]       # the whole table, every time
    assert counts == {"frames": 2, "objects": 6, "ignore_regions": 2} and len(api.getAnnIds()) == 8
    assert api.getImgIds() == [1, 2]
    for i, fr in enumerate(frames):
        img = api.loadImgs(i + 1)[0]
        assert (img["file_name"], img["width"], img["height"]) == (f"00000{i}.png", F.W, F.H)
        assert (img["frame"], img["timestamp_s"]) == (fr.labels["frame"], fr.labels["timestamp_s"])
        assert img["unlabelled_fraction"] == fr.labels["unlabelled_fraction"]
        assert (out / "images" / img["file_name"]).read_bytes() == open(fr.image, "rb").read()
        anns = api.loadAnns(api.getAnnIds(imgIds=[i + 1]))
        expected = _expected_masks(fr)
        assert sorted(a["track_id"] for a in anns) == sorted(expected)
        by_track = {o["track_id"]: o for o in fr.labels["objects"]}
        for a in anns:
            o = by_track[a["track_id"]]
            iscrowd, mask = expected[a["track_id"]]
            assert isinstance(a["segmentation"]["counts"], list)                 # uncompressed RLE
            assert a["iscrowd"] == iscrowd and a["category_id"] == categories.category_id(o["class"])
            assert a["synthetic"] == o["synthetic"] and a["occlusion"] == o["occlusion"]
            assert a["visible_fraction"] == o["visible_fraction"] and a["truncation"] == o["truncation"]
            assert np.array_equal(api.annToMask(a).astype(bool), mask)
            assert a["area"] == mask.sum() and a["bbox"] == coco.mask_bbox(mask)
            if o["synthetic"]:
                assert a["area"] == o["visible_pixels"]
                x0, y0, x1, y1 = o["bbox_visible"]
                assert a["bbox"] == [x0, y0, x1 - x0, y1 - y0]
        assert sum(a["iscrowd"] for a in anns) == 1


def test_torchvision_loads_masks_boxes_and_labels(exported):
    out, frames, _ = exported
    tv = _torchvision()
    from torchvision import datasets

    ds = datasets.CocoDetection(str(out / "images"), str(out / "annotations.json"))
    wrapped = datasets.wrap_dataset_for_transforms_v2(ds, target_keys=("boxes", "labels", "masks", "image_id"))
    assert len(wrapped) == len(frames) and tv.__version__.startswith("0.28.0")
    for i, fr in enumerate(frames):
        image, target = wrapped[i]
        assert target["image_id"] == i + 1 and tuple(image.size) == (F.W, F.H)
        anns = ds.coco.loadAnns(ds.coco.getAnnIds(imgIds=[i + 1]))
        expected = _expected_masks(fr)
        masks = target["masks"].numpy().astype(bool)
        assert masks.shape == (len(anns), F.H, F.W)
        for a, m, box, label in zip(anns, masks, target["boxes"].tolist(), target["labels"].tolist()):
            assert np.array_equal(m, expected[a["track_id"]][1])
            x, y, w, h = a["bbox"]
            assert box == pytest.approx([x, y, x + w, y + h]) and label == a["category_id"]


def test_ids_are_fixed_whatever_classes_show(tmp_path):
    """A frame with only the van: the van keeps its id, the table is whole; a class the table lacks is an error."""
    frames = F.export_frames(tmp_path)
    only_van = [fr for fr in frames[:1]]
    only_van[0].labels["objects"] = [o for o in only_van[0].labels["objects"] if o["class"] == "van"]
    data = coco.dataset(only_van, ["a.png"])
    assert [a["category_id"] for a in data["annotations"]] == [categories.category_id("van")] == [11]
    assert len(data["categories"]) == len(categories.CATEGORIES)
    only_van[0].labels["objects"][0]["class"] = "hovercraft"
    with pytest.raises(errors.InputError) as e:
        coco.dataset(only_van, ["a.png"])
    assert e.value.field == "objects[0].class" and "hovercraft" in e.value.message


def test_strict_json(exported):
    out, _, _ = exported
    json.loads((out / "annotations.json").read_text(), parse_constant=lambda c: pytest.fail(c))
