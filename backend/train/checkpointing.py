"""What a training step keeps for the backward pass, and in what pieces it encodes frames (docs/design.md §13).

Three settings of the training config trade recomputation for memory; none changes what is computed (the same
functions on the same numbers, so the loss and the weights agree with the unchunked, diffusers-checkpointed step
to float rounding: tests/backend/train/test_checkpointing.py):

- ``checkpointing_units`` (with ``gradient_checkpointing``), the UNet's checkpointed units. ``"blocks"`` (the
  default): every ``SpatioTemporalResBlock`` and every ``TransformerSpatioTemporalModel`` runs under
  ``torch.utils.checkpoint`` as a whole, so the forward pass keeps only each unit's input and the backward pass
  recomputes one unit at a time. ``"diffusers"``: diffusers' own flags (the checkpointing before issue 44), which
  checkpoint the resnets and the spatial transformer blocks but keep every activation of the temporal transformer
  blocks, the time mixers and the attention projections — at 1024×576 × 14 frames the larger part of the UNet's
  saved activations (bench/train_throughput.py --estimate has the breakdown).
- ``condition_chunk_frames``: the condition encoder (SVD's VAE encoder at full resolution, 128 channels per pixel in
  its first blocks, with gradients) runs over the B·F frames in chunks of this many frames; with checkpointing each
  chunk is one checkpointed unit, so the forward pass keeps only the chunk's inputs and the backward pass
  recomputes one chunk. 0: all frames at once (diffusers' per-down-block checkpointing then applies).
- ``encode_chunk_frames``: the frozen VAE encodes the target frames (no gradients) in chunks of this many frames,
  each chunk's activations freed before the next; 0: all at once.

The encoders are 2-D networks applied frame by frame (group norms are per image), so a chunk's result is the
frames' result in the whole batch. Under DDP the chunked condition encoder is one module (``FrameChunks``) that
DDP wraps, so DDP sees one forward per micro-step whatever the chunk count.
"""

from __future__ import annotations

import functools

import torch
from torch.utils.checkpoint import checkpoint

from ..model.condition import encode_conditions
from .config import CHECKPOINTING_UNITS as UNITS


def _block_types() -> tuple:
    """The UNet's units that ``"blocks"`` checkpoints whole (resnets and spatio-temporal transformers)."""
    from diffusers.models.resnet import SpatioTemporalResBlock
    from diffusers.models.transformers.transformer_temporal import TransformerSpatioTemporalModel

    return SpatioTemporalResBlock, TransformerSpatioTemporalModel


def _checkpointed(forward, *args, **kwargs):
    """``forward(*args, **kwargs)`` as one checkpointed unit while gradients are recorded (plain otherwise)."""
    if torch.is_grad_enabled():
        return checkpoint(forward, *args, use_reentrant=False, **kwargs)
    return forward(*args, **kwargs)


def checkpoint_unet(unet: torch.nn.Module, units: str | None) -> None:
    """Set the UNet's gradient checkpointing: None off, ``"diffusers"`` diffusers' flags, ``"blocks"`` every
    resnet and spatio-temporal transformer whole (module docstring). Parameter names and the state dict do not
    change (each unit's ``forward`` is wrapped on the instance, not the module replaced)."""
    if units is not None and units not in UNITS:
        raise ValueError(f"checkpointing units must be one of {UNITS} or None, got {units!r}")
    unet.disable_gradient_checkpointing()
    for m in unet.modules():
        m.__dict__.pop("forward", None)   # undo an earlier "blocks"
    if units == "diffusers":
        unet.enable_gradient_checkpointing()
    elif units == "blocks":
        types = _block_types()
        for m in unet.modules():
            if isinstance(m, types):
                m.forward = functools.partial(_checkpointed, type(m).forward.__get__(m))


