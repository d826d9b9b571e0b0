"""The sampler coordinates of the GPI (identify.fitting.coordinates): an exact bijection,
the right Jacobian, and a move that leaves the posterior of the parameters invariant."""

import emcee
import numpy as np
import pytest

from identify.fitting.coordinates import CoordinateMove, GPICoordinates, IdentityCoordinates, coordinates_for
from identify.fitting.moves import DifferentialMove, SnookerMove


def _coords(**changes):
    kw, x = GPICoordinates.get_test_parameters()
    kw.update(changes)
    return GPICoordinates(**kw), x


def _numerical_log_det(coords, x0):
    """log |det du/dx| at ``x0`` by central differences of ``coords.forward``."""
    h = 1e-6 * np.maximum(np.abs(x0), 1e-3)
    jac = np.empty((x0.size, x0.size))
    for k in range(x0.size):
        up, down = x0.copy(), x0.copy()
        up[k] += h[k]
        down[k] -= h[k]
        jac[:, k] = (coords.forward(up)[0] - coords.forward(down)[0]) / (2 * h[k])
    return np.linalg.slogdet(jac)[1]


def _spread(x, rng, n, rel=0.1):
    return x * (1 + rel * rng.standard_normal((n, x.size)))


def test_all_blocks_in_use_for_the_normalised_gpi():
    coords, _ = _coords()
    assert coords.blocks == ("weights", "envelope_a", "envelope_b", "omega_c", "omega_d")


@pytest.mark.parametrize("alpha", [-0.1993, 0.1993, -1.3])
def test_round_trip_is_exact(alpha):
    kw, x = GPICoordinates.get_test_parameters()
    template = np.array(kw["template"], dtype=float)
    template[0] = alpha  # alpha is the first GPI parameter
    coords = GPICoordinates(**{**kw, "template": template})
    rng = np.random.default_rng(1)
    xs = _spread(x, rng, 200)
    xs[:, 1] = rng.uniform(-1, 1, 200)  # tau of either sign
    back = coords.inverse(coords.forward(xs))
    assert np.isfinite(back).all()
    np.testing.assert_allclose(back, xs, rtol=1e-12, atol=1e-12)


def test_round_trip_from_the_coordinates_side():
    coords, x = _coords()
    u = coords.forward(_spread(x, np.random.default_rng(2), 50))
    np.testing.assert_allclose(coords.forward(coords.inverse(u)), u, rtol=1e-12, atol=1e-12)


def test_log_det_matches_a_numerical_jacobian():
    coords, x = _coords()
    rng = np.random.default_rng(3)
    for x0 in _spread(x, rng, 5):
        assert coords.log_det(x0[None, :])[0] == pytest.approx(_numerical_log_det(coords, x0), abs=1e-6)


def test_points_outside_the_range_map_to_nan():
    coords, x = _coords()
    u = coords.forward(np.vstack([x, x, x]))
    u[0, 0] = -1.0  # a negative total weight
    u[1, 1] = 1e3 * u[1, 0]  # a threshold moment no tau in [-5, 5] gives
    back = coords.inverse(u)
    assert np.isnan(back[:2]).all() and np.isfinite(back[2]).all()


def test_blocks_with_pinned_or_unbounded_parameters_are_left_alone():
    kw, x = GPICoordinates.get_test_parameters()
    names = list(kw["names"])
    keep = [i for i, n in enumerate(names) if n not in ("tau", "a2")]
    lower = np.array(kw["lower"])[keep]
    lower[[names[i] for i in keep].index("c1")] = -50.0  # c1 may change sign: no log
    coords = GPICoordinates(**{**kw, "names": [names[i] for i in keep], "lower": lower})
    assert coords.blocks == ("envelope_b", "omega_d")
    xs = _spread(x[keep], np.random.default_rng(4), 20)
    np.testing.assert_allclose(coords.inverse(coords.forward(xs)), xs, rtol=1e-12)


