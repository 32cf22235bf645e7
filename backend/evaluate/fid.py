"""Feature statistics, Fréchet (Inception) distance and kernel Inception distance, in float64 throughout.

Features are rows of an (N, D) array (Inception pool3: D = 2048). FID and KID are returned in feature units
squared, with no rescaling (pytorch-fid and the KID paper report the same numbers; KID is often quoted x 1000).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch


def _as_float64_rows(features, what="features") -> np.ndarray:
    if hasattr(features, "detach"):  # torch tensor, on any device and of any float dtype
        features = features.detach().to("cpu").double().numpy()
    x = np.asarray(features, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"{what} must be a 2-D (N, D) array, got shape {x.shape}")
    return x


class FeatureStats:
    """Streaming mean and covariance of feature rows, accumulated in float64.

    ``update`` may be called any number of times; the result equals one call with all rows concatenated (to ~1e-12
    relative). Each batch is folded in with Chan et al.'s pairwise update (batch mean, centred scatter matrix, then a
    rank-one correction for the shift between the means) rather than raw sums of x and x xᵀ: the raw-sum form loses
    digits to cancellation when the mean is large against the spread, the centred form does not, at the same cost.

    ``keep_features=True`` also keeps the rows (needed for :func:`kid`); :meth:`features` returns them.
    """

    def __init__(self, keep_features: bool = False) -> None:
        self.keep_features = keep_features
        self._n = 0
        self._mean = None    # (D,) float64
        self._m2 = None      # (D, D) float64: sum over rows of (x - mean)(x - mean)ᵀ
        self._kept = []

    @property
    def dim(self) -> int | None:
        """Feature dimension D, or None before the first update."""
        return None if self._mean is None else self._mean.shape[0]

    @property
    def count(self) -> int:
        """Number of rows accumulated."""
        return self._n

    @property
    def mean(self) -> np.ndarray:
        """(D,) float64 mean (a copy)."""
        if self._n == 0:
            raise ValueError("FeatureStats: no features accumulated yet")
        return self._mean.copy()

    @property
    def cov(self) -> np.ndarray:
        """(D, D) float64 unbiased covariance (divides by N - 1; a copy)."""
        if self._n < 2:
            raise ValueError(f"FeatureStats: a covariance needs at least 2 feature rows, have {self._n}")
        return self._m2 / (self._n - 1)

    def _fold(self, n_b: int, mean_b: np.ndarray, m2_b: np.ndarray) -> None:
        if self._n == 0:
            self._n, self._mean, self._m2 = n_b, mean_b.copy(), m2_b.copy()
            return
        n = self._n + n_b
        delta = mean_b - self._mean
        self._mean = self._mean + delta * (n_b / n)
        self._m2 = self._m2 + m2_b + np.outer(delta, delta) * (self._n * n_b / n)
        self._n = n

    def update(self, features: np.ndarray | torch.Tensor) -> FeatureStats:
        """Add (N, D) rows (torch tensor or numpy array, any float dtype). Rows with NaN/inf reject the whole batch."""
        x = _as_float64_rows(features)
        if self.dim is not None and x.shape[1] != self.dim:
            raise ValueError(f"features have dimension {x.shape[1]}, the statistics so far have {self.dim}")
        bad = int((~np.isfinite(x).all(axis=1)).sum())
        if bad:
            raise ValueError(f"{bad} of {x.shape[0]} feature rows contain NaN or inf")
        if x.shape[0] == 0:
            return self
        mean_b = x.mean(axis=0)
        xc = x - mean_b
        self._fold(x.shape[0], mean_b, xc.T @ xc)
        if self.keep_features:
            self._kept.append(x.copy())
        return self

    def merge(self, other: FeatureStats) -> FeatureStats:
        """Fold another FeatureStats into this one (in place; returns self)."""
        if other.count == 0:
            return self
        if self.dim is not None and other.dim != self.dim:
            raise ValueError(f"cannot merge statistics of dimension {other.dim} into dimension {self.dim}")
        if self.keep_features and not other.keep_features:
            raise ValueError("cannot merge: this FeatureStats keeps its features, the other one did not")
        self._fold(other._n, other._mean, other._m2)
        if self.keep_features:
            self._kept.append(other.features())
        return self

    def features(self) -> np.ndarray:
        """All rows seen so far as one (N, D) float64 array (requires ``keep_features=True``)."""
        if not self.keep_features:
            raise ValueError("FeatureStats was made without keep_features=True, so its rows were not kept")
        if not self._kept:
            return np.zeros((0, self.dim or 0))
        if len(self._kept) > 1:
            self._kept = [np.concatenate(self._kept, axis=0)]  # concatenate once, then reuse
        return self._kept[0]


def _psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """Symmetric square root of a symmetric PSD matrix via eigh; rounding-negative eigenvalues count as 0."""
    w, v = np.linalg.eigh(cov)
    s = (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T
    return (s + s.T) * 0.5


def _trace_sqrt_product(cov1: np.ndarray, cov2: np.ndarray) -> float:
    """tr((C1 C2)^{1/2}) for symmetric positive semi-definite C1, C2.

    With S1 = C1^{1/2} and S2 = C2^{1/2} (symmetric, from eigendecompositions), C1 C2 has the eigenvalues of
    S1 C2 S1 = (S1 S2)(S1 S2)ᵀ, so the trace is the sum of the singular values of S1 S2 (its nuclear norm).

    Why this form: it stays real and needs no eps offset, unlike ``scipy.linalg.sqrtm(C1 @ C2)`` of a non-symmetric
    matrix (complex parts, failures on the singular covariances that N < D rows give). And it takes singular values
    of a matrix of the covariances' own scale: taking eigenvalues of S1 C2 S1 and then their square roots instead
    turns rounding noise of order eps * |C|² in each (near-)null direction into errors of order sqrt(eps) * |C| in
    the trace, which is visible in FID of nearly identical sets. For C1 = C2 this gives tr C to rounding, even
    when C is singular.
    """
    return float(np.linalg.svd(_psd_sqrt(cov1) @ _psd_sqrt(cov2), compute_uv=False).sum())


def frechet_distance(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> float:
    """Fréchet distance between N(mu1, cov1) and N(mu2, cov2): |mu1 - mu2|² + tr C1 + tr C2 - 2 tr((C1 C2)^{1/2}).

    Inputs are (D,) means and (D, D) symmetric PSD covariances (numpy or anything ``np.asarray`` takes), computed in
    float64. The matrix square root trace is taken as in :func:`_trace_sqrt_product`. A result that rounding makes
    slightly negative is returned as 0.
    """
    mu1, mu2 = np.asarray(mu1, np.float64), np.asarray(mu2, np.float64)
    cov1, cov2 = np.asarray(cov1, np.float64), np.asarray(cov2, np.float64)
    d = mu1.shape[0] if mu1.ndim == 1 else -1
    if mu1.shape != (d,) or mu2.shape != (d,) or cov1.shape != (d, d) or cov2.shape != (d, d):
        raise ValueError(f"frechet_distance: shapes do not match: mu1 {mu1.shape}, cov1 {cov1.shape}, "
                         f"mu2 {mu2.shape}, cov2 {cov2.shape}")
    for name, a in (("mu1", mu1), ("cov1", cov1), ("mu2", mu2), ("cov2", cov2)):
        if not np.isfinite(a).all():
            raise ValueError(f"frechet_distance: {name} contains NaN or inf")
    # Symmetrise: a covariance from float accumulation can be asymmetric in the last bit.
    cov1 = (cov1 + cov1.T) * 0.5
    cov2 = (cov2 + cov2.T) * 0.5
    diff = mu1 - mu2
    value = diff @ diff + np.trace(cov1) + np.trace(cov2) - 2.0 * _trace_sqrt_product(cov1, cov2)
    return max(float(value), 0.0)


def fid(stats_a: FeatureStats, stats_b: FeatureStats) -> float:
    """FID between two feature sets given as :class:`FeatureStats` (each with at least 2 rows)."""
    return frechet_distance(stats_a.mean, stats_a.cov, stats_b.mean, stats_b.cov)


def _kid_rows(features, name: str) -> np.ndarray:
    if isinstance(features, FeatureStats):
        return features.features()
    x = _as_float64_rows(features, name)
    if not np.isfinite(x).all():
        raise ValueError(f"kid: {name} contains NaN or inf")
    return x


def kid(features_a: np.ndarray | torch.Tensor | FeatureStats, features_b: np.ndarray | torch.Tensor | FeatureStats,
        subsets: int = 100, subset_size: int = 1000, seed: int = 0) -> tuple[float, float]:
    """Kernel Inception distance (Bińkowski et al. 2018): unbiased MMD² with k(x, y) = (x·y / D + 1)³.

    ``features_a``/``features_b``: (N, D) rows (numpy, torch) or :class:`FeatureStats` made with
    ``keep_features=True``. For each of ``subsets`` rounds, ``m = min(subset_size, Na, Nb)`` rows are drawn without
    replacement from each set (``numpy.random.default_rng(seed)``, so a seed gives the same result every time) and

        MMD²_u = Σ_{i≠j} k(a_i, a_j) / (m(m-1)) + Σ_{i≠j} k(b_i, b_j) / (m(m-1)) - 2 Σ_{i,j} k(a_i, b_j) / m².

    Returns (mean, std) over the rounds (population std, ddof=0). The estimator is unbiased, so it can be slightly
    negative for sets from the same distribution.
    """
    a = _kid_rows(features_a, "features_a")
    b = _kid_rows(features_b, "features_b")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"kid: feature dimensions differ ({a.shape[1]} and {b.shape[1]})")
    m = min(int(subset_size), a.shape[0], b.shape[0])
    if m < 2:
        raise ValueError(f"kid: needs at least 2 rows in each set (have {a.shape[0]} and {b.shape[0]}, "
                         f"subset_size {subset_size})")
    if subsets < 1:
        raise ValueError(f"kid: subsets must be >= 1, got {subsets}")
    d = a.shape[1]
    rng = np.random.default_rng(seed)
    values = np.empty(subsets)
    for s in range(subsets):
        x = a[rng.choice(a.shape[0], m, replace=False)]
        y = b[rng.choice(b.shape[0], m, replace=False)]
        kxx = (x @ x.T / d + 1.0) ** 3
        kyy = (y @ y.T / d + 1.0) ** 3
        kxy = (x @ y.T / d + 1.0) ** 3
        values[s] = ((kxx.sum() - np.trace(kxx)) / (m * (m - 1)) + (kyy.sum() - np.trace(kyy)) / (m * (m - 1))
                     - 2.0 * kxy.sum() / (m * m))
    return float(values.mean()), float(values.std())
