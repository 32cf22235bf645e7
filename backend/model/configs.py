"""Stable Video Diffusion component configurations, and stock-layout folders with random weights built from them.

``full``: the architecture of stabilityai/stable-video-diffusion-img2vid(-xt) (UNet 1.52 B parameters, the real
VAE with four down blocks so latents are 1/8 of the image, CLIP ViT-H/14 with a 1024 projection), for benchmarks
that need the true cost. ``tiny``: the same classes, a few channels wide, still a true 1/8 VAE (four
``DownEncoderBlock2D``) and a 224 px CLIP input (patch 32), for tests on the CPU. Nothing is downloaded: weights
are random, folders are written with ``save_pretrained`` (safetensors) exactly as a stock snapshot is laid out.
"""

from __future__ import annotations

import torch

from .checkpoint import CLIP_MEAN, CLIP_STD

SCHEDULER = {"beta_end": 0.012, "beta_schedule": "scaled_linear", "beta_start": 0.00085, "clip_sample": False,
             "interpolation_type": "linear", "num_train_timesteps": 1000, "prediction_type": "v_prediction",
             "set_alpha_to_one": False, "sigma_max": 700.0, "sigma_min": 0.002, "skip_prk_steps": True,
             "steps_offset": 1, "timestep_spacing": "leading", "timestep_type": "continuous",
             "trained_betas": None, "use_karras_sigmas": True}

FULL = {
    "unet": {"sample_size": 96, "in_channels": 8, "out_channels": 4,
             "block_out_channels": (320, 640, 1280, 1280), "layers_per_block": 2,
             "down_block_types": ("CrossAttnDownBlockSpatioTemporal",) * 3 + ("DownBlockSpatioTemporal",),
             "up_block_types": ("UpBlockSpatioTemporal",) + ("CrossAttnUpBlockSpatioTemporal",) * 3,
             "cross_attention_dim": 1024, "num_attention_heads": (5, 10, 20, 20), "addition_time_embed_dim": 256,
             "projection_class_embeddings_input_dim": 768, "num_frames": 25},
    "vae": {"in_channels": 3, "out_channels": 3, "down_block_types": ("DownEncoderBlock2D",) * 4,
            "block_out_channels": (128, 256, 512, 512), "layers_per_block": 2, "latent_channels": 4,
            "sample_size": 768, "scaling_factor": 0.18215, "force_upcast": True},
    "clip": {"hidden_size": 1280, "intermediate_size": 5120, "projection_dim": 1024, "num_hidden_layers": 32,
             "num_attention_heads": 16, "image_size": 224, "patch_size": 14, "hidden_act": "gelu"},
}

TINY = {
    "unet": {"sample_size": 32, "in_channels": 8, "out_channels": 4, "block_out_channels": (32, 64),
             "layers_per_block": 1,
             # attention only at the lower resolution (and in the mid block): the CPU tests' cost is attention
             "down_block_types": ("DownBlockSpatioTemporal", "CrossAttnDownBlockSpatioTemporal"),
             "up_block_types": ("CrossAttnUpBlockSpatioTemporal", "UpBlockSpatioTemporal"),
             "cross_attention_dim": 32, "num_attention_heads": (4, 8), "addition_time_embed_dim": 32,
             "projection_class_embeddings_input_dim": 96, "num_frames": 25},
    "vae": {"in_channels": 3, "out_channels": 3, "down_block_types": ("DownEncoderBlock2D",) * 4,
            "block_out_channels": (32, 32, 64, 64), "layers_per_block": 1, "latent_channels": 4,
            "sample_size": 64, "scaling_factor": 0.18215, "force_upcast": True},
    "clip": {"hidden_size": 32, "intermediate_size": 37, "projection_dim": 32, "num_hidden_layers": 2,
             "num_attention_heads": 4, "image_size": 224, "patch_size": 32, "hidden_act": "gelu"},
}

SIZES = {"full": FULL, "tiny": TINY}


def build_components(size: str = "tiny", seed: int = 0) -> dict:
    """Random-weight SVD components (unet, vae, image_encoder, feature_extractor, scheduler) of one size."""
    from diffusers import AutoencoderKLTemporalDecoder, EulerDiscreteScheduler, UNetSpatioTemporalConditionModel
    from transformers import CLIPImageProcessor, CLIPVisionConfig, CLIPVisionModelWithProjection

    cfg = SIZES[size]
    torch.manual_seed(seed)
    unet = UNetSpatioTemporalConditionModel(**cfg["unet"])
    vae = AutoencoderKLTemporalDecoder(**cfg["vae"])
    image_encoder = CLIPVisionModelWithProjection(CLIPVisionConfig(**cfg["clip"]))
    image = cfg["clip"]["image_size"]
    feature_extractor = CLIPImageProcessor(crop_size={"height": image, "width": image},
                                           size={"shortest_edge": image}, do_center_crop=True, do_normalize=True,
                                           image_mean=list(CLIP_MEAN), image_std=list(CLIP_STD))
    scheduler = EulerDiscreteScheduler.from_config(SCHEDULER)  # as a stock scheduler_config.json loads
    return {"unet": unet, "vae": vae, "image_encoder": image_encoder, "feature_extractor": feature_extractor,
            "scheduler": scheduler}


def save_stock_svd(path: str, size: str = "tiny", seed: int = 0) -> str:
    """Write a folder laid out like a stock SVD img2vid snapshot (model_index.json, one subfolder per component,
    safetensors), with random weights. Returns ``path``."""
    from diffusers import StableVideoDiffusionPipeline

    StableVideoDiffusionPipeline(**build_components(size, seed)).save_pretrained(path, safe_serialization=True)
    return path