@pytest.mark.parametrize(
    "a0, a1, centre, three_values",
    [
        (90.0, 0.45, -2.9, True),  # the record sees the tanh's tail: its centre below the 0-5 A input
        (90.0, 0.45, 7.5, True),  # ... above it
        (50.0, 0.02, 2.5, True),  # a near-straight piece: a small slope, a large amplitude
        (3.0, 1.0, 1.5, True),
        (3.0, 8.0, 2.5, False),  # a step sharper than the points' spacing: flat at the outer inputs
        (3.0, 2.0, 7.0, False),  # nearly constant over the input range (the tanh flat at every input)
    ],
)
def test_envelopes_round_trip_in_every_regime(a0, a1, centre, three_values):
    kw, x = GPICoordinates.get_test_parameters()
    names = kw["names"]
    row = x.copy()
    row[names.index("a0")], row[names.index("a1")], row[names.index("a2")] = a0, a1, -a1 * centre
    coords = GPICoordinates(**kw, reference=row)
    assert ("envelope_a" in coords.three_values) is three_values
    assert "envelope_a" in coords.blocks
    back = coords.inverse(coords.forward(row))[0]
    np.testing.assert_allclose(back, row, rtol=1e-9, atol=1e-9)
    assert coords.log_det(row[None, :])[0] == pytest.approx(_numerical_log_det(coords, row), abs=1e-5)


def test_without_a_reference_every_envelope_takes_three_values():
    coords, _ = _coords()
    assert coords.three_values == ("envelope_a", "envelope_b")


def test_envelope_values_no_increasing_tanh_passes_through_map_to_nan():
    coords, x = _coords()
    names = GPICoordinates.get_test_parameters()[0]["names"]
    u = coords.forward(np.vstack([x, x, x]))
    e1, em, e2 = (names.index(n) for n in ("a0", "a1", "a3"))  # the rising envelope's three values
    total_weight, amplitude = u[1, names.index("rho")], np.exp(u[1, names.index("a2")])
    u[0, em] = u[0, e1] - 1.0  # falls from the first value to the middle one
    u[1, e2] = u[1, e1] + 2.5 * total_weight * amplitude  # rises by more than the tanh's 2 a0
    back = coords.inverse(u)
    assert np.isnan(back[:2]).all() and np.isfinite(back[2]).all()


def test_registry():
    class NoModel:
        pass

    assert isinstance(coordinates_for("gpi", NoModel()), IdentityCoordinates)
    assert isinstance(coordinates_for("identity", None), IdentityCoordinates)
    assert coordinates_for(lambda lp: "mine", None) == "mine"
    with pytest.raises(ValueError, match="unknown sampler coordinates 'polar'"):
        coordinates_for("polar", None)


