"""The render-condition encoder (docs/design.md §5): SVD's VAE encoder over I ‖ M_a, and the validity mask in
latent space.

Inputs, per frame: I (3, H, W) in [0, 1] (the condition image), M_a (1, H, W) in [0, 1] (the asset mask) and the
validity V = 1 − hole (1, H, W). Both I and M_a enter the encoder mapped to [−1, 1], as SVD's VAE sees images.
The encoder is SVD's (same blocks, same weights) with its first convolution widened from 3 to 4 input channels;
the new channel's weights start at zero, so an untrained SCPainter checkpoint encodes I exactly as SVD's VAE does.
The latent is the mode (mean) of the encoder's diagonal Gaussian, not multiplied by the VAE scaling factor
(SVD's image-latent slot).

Validity in latent space: each latent cell covers an 8 x 8 pixel block; its validity is the fraction of valid
pixels in the block (area average), and the latent is multiplied by it. Fully covered cells pass unchanged, cells
in holes become 0 (what the unconditional branch sees everywhere), partly covered cells are attenuated in
proportion, so a sparse but valid point pattern keeps some weight instead of vanishing.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.autoencoders.vae import Encoder
from diffusers.models.modeling_utils import ModelMixin


class ConditionEncoder(ModelMixin, ConfigMixin):
    """SVD's VAE encoder widened to I ‖ M_a; ``forward`` returns the condition latent (N, latent_channels, H/8, W/8)."""

    _supports_gradient_checkpointing = True  # diffusers' Encoder checkpoints its blocks when asked

    @register_to_config
    def __init__(self, in_channels: int = 4, latent_channels: int = 4,
                 down_block_types: tuple = ("DownEncoderBlock2D",) * 4,
                 block_out_channels: tuple = (128, 256, 512, 512), layers_per_block: int = 2):
        super().__init__()
        self.encoder = Encoder(in_channels=in_channels, out_channels=latent_channels,
                               down_block_types=down_block_types, block_out_channels=block_out_channels,
                               layers_per_block=layers_per_block, double_z=True)
        self.quant_conv = torch.nn.Conv2d(2 * latent_channels, 2 * latent_channels, 1)

    @property
    def downsample(self) -> int:
        return 2 ** (len(self.config.block_out_channels) - 1)

    @classmethod
    def from_vae(cls, vae) -> ConditionEncoder:
        """Copy an ``AutoencoderKLTemporalDecoder``'s encoder, widening ``conv_in`` by a zero-initialised channel."""
        c = vae.config
        enc = cls(in_channels=c.in_channels + 1, latent_channels=c.latent_channels,
                  down_block_types=tuple(c.down_block_types), block_out_channels=tuple(c.block_out_channels),
                  layers_per_block=c.layers_per_block)
        state = {k[len("encoder."):]: v for k, v in vae.state_dict().items() if k.startswith("encoder.")}
        w = state["conv_in.weight"]
        state["conv_in.weight"] = torch.cat([w, torch.zeros_like(w[:, :1])], dim=1)
        enc.encoder.load_state_dict(state)
        enc.quant_conv.load_state_dict(vae.quant_conv.state_dict())
        return enc if vae.dtype == torch.float32 else enc.to(dtype=vae.dtype)

    def forward(self, image: torch.Tensor, asset_mask: torch.Tensor) -> torch.Tensor:
        """image (N, 3, H, W) and asset_mask (N, 1, H, W), both already in [−1, 1]."""
        moments = self.quant_conv(self.encoder(torch.cat([image, asset_mask], dim=1)))
        return moments[:, : self.config.latent_channels]  # the mode of the diagonal Gaussian


def latent_validity(valid: torch.Tensor, factor: int = 8) -> torch.Tensor:
    """(N, 1, H, W) validity in [0, 1] -> (N, 1, H/factor, W/factor): the valid fraction of each block."""
    if valid.shape[-1] % factor or valid.shape[-2] % factor:
        raise ValueError(f"validity of size {tuple(valid.shape[-2:])} is not a multiple of {factor}")
    return F.avg_pool2d(valid, factor)


def encode_conditions(encoder: ConditionEncoder, image, asset_mask, valid, noise_aug: float = 0.0, generator=None,
                      noise=None):
    """Condition latents (N, C, h, w) from I (N, 3, H, W), the asset mask M_a and the validity V (N, 1, H, W), all
    in [0, 1]. ``noise_aug`` adds SVD's Gaussian noise augmentation to the [−1, 1] image: ``noise`` (shaped like
    ``image``) when given, else drawn on the CPU from ``generator`` (device-independent results)."""
    base = getattr(encoder, "module", encoder)  # a DistributedDataParallel wrapper runs forward, the model knows
    x = image * 2.0 - 1.0
    if noise_aug > 0:
        if noise is None:
            noise = torch.randn(x.shape, generator=generator, dtype=torch.float32)
        x = x + noise_aug * noise.to(x.device, x.dtype)
    dt = next(encoder.parameters()).dtype
    latent = encoder(x.to(dt), (asset_mask * 2.0 - 1.0).to(dt)).float()
    return latent * latent_validity(valid.float(), base.downsample)
