"""FID/KID statistics: exact closed forms for Gaussians, streaming accumulation, and a tiny random feature extractor."""

import numpy as np
import pytest
import scipy.linalg
import torch

from backend.evaluate.fid import (
    FeatureStats,
    _trace_sqrt_product,
    fid,
    frechet_distance,
    kid,
)


def _extractor():
    """A fixed random conv + ReLU + global average pool: (N, 3, H, W) -> (N, 16) features."""
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 16, 5, stride=2), torch.nn.ReLU(),
                              torch.nn.AdaptiveAvgPool2d(1), torch.nn.Flatten())
    return net.eval().requires_grad_(False)


def _images(n, seed, shift=0.0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, 3, 24, 20, generator=g) + shift).clamp(0, 1)


def _stats(features, **kw):
    return FeatureStats(**kw).update(features)


def _random_spd(d, rng, scale=1.0):
    a = rng.normal(size=(d, d))
    return scale * (a @ a.T / d + 0.1 * np.eye(d))


def test_fid_of_a_set_with_itself_is_zero_and_symmetric():
    net = _extractor()
    fx = net(_images(64, 1))
    fy = net(_images(64, 2, shift=0.15))
    sx, sy = _stats(fx), _stats(fy)
    assert fid(sx, sx) == pytest.approx(0.0, abs=1e-8 * np.trace(sx.cov))
    d_xy, d_yx = fid(sx, sy), fid(sy, sx)
    assert d_xy > 1e-3
    assert d_xy == pytest.approx(d_yx, rel=1e-8)


def test_identical_singular_statistics_give_zero():
    # N < D: a rank-deficient covariance, as Inception's 2048-d features give for small sets.
    x = np.random.default_rng(3).normal(size=(10, 40)) * 3 + 5
    s = _stats(x)
    assert np.linalg.matrix_rank(s.cov) == 9
    assert frechet_distance(s.mean, s.cov, s.mean, s.cov) <= 1e-8 * np.trace(s.cov)
    # unclamped: tr((C C)^{1/2}) = tr(C) to rounding, for the singular C as well
    assert _trace_sqrt_product(s.cov, s.cov) == pytest.approx(np.trace(s.cov), rel=1e-10)


def test_frechet_distance_diagonal_closed_form():
    rng = np.random.default_rng(0)
    d = 7
    a, b = rng.uniform(0.1, 4.0, d), rng.uniform(0.0, 4.0, d)
    b[0] = 0.0  # a degenerate direction
    mu1, mu2 = rng.normal(size=d), rng.normal(size=d)
    expected = np.sum((np.sqrt(a) - np.sqrt(b)) ** 2) + np.sum((mu1 - mu2) ** 2)
    assert frechet_distance(mu1, np.diag(a), mu2, np.diag(b)) == pytest.approx(expected, rel=1e-10)


def test_frechet_distance_commuting_full_covariances():
    # Same eigenvectors: (C1 C2)^{1/2} = Q diag(sqrt(a b)) Qᵀ, so the distance is the diagonal one in that basis.
    rng = np.random.default_rng(1)
    d = 9
    q, _ = np.linalg.qr(rng.normal(size=(d, d)))
    a, b = rng.uniform(0.05, 3.0, d), rng.uniform(0.05, 3.0, d)
    mu1, mu2 = rng.normal(size=d), rng.normal(size=d)
    expected = np.sum((np.sqrt(a) - np.sqrt(b)) ** 2) + np.sum((mu1 - mu2) ** 2)
    got = frechet_distance(mu1, q @ np.diag(a) @ q.T, mu2, q @ np.diag(b) @ q.T)
    assert got == pytest.approx(expected, rel=1e-9)


def test_frechet_distance_non_commuting_against_scipy_sqrtm():
    rng = np.random.default_rng(2)
    d = 12
    c1, c2 = _random_spd(d, rng), _random_spd(d, rng, scale=2.0)
    assert not np.allclose(c1 @ c2, c2 @ c1)
    mu1, mu2 = rng.normal(size=d), rng.normal(size=d)
    ref_sqrt = np.real(np.trace(scipy.linalg.sqrtm(c1 @ c2)))
    expected = np.sum((mu1 - mu2) ** 2) + np.trace(c1) + np.trace(c2) - 2 * ref_sqrt
    assert frechet_distance(mu1, c1, mu2, c2) == pytest.approx(expected, rel=1e-9)
    assert frechet_distance(mu2, c2, mu1, c1) == pytest.approx(expected, rel=1e-9)


def test_frechet_distance_rejects_bad_shapes_and_nan():
    with pytest.raises(ValueError, match="shapes"):
        frechet_distance(np.zeros(3), np.eye(3), np.zeros(4), np.eye(4))
    cov = np.eye(3)
    cov[0, 0] = np.nan
    with pytest.raises(ValueError, match="cov2"):
        frechet_distance(np.zeros(3), np.eye(3), np.zeros(3), cov)


