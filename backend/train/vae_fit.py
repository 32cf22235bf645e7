"""The VAE fit of the documented street run (tools/train_street.py): a random tiny VAE cannot make an image, so it
is first fitted as an autoencoder to the clip's frames, standing in for SVD's pretrained VAE. Training-side (it
reads frames as training does, through ``clip`` and ``pairs``), so the model package imports nothing from here.
"""

from __future__ import annotations

import os

import torch

from .clip import Clip
from .pairs import load_clip_frames, load_resized


def fit_vae(svd: str, frames, width: int, height: int, steps: int = 400, seed: int = 0, log=None) -> dict:
    """Fit the VAE of an SVD folder made by ``model.configs.save_stock_svd`` (encoder and temporal decoder) to
    reconstruct clips of 4 consecutive ``frames`` at width x height: MSE + 1e-6 KL, AdamW 1e-3. ``frames``: a
    training clip (``clip.Clip``: its frames as training sees them, undistorted, a video decoded) or a list of
    image files (resized with Lanczos). Saves it in place; returns the mean loss of the first and last 10 steps."""
    from diffusers import AutoencoderKLTemporalDecoder

    torch.manual_seed(seed)
    vae = AutoencoderKLTemporalDecoder.from_pretrained(svd, subfolder="vae", local_files_only=True)
    if isinstance(frames, Clip):
        video = load_clip_frames(frames, width, height).contiguous()
    else:
        video = torch.stack([load_resized(f, width, height) for f in frames])
    video = video.float() / 255.0 * 2 - 1
    opt = torch.optim.AdamW(vae.parameters(), lr=1e-3)
    g = torch.Generator().manual_seed(seed)
    losses = []
    vae.train()
    for step in range(steps):
        t0 = int(torch.randint(0, len(video) - 3, (1,), generator=g))
        x = video[t0:t0 + 4]
        dist = vae.encode(x).latent_dist
        z = dist.mean + dist.std * torch.randn(dist.mean.shape, generator=g)
        rec = vae.decode(z, num_frames=4).sample
        kl = 0.5 * (dist.mean ** 2 + dist.var - 1 - dist.logvar).mean()
        loss = torch.nn.functional.mse_loss(rec, x) + 1e-6 * kl
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if log is not None and step % 50 == 0:
            log(f"fit VAE: step {step}: loss {losses[-1]:.4f}")
    vae.eval().save_pretrained(os.path.join(svd, "vae"), safe_serialization=True)
    return {"first": sum(losses[:10]) / 10, "last": sum(losses[-10:]) / 10}
