"""Reuse of the UNet's deep features across sampler steps (DeepCache, Ma et al. 2024) for SVD's
``UNetSpatioTemporalConditionModel``: the generate setting ``feature_reuse`` (docs/design.md §11).

SVD's UNet is a U: ``conv_in``, down blocks (each: resnets (+ attention), a downsampler but the last), the mid
block, up blocks (each consuming as many skip features as it has resnets, from the deepest end), ``conv_out``.
Adjacent sampler steps change the deep features little, so a **full** evaluation keeps ``h_deep``, the input of the
last ``depth`` up blocks (the output of everything deeper), and a **shallow** evaluation runs only ``conv_in``, the
first ``depth`` down blocks (their skip features) and the last ``depth`` up blocks on the kept ``h_deep``. Its cost
is the shallow blocks' share of the network (``bench/generate.py`` counts it in FLOPs at the full architecture: SVD's
first level holds the attention over the most tokens, so a shallow step is not nearly free).

``unet_forward`` is diffusers' forward written out (same modules, same order, same arithmetic:
tests/backend/model/test_feature_reuse.py checks that the full path equals ``unet(...)`` exactly) plus that split.
``FeatureReuse`` wraps a UNet with the UNet's own call signature, so ``edm.Denoiser`` (the one caller of the UNet)
calls it unchanged; the sampler sets ``key`` (which window and batch the features belong to) and ``full`` before
each evaluation. The shallow path's first down block still runs its downsampler (its output feeds only the deep
path): one strided convolution, kept so that the block is called as a whole.
"""

from __future__ import annotations

import torch

from . import gpu_speed


#: The FLOPs of a shallow evaluation (depth 1) as a share of a whole one at SVD's architecture, 14 frames of
#: 576 x 1024 (bench/generate.py ``shallow_flops("full")`` counts it on fake tensors: 0.417). The speed table's
#: ``cost`` counts a shallow evaluation at this share; the tiny test model's share is smaller (no attention at its
#: first level), so the table uses the full architecture's.
SHALLOW_FLOPS = 0.417


def unet_forward(unet, sample: torch.Tensor, timestep: torch.Tensor, encoder_hidden_states: torch.Tensor,
                 added_time_ids: torch.Tensor, depth: int = 1,
                 h_deep: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """(out (B, F, C_out, h, w), h_deep) of SVD's UNet on sample (B, F, C_in, h, w), timestep (a number, () or (B,)),
    encoder_hidden_states (B, 1, D) and added_time_ids (B, 3), all in the UNet's dtype.

    ``h_deep`` None: the full network; the returned ``h_deep`` is the input of its last ``depth`` up blocks
    ((B·F, C, h', w')). ``h_deep`` given: the shallow path (module docstring), which returns it unchanged."""
    B, F = sample.shape[:2]
    t = torch.as_tensor(timestep, device=sample.device)
    t = (t[None] if t.dim() == 0 else t).expand(B)
    emb = unet.time_embedding(unet.time_proj(t).to(dtype=sample.dtype))
    time_embeds = unet.add_time_proj(added_time_ids.flatten()).reshape((B, -1)).to(emb.dtype)
    emb = emb + unet.add_embedding(time_embeds)
    emb = emb.repeat_interleave(F, dim=0, output_size=B * F)                     # one row per frame
    ehs = encoder_hidden_states.repeat_interleave(F, dim=0, output_size=B * F)
    h = unet.conv_in(sample.flatten(0, 1))
    indicator = torch.zeros(B, F, dtype=h.dtype, device=h.device)

    def run(block, h, **kw):
        if getattr(block, "has_cross_attention", False):
            kw["encoder_hidden_states"] = ehs
        return block(hidden_states=h, temb=emb, image_only_indicator=indicator, **kw)

    ups = list(unet.up_blocks)
    shallow = h_deep is not None
    skips = [h]
    for block in (unet.down_blocks[:depth] if shallow else unet.down_blocks):
        h, res = run(block, h)
        skips += list(res)
    if shallow:
        skips = skips[:sum(len(b.resnets) for b in ups[len(ups) - depth:])]   # what the last up blocks consume
        h = h_deep
    else:
        h = run(unet.mid_block, h)
    up_factor = 2 ** unet.num_upsamplers
    forward_size = any(s % up_factor for s in sample.shape[-2:])
    for i, block in enumerate(ups):
        if shallow and i < len(ups) - depth:
            continue
        if i == len(ups) - depth and not shallow:
            h_deep = h
        res, skips = skips[-len(block.resnets):], skips[:-len(block.resnets)]
        size = skips[-1].shape[2:] if forward_size and i < len(ups) - 1 else None
        h = run(block, h, res_hidden_states_tuple=tuple(res), upsample_size=size)
    h = unet.conv_out(unet.conv_act(unet.conv_norm_out(h)))
    return h.reshape(B, F, *h.shape[1:]), h_deep


class FeatureReuse:
    """A UNet with the UNet's call signature whose evaluations reuse deep features (module docstring).

    Before each evaluation the sampler sets ``key`` (hashable: which window and batch) and ``full`` (run the whole
    network and keep its ``h_deep`` under ``key``); a shallow evaluation whose key has no kept feature runs in full.
    ``last_shallow``: whether the last call was shallow. ``config`` is the UNet's. ``compile``: the generate
    setting (``gpu_speed.compile_fn``), applied to ``unet_forward``."""

    def __init__(self, unet, depth: int = 1, compile: str = "off"):
        unet = getattr(unet, "_orig_mod", unet)   # a torch.compile'd UNet: its modules, compiled below instead
        if not 1 <= depth < len(unet.up_blocks):
            raise ValueError(f"depth must be in [1, {len(unet.up_blocks) - 1}], got {depth}")
        self.unet, self.depth = unet, depth
        self.forward = gpu_speed.compile_fn(unet_forward, compile)   # one graph each for the full and shallow path
        self.config = unet.config
        self.key, self.full = None, True
        self.kept: dict = {}
        self.last_shallow = False

    def __call__(self, sample, timestep, encoder_hidden_states, added_time_ids, return_dict=False):
        full = self.full or self.key not in self.kept
        out, h_deep = self.forward(self.unet, sample, timestep, encoder_hidden_states, added_time_ids, self.depth,
                                   None if full else self.kept[self.key])
        if full:   # a copy: a CUDA-graph replay (compile reduce-overhead) overwrites its outputs in place
            self.kept[self.key] = h_deep if self.forward is unet_forward else h_deep.clone()
        self.last_shallow = not full
        return (out,)