def test_streaming_equals_one_batch():
    rng = np.random.default_rng(4)
    # A large offset against a unit spread: raw sums of x xᵀ would lose ~8 digits here.
    x = rng.normal(size=(1000, 6)) @ rng.normal(size=(6, 6)) + 1e4
    one = _stats(x)
    streamed = FeatureStats()
    for chunk in np.array_split(x, [1, 2, 50, 51, 300, 777]) + [x[:0]]:  # single rows and an empty batch too
        streamed.update(chunk)
    ref_cov = np.cov(x, rowvar=False)
    atol = 1e-10 * np.abs(ref_cov).max()
    assert one.count == streamed.count == 1000
    np.testing.assert_allclose(one.mean, x.mean(0), rtol=1e-14)
    np.testing.assert_allclose(one.cov, ref_cov, rtol=1e-10, atol=atol)
    np.testing.assert_allclose(streamed.mean, one.mean, rtol=1e-14)
    np.testing.assert_allclose(streamed.cov, one.cov, rtol=1e-10, atol=atol)


def test_torch_and_numpy_inputs_agree():
    x = torch.randn(30, 5, generator=torch.Generator().manual_seed(0)).half()
    a, b = _stats(x), _stats(x.float().numpy())
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.cov, b.cov)


def test_merge_equals_update_and_keeps_features():
    rng = np.random.default_rng(5)
    x, y = rng.normal(size=(40, 5)), rng.normal(size=(25, 5)) + 2
    a = _stats(x, keep_features=True)
    a.merge(_stats(y, keep_features=True))
    both = _stats(np.concatenate([x, y]))
    assert a.count == 65
    np.testing.assert_allclose(a.mean, both.mean, rtol=1e-12)
    np.testing.assert_allclose(a.cov, both.cov, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(a.features(), np.concatenate([x, y]))
    with pytest.raises(ValueError, match="keeps its features"):
        a.merge(_stats(y))
    with pytest.raises(ValueError, match="dimension"):
        a.merge(_stats(rng.normal(size=(3, 4)), keep_features=True))


def test_update_rejects_non_finite_rows_and_wrong_shapes():
    s = FeatureStats(keep_features=True)
    x = np.ones((5, 3))
    x[1, 0], x[3, 2] = np.nan, np.inf
    with pytest.raises(ValueError, match="2 of 5 feature rows"):
        s.update(x)
    assert s.count == 0 and s.features().shape[0] == 0
    with pytest.raises(ValueError, match="2-D"):
        s.update(np.ones(3))
    s.update(np.ones((2, 3)))
    with pytest.raises(ValueError, match="dimension 4"):
        s.update(np.ones((2, 4)))
    with pytest.raises(ValueError, match="keep_features"):
        FeatureStats().features()
    with pytest.raises(ValueError, match="at least 2"):
        _ = FeatureStats().update(np.ones((1, 3))).cov


def test_kid_identical_near_zero_shifted_positive_and_seeded():
    net = _extractor()
    fx = net(_images(120, 6)).double().numpy()
    fx2 = net(_images(120, 7)).double().numpy()
    fy = net(_images(120, 8, shift=0.2)).double().numpy()
    same_mean, same_std = kid(fx, fx, subsets=20, subset_size=50)
    other_mean, _ = kid(fx, fx2, subsets=20, subset_size=50)
    shifted_mean, _ = kid(fx, fy, subsets=20, subset_size=50)
    assert shifted_mean > 0
    assert abs(same_mean) < 0.02 * shifted_mean
    assert abs(other_mean) < 0.05 * shifted_mean
    assert same_std >= 0
    # deterministic for a seed, and the seed matters
    assert kid(fx, fy, subsets=5, subset_size=30, seed=3) == kid(fx, fy, subsets=5, subset_size=30, seed=3)
    assert kid(fx, fy, subsets=5, subset_size=30, seed=3) != kid(fx, fy, subsets=5, subset_size=30, seed=4)
    # FeatureStats with kept rows and torch tensors are accepted alike
    sx = _stats(fx, keep_features=True)
    assert kid(sx, torch.from_numpy(fy), subsets=5, subset_size=30) == kid(fx, fy, subsets=5, subset_size=30)


def test_kid_matches_a_direct_formula_on_full_sets():
    # subset_size larger than the sets clips to the smaller set; with equal sizes every round uses all rows.
    rng = np.random.default_rng(9)
    x, y = rng.normal(size=(12, 4)), rng.normal(size=(12, 4)) + 0.5
    m, d = 12, 4

    def k(a, b):
        return (a @ b / d + 1.0) ** 3

    kxx = sum(k(x[i], x[j]) for i in range(m) for j in range(m) if i != j) / (m * (m - 1))
    kyy = sum(k(y[i], y[j]) for i in range(m) for j in range(m) if i != j) / (m * (m - 1))
    kxy = sum(k(x[i], y[j]) for i in range(m) for j in range(m)) / (m * m)
    mean, std = kid(x, y, subsets=3, subset_size=1000)
    assert mean == pytest.approx(kxx + kyy - 2 * kxy, rel=1e-12)
    assert std == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="at least 2 rows"):
        kid(x[:1], y)
