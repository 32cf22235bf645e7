"""COCO export read back with pycocotools (a test-only tool): masks, RLE strings, boxes, categories."""

import json
import os

import numpy as np
import pytest
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from tests.backend.export import export_fixtures as F
from backend.export import coco


@pytest.mark.parametrize("seed", range(40))
def test_rle_matches_pycocotools(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 300, 2)
    mask = rng.random((h, w)) < rng.random()
    if seed == 0:
        mask[:] = False
    elif seed == 1:
        mask[:] = True
    elif seed == 2:  # long runs of every size: several characters per count, negative differences
        mask[:] = False
        mask[: h // 2, : w // 3] = True
        mask[-1, -1] = True
    ours = coco.rle_encode(mask)
    theirs = mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))
    assert ours["counts"] == theirs["counts"].decode() and ours["size"] == list(theirs["size"])
    assert np.array_equal(mask_utils.decode({"size": ours["size"], "counts": ours["counts"].encode()}), mask)
    if mask.any():
        assert coco.mask_bbox(mask) == list(mask_utils.toBbox(theirs))


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    return F.write_dataset(tmp_path_factory, coco, "coco")


def test_pycocotools_reads_it_back(exported):
    out, frames, counts = exported
    assert sorted(os.listdir(out)) == ["annotations.json", "images"]
    api = COCO(str(out / "annotations.json"))
    assert [c["name"] for c in api.loadCats(api.getCatIds())] == ["car", "van"] and api.getCatIds() == [1, 2]
    assert counts == {"frames": 2, "objects": len(api.getAnnIds())} and counts["objects"] == 6
    for i, fr in enumerate(frames):
        img = api.loadImgs(i + 1)[0]
        assert (img["file_name"], img["width"], img["height"]) == (f"00000{i}.png", F.W, F.H)
        assert (img["frame"], img["timestamp_s"]) == (fr.labels["frame"], fr.labels["timestamp_s"])
        assert (out / "images" / img["file_name"]).read_bytes() == open(fr.image, "rb").read()
        anns = api.loadAnns(api.getAnnIds(imgIds=[i + 1]))
        by_track = {a["track_id"]: a for a in anns}
        for o in fr.labels["objects"]:
            a = by_track[o["track_id"]]
            assert a["iscrowd"] == 0 and a["synthetic"] == o["synthetic"] and a["occlusion"] == o["occlusion"]
            assert a["visible_fraction"] == o["visible_fraction"] and a["truncation"] == o["truncation"]
            m = api.annToMask(a).astype(bool)
            if o["synthetic"]:
                mine = np.rint(fr.instance) == o["track_id"]
                assert np.array_equal(m, mine) and a["area"] == mine.sum() == o["visible_pixels"]
                assert a["segmentation"]["counts"] == \
                    mask_utils.encode(np.asfortranarray(mine.astype(np.uint8)))["counts"].decode()
                assert a["bbox"] == list(mask_utils.toBbox(a["segmentation"]))
                x0, y0, x1, y1 = o["bbox_visible"]
                assert a["bbox"] == [x0, y0, x1 - x0, y1 - y0]
            else:   # approximate: the visible box as a polygon
                x0, y0, x1, y1 = o["bbox_visible"]
                assert a["bbox"] == [x0, y0, x1 - x0, y1 - y0] and a["area"] == (x1 - x0) * (y1 - y0)
                assert a["category_id"] == 2 and abs(int(m.sum()) - a["area"]) <= (x1 - x0) + (y1 - y0)


def test_strict_json(exported):
    out, _, _ = exported
    json.loads((out / "annotations.json").read_text(), parse_constant=lambda c: pytest.fail(c))
