"""core.geometry.similarity: Umeyama and camera-path fits, exact 1e5 m from the origin; cameras re-expressed in a new world."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.geometry import similarity
from tests.core.geometry.camera_fixtures import random_rotation, random_w2c


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_umeyama_recovers_similarity(offset):
    rng = np.random.default_rng(3)
    R = random_rotation(rng)
    s, t = 7.3, np.array([offset, -offset, 12.0])
    x = rng.standard_normal((100, 3))
    y = s * x @ R.T + t
    fit = similarity.umeyama(x, y)
    assert fit.scale == pytest.approx(s, rel=1e-12)
    assert np.abs(fit.rotation - R).max() < 1e-12
    assert np.abs(fit.apply(x) - y).max() < 1e-9
    assert fit.rms < 1e-9


def test_umeyama_collinear_is_a_clear_error():
    x = np.stack([np.arange(10.0), np.zeros(10), np.zeros(10)], 1)
    with pytest.raises(ValueError, match="collinear"):
        similarity.umeyama(x, 2 * x)


def test_umeyama_with_noise_reports_residual():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((500, 3)) * 10
    y = 2 * x + rng.normal(0, 0.01, x.shape)
    fit = similarity.umeyama(x, y)
    assert 0.005 < fit.rms < 0.03


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_fit_to_cameras_straight_drive(offset):
    """A straight drive is collinear, but camera orientations fix the roll: the fit is still exact."""
    rng = np.random.default_rng(5)
    S = 10
    src = np.tile(np.eye(4), (S, 1, 1))
    src[:, 2, 3] = -np.arange(S) * 0.1  # moving along its own +z, unit-less
    R = random_rotation(rng)
    M = similarity.similarity_matrix(3.5, R, [offset, 2.0, offset])
    dst = similarity.transform_world_to_camera(src, M)
    fit = similarity.fit_similarity_to_cameras(src, dst)
    assert np.abs(fit.matrix() - M).max() < 1e-9 * max(1, offset)
    assert fit.rms < 1e-9 * max(1, offset) and fit.rotation_rms_deg < 1e-6


def test_transform_world_to_camera_preserves_pixels():
    rng = np.random.default_rng(6)
    K = np.array([[300.0, 0, 200], [0, 300, 150], [0, 0, 1]])
    T = random_w2c(rng)
    X = C.camera_centers(T) + rng.uniform(-5, 5, (40, 3))
    uv, z = C.project(K, T, X)
    M = similarity.similarity_matrix(0.37, random_rotation(rng), [1e5, 3, -2])
    X2 = (0.37 * X) @ M[:3, :3].T / 0.37 + M[:3, 3]
    uv2, z2 = C.project(K, similarity.transform_world_to_camera(T, M), X2)
    assert np.abs(uv2 - uv)[z > 0].max() < 1e-6
    assert np.allclose(z2, 0.37 * z)


def test_decompose_similarity_rejects_shear():
    M = np.eye(4)
    M[0, 1] = 0.5
    with pytest.raises(ValueError):
        similarity.decompose_similarity(M)