def encode_in_chunks(encoder: torch.nn.Module, image: torch.Tensor, asset_mask: torch.Tensor, valid: torch.Tensor,
                     noise_aug: float, noise: torch.Tensor | None, frames: int, checkpointed: bool) -> torch.Tensor:
    """``condition.encode_conditions`` over N images (N, 3, H, W) / (N, 1, H, W) in chunks of ``frames`` (0: all),
    each chunk one checkpointed unit when ``checkpointed`` and gradients are recorded; ``noise`` (N, 3, H, W) the
    augmentation noise. Returns (N, C, h, w) float32."""
    n = image.shape[0]
    step = frames if frames > 0 else n
    out = []
    for s in range(0, n, step):
        part = (image[s:s + step], asset_mask[s:s + step], valid[s:s + step])
        nz = None if noise is None else noise[s:s + step]
        if checkpointed and torch.is_grad_enabled():
            out.append(checkpoint(_encode, encoder, *part, noise_aug, nz, use_reentrant=False))
        else:
            out.append(_encode(encoder, *part, noise_aug, nz))
    return out[0] if len(out) == 1 else torch.cat(out)


def _encode(encoder, image, asset_mask, valid, noise_aug, noise):
    return encode_conditions(encoder, image, asset_mask, valid, noise_aug, noise=noise)


class FrameChunks(torch.nn.Module):
    """The condition encoder run in chunks of ``frames`` frames (``encode_in_chunks``), as one module so that DDP
    wraps it and sees one forward per micro-step. ``encoder`` is the ``ConditionEncoder`` (its parameters are the
    trained ones; this wrapper has none of its own)."""

    def __init__(self, encoder: torch.nn.Module, frames: int, checkpointed: bool) -> None:
        super().__init__()
        self.encoder, self.frames, self.checkpointed = encoder, frames, checkpointed
        if checkpointed and frames == 0:
            encoder.enable_gradient_checkpointing()    # all frames at once: diffusers' per-down-block units
        else:   # each chunk is the unit; nested checkpoints would only recompute more
            encoder.disable_gradient_checkpointing()

    @property
    def downsample(self) -> int:
        return self.encoder.downsample

    def forward(self, image: torch.Tensor, asset_mask: torch.Tensor, valid: torch.Tensor, noise_aug: float = 0.0,
                noise: torch.Tensor | None = None) -> torch.Tensor:
        """image (N, 3, H, W), asset_mask and valid (N, 1, H, W) in [0, 1], noise like image: (N, C, h, w)."""
        return encode_in_chunks(self.encoder, image, asset_mask, valid, noise_aug, noise, self.frames,
                                self.checkpointed and self.frames > 0)


def condition_latents(encoder: torch.nn.Module, image: torch.Tensor, asset_mask: torch.Tensor, valid: torch.Tensor,
                      noise_aug: float, noise: torch.Tensor | None) -> torch.Tensor:
    """The training step's condition latents (N, C, h, w): through ``encoder`` when it is a ``FrameChunks`` (or a
    DDP wrapper of one), else ``encode_conditions`` over all frames at once (a bare encoder, DDP-wrapped or not)."""
    base = getattr(encoder, "module", encoder)
    if isinstance(base, FrameChunks):
        return encoder(image, asset_mask, valid, noise_aug, noise)
    return encode_conditions(encoder, image, asset_mask, valid, noise_aug, noise=noise)


def configure(unet: torch.nn.Module, encoder: torch.nn.Module, cfg) -> FrameChunks:
    """Apply the training config ``cfg``'s checkpointing (``gradient_checkpointing``, ``checkpointing_units``,
    ``condition_chunk_frames``) to the UNet, and return the condition encoder as the training step runs it (the
    module that DDP wraps and ``objective.loss`` calls)."""
    checkpoint_unet(unet, cfg.checkpointing_units if cfg.gradient_checkpointing else None)
    return FrameChunks(encoder, cfg.condition_chunk_frames, cfg.gradient_checkpointing and cfg.train_condition_encoder)
