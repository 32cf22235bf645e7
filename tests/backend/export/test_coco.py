"""COCO export read back with the loaders teams train with (test-only tools): pycocotools' ``COCO`` and
torchvision's ``CocoDetection`` + ``wrap_dataset_for_transforms_v2`` (in a process of its own:
``torchvision_loader.py`` says why): masks equal to the instance pass, boxes, the fixed category table, ignore
regions as ``iscrowd`` 1."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from tests.backend.export import export_fixtures as F
from backend.export import coco
from scpainter_blender.core import categories, errors, labels

#: Where the isolated test-only packages are (``requirements-isolated.txt``; tools/setup*.sh install them into the
#: environment's ``isolated`` folder); ``SCPAINTER_ISOLATED_PACKAGES`` names another.
ISOLATED = os.environ.get("SCPAINTER_ISOLATED_PACKAGES") or os.path.join(sys.prefix, "isolated")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


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
    """torchvision's CocoDetection + wrap_dataset_for_transforms_v2 (in its own process: ``torchvision_loader``)
    loads every image, with each annotation's mask equal to the instance pass (or the rectangle), its box and its
    category id."""
    out, frames, _ = exported
    assert os.path.isdir(os.path.join(ISOLATED, "torchvision")), \
        f"torchvision is not in {ISOLATED}: run tools/setup.sh (requirements-isolated.txt)"
    result = str(out.parent / "torchvision.npz")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([ISOLATED, ROOT])}
    run = subprocess.run([sys.executable, "-m", "tests.backend.export.torchvision_loader",
                          str(out / "annotations.json"), str(out / "images"), result],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    got = np.load(result)
    assert str(got["version"]).startswith("0.28.0") and int(got["count"]) == len(frames)
    api = COCO(str(out / "annotations.json"))
    for i, fr in enumerate(frames):
        assert int(got[f"image_id_{i}"]) == i + 1 and tuple(got[f"size_{i}"]) == (F.W, F.H)
        anns = api.loadAnns(api.getAnnIds(imgIds=[i + 1]))
        expected = _expected_masks(fr)
        masks = got[f"masks_{i}"]
        assert masks.shape == (len(anns), F.H, F.W)
        for a, m, box, label in zip(anns, masks, got[f"boxes_{i}"].tolist(), got[f"labels_{i}"].tolist()):
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
