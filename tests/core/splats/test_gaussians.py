"""core.splats.gaussians: the values: decoding raw file values (activations, bad rows dropped and counted), encoding them
back, and the SH colour (basis orthonormal, sh_to_rgb). Files: test_reader (read/load, dispatch, fuzz),
test_ply_format, test_inria, test_compressed, test_trellis."""

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
from scpainter_blender.core.splats import gaussians as splats
from scpainter_blender.core.splats.sh import SH_C0, SH_C1


def test_decoding_activations():
    ply = F.random_ply(degree=2)
    g = splats.decode(ply)
    assert np.allclose(g.scales, np.exp(ply.scale), rtol=1e-6)
    assert np.allclose(g.opacities, 1 / (1 + np.exp(-ply.opacity)), rtol=1e-6)
    assert np.allclose(np.linalg.norm(g.quats, axis=1), 1.0, atol=1e-6)
    assert np.allclose(g.quats, ply.rot / np.linalg.norm(ply.rot, axis=1, keepdims=True), atol=1e-6)
    assert np.array_equal(g.sh[:, 0], ply.f_dc)
    assert np.array_equal(g.sh[:, 1:, 0], ply.f_rest[:, 0])  # channel-major f_rest: red's coefficients first
    assert np.array_equal(g.sh[:, 1:, 2], ply.f_rest[:, 2])


def test_encode_inverts_decode():
    ply = F.random_ply(degree=1, extras=False)
    back = splats.encode(splats.decode(ply))
    assert np.allclose(back.scale, ply.scale, atol=1e-5)
    assert np.allclose(back.opacity, ply.opacity, atol=1e-3)


def test_edge_cases_dropped_and_counted():
    ply = F.random_ply(N=8, degree=3, extras=False)
    ply.rot[0] = 0.0                      # zero quaternion
    ply.xyz[1, 2] = np.inf                # non-finite position
    ply.f_rest[2, 1, 5] = np.nan          # non-finite SH
    ply.scale[3] = [100.0, 0.0, 0.0]      # exp overflows float32
    ply.scale[4] = [-60.0, -60.0, -60.0]  # degenerate (tiny) but valid
    ply.opacity[5] = 1e4                  # saturated opacity: exactly 1, not NaN
    ply.opacity[6] = -1e4
    g = splats.decode(ply)
    assert g.dropped == {"non_finite": 2, "zero_quaternion": 1, "scale_overflow": 1}
    assert len(g) == 4
    for arr in (g.means, g.scales, g.quats, g.opacities, g.sh):
        assert np.all(np.isfinite(arr))
    assert g.opacities.max() == 1.0 and g.opacities.min() == 0.0
    assert g.scales.min() >= 0.0


# -- spherical harmonics -------------------------------------------------------------------------------------------

def fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def test_sh_basis_is_orthonormal():
    d = fibonacci_sphere(200_000)
    B = splats.sh_basis(d, 3)
    gram = 4 * np.pi * (B.T @ B) / len(d)  # ∫ Y_i Y_j dΩ
    assert np.abs(gram - np.eye(16)).max() < 1e-3


def test_sh_to_rgb():
    rng = np.random.default_rng(0)
    sh = rng.normal(0, 0.3, (100, 16, 3))
    d = fibonacci_sphere(100)
    dc_only = splats.sh_to_rgb(sh, d, degree=0)
    assert np.allclose(dc_only, np.maximum(0.5 + SH_C0 * sh[:, 0], 0))
    full = splats.sh_to_rgb(sh, d)
    assert np.allclose(full, np.maximum(0.5 + np.einsum("nk,nkc->nc", splats.sh_basis(d, 3), sh), 0))
    assert full.min() >= 0.0
    # degree 1 along +z: the basis is (C0, -C1·y, C1·z, -C1·x) = (C0, 0, C1, 0)
    one = np.zeros((1, 4, 3))
    one[0, 2] = 1.0
    assert np.allclose(splats.sh_to_rgb(one, [[0, 0, 1.0]]), 0.5 + SH_C1)
    with pytest.raises(ValueError):
        splats.sh_to_rgb(one, [[0, 0, 1.0]], degree=2)
