"""The condition encoder starts as SVD's VAE encoder; the latent validity rule."""

import pytest
import torch
from diffusers import AutoencoderKLTemporalDecoder

from backend.model import condition


def test_untrained_condition_latent_equals_svd_vae_encoding(tiny_svd):
    vae = AutoencoderKLTemporalDecoder.from_pretrained(tiny_svd, subfolder="vae", local_files_only=True,
                                                       use_safetensors=True)
    enc = condition.ConditionEncoder.from_vae(vae)
    gen = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 64, 96, generator=gen)
    asset_mask = (torch.rand(2, 1, 64, 96, generator=gen) > 0.5).float()  # any mask: its channel weighs zero
    valid = torch.ones(2, 1, 64, 96)
    with torch.no_grad():
        ours = condition.encode_conditions(enc, image, asset_mask, valid)
        svd = vae.encode(image * 2 - 1).latent_dist.mode()
    assert ours.shape == (2, 4, 8, 12)
    assert torch.allclose(ours, svd, atol=1e-6)
    assert enc.encoder.conv_in.weight.shape[1] == 4 and not enc.encoder.conv_in.weight[:, 3].any()


def test_latent_validity_is_the_valid_fraction_of_each_block():
    valid = torch.zeros(1, 1, 16, 24)
    valid[..., :8, :8] = 1.0                 # one full block
    valid[..., 8:, 8:12] = 1.0               # half of another
    valid[..., 0, 16] = 1.0                  # one pixel of a third
    lv = condition.latent_validity(valid)
    assert lv.shape == (1, 1, 2, 3)
    assert torch.allclose(lv[0, 0], torch.tensor([[1.0, 0.0, 1 / 64], [0.0, 0.5, 0.0]]))
    with pytest.raises(ValueError, match="multiple of 8"):
        condition.latent_validity(torch.ones(1, 1, 10, 16))


def test_holes_zero_the_latent(tiny_svd):
    vae = AutoencoderKLTemporalDecoder.from_pretrained(tiny_svd, subfolder="vae", local_files_only=True,
                                                       use_safetensors=True)
    enc = condition.ConditionEncoder.from_vae(vae)
    image, asset_mask = torch.rand(1, 3, 32, 32), torch.zeros(1, 1, 32, 32)
    valid = torch.ones(1, 1, 32, 32)
    valid[..., :, 16:] = 0
    with torch.no_grad():
        lat = condition.encode_conditions(enc, image, asset_mask, valid)
    assert not lat[..., 2:].any() and lat[..., :2].abs().sum() > 0
