r"""A slow, independent reference sampler for the posterior: textbook random-walk Metropolis.

emcee's ensemble moves are checked against it on a real GPI posterior
(``tests/test_posterior.py``): independent chains, a fixed Gaussian proposal shaped like
the Laplace covariance, the plain Metropolis acceptance rule, nothing adaptive, so its
stationary distribution is the posterior by construction; only its run length is an
assumption (checked by its own autocorrelation time).

Importance sampling from the Laplace approximation was tried first and dropped: on the
GPI posterior its weights collapse (effective sample size below 100 of 80,000 draws)
along the curved envelope/weight ridge, and it then reports too narrow a posterior.
"""

from __future__ import annotations

import numpy as np

__all__ = ["random_walk_metropolis"]


def random_walk_metropolis(log_post, start, covariance, rng, *, n_steps=10000, scale=None):
    """Independent parallel random-walk Metropolis chains: the textbook sampler.

    Each of the ``C`` chains proposes ``x' = x + L e`` with ``e ~ N(0, I)`` and
    ``L L^T = scale^2 * covariance`` and accepts with probability
    ``min(1, exp(log_post(x') - log_post(x)))``. All chains are advanced in one
    vectorised ``log_post`` call per step.

    Parameters
    ----------
    log_post : callable ``(C, D) -> (C,)``
    start : array_like, shape (C, D)
        Starting points (inside the support).
    covariance : array_like, shape (D, D)
        Proposal shape, e.g. the Laplace covariance.
    rng : numpy.random.Generator
    n_steps : int, default 10000
    scale : float, optional
        Default ``2.38 / sqrt(D)`` (the optimal scale for a Gaussian target).

    Returns
    -------
    chain : ndarray, shape (n_steps, C, D)
    acceptance : float
        Mean acceptance fraction.
    """
    x = np.array(start, dtype=float)
    n_chains, dim = x.shape
    scale = 2.38 / np.sqrt(dim) if scale is None else scale
    chol = np.linalg.cholesky(np.asarray(covariance, dtype=float)) * scale
    lp = np.asarray(log_post(x), dtype=float)
    if not np.isfinite(lp).all():
        raise ValueError("a starting point lies outside the posterior's support")
    chain = np.empty((n_steps, n_chains, dim))
    accepted = 0
    for step in range(n_steps):
        proposal = x + rng.standard_normal((n_chains, dim)) @ chol.T
        lp_new = np.asarray(log_post(proposal), dtype=float)
        accept = np.log(rng.uniform(size=n_chains)) < lp_new - lp
        x[accept], lp[accept] = proposal[accept], lp_new[accept]
        accepted += int(accept.sum())
        chain[step] = x
    return chain, accepted / (n_steps * n_chains)
