"""The package's ensemble loop against emcee's: the same chain, bit for bit, and emcee's refusals."""

from __future__ import annotations

import emcee
import numpy as np
import pytest

from identify.fitting.coordinates import CoordinateMove
from identify.fitting.ensemble import EnsembleLoop
from identify.fitting.moves import MOVES, DifferentialMove


class Correlated:
    """A 4-D correlated normal log-density, all rows at once; ``vectorised`` says so to the moves."""

    def __init__(self, vectorised):
        rng = np.random.default_rng(5)
        a = rng.normal(size=(4, 4))
        self.precision = np.linalg.inv(a @ a.T + np.eye(4))
        self.vectorised_log_probability = vectorised

    def __call__(self, x):
        x = np.atleast_2d(x)
        return -0.5 * np.einsum("ij,jk,ik->i", x, self.precision, x)


class Affine:
    """Sampler coordinates u = 2 x + 1 (a constant log-determinant)."""

    def forward(self, x):
        return 2.0 * np.asarray(x, dtype=float) + 1.0

    def inverse(self, u):
        return (np.asarray(u, dtype=float) - 1.0) / 2.0

    def log_det(self, x):
        return np.full(np.shape(x)[0], 4 * np.log(2.0))


SCHEDULES = {
    "stretch": lambda: emcee.moves.StretchMove(),
    "de": MOVES["de"],
    "de in other coordinates": lambda: [(CoordinateMove(m, Affine()), w) for m, w in MOVES["de"]()],
    "unweighted list": lambda: [DifferentialMove(), emcee.moves.StretchMove()],
}


def _start(n_walkers=16, seed=2):
    coords = np.random.default_rng(seed).normal(size=(n_walkers, 4))
    return emcee.State(coords, random_state=np.random.RandomState(11).get_state())


def _emcee_chain(schedule, log_prob, steps):
    sampler = emcee.EnsembleSampler(16, 4, log_prob, vectorize=True, moves=SCHEDULES[schedule]())
    state = sampler.run_mcmc(_start(), steps)
    return sampler.get_chain(), sampler.get_log_prob(), sampler.backend.accepted, state.random_state


def _loop_chain(schedule, log_prob, steps, chunks=1):
    backend = emcee.backends.Backend()
    backend.reset(16, 4)
    loop = EnsembleLoop(log_prob, 16, 4, SCHEDULES[schedule](), backend, np.random.RandomState(0))
    backend.grow(steps, None)
    state = loop.start(_start())
    for _ in range(chunks):
        *_, state = loop.steps(state, steps // chunks)
    return backend.get_chain(), backend.get_log_prob(), backend.accepted, state.random_state


@pytest.mark.parametrize("schedule", sorted(SCHEDULES))
@pytest.mark.parametrize("vectorised", [True, False])
def test_the_loop_draws_emcees_chain_bit_for_bit(schedule, vectorised):
    steps = 60
    ours = _loop_chain(schedule, Correlated(vectorised), steps, chunks=3)
    stock = _emcee_chain(schedule, Correlated(vectorised), steps)
    assert ours[0].shape == (steps, 16, 4)
    assert np.array_equal(ours[0], stock[0]) and np.array_equal(ours[1], stock[1])
    assert np.array_equal(ours[2], stock[2]) and ours[2].sum() > 0  # some proposals accepted
    assert all(np.array_equal(a, b) for a, b in zip(ours[3], stock[3]))  # the generator ends in the same state


def _loop(log_prob=None):
    backend = emcee.backends.Backend()
    backend.reset(16, 4)
    return EnsembleLoop(log_prob or Correlated(True), 16, 4, MOVES["de"](), backend, np.random.RandomState(0))


def test_the_start_is_refused_as_emcee_refuses_it():
    with pytest.raises(ValueError, match="incompatible input dimensions"):
        _loop().start(np.zeros((8, 4)))
    with pytest.raises(ValueError, match="large condition number"):
        _loop().start(np.ones((16, 4)))
    _loop().start(np.ones((16, 4)) + 1e-300, check_independence=False)  # a resumed run's walkers are not checked
    with pytest.raises(ValueError, match="returned NaN"):
        _loop(lambda x: np.full(len(x), np.nan)).start(_start())
    with pytest.raises(ValueError, match="initial log_prob was NaN"):
        _loop().start(emcee.State(_start().coords, log_prob=np.full(16, np.nan)))
    with pytest.raises(ValueError, match="shape"):
        _loop(lambda x: np.zeros(len(x) + 1)).start(_start())


def test_a_nan_from_the_log_probability_inside_a_step_is_refused():
    calls = []

    def log_prob(x):
        calls.append(len(x))
        return np.zeros(len(x)) if len(calls) == 1 else np.full(len(x), np.nan)

    loop = _loop(log_prob)
    loop.moves = [emcee.moves.StretchMove()]  # the stock move: emcee's checked log-probability
    state = loop.start(_start())
    with pytest.raises(ValueError, match="returned NaN"):
        next(loop.steps(state, 1))
