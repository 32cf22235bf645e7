"""core.splats.sh: the one SH basis (core.splats.gaussians and the condition renderer evaluate it), checked against the definition:
orthonormal real harmonics in the 3DGS order and signs. The renderer's torch evaluation is compared with
core.splats.gaussians in tests/backend/render/test_gaussians.py."""

import math

import numpy as np
import pytest

from scpainter_blender.core.splats import sh, gaussians as splats


def sphere_quadrature():
    """Nodes (M, 3) and weights (M,) integrating polynomials up to degree 15 on the unit sphere exactly:
    Gauss-Legendre in cos θ times the trapezoid rule in φ."""
    ct, wt = np.polynomial.legendre.leggauss(8)
    phi = np.arange(16) * (2 * np.pi / 16)
    c, p = np.meshgrid(ct, phi, indexing="ij")
    s = np.sqrt(1 - c * c)
    dirs = np.stack([s * np.cos(p), s * np.sin(p), c], -1).reshape(-1, 3)
    return dirs, np.repeat(wt, 16) * (2 * np.pi / 16)


def test_basis_is_orthonormal_on_the_sphere():
    """∫ Y_i Y_j dΩ = δ_ij for all 16 functions: every constant and every polynomial is right (up to sign)."""
    dirs, w = sphere_quadrature()
    B = splats.sh_basis(dirs, 3)
    assert B.shape == (len(dirs), 16)
    gram = B.T @ (B * w[:, None])
    assert np.abs(gram - np.eye(16)).max() < 1e-12


def test_constants_are_the_closed_forms():
    r = 1 / math.sqrt(math.pi)
    assert sh.SH_C0 == pytest.approx(0.5 * r, abs=1e-15)
    assert sh.SH_C1 == pytest.approx(0.5 * math.sqrt(3) * r, abs=1e-15)
    assert sh.SH_C2 == pytest.approx([0.5 * math.sqrt(15) * r, -0.5 * math.sqrt(15) * r, 0.25 * math.sqrt(5) * r,
                                      -0.5 * math.sqrt(15) * r, 0.25 * math.sqrt(15) * r], abs=1e-15)
    assert sh.SH_C3 == pytest.approx([-0.25 * math.sqrt(35 / 2) * r, 0.5 * math.sqrt(105) * r,
                                      -0.25 * math.sqrt(21 / 2) * r, 0.25 * math.sqrt(7) * r,
                                      -0.25 * math.sqrt(21 / 2) * r, 0.25 * math.sqrt(105) * r,
                                      -0.25 * math.sqrt(35 / 2) * r], abs=1e-14)
    assert not hasattr(splats, "SH_C0")   # one definition: core.splats.sh, imported from there (no re-export)


def test_3dgs_order_and_signs():
    """Degree 1 is (−C1 y, C1 z, −C1 x), as the INRIA rasterizer's computeColorFromSH writes it."""
    B = splats.sh_basis([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], 1)
    assert np.allclose(B[:, 1:], [[0, sh.SH_C1, 0], [0, 0, -sh.SH_C1], [-sh.SH_C1, 0, 0]])


def test_bad_degrees():
    with pytest.raises(ValueError, match="0-3"):
        sh.basis(0.0, 0.0, 1.0, 4)
    with pytest.raises(ValueError, match="1, 4, 9 or 16"):
        sh.degree_of(5)
    assert [sh.degree_of(k) for k in (1, 4, 9, 16)] == [0, 1, 2, 3]
