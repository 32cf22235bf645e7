"""PSNR and SSIM: closed forms, known properties, and SSIM against a plain-loop float64 reference."""

import itertools
import math

import numpy as np
import pytest
import torch

from backend.evaluate.image_metrics import psnr, ssim, ssim_map


def _rand(shape, seed):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _reference_ssim_map(a, b, data_range=1.0):
    """SSIM map by explicit loops over every fully-inside 11x11 window (Wang et al. 2004), float64 numpy."""
    r = np.arange(11) - 5.0
    g = np.exp(-r ** 2 / (2 * 1.5 ** 2))
    w = np.outer(g, g)
    w /= w.sum()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    n, c, h, wd = a.shape
    out = np.zeros((n, c, h - 10, wd - 10))
    for i in range(n):
        for ch in range(c):
            for y in range(h - 10):
                for x in range(wd - 10):
                    pa, pb = a[i, ch, y:y + 11, x:x + 11], b[i, ch, y:y + 11, x:x + 11]
                    ma, mb = (w * pa).sum(), (w * pb).sum()
                    va, vb = (w * (pa - ma) ** 2).sum(), (w * (pb - mb) ** 2).sum()
                    cab = (w * (pa - ma) * (pb - mb)).sum()
                    num = (2 * ma * mb + c1) * (2 * cab + c2)
                    out[i, ch, y, x] = num / ((ma ** 2 + mb ** 2 + c1) * (va + vb + c2))
    return out


def test_ssim_matches_loop_reference_with_and_without_mask():
    a = _rand((2, 3, 16, 19), 0)
    b = (a + 0.15 * _rand((2, 3, 16, 19), 1) - 0.05).clamp(0, 1)
    ref = _reference_ssim_map(a.numpy(), b.numpy())
    np.testing.assert_allclose(ssim_map(a, b).numpy(), ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ssim(a, b).numpy(), ref.mean(axis=(1, 2, 3)), rtol=1e-10)

    mask = _rand((2, 1, 16, 19), 2) > 0.4
    crop = mask[:, :, 5:-5, 5:-5].numpy()
    expected = [ref[i][:, crop[i, 0]].mean() for i in range(2)]
    got = ssim(a, b, mask=mask)
    assert got.dtype == torch.float64 and got.shape == (2,)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-10)
    # an all-true mask is the unmasked mean
    np.testing.assert_allclose(ssim(a, b, mask=torch.ones(2, 1, 16, 19, dtype=torch.bool)).numpy(),
                               ssim(a, b).numpy(), rtol=1e-12)


def test_ssim_properties():
    x = _rand((1, 3, 32, 30), 3)
    assert ssim(x, x).item() == pytest.approx(1.0, abs=1e-12)
    y = (x + 0.1 * _rand((1, 3, 32, 30), 4)).clamp(0, 1)
    assert ssim(x, y).item() == pytest.approx(ssim(y, x).item(), rel=1e-12)
    noisy = [ssim(x, (x + s * torch.randn(x.shape, generator=torch.Generator().manual_seed(5),
                                          dtype=torch.float64)).clamp(0, 1)).item() for s in (0.01, 0.05, 0.1, 0.3)]
    assert all(p > q for p, q in itertools.pairwise(noisy)) and noisy[0] < 1.0


def test_ssim_constant_offset_is_the_luminance_term():
    # Constant images: zero variance, so SSIM is the luminance term (2ab + C1) / (a² + b² + C1) everywhere.
    a, b = 0.3, 0.55
    c1 = 0.01 ** 2
    x = torch.full((1, 3, 14, 14), a, dtype=torch.float64)
    expected = (2 * a * b + c1) / (a * a + b * b + c1)
    assert ssim(x, x + (b - a)).item() == pytest.approx(expected, rel=1e-9)
    # data_range scales C1 and C2: the same pair expressed in 0..255 gives the same value
    assert ssim(255 * x, 255 * (x + (b - a)), data_range=255.0).item() == pytest.approx(expected, rel=1e-9)


def test_psnr_values():
    a = 0.8 * _rand((2, 3, 8, 9), 6)
    assert psnr(a, a).tolist() == [math.inf, math.inf]
    got = psnr(a, a + 0.1)  # MSE 0.01 -> 20 dB
    assert got.dtype == torch.float64
    np.testing.assert_allclose(got.numpy(), [20.0, 20.0], rtol=1e-12)
    np.testing.assert_allclose(psnr(255 * a, 255 * (a + 0.1), data_range=255.0).numpy(), [20.0, 20.0], rtol=1e-12)


def test_psnr_mask_counts_only_masked_pixels():
    a = 0.5 * torch.ones(2, 3, 6, 6, dtype=torch.float64)
    b = a.clone()
    b[:, :, :, :3] += 0.01    # error 0.01 on the left half
    b[:, :, :, 3:] += 0.3     # large error on the right half, masked out
    mask = torch.zeros(2, 1, 6, 6, dtype=torch.bool)
    mask[:, :, :, :3] = True
    mask[1] = False           # second image: nothing to measure
    got = psnr(a, b, mask=mask)
    assert got[0].item() == pytest.approx(40.0, rel=1e-9)
    assert math.isnan(got[1].item())


def test_single_image_numpy_and_errors():
    a, b = _rand((3, 16, 16), 7), _rand((3, 16, 16), 8)
    assert psnr(a, b).shape == (1,) and ssim(a, b).shape == (1,)
    assert ssim(a.float().numpy(), b.float().numpy()).item() == pytest.approx(ssim(a.float(), b.float()).item())
    with pytest.raises(ValueError, match="differ in shape"):
        psnr(a, b[:, :8])
    with pytest.raises(ValueError, match="bool"):
        psnr(a, b, mask=torch.ones(1, 16, 16))
    with pytest.raises(ValueError, match=r"\(N, 1, H, W\)"):
        ssim(a, b, mask=torch.ones(3, 16, 16, dtype=torch.bool))
    # a batch's mask may also come without its channel axis
    m = torch.rand(2, 16, 16, generator=torch.Generator().manual_seed(9)) > 0.5
    ab, bb = torch.stack([a, b]), torch.stack([b, a])
    assert torch.equal(psnr(ab, bb, mask=m), psnr(ab, bb, mask=m[:, None]))
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(a[:, :10], b[:, :10])
    with pytest.raises(ValueError, match=r"\(N, C, H, W\)"):
        psnr(a[0], b[0])
