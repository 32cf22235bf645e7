"""Training pairs: sources from t ± window but never t, the renderer's geometry, assets at their boxes, determinism."""

import numpy as np
import pytest
import torch

from backend.train import clip as clip_mod
from backend.train import pairs


@pytest.fixture(scope="module")
def maker(street_clip_path):
    c = clip_mod.load(street_clip_path)
    return pairs.PairMaker(c, pairs.PairSettings(width=259, height=147, frames=3, confidence_percentile=0.0))


def test_sources_are_neighbours_within_the_window_never_the_target(maker):
    rng = np.random.default_rng(0)
    counts = np.zeros(16)
    for _ in range(300):
        t = int(rng.integers(16))
        src = maker.sources(t, rng)
        assert src and t not in src and all(abs(s - t) <= 8 and 0 <= s < 16 for s in src)
        counts[src] += 1
    assert counts.min() > 0  # every frame serves as a source for some target


def _psnr(a, b, mask):
    return float(10 * torch.log10(1 / ((a - b) ** 2).mean(0)[mask].mean()))


def test_novel_view_pair_reprojects_neighbours_onto_the_target(maker):
    s = maker.sample(np.random.default_rng(1), t0=5, asset=False)
    assert s["car"] == -1 and all(5 + i not in src for i, src in enumerate(s["sources"]))
    valid = s["valid"][:, 0] > 0.5
    assert 0.5 < float(valid.float().mean()) < 1.0       # neighbours cover most, not all, of the target
    for i in range(3):                                   # covered pixels show the target (wrong geometry: < 15 dB)
        assert _psnr(s["image"][i], s["target"][i], valid[i]) > 20.0
    assert float(s["asset_mask"].max()) == 0.0


def test_asset_pair_removes_the_car_and_puts_its_asset_on_its_pixels(maker, street):
    k = 0  # the nearest parked car, 7.5 m down the road: hundreds of pixels in the first frames
    s = maker.sample(np.random.default_rng(3), t0=0, asset=True, car=k)
    assert s["car"] == k
    inst = street.metric()["instance"]
    car_id = street.info["cars"][k]["instance"]
    checked = 0
    for i, t in enumerate(range(0, 3)):
        truth = torch.from_numpy((inst[t] == car_id).astype(np.float32))[None, None]
        truth = torch.nn.functional.interpolate(truth, size=(147, 259), mode="area")[0, 0] > 0.5
        mask = s["asset_mask"][i, 0] > 0.5
        if truth.sum() < 200:
            continue
        iou = float((mask & truth).sum() / (mask | truth).sum())
        assert iou > 0.6, (t, iou)
        checked += 1
    assert checked >= 2


def test_car_points_inside_the_grown_box_are_removed(maker):
    car = maker.clip.cars[0]
    with_car = maker._points([0, 1, 2], None)[0]
    without = maker._points([0, 1, 2], car)[0]
    T, size = clip_mod.grown_box(car.boxes[0], car.size, 0.2, 0.1)
    from scpainter_blender.core.geometry.fits import points_in_box

    inside = points_in_box(with_car.numpy().astype(np.float64) + maker.origin, T, size)
    assert inside.sum() > 100 and len(without) == len(with_car) - inside.sum()


def test_dataset_items_depend_only_on_seed_and_index(street_clip_path):
    st = pairs.PairSettings(width=128, height=64, frames=2)
    a = pairs.PairDataset([street_clip_path], st, seed=5)
    b = pairs.PairDataset([street_clip_path], st, seed=5)
    x, y = a[7], b[7]
    a[3]
    z = a[7]
    for k in ("target", "image", "asset_mask", "valid"):
        assert torch.equal(x[k], y[k]) and torch.equal(x[k], z[k])
    assert (x["t0"], x["car"]) == (z["t0"], z["car"])
    assert not torch.equal(a[8]["image"], x["image"])


def test_clip_shorter_than_a_sample_is_refused(street_clip_path):
    with pytest.raises(clip_mod.ClipError, match="fewer than"):
        pairs.PairMaker(clip_mod.load(street_clip_path), pairs.PairSettings(frames=40))
