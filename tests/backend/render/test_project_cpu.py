"""The CPU fast path of the Gaussian pass against its torch references, piece by piece.

The numba projection (``project_cpu``) against ``gaussians.project_factors_torch``: the same rows and radii, the
same values to float64 rounding. The counting sort (``tiles_cpu``) against ``tiles.bin_tiles``: identical tile
lists. The compositing kernel fed by either list: identical layers. (The whole path against the dense float64
render: test_gaussians.py.)
"""

import numpy as np
import pytest
import torch

from backend.render import gaussians as GS
from backend.render import tiles as TL
from backend.render import tiles_cpu
from tests.backend.render.test_gaussians import EYE, K, extreme_scene, random_scene

K_OFF = np.array([[60.0, 0.4, 12.0], [0, 55.0, 40.0], [0, 0, 1]])  # off-centre, with skew

SCENES = {
    "random-deg1": lambda: random_scene(300, 20, 1),
    "random-deg3": lambda: random_scene(200, 21, 3),
    "extreme": extreme_scene,
    "empty": lambda: tuple(a[:0] for a in random_scene(5, 22, 0)),
}


def tensors(scene, dtype=torch.float64):
    return [torch.as_tensor(np.asarray(a), dtype=dtype) for a in scene]


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("Kx", [K, K_OFF], ids=["centred", "off-centre"])
def test_numba_projection_matches_torch(name, Kx):
    scene = tensors(SCENES[name]())
    ref = GS.project(*scene, Kx, EYE, 64, 48, fast=False)
    got = GS.project(*scene, Kx, EYE, 64, 48, fast=True)
    assert set(got) == set(ref)
    assert torch.equal(got["index"], ref["index"]) and torch.equal(got["radius"], ref["radius"])
    for key in ("mean2d", "conic", "depth", "opacity", "color"):
        assert got[key].dtype == torch.float64 and got[key].shape == ref[key].shape, key
        assert torch.allclose(got[key], ref[key], rtol=1e-12, atol=1e-12), key
    if name == "random-deg1":
        assert len(ref["index"]) > 200


def test_numba_projection_keeps_float32_and_finite_rows():
    scene = tensors(extreme_scene(), torch.float32)
    got = GS.project(*scene, K, EYE, 64, 48)
    ref = GS.project(*tensors(extreme_scene()), K, EYE, 64, 48, fast=False)
    assert all(v.dtype == torch.float32 for k, v in got.items() if k != "index")
    assert all(bool(torch.isfinite(v).all()) for v in got.values())
    # row 8 has o = 1/255 rounded to float32, a hair above 1/255 in float64: an extent of 1 px (kept, every α
    # below 1/255 but at its mean) where the float64 scene has an extent of 0 (culled). Both are exact.
    kept = set(got["index"].tolist())
    assert kept - {8} == set(ref["index"].tolist()) - {8}
    assert {2, 3, 4, 5, 9, 10}.isdisjoint(kept) and {0, 1, 6} <= kept  # see extreme_scene


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
def test_counting_sort_gives_the_torch_tile_lists(name, dtype):
    proj = GS.project(*tensors(SCENES[name](), dtype), K, EYE, 64, 48, fast=False)
    order, _, _, boxes, _, _, _ = tiles_cpu.prepare(proj, 64, 48, 8)
    assert np.array_equal(boxes, GS.pixel_boxes(proj, 64, 48).numpy()[order])
    for tile in (1, 4, 8, 16, 64):
        ref = TL.bin_tiles(proj, 64, 48, tile)
        got = tiles_cpu.bin_tiles(proj, 64, 48, tile)
        for key in ("entries", "entry_tile", "tile_start"):
            assert torch.equal(got[key], ref[key]), (key, tile)
        assert (got["tiles_x"], got["tiles_y"]) == (ref["tiles_x"], ref["tiles_y"])


