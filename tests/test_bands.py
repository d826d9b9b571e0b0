"""identify.output.bands.mixture_quantile against the report's bisection and a direct check."""

import numpy as np
import pytest
from scipy.special import ndtr

from identify.output.bands import mixture_quantile
from identify.output.report import mixture_quantile as bisection


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
