"""identify.output.bands.mixture_quantile (the one home of the mixture quantile: the report and
predict use it) against a plain vectorised bisection and a direct check."""

import numpy as np
import pytest
from scipy.special import ndtr, ndtri

from identify.output.bands import mixture_quantile


def bisection(centres, sigmas, probability, tolerance=1e-3, block=4096):
    """Reference: quantile of the equal-weight mixture of N(centres[i, t], sigmas[i]^2), for every t
    (the report's own implementation until the report used identify.output.bands).

    Bisection on the mixture CDF inside the exact bracket
    ``[min_i (c_i + s_i z_p), max_i (c_i + s_i z_p)]`` (every component's CDF is below
    ``p`` at the left end and above it at the right end), to ``tolerance * min(s)``; in
    blocks of ``block`` samples to bound memory.

    Parameters
    ----------
    centres : ndarray, shape (D, T)
    sigmas : ndarray, shape (D,)
        All > 0.
    probability : float

    Returns
    -------
    ndarray, shape (T,)
    """
    sigmas = np.asarray(sigmas, dtype=float)[:, None]
    n_samples = centres.shape[1]
    result = np.empty(n_samples)
    offsets = sigmas * ndtri(probability)
    precision = tolerance * float(sigmas.min())
    for start in range(0, n_samples, block):
        c = centres[:, start : start + block]
        low = (c + offsets).min(axis=0)
        high = (c + offsets).max(axis=0)
        while (high - low).max() > precision:
            middle = 0.5 * (low + high)
            below = ndtr((middle[None, :] - c) / sigmas).mean(axis=0) < probability
            low = np.where(below, middle, low)
            high = np.where(below, high, middle)
        result[start : start + block] = 0.5 * (low + high)
    return result


@pytest.mark.parametrize("probability", [0.025, 0.5, 0.975])
def test_mixture_quantile_agrees_with_the_bisection_and_the_cdf(probability):
    rng = np.random.default_rng(4)
    centres = rng.standard_normal((50, 300)) * rng.uniform(0.01, 3.0, 300) + np.linspace(-5, 5, 300)
    sigmas = rng.uniform(0.2, 0.8, 50)
    q = mixture_quantile(centres, sigmas, probability)
    np.testing.assert_allclose(q, bisection(centres, sigmas, probability), rtol=0, atol=1e-3 * sigmas.min())
    cdf = ndtr((q[None, :] - centres) / sigmas[:, None]).mean(axis=0)
    np.testing.assert_allclose(cdf, probability, rtol=0, atol=1e-6)


def test_one_component_is_its_own_quantile():
    q = mixture_quantile(np.array([[1.0, 2.0]]), 0.5, 0.975)
    np.testing.assert_allclose(q, [1.0 + 0.5 * 1.959963984540054, 2.0 + 0.5 * 1.959963984540054], rtol=1e-12)
