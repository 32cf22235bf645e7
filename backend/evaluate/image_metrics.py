"""Per-image PSNR and SSIM.

Convention: images are torch tensors (or numpy arrays) laid out channel-first, (N, C, H, W) or a single (C, H, W),
float values in [0, data_range] (usually C = 3, sRGB display values in [0, 1]). Both metrics are computed in float64
and return one value per image as an (N,) float64 tensor on the input's device. ``mask`` is a bool (N, 1, H, W)
(also (N, H, W), or (1, H, W) for a single image): only pixels where it is true count, in every channel. An image
whose mask has no true pixel gets NaN.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _as_batch(x, name: str) -> torch.Tensor:
    x = torch.as_tensor(x)
    if x.ndim == 3:
        x = x.unsqueeze(0)
    if x.ndim != 4:
        raise ValueError(f"{name} must be (N, C, H, W) or (C, H, W), got shape {tuple(x.shape)}")
    return x.to(torch.float64)


def _prepare(a, b, mask):
    single = torch.as_tensor(a).ndim == 3
    a, b = _as_batch(a, "a"), _as_batch(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {tuple(a.shape)} and {tuple(b.shape)}")
    b = b.to(a.device)
    if mask is not None:
        mask = torch.as_tensor(mask)
        if mask.dtype != torch.bool:
            raise ValueError(f"mask must be bool (true = pixel counts), got {mask.dtype}")
        if mask.ndim == 3:  # (1, H, W) with a single (C, H, W) image, (N, H, W) with a batch
            mask = mask.unsqueeze(0 if single else 1)
        n, _, h, w = a.shape
        if tuple(mask.shape) != (n, 1, h, w):
            raise ValueError(f"mask must be (N, 1, H, W) = {(n, 1, h, w)}, got {tuple(mask.shape)}")
        mask = mask.to(a.device)
    return a, b, mask


def _masked_mean(values: torch.Tensor, mask) -> torch.Tensor:
    """Per-image mean of (N, C, H, W) values over all channels and the pixels where mask (N, 1, H, W) is true."""
    if mask is None:
        return values.flatten(1).mean(1)
    weight = mask.to(values.dtype).expand_as(values)
    total = (values * weight).flatten(1).sum(1)
    count = weight.flatten(1).sum(1)
    return total / count  # 0/0 = NaN for an empty mask, by design


def psnr(a, b, mask=None, data_range: float = 1.0) -> torch.Tensor:
    """PSNR in dB per image: 10 log10(data_range² / MSE), the MSE taken over all channels (and masked pixels).

    Identical images (MSE = 0) give +inf.
    """
    a, b, mask = _prepare(a, b, mask)
    mse = _masked_mean((a - b) ** 2, mask)
    # MSE = 0 gives data_range²/0 = inf and so +inf dB; an empty mask gives 0/0 = NaN.
    return 10.0 * torch.log10(data_range ** 2 / mse)


def _gaussian_window(device) -> torch.Tensor:
    r = torch.arange(SSIM_WINDOW, dtype=torch.float64, device=device) - (SSIM_WINDOW - 1) / 2
    g = torch.exp(-(r ** 2) / (2 * SSIM_SIGMA ** 2))
    return g / g.sum()


def ssim_map(a, b, data_range: float = 1.0) -> torch.Tensor:
    """The SSIM map (N, C, H - 10, W - 10), float64: one value per channel and fully-inside 11x11 window.

    Wang et al. 2004: an 11x11 Gaussian window (sigma 1.5, normalised to sum 1), valid convolution (no padding, so
    the map is 5 px smaller on every side), C1 = (0.01 L)², C2 = (0.03 L)² with L = ``data_range``, and the
    window-weighted (not N-1 corrected) variances and covariance, as in the authors' reference code.
    """
    a, b, _ = _prepare(a, b, None)
    c, h, w = a.shape[1:]
    if h < SSIM_WINDOW or w < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {h}x{w}")
    g = _gaussian_window(a.device)
    # The Gaussian is separable: a 1x11 then an 11x1 depthwise pass equals the 11x11 window at a fraction of the cost.
    gx = g.view(1, 1, 1, -1).repeat(c, 1, 1, 1)
    gy = g.view(1, 1, -1, 1).repeat(c, 1, 1, 1)

    def blur(x):
        return F.conv2d(F.conv2d(x, gx, groups=c), gy, groups=c)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a ** 2
    var_b = blur(b * b) - mu_b ** 2
    cov_ab = blur(a * b) - mu_a * mu_b
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    return ((2 * mu_a * mu_b + c1) * (2 * cov_ab + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))


def ssim(a, b, mask=None, data_range: float = 1.0) -> torch.Tensor:
    """Mean SSIM per image (see :func:`ssim_map`), averaged over channels and window positions.

    With ``mask``, the mask is cropped by the same 5 px border as the map and the map is averaged where the cropped
    mask is true (a window centred on a masked pixel counts, whatever its footprint covers).
    """
    a, b, mask = _prepare(a, b, mask)
    values = ssim_map(a, b, data_range)
    if mask is not None:
        r = SSIM_WINDOW // 2
        mask = mask[:, :, r:mask.shape[2] - r, r:mask.shape[3] - r]
    return _masked_mean(values, mask)
