"""Tiny SVD components and the VAE fit of the documented street run."""

import torch


def test_fit_vae_learns_to_reconstruct_the_frames(street, tmp_path):
    """The documented street run's stand-in for SVD's pretrained VAE: a few steps already cut the error."""
    from diffusers import AutoencoderKLTemporalDecoder

    from backend.model import configs
    from backend.train.vae_fit import fit_vae

    svd = configs.save_stock_svd(str(tmp_path / "svd"), "tiny", seed=0)
    frames = [street.frame_path("recorded", i) for i in range(6)]
    r = fit_vae(svd, frames, 64, 64, steps=30)
    assert r["last"] < 0.7 * r["first"], r
    vae = AutoencoderKLTemporalDecoder.from_pretrained(svd, subfolder="vae", local_files_only=True)
    fresh = configs.build_components("tiny", seed=0)["vae"]  # the random weights it started from
    w = "encoder.conv_in.weight"
    assert not torch.equal(vae.state_dict()[w], fresh.state_dict()[w])  # the fitted weights were saved in place
