"""Evaluation metrics: FID/KID over Inception-v3 pool3 features, and per-image PSNR/SSIM."""