def _sample_gaussian_in_parameters(jacobian=True, steps=3000, seed=5):
    """emcee with the coordinate move on a Gaussian *in the parameters* (sd 15 %)."""
    coords, x = _coords()
    sd = 0.15 * np.abs(x)

    def log_prob(xs):
        return -0.5 * (((xs - x) / sd) ** 2).sum(axis=1)

    class NoJacobian(GPICoordinates):
        def log_det(self, xs):
            return np.zeros(np.atleast_2d(xs).shape[0])

    if not jacobian:
        kw, _ = GPICoordinates.get_test_parameters()
        coords = NoJacobian(**kw)
    moves = [(CoordinateMove(emcee.moves.DEMove(), coords), 0.8), (CoordinateMove(SnookerMove(), coords), 0.2)]
    rng = np.random.default_rng(seed)
    sampler = emcee.EnsembleSampler(40, x.size, log_prob, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()
    sampler.run_mcmc(x + 0.1 * sd * rng.standard_normal((40, x.size)), steps, progress=False)
    draws = sampler.get_chain(discard=1000, flat=True)
    return draws, x, sd


def test_the_move_leaves_the_parameter_posterior_invariant():
    draws, x, sd = _sample_gaussian_in_parameters()
    z = (draws.mean(axis=0) - x) / sd
    assert np.abs(z).max() < 0.15  # means within ~3 Monte Carlo errors (ESS ~ 2000)
    ratio = draws.std(axis=0) / sd
    assert 0.9 < ratio.min() and ratio.max() < 1.1


def test_without_the_jacobian_the_same_move_samples_the_wrong_distribution():
    """The check above can fail: dropping the Jacobian factor biases the scale parameters."""
    draws, x, sd = _sample_gaussian_in_parameters(jacobian=False)
    z = (draws.mean(axis=0) - x) / sd
    ratio = draws.std(axis=0) / sd
    assert np.abs(z).max() > 0.3 or ratio.min() < 0.85 or ratio.max() > 1.15


def _thermal_coords():
    from model import Model

    kw, x = GPICoordinates.get_test_parameters()
    model = Model(["thermal"])
    thermal = {
        "thermal_tau": 20.0,
        "thermal_sensitivity": 0.08,
        "thermal_expansion": 3.0,
        "thermal_tau_core": 300.0,
        "thermal_sensitivity_core": 0.01,
        "thermal_expansion_core": -0.5,
    }
    names = list(kw["names"]) + list(thermal)
    lower = np.concatenate([kw["lower"], [model.parameters[n].lower for n in thermal]])
    coords = GPICoordinates(**{**kw, "names": names, "lower": lower}, duration=70.0)
    return coords, np.concatenate([x, list(thermal.values())])


def test_thermal_nodes_are_blocks_round_trip_and_jacobian():
    coords, x = _thermal_coords()
    assert coords.blocks[-2:] == ("thermal", "thermal_core")
    rng = np.random.default_rng(6)
    xs = _spread(x, rng, 100, rel=0.3)
    xs[:, -6] = np.abs(xs[:, -6])
    xs[:, -3] = np.exp(rng.uniform(0, np.log(5000), 100))  # node-2 time constants from 1 s to 5000 s
    np.testing.assert_allclose(coords.inverse(coords.forward(xs)), xs, rtol=1e-12, atol=1e-12)
    assert coords.log_det(xs[:1])[0] == pytest.approx(_numerical_log_det(coords, xs[0]), abs=1e-5)


def test_no_thermal_blocks_without_the_record_duration():
    _, x = _thermal_coords()
    kw, _ = GPICoordinates.get_test_parameters()
    coords, _ = _thermal_coords()
    assert (
        "thermal"
        not in GPICoordinates(**{**kw, "names": coords.names, "lower": np.zeros(len(coords.names)) + 1e-3}).blocks
    )


def test_the_move_gives_emcees_stock_chain_bit_for_bit():
    """CoordinateMove.propose keeps the ensemble's coordinates between calls and accepts in
    one vectorised test: the chain is the one emcee's own RedBlueMove.propose gives."""

    class Stock(CoordinateMove):
        def propose(self, model, state):
            return emcee.moves.RedBlueMove.propose(self, model, state)

    coords, x = _coords()
    sd = 0.15 * np.abs(x)

    def log_prob(xs):
        return -0.5 * (((xs - x) / sd) ** 2).sum(axis=1)

    chains = []
    for kind in (CoordinateMove, Stock):
        moves = [(kind(emcee.moves.DEMove(), coords), 0.8), (kind(SnookerMove(), coords), 0.2)]
        sampler = emcee.EnsembleSampler(40, x.size, log_prob, vectorize=True, moves=moves)
        sampler.random_state = np.random.RandomState(7).get_state()
        start = x + 0.1 * sd * np.random.default_rng(7).standard_normal((40, x.size))
        sampler.run_mcmc(start, 300, progress=False)
        chains.append((sampler.get_chain(), sampler.get_log_prob(), sampler.acceptance_fraction))
    for new, stock in zip(*chains):
        np.testing.assert_array_equal(new, stock)


@pytest.mark.parametrize("in_coordinates", [False, True])
def test_the_differential_move_gives_emcees_demove_chain_bit_for_bit(in_coordinates):
    """DifferentialMove draws what emcee's DEMove draws and proposes what it proposes."""
    coords, x = _coords()
    sd = 0.15 * np.abs(x)

    def log_prob(xs):
        return -0.5 * (((xs - x) / sd) ** 2).sum(axis=1)

    chains = []
    for kind in (DifferentialMove, emcee.moves.DEMove):
        move = CoordinateMove(kind(), coords) if in_coordinates else kind()
        sampler = emcee.EnsembleSampler(40, x.size, log_prob, vectorize=True, moves=[(move, 0.8), (SnookerMove(), 0.2)])
        sampler.random_state = np.random.RandomState(3).get_state()
        start = x + 0.1 * sd * np.random.default_rng(3).standard_normal((40, x.size))
        sampler.run_mcmc(start, 200, progress=False)
        chains.append((sampler.get_chain(), sampler.get_log_prob(), sampler.acceptance_fraction))
    assert chains[0][2].mean() > 0.05  # the walkers moved
    for new, stock in zip(*chains):
        np.testing.assert_array_equal(new, stock)


def test_the_compiled_way_back_is_the_inverse_and_log_det():
    """``GPICoordinates.back`` (one compiled pass, each solve started from its walker) gives what
    the map's ``inverse`` and ``log_det`` give step by step (started afresh), to the solves'
    tolerance; rows outside the map's range and non-finite factors exactly so."""
    from identify.fitting.coordinates import back_in_steps

    coords, x = _coords()
    rng = np.random.default_rng(8)
    s = _spread(x, rng, 12)
    u = coords.forward(s)
    q_u = u + 0.2 * (u[rng.permutation(12)] - u)
    q_u[2, coords.names.index("rho")] = -1.0  # total weight <= 0: outside the map's range
    factors = rng.normal(size=12)
    factors[4] = -np.inf
    log_det_s = coords.log_det(s)
    fused = coords.back(s, q_u, factors, log_det_s)
    steps = back_in_steps(coords, s, q_u, factors, log_det_s)
    for a, b in zip(fused, steps):
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
    assert fused[1][2] == -np.inf and fused[1][4] == -np.inf and np.array_equal(fused[0][2], s[2])
    assert np.isfinite(fused[1][[0, 1, 3, 5]]).all()


def test_the_snooker_proposal_is_ter_braak_and_vrugts_update():
    """The compiled arithmetic of ``SnookerMove.get_proposal``: ``x + gamma e e^T (z1 - z2)`` with
    ``e = (x - z)/|x - z|`` and the factor ``(d - 1) log(|x' - z| / |x - z|)``, ``z, z1, z2`` one
    walker from each other split in a random order (the same draws as the array code)."""
    rng = np.random.default_rng(2)
    s = rng.normal(size=(7, 5))
    c = [rng.normal(size=(7, 5)) + j for j in range(3)]
    move = SnookerMove()
    proposal, log_factor = move.get_proposal(s, c, np.random.RandomState(4))
    random = np.random.RandomState(4)
    picks = np.stack([c[j][random.randint(7, size=7)] for j in range(3)], axis=1)
    roles = np.argsort(random.uniform(size=(7, 3)), axis=1)
    for i in range(7):
        z, z1, z2 = picks[i, roles[i]]
        e = (s[i] - z) / np.linalg.norm(s[i] - z)
        expected = s[i] + move.gammas * e * (e @ (z1 - z2))
        np.testing.assert_allclose(proposal[i], expected, rtol=1e-13, atol=1e-13)
        ratio = np.linalg.norm(expected - z) / np.linalg.norm(s[i] - z)
        assert log_factor[i] == pytest.approx(4.0 * np.log(ratio), abs=1e-12)