def test_depth_ties_go_to_the_lower_index():
    """Equal depths: the lists follow the original index, as gaussians.depth_rank does (rows given out of index
    order too)."""
    means, quats, scales, opac, sh = random_scene(50, 23, 0)
    means[:, 2] = np.repeat([4.0, 6.0], 25)  # two depth planes: every Gaussian ties with 24 others
    proj = GS.project(*tensors((means, quats, scales, opac, sh)), K, EYE, 64, 48)
    ref = TL.bin_tiles(proj, 64, 48, 8)
    assert torch.equal(tiles_cpu.bin_tiles(proj, 64, 48, 8)["entries"], ref["entries"])
    shuffled = torch.randperm(len(proj["index"]), generator=torch.Generator().manual_seed(0))
    proj_s = {k: v[shuffled] for k, v in proj.items()}
    ref_s = TL.bin_tiles(proj_s, 64, 48, 8)
    assert torch.equal(tiles_cpu.bin_tiles(proj_s, 64, 48, 8)["entries"], ref_s["entries"])


def test_kernel_gives_identical_layers_from_either_list():
    """The compositing kernel fed the torch lists (converted to depth ranks) and the counting-sort lists: the same
    bits, with and without points in front."""
    proj = GS.project(*tensors(random_scene(300, 24, 1)), K, EYE, 64, 48)
    bg = np.full(48 * 64, np.inf)
    bg.reshape(48, 64)[:, :32] = 5.0
    order, params, colors, boxes, tile_start, entries, tiles_x = tiles_cpu.prepare(proj, 64, 48, 8)
    ref = TL.bin_tiles(proj, 64, 48, 8)
    rank = np.empty(len(order), np.int32)
    rank[order] = np.arange(len(order))
    torch_entries = rank[ref["entries"].numpy()]
    assert np.array_equal(torch_entries, entries)
    for background in (np.full(48 * 64, np.inf), bg):
        outs = []
        for ent, start in ((entries, tile_start), (torch_entries, ref["tile_start"].numpy())):
            out = (np.zeros((48 * 64, 3), np.float32), np.zeros(48 * 64, np.float32), np.zeros(48 * 64, np.float32),
                   np.zeros(48 * 64, np.int32))
            tiles_cpu._composite(params, colors, boxes, np.ascontiguousarray(ent), np.ascontiguousarray(start),
                                 background, 64, 48, tiles_x, 8, 1, *out, False, np.zeros((0, 1), np.int64))
            outs.append(out)
        assert all(np.array_equal(a, b) for a, b in zip(*outs))
        assert outs[0][1].max() > 0.5
    # and the production entry point returns those layers
    col, mask, *_ = TL.rasterize(proj, 64, 48, torch.from_numpy(bg.reshape(48, 64)))
    assert np.array_equal(mask.numpy().reshape(-1).astype(np.float32), outs[1][1])


def test_fast_path_equals_the_pair_reference_in_float64():
    """End to end against the torch pair rasterizer on the torch projection (float64): the fast path differs only
    by its float32 outputs."""
    for seed in (25, 26):
        scene = tensors(random_scene(300, seed, 2))
        bg = torch.full((48, 64), float("inf"), dtype=torch.float64)
        bg[10:30, 20:50] = 6.0
        ref = GS.rasterize(GS.project(*scene, K_OFF, EYE, 64, 48, fast=False), 64, 48, bg)
        got = TL.rasterize(GS.project(*scene, K_OFF, EYE, 64, 48), 64, 48, bg)
        for r, g in zip(ref[:2], got[:2]):
            assert float((r - g).abs().max()) <= 1e-6
        finite = torch.isfinite(ref[2])
        assert torch.equal(finite, torch.isfinite(got[2]))
        assert torch.allclose(ref[2][finite], got[2][finite], rtol=1e-6)


def test_radix_depth_order_is_numpy_s_stable_argsort():
    rng = np.random.default_rng(27)
    for depth in (rng.uniform(0.05, 300.0, 5000), np.round(rng.uniform(3, 6, 5000), 1), np.full(7, 4.0),
                  np.array([1e-300, 5e-324, 1e300, 2.0]), np.array([])):
        assert np.array_equal(tiles_cpu._radix_order(depth.view(np.int64)), np.argsort(depth, kind="stable"))
