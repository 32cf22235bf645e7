"""Deep-feature reuse (DeepCache) for SVD's UNet: the forward written out equals diffusers' exactly, and a shallow
evaluation on unchanged inputs gives the whole network's output."""

import pytest
import torch
from diffusers import UNetSpatioTemporalConditionModel

from backend.model import configs
from backend.model.feature_reuse import FeatureReuse, unet_forward


@pytest.fixture(scope="module")
def unet():
    torch.manual_seed(0)
    net = UNetSpatioTemporalConditionModel(**configs.TINY["unet"]).eval()
    with torch.no_grad():
        for p in net.parameters():          # no zero-initialised layer left: every block shows in the output
            p.add_(0.02 * torch.randn_like(p))
    return net


def inputs(batch=2, frames=5, h=16, w=24, seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(batch, frames, 8, h, w, generator=g), torch.rand(batch, generator=g),
            torch.randn(batch, 1, 32, generator=g), torch.randn(batch, 3, generator=g))


@pytest.mark.parametrize("size", [(16, 24), (12, 20)])   # (12, 20): not a multiple of 4, the upsample size forwarded
def test_the_full_path_is_diffusers_forward_exactly(unet, size):
    x, t, ehs, ids = inputs(h=size[0], w=size[1])
    with torch.no_grad():
        ref = unet(x, t, encoder_hidden_states=ehs, added_time_ids=ids, return_dict=False)[0]
        out, h_deep = unet_forward(unet, x, t, ehs, ids)
        assert torch.equal(out, ref)
        # the kept feature is the last up block's input: a shallow pass on the same inputs is the same network
        shallow, _ = unet_forward(unet, x, t, ehs, ids, h_deep=h_deep)
        assert torch.equal(shallow, ref)
        # on other inputs it is an approximation (the deep path's output is stale), never the full value
        x2 = x * 1.01
        ref2 = unet(x2, t, encoder_hidden_states=ehs, added_time_ids=ids, return_dict=False)[0]
        approx, _ = unet_forward(unet, x2, t, ehs, ids, h_deep=h_deep)
        assert not torch.equal(approx, ref2) and float((approx - ref2).abs().mean()) < 0.1 * float(ref2.abs().mean())


def test_feature_reuse_keeps_one_feature_per_key_and_runs_whole_without_one(unet):
    reuse = FeatureReuse(unet)
    x, t, ehs, ids = inputs()
    with torch.no_grad():
        reuse.key, reuse.full = "a", False                  # nothing kept under "a": runs whole
        first = reuse(x, t, ehs, ids)[0]
        assert not reuse.last_shallow and set(reuse.kept) == {"a"}
        again = reuse(x, t, ehs, ids)[0]                    # shallow on the kept feature
        assert reuse.last_shallow and torch.equal(again, first)
        reuse.key = "b"
        reuse(x[:1], t[:1], ehs[:1], ids[:1])
        assert not reuse.last_shallow and set(reuse.kept) == {"a", "b"}
    with pytest.raises(ValueError):
        FeatureReuse(unet, depth=len(unet.up_blocks))
