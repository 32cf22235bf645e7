"""``raster_choice.choose``: the compositor and tile size per device and size, the forcing options, and
``tiles.rasterize`` following it (the pairs forced give the reference's layers exactly)."""

import numpy as np
import pytest
import torch

from backend.render import gaussians as GS
from backend.render import raster_choice as RC
from backend.render import tiles as TL
from tests.backend.render.test_gaussians import EYE, K, random_scene


def test_defaults_follow_the_measured_thresholds():
    assert RC.TILE_CUDA == 8 and RC.TILE_CPU == 8  # H200 JSON: 8 beat 16 and 32; this machine: 8 beat 4 and 16
    for n in (1, 2_000, 200_000, 3_000_000):
        assert RC.choose("cpu", n, 1024, 576)[:2] == ("tiles", RC.TILE_CPU)
        assert RC.choose("cuda", n, 1024, 576)[:2] == ("tiles", RC.TILE_CUDA)
    assert RC.choose("mps", 10, 64, 48)[:2] == ("pairs", None)  # no tile kernel there


def test_thresholds_pick_the_pairs_below_them(monkeypatch):
    monkeypatch.setattr(RC, "CUDA_PAIRS_MAX_GAUSSIANS_PER_MPIX", 10_000.0)
    # 10 k per megapixel at 1024 x 576 (0.59 Mpx): the pairs up to 5 898 Gaussians, the tiles above
    assert RC.choose("cuda", 5_898, 1024, 576)[:2] == ("pairs", None)
    assert RC.choose("cuda", 5_899, 1024, 576)[:2] == ("tiles", RC.TILE_CUDA)
    assert RC.choose("cuda", 5_899, 2048, 1152)[:2] == ("pairs", None)  # four times the pixels
    assert RC.choose("cpu", 10, 1024, 576)[:2] == ("tiles", RC.TILE_CPU)  # the CPU's own threshold (none)


def test_forcing():
    assert RC.choose("cuda", 200_000, 1024, 576, method="pairs")[:2] == ("pairs", None)
    assert RC.choose("cuda", 10, 64, 48, method="tiles")[:2] == ("tiles", RC.TILE_CUDA)
    assert RC.choose("cuda", 10, 64, 48, tile=16)[:2] == ("tiles", 16)
    assert RC.choose("cpu", 10, 64, 48, tile=12)[:2] == ("tiles", 12)  # numba takes any tile
    with pytest.raises(ValueError, match="power of two"):
        RC.choose("cuda", 10, 64, 48, tile=12)
    with pytest.raises(ValueError, match="unknown Gaussian compositor 'fast'"):
        RC.choose("cpu", 10, 64, 48, method="fast")


def test_rasterize_follows_the_choice():
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    proj = GS.project(*(t(a) for a in random_scene(120, 3)), K, EYE, 64, 48)
    bg = torch.full((48, 64), 6.0, dtype=torch.float64)
    ref = GS.rasterize(proj, 64, 48, bg)
    pairs = TL.rasterize(proj, 64, 48, bg, method="pairs")
    assert all(torch.equal(a, b) for a, b in zip(pairs, ref))  # the reference itself, not a copy of its rules
    for kw in ({}, {"method": "tiles"}, {"tile": 4}, {"tile": 16}):
        got = TL.rasterize(proj, 64, 48, bg, **kw)
        assert float((got[0] - ref[0]).abs().max()) <= 1e-6 and torch.equal(got[3], ref[3]), kw
