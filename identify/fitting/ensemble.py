"""The ensemble sampler's loop: emcee's, the same draws in the same order, with less work a step.

:class:`EnsembleLoop` runs emcee moves (the red-blue protocol: ``move.propose(model, state)``
returning the new state and the accepted walkers) as :meth:`emcee.EnsembleSampler.sample` does
(emcee 3.1): a move picked at random by its weight, its proposal, the step stored. The chain
is emcee's, bit for bit (``tests/test_ensemble.py`` runs both); what differs is what a step
costs beside the log-probability:

* the move is picked with the one uniform draw :meth:`numpy.random.RandomState.choice` makes
  (the same number, compared with the same cumulative weights), without ``choice``'s checks
  of the weights, done once here;
* no progress bar, thinning, tuning or blobs, and the state checked once, at :meth:`start`.

The generator's state is copied after every step, as emcee does (31 us, a tenth of the
sampler's own time a step, but the state a step is stored with must be the one after it
whatever interrupts the next: a second Ctrl-C inside a model call leaves every completed
step resumable bit for bit).

The log-probability is called directly with all proposals (``vectorize=True``: one call a
split), its NaN refused as emcee refuses it; no blobs.
"""

from __future__ import annotations

import emcee
import numpy as np

__all__ = ["EnsembleLoop"]


class EnsembleLoop:
    """emcee's ensemble sampling loop: :meth:`start`, then :meth:`steps`.

    Parameters
    ----------
    log_prob : callable
        ``f(x)`` with ``x`` of shape ``(n, D)`` -> log-probabilities ``(n,)``, never NaN.
    n_walkers, ndim : int
    moves : emcee.moves.Move or list of (Move, weight)
        As :class:`emcee.EnsembleSampler` takes them (a list of moves without weights: equal
        weights).
    backend : emcee.backends.Backend
        Where every step goes (``save_step(state, accepted)``), with the generator's state.
    random : numpy.random.RandomState
        The generator every move draws from (emcee's ``model.random``).

    Attributes
    ----------
    model : emcee.model.Model
        What the moves are given: the log-probability, its checked form and the generator.
    """

    def __init__(self, log_prob, n_walkers, ndim, moves, backend, random):
        self.n_walkers, self.ndim = int(n_walkers), int(ndim)
        self.backend = backend
        self.random = random
        self.log_prob = log_prob
        self.moves, weights = _schedule(moves)
        # emcee's weights, normalised as it does, then choice's cumulative sum of them
        weights = np.atleast_1d(np.asarray(weights, dtype=float)).copy()
        weights /= np.sum(weights)
        cdf = weights.cumsum()
        cdf /= cdf[-1]
        self._cdf = cdf
        self.model = emcee.model.Model(log_prob, self.compute_log_prob, map, random)

    def compute_log_prob(self, coords):
        """emcee's ``compute_log_prob`` of a vectorised function without blobs: ``(log_prob (n,), None)``;
        a non-finite coordinate or a NaN log-probability is refused as emcee refuses it."""
        coords = np.asarray(coords, dtype=float)
        if np.any(np.isinf(coords)):
            raise ValueError("At least one parameter value was infinite")
        if np.any(np.isnan(coords)):
            raise ValueError("At least one parameter value was NaN")
        log_prob = np.asarray(self.log_prob(coords), dtype=float)
        if log_prob.shape != (coords.shape[0],):
            raise ValueError(f"the log-probability gave shape {log_prob.shape} for {coords.shape[0]} walkers")
        if np.any(np.isnan(log_prob)):
            raise ValueError("Probability function returned NaN")
        return log_prob, None

    def start(self, state, *, check_independence=True) -> emcee.State:
        """The state to step from: emcee's checks of the start (shape, linearly independent
        walkers unless ``check_independence`` is False, a log-probability that is not NaN), its
        log-probabilities computed when missing, and the generator set to its random state
        when it carries one."""
        state = emcee.State(state, copy=True)
        if np.shape(state.coords) != (self.n_walkers, self.ndim):
            raise ValueError(f"incompatible input dimensions {np.shape(state.coords)}")
        if check_independence and not emcee.ensemble.walkers_independent(state.coords):
            raise ValueError(
                "Initial state has a large condition number. "
                "Make sure that your walkers are linearly independent for the best performance"
            )
        if state.random_state is not None:
            self.random.set_state(state.random_state)
        if state.log_prob is None:
            state.log_prob, state.blobs = self.compute_log_prob(state.coords)
        if np.shape(state.log_prob) != (self.n_walkers,):
            raise ValueError("incompatible input dimensions")
        if np.any(np.isnan(state.log_prob)):
            raise ValueError("The initial log_prob was NaN")
        return state

    def steps(self, state, n_steps):
        """Yield the state after each of ``n_steps`` steps from ``state`` (a :meth:`start` state),
        each stored in the backend first. The yielded object is the one state, updated in place:
        copy what is kept."""
        for _ in range(int(n_steps)):
            move = self.moves[int(self._cdf.searchsorted(self.random.random_sample(), side="right"))]
            state, accepted = move.propose(self.model, state)
            state.random_state = self.random.get_state()
            self.backend.save_step(state, accepted)
            yield state


def _schedule(moves):
    """``(moves, weights)`` from what :class:`emcee.EnsembleSampler` takes as ``moves``."""
    if isinstance(moves, emcee.moves.Move):
        return [moves], [1.0]
    moves = list(moves)
    if moves and all(isinstance(m, tuple) for m in moves):
        chosen, weights = zip(*moves)
        return list(chosen), list(weights)
    return moves, [1.0] * len(moves)
