"""The sampler's moves: emcee's differential-evolution moves, with the same draws and less overhead.

:data:`MOVES` names the schedules :func:`identify.fitting.posterior.sample_posterior` offers.
Both moves here are emcee red-blue moves (one small protocol: ``get_proposal(s, c, random)``
returns the proposals and their log factors), so they plug into
:class:`identify.fitting.coordinates.CoordinateMove` and any emcee sampler.
"""

from __future__ import annotations

import emcee
import numpy as np

from ._posterior_kernels import snooker_proposals

__all__ = ["DifferentialMove", "SnookerMove", "MOVES"]


class DifferentialMove(emcee.moves.DEMove):
    r"""emcee's differential-evolution move (Nelson et al. 2013), bit for bit, with less overhead.

    For walker :math:`x` pick an ordered pair :math:`(z_1, z_2)` of distinct walkers of the
    other split and propose :math:`x' = x + \gamma (z_2 - z_1)`,
    :math:`\gamma = \gamma_0 (1 + \sigma n)`, :math:`n` standard normal. The draws are
    emcee 3.1's :class:`emcee.moves.DEMove` (the pair index by ``randint``, which is what its
    ``choice`` draws, then the normals), so the chain is its chain; the pairs table is kept
    between calls and the differences taken without the ``(n, 2, D)`` temporary
    (``tests/test_coordinates.py`` compares the chains).
    """

    def __init__(self, sigma=1.0e-5, gamma0=None, **kwargs):
        super().__init__(sigma=sigma, gamma0=gamma0, **kwargs)
        self._pairs = np.empty((0, 2), dtype=np.int64)

    def _pairs_of(self, n):
        """Every ordered pair of distinct indices below ``n``: emcee's table, in its order."""
        if self._pairs.shape[0] != n * (n - 1):
            rows, cols = np.tril_indices(n, -1)
            self._pairs = np.column_stack([np.concatenate([rows, cols]), np.concatenate([cols, rows])])
        return self._pairs

    def get_proposal(self, s, c, random):
        """Proposals ``(n, D)`` for the walkers ``s`` from the other split(s) ``c``, and zero log
        factors ``(n,)``."""
        c = c[0] if len(c) == 1 else np.concatenate(c, axis=0)
        n = s.shape[0]
        pairs = self._pairs_of(c.shape[0])[random.randint(0, self._pairs.shape[0], size=n)]
        gamma = self.g0 * (1 + self.sigma * random.randn(n, 1))
        return s + gamma * (c[pairs[:, 1]] - c[pairs[:, 0]]), np.zeros(n, dtype=np.float64)


class SnookerMove(emcee.moves.DESnookerMove):
    r"""The differential-evolution snooker update of ter Braak and Vrugt (2008), corrected.

    For walker :math:`x`, pick three other walkers :math:`z, z_1, z_2`; with the unit
    vector :math:`e = (x - z)/\lVert x - z\rVert` propose
    :math:`x' = x + \gamma_s\, e\, e^\top (z_1 - z_2)` and accept with probability
    :math:`\min\{1, \pi(x')/\pi(x)\, (\lVert x' - z\rVert / \lVert x - z\rVert)^{d-1}\}`
    (ter Braak and Vrugt, Stat. Comput. 18, 435-446, 2008, eq. 3).

    emcee 3.1.6's :class:`emcee.moves.DESnookerMove` divides by
    :math:`\sqrt{\lVert x - z\rVert}` instead of :math:`\lVert x - z\rVert` and uses the
    exponent :math:`(d-1)/2`; fixed upstream in dfm/emcee pull request #531 (merged
    2024-12), not in a release yet. The released move does not leave the posterior
    invariant: on the 18-parameter GPI posterior it drew marginal standard deviations
    0.83-0.99 times the Laplace ones where a random-walk Metropolis chain drew 1.01-1.14,
    and on a standard normal it shrinks the variance (``tests/test_posterior.py``).
    """

    def get_proposal(self, s, c, random):
        """Proposals ``(n, D)`` for the walkers ``s`` and the log Jacobian factors ``(n,)``,
        all walkers at once (emcee's loops over them in Python): the draws here, the arithmetic
        in one compiled pass (:func:`identify.fitting._posterior_kernels.snooker_proposals`)."""
        n_walkers = s.shape[0]
        # each walker's z, z1, z2 from the three other splits, one from each, in a random order
        # (the order of three uniforms per walker: np.argsort's, done in the compiled pass)
        picks = np.empty((n_walkers, 3), dtype=np.int64)
        for j in range(3):
            picks[:, j] = random.randint(len(c[j]), size=n_walkers)
        keys = random.uniform(size=(n_walkers, 3))
        proposal = np.empty((n_walkers, s.shape[1]))
        log_factor = np.empty(n_walkers)
        groups = [np.ascontiguousarray(c[j], dtype=float) for j in range(3)]
        snooker_proposals(
            np.ascontiguousarray(s, dtype=float), *groups, picks, keys, float(self.gammas), proposal, log_factor
        )
        return proposal, log_factor


#: move name -> factory of an emcee move schedule.
MOVES = {
    "stretch": lambda: emcee.moves.StretchMove(),
    "de": lambda: [(DifferentialMove(), 0.8), (SnookerMove(), 0.2)],
}
