"""The fast GPI kernel against the scalar oracle, its properties, its errors, and the paper's input.

Tolerances
----------
Model and oracle do the same arithmetic in a possibly different order and with
possibly different ``tanh``/``exp`` implementations (numba's vs :mod:`math`), so they
may differ by a few ulp of the largest term. We compare to ``1e-9 * scale`` with
``scale = 1 + max_k (|Omega_k| + sum_j |p_j z_j(t_k)|)``, the magnitude of the terms
summed: a rounding difference is ~1e-15 of that, while any real error in a branch, a
bound or an operator moves the output by a sizeable fraction of a term.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import classical_pi_reference, gpi_reference

from model import TABLE1, THETA_NAMES, bound_overlap, classical_pi, envelope, gpi, paper_current
from model.gpi import distinct_rows, gpi_grouped
from model.signals import QUIET_SECONDS

N_OPERATORS = 12
A_SLICE, B_SLICE, C_SLICE, D_SLICE = slice(3, 7), slice(7, 11), slice(11, 15), slice(15, 19)
#: Every input of the property tests lies in [0, 5] A. Bounds kept apart by >= 0.01 on this
#: grid stay apart in between: 2.5e-4 A spacing times envelope slopes below 40 /A.
DENSE_0_TO_5_AMPERES = np.linspace(0.0, 5.0, 20001)
FAST_SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ----------------------------------------------------------------------------- helpers


def oracle_scale(reference):
    """``1 + max_k (|Omega_k| + sum_j |p_j z_j|)``: the magnitude of the summed terms."""
    p = np.abs(np.asarray(reference.weights))
    z = np.abs(np.asarray(reference.memory))
    return 1.0 + float(np.max(np.abs(reference.omega) + z @ p))


def assert_matches_oracle(theta, current, **options):
    """gpi(theta, current) equals the oracle row by row to ``1e-9 * scale``."""
    fast = np.atleast_2d(gpi(theta, current, **options))
    theta2 = np.atleast_2d(theta)
    current2 = np.atleast_2d(current)
    initial = np.broadcast_to(np.asarray(options.pop("initial_memory", 0.0), float), (theta2.shape[0],))
    scale = options.pop("threshold_scale", None)
    scale2 = None if scale is None else np.atleast_2d(scale)
    for w in range(theta2.shape[0]):
        row = current2[w if current2.shape[0] > 1 else 0]
        if scale2 is not None:
            options["threshold_scale"] = scale2[w if scale2.shape[0] > 1 else 0]
        reference = gpi_reference(theta2[w], row, initial_memory=initial[w], **options)
        np.testing.assert_allclose(fast[w], reference.output, rtol=0, atol=1e-9 * oracle_scale(reference))


def max_bound_excess(theta, current, n_operators=N_OPERATORS):
    """``max_k (rising(v_k) - falling(v_k)) - 2 min_j r_j`` in the swapped reading (> 0: bounds cross)."""
    rising = envelope(theta[A_SLICE], current)
    falling = envelope(theta[B_SLICE], current)
    min_threshold = min(theta[0] * 1, theta[0] * n_operators)
    return float(np.max(rising - falling) - 2.0 * min_threshold)


def perturbed_table1(rng, relative_spread, current, margin=0.01):
    """Table 1 with every entry scaled by ``1 + relative_spread * N(0, 1)``, kept well defined.

    Envelope amplitudes and slopes stay positive (increasing envelopes), alpha keeps its
    printed (negative) sign, and when the perturbed bounds would cross on ``current`` the
    falling offset ``b3`` is raised just enough (plus ``margin``) that they do not.
    """
    theta = TABLE1 * (1.0 + relative_spread * rng.standard_normal(TABLE1.size))
    for name in ("a0", "a1", "b0", "b1", "rho"):
        i = THETA_NAMES.index(name)
        theta[i] = abs(theta[i])
    theta[0] = -abs(theta[0])
    excess = max_bound_excess(theta, current)
    if excess > -margin:
        theta[THETA_NAMES.index("b3")] += excess + margin
    assert max_bound_excess(theta, current) < 0
    return theta


def noisy_current(rng, n_samples, low=0.0, high=5.0):
    """Independent uniform samples: a reversal at almost every sample."""
    return rng.uniform(low, high, n_samples)


def current_with_flats(rng, n_samples):
    """A random walk quantised to 0.25 A and held: long runs of equal samples."""
    steps = rng.choice([-0.25, 0.0, 0.0, 0.0, 0.25], n_samples)
    level = np.clip(2.5 + np.cumsum(steps), 0.0, 5.0)
    return np.repeat(level, 3)[:n_samples]


@pytest.fixture(scope="module")
def paper_input():
    return paper_current(100.0, "literal")[1]


# ----------------------------------------------------------------------------- exactness against the oracle


@pytest.mark.parametrize("reading", ["swapped", "literal"])
@pytest.mark.parametrize("input_reading", ["literal", "centred"])
def test_table1_on_paper_input_matches_oracle(reading, input_reading):
    _, current = paper_current(100.0, input_reading)
    assert_matches_oracle(TABLE1, current, reading=reading)


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_random_perturbations_of_table1_match_oracle(reading, paper_input):
    rng = np.random.default_rng(20240501)
    current = paper_input[::7]  # 1001 samples, same shape of drive
    for _ in range(6):
        theta = perturbed_table1(rng, 0.15, current)
        assert_matches_oracle(theta, current, reading=reading)


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_noisy_input_with_many_reversals_matches_oracle(reading):
    rng = np.random.default_rng(7)
    current = noisy_current(rng, 3000)
    assert np.count_nonzero(np.diff(np.sign(np.diff(current)))) > 1500  # really many reversals
    assert_matches_oracle(TABLE1, current, reading=reading)
    assert_matches_oracle(perturbed_table1(rng, 0.1, current), current, reading=reading)


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_input_with_flat_stretches_matches_oracle(reading):
    rng = np.random.default_rng(11)
    current = current_with_flats(rng, 3000)
    assert np.count_nonzero(np.diff(current) == 0.0) > 1500
    assert_matches_oracle(TABLE1, current, reading=reading)
    assert_matches_oracle(perturbed_table1(rng, 0.1, current), current, reading=reading)


@pytest.mark.parametrize("n_operators", [1, 3, 12, 40])
def test_operator_counts_match_oracle(n_operators):
    rng = np.random.default_rng(n_operators)
    current = noisy_current(rng, 400, 0.0, 4.0)
    theta = TABLE1.copy()
    theta[0] = -0.05  # smaller step so that 40 operators still keep their bounds apart
    assert_matches_oracle(theta, current, n_operators=n_operators)


def test_batch_with_shared_current_matches_oracle_and_single_calls(paper_input):
    rng = np.random.default_rng(3)
    current = paper_input[::5]
    thetas = np.stack([perturbed_table1(rng, 0.1, current) for _ in range(5)])
    assert_matches_oracle(thetas, current)
    batch = gpi(thetas, current)
    assert batch.shape == (5, current.size)
    for w in range(5):
        np.testing.assert_array_equal(batch[w], gpi(thetas[w], current))


def test_batch_with_per_row_current_matches_oracle():
    rng = np.random.default_rng(5)
    currents = np.stack([noisy_current(rng, 500), current_with_flats(rng, 500), noisy_current(rng, 500, 1.0, 4.0)])
    thetas = np.stack([perturbed_table1(rng, 0.1, currents.ravel()) for _ in range(3)])
    assert_matches_oracle(thetas, currents)
    out = gpi(thetas, currents)
    assert out.shape == (3, 500)
    for w in range(3):  # each row sees its own input, not row 0's
        np.testing.assert_array_equal(out[w], gpi(thetas[w], currents[w]))


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_initial_excursion_is_the_memory_of_a_prior_path(reading, paper_input):
    """``initial_excursion = e`` starts the record from the memory the oracle reaches along the
    path v0 -> v0 + e -> v0 (prepended to the input); from the record's first motion on the
    outputs agree (before it, Omega's branch is the record's convention, rising, where the
    oracle keeps the prior path's last one)."""
    current = paper_input[::10]
    v0 = float(current[0])
    thetas = np.tile(TABLE1, (5, 1))
    thetas[3, 0] = -0.3  # negative thresholds: bounds cross
    excursions = np.array([2.0, -1.5, 0.4, 3.0, -4.0])
    levels = np.array([0.0, 3.0, -40.0, 0.0, 10.0])
    fast = gpi(thetas, current, reading=reading, initial_memory=levels, initial_excursion=excursions)
    for w in range(len(thetas)):
        path = np.r_[v0, v0 + excursions[w], current]
        reference = gpi_reference(thetas[w], path, reading=reading, initial_memory=levels[w])
        moved = int(np.flatnonzero(np.diff(current) != 0)[0]) + 1
        np.testing.assert_allclose(
            fast[w, moved:], reference.output[2 + moved :], rtol=0, atol=1e-9 * oracle_scale(reference)
        )
        assert np.array_equal(
            fast[w], gpi(thetas[w], current, reading=reading, initial_memory=levels[w], initial_excursion=excursions[w])
        )
    # the excursion is seen: the raised trace persists in the wide operators
    plain = gpi(thetas[0], current, reading=reading)
    assert np.max(np.abs(fast[0] - plain)) > 1e-3 * np.ptp(plain)
    # 0 is exactly no excursion
    assert np.array_equal(
        gpi(thetas, current, reading=reading, initial_memory=levels, initial_excursion=0.0),
        gpi(thetas, current, reading=reading, initial_memory=levels),
    )


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_initial_held_memory_matches_oracle_and_is_kept_until_a_motion_against_it(reading, paper_input):
    """``initial_held`` (a memory beyond the bounds, added after the clamp) against the oracle,
    per set and per operator; 0 is exactly none; a memory held above the upper bounds is
    kept at rest and until the rising bound passes it."""
    current = paper_input[::10]
    thetas = np.tile(TABLE1, (4, 1))
    thetas[2, 0] = -0.3  # negative thresholds: bounds cross
    width = np.arange(1, N_OPERATORS + 1) / N_OPERATORS
    held = np.array([0.5 + 0.0 * width, -0.3 + 0.8 * width, 2.0 - 1.5 * width, 0.0 * width])
    levels = np.array([0.0, 3.0, 0.0, -2.0])
    fast = gpi(thetas, current, reading=reading, initial_memory=levels, initial_held=held)
    for w in range(len(thetas)):
        reference = gpi_reference(thetas[w], current, reading=reading, initial_memory=levels[w], initial_held=held[w])
        np.testing.assert_allclose(fast[w], reference.output, rtol=0, atol=1e-9 * oracle_scale(reference))
        assert np.array_equal(
            fast[w], gpi(thetas[w], current, reading=reading, initial_memory=levels[w], initial_held=held[w])
        )
    assert np.array_equal(fast[3], gpi(thetas[3], current, reading=reading, initial_memory=levels[3]))
    assert np.array_equal(
        gpi(TABLE1, current, reading=reading, initial_held=np.zeros(N_OPERATORS)), gpi(TABLE1, current, reading=reading)
    )
    if reading == "swapped":  # Table 1: every memory 0.5 higher at rest, kept until a bound passes it
        plain = gpi(TABLE1, current)
        shift = fast[0] - plain
        weights = TABLE1[1] * np.exp(-TABLE1[2] * TABLE1[0] * np.arange(1, N_OPERATORS + 1))
        at_rest = np.flatnonzero(current == current[0])
        at_rest = at_rest[: np.argmax(np.diff(np.r_[at_rest, -1]) != 1) + 1]  # before the first motion
        np.testing.assert_allclose(shift[at_rest], 0.5 * weights.sum(), rtol=1e-9)
        first_peak = int(np.flatnonzero(np.diff(current) < 0)[0])
        rise = shift[at_rest[-1] : first_peak + 1]
        assert np.all(np.diff(rise) <= 1e-12) and rise[0] > rise[-1]  # the rising bounds overtake it, one by one
        assert np.all(np.abs(shift[first_peak:]) < 1e-9 * np.ptp(plain))  # and it never comes back


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_shared_sets_are_each_sets_own_response_bit_for_bit(reading):
    """A finite-difference-shaped batch: each parameter alone perturbed, exact repeats, and
    Omega-only changes (computed once, or on a leader's memories) give every row its own
    single call's output, bit for bit, on an input with flat stretches (repeated samples),
    with per-set initial states and a per-set width; and they match the oracle."""
    rng = np.random.default_rng(11)
    current = current_with_flats(rng, 700)
    base = perturbed_table1(rng, 0.05, current)
    rows = np.repeat(base[None, :], 24, axis=0)
    for k in range(19):
        rows[k + 1, k] *= 1.0 + 1e-7
    rows[20] = rows[0]  # an exact repeat
    rows[21] = rows[12]  # a repeat of an Omega-only change
    rows[22, C_SLICE] *= 1.2  # both Omega branches changed
    rows[22, D_SLICE] *= 0.9
    rows[23, 3] *= 1.01  # a play parameter: a leader of its own
    levels = np.where(np.arange(24) % 7 == 3, 2.0, 0.0)  # rows 3, 10, 17 start elsewhere: not shared
    width = 1.0 + 0.2 * np.exp(-np.arange(current.size) / 200.0)
    widths = np.repeat(width[None, :], 24, axis=0)
    widths[5] = 1.0  # its own width: not shared
    held = np.zeros((24, N_OPERATORS))
    held[[2, 9, 16]] = 0.4  # start beyond the bounds: not shared with rows that do not
    for options in (
        {},
        {"initial_memory": levels, "initial_excursion": 0.7},
        {"threshold_scale": widths},
        {"initial_held": held},
    ):
        batch = gpi(rows, current, reading=reading, **options)
        for w in range(24):
            one = {k: (v[w] if isinstance(v, np.ndarray) else v) for k, v in options.items()}
            assert np.array_equal(batch[w], gpi(rows[w], current, reading=reading, **one)), (options.keys(), w)
    assert_matches_oracle(rows, current, reading=reading)
    assert not np.array_equal(batch[22], batch[0])  # the shared rows are not copies of their leader
    assert np.array_equal(batch[20], batch[0]) and np.array_equal(batch[21], batch[12])


def test_distinct_rows_groups_by_value_in_order_of_first_appearance():
    a = np.array([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0], [1.0, -2.0], [3.0, 4.0]])
    first, group = distinct_rows(a, np.array([0, 0, 0, 0, 1]))
    assert first.tolist() == [0, 1, 3, 4] and group.tolist() == [0, 1, 0, 2, 3]
    first, group = distinct_rows(np.array([0.0, -0.0]))  # bit for bit: -0.0 is its own row
    assert first.tolist() == [0, 1]
    assert [x.tolist() for x in distinct_rows(a[:1])] == [[0], [0]]


def test_gpi_grouped_equals_gpi_on_the_rows_it_names(paper_input):
    current = paper_input[::10]
    drives = np.stack([current, 0.9 * current, current + 0.1])
    row_of = np.array([2, 0, 0, 1, 2])
    thetas = np.tile(TABLE1, (5, 1))
    thetas[2, 12] *= 1.1
    widths = np.stack([np.ones_like(current), 1.1 * np.ones_like(current), np.linspace(1.0, 1.3, current.size)])
    out, inverse = gpi_grouped(thetas, drives, row_of, initial_memory=0.5, threshold_scale=widths)
    expected = gpi(thetas, drives[row_of], initial_memory=0.5, threshold_scale=widths[row_of])
    assert np.array_equal(out[inverse], expected)
    assert out.shape[0] == 4 and inverse[4] == inverse[0]  # sets 0 and 4 are the same set on the same drive
    for bad, message in (({"row_of": [0, 1, 3, 0, 0]}, "row_of"), ({"row_of": [0, 1]}, "row_of")):
        with pytest.raises(ValueError, match=message):
            gpi_grouped(thetas, drives, bad["row_of"])
    broken = drives.copy()
    broken[1, 4] = np.nan
    with pytest.raises(ValueError, match=r"current\[1, 4\]"):
        gpi_grouped(thetas, broken, row_of)


def test_single_theta_with_2d_current_returns_2d():
    current = np.linspace(0.0, 5.0, 50)[None, :]
    out = gpi(TABLE1, current)
    assert out.shape == (1, 50)
    np.testing.assert_array_equal(out[0], gpi(TABLE1, current[0]))


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_initial_memory_matches_oracle(reading, paper_input):
    current = paper_input[::10]
    for level in (-40.0, -3.0, 2.5, 40.0):
        assert_matches_oracle(TABLE1, current, reading=reading, initial_memory=level)
    thetas = np.tile(TABLE1, (4, 1))
    levels = np.array([-40.0, -3.0, 2.5, 40.0])
    assert_matches_oracle(thetas, current, reading=reading, initial_memory=levels)
    out = gpi(thetas, current, reading=reading, initial_memory=levels)
    if reading == "swapped":  # the initial state matters: the four rows differ at rest
        assert np.ptp(out[:, 0]) > 1.0
    else:  # crossing bounds: max(L, min(U, z0)) = L whatever z0 is
        assert np.ptp(out[:, 0]) == 0.0


@pytest.mark.parametrize("reading", ["swapped", "literal"])
def test_time_varying_thresholds_match_oracle(reading, paper_input):
    """A play width that changes over the record (thresholds r_j s_k, weights of eq. (8)):
    as the oracle, row by row; a factor 1 everywhere is the plain GPI bit for bit."""
    current = paper_input[::10]
    travel = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(current)))])
    narrowing = 1.0 + 0.4 * np.exp(-travel / 8.0)  # wider on the virgin cycles
    widening = 0.7 + 0.3 * travel / travel[-1]
    assert_matches_oracle(TABLE1, current, reading=reading, threshold_scale=narrowing)
    thetas = np.stack([TABLE1, np.array(TABLE1) * 1.03])
    assert_matches_oracle(thetas, current, reading=reading, threshold_scale=np.stack([narrowing, widening]))
    assert_matches_oracle(thetas, current, reading=reading, threshold_scale=widening)  # one row shared
    assert np.array_equal(
        gpi(TABLE1, current, reading=reading, threshold_scale=np.ones_like(current)),
        gpi(TABLE1, current, reading=reading),
    )
    assert (
        np.abs(
            gpi(TABLE1, current, reading=reading, threshold_scale=narrowing) - gpi(TABLE1, current, reading=reading)
        ).max()
        > 1.0
    )


def test_kernel_tanh_is_within_a_few_ulp_odd_and_monotone():
    """The kernel's exp-based tanh (model.gpi_kernels.fast_tanh) against math.tanh."""
    import math

    from numba import njit

    from model.gpi_kernels import fast_tanh

    @njit
    def kernel_tanh(x, out):
        for i in range(x.size):
            out[i] = fast_tanh(x[i])

    rng = np.random.default_rng(2)
    x = np.concatenate(
        [
            rng.uniform(-25.0, 25.0, 20000),
            np.logspace(-300, 2.5, 5000),
            0.5 + np.arange(-500, 500) * np.spacing(0.5),  # the switch between the two formulas
            [0.0, 1e308, 710.0, 19.1, 0.5],
        ]
    )
    x = np.concatenate([x, -x])
    fast = np.empty_like(x)
    kernel_tanh(x, fast)
    exact = np.array([math.tanh(value) for value in x])
    ulps = np.abs(fast - exact) / np.spacing(np.maximum(np.abs(exact), np.finfo(float).tiny))
    assert ulps.max() <= 4
    half = x.size // 2
    np.testing.assert_array_equal(fast[half:], -fast[:half])
    grid = np.sort(x)
    on_grid = np.empty_like(grid)
    kernel_tanh(grid, on_grid)
    assert np.all(np.diff(on_grid) >= 0)


# ----------------------------------------------------------------------------- regression pin of Table 1


def test_table1_response_pinned(paper_input):
    """Table 1 on the paper's input (100 Hz, literal input reading).

    Provenance: computed with model.gpi at commit 2433aa4 (issue 2) and reproduced
    independently by tests/reference.py to < 4e-13; tolerance 1e-9 um (rest) and
    1e-6 um (extrema), far below any change of the model's meaning.
    """
    swapped = gpi(TABLE1, paper_input)
    assert swapped[0] == pytest.approx(-0.5598355820, abs=1e-9)  # rest: "output is 0 when not energised"
    assert np.all(swapped[: int(QUIET_SECONDS * 100)] == swapped[0])  # nothing moves while the coils are off
    assert swapped.max() == pytest.approx(295.6989024, abs=1e-6)
    assert swapped.argmax() == 1501  # t = 15.01 s, first sample falling from the 5 A peak (d-branch)
    literal = gpi(TABLE1, paper_input, reading="literal")
    assert literal[0] == pytest.approx(217.0473429928, abs=1e-6)
    assert literal.min() == pytest.approx(-569.1818597213, abs=1e-6)
    assert literal.max() == pytest.approx(649.6448019228, abs=1e-6)


def test_table1_bound_margin_is_positive_but_small_on_0_to_5_amperes():
    """The docstring's evidence: smallest margin 0.0157 at 5 A for j = 12."""
    current = np.linspace(0.0, 5.0, 5001)
    margin = -max_bound_excess(TABLE1, current)
    assert margin == pytest.approx(0.0157, abs=5e-5)
    assert np.argmax(envelope(TABLE1[A_SLICE], current) - envelope(TABLE1[B_SLICE], current)) == current.size - 1


# ----------------------------------------------------------------------------- properties


values_0_to_5 = st.floats(0.0, 5.0, allow_nan=False, allow_infinity=False)


@FAST_SETTINGS
@given(
    first=st.floats(0.5, 4.5),
    history_a=st.lists(st.floats(0.5, 4.5), min_size=1, max_size=40),
    history_b=st.lists(st.floats(0.5, 4.5), min_size=1, max_size=40),
    top=st.floats(4.6, 5.0),
    bottom=st.floats(0.0, 0.4),
    tail=st.lists(values_0_to_5, min_size=1, max_size=40),
    seed=st.integers(0, 2**32 - 1),
)
def test_wiping_out_by_a_larger_excursion(first, history_a, history_b, top, bottom, tail, seed):
    """Two histories, then a common excursion above both maxima and below both minima:
    identical outputs from the excursion's minimum on (increasing envelopes, non-crossing
    bounds; both histories start at the same sample and initial memory)."""
    theta = perturbed_table1(np.random.default_rng(seed), 0.05, DENSE_0_TO_5_AMPERES)
    excursion_and_tail = [top, bottom, *tail]
    out_a = gpi(theta, [first, *history_a, *excursion_and_tail])
    out_b = gpi(theta, [first, *history_b, *excursion_and_tail])
    common = len(excursion_and_tail) - 1  # from `bottom` on
    np.testing.assert_array_equal(out_a[-common:], out_b[-common:])


def test_wiping_out_erases_a_real_difference():
    """A deterministic case where the histories do leave different states before the excursion."""
    history_a, history_b = [1.0, 4.0, 2.0], [1.0, 1.5, 3.5]
    excursion = [5.0, 0.0, 2.5, 3.0]
    out_a = gpi(TABLE1, history_a + excursion)
    out_b = gpi(TABLE1, history_b + excursion)
    # The state before the excursion differs: the same next input gives different outputs.
    assert abs(gpi(TABLE1, history_a + [3.0])[-1] - gpi(TABLE1, history_b + [3.0])[-1]) > 1.0
    np.testing.assert_array_equal(out_a[4:], out_b[4:])


@FAST_SETTINGS
@given(
    levels=st.lists(st.integers(0, 100), min_size=2, max_size=60),
    inserts=st.lists(st.integers(0, 4), min_size=59, max_size=59),
    reading=st.sampled_from(["swapped", "literal"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_rate_independence(levels, inserts, reading, seed):
    """Sampling the same piecewise-monotone input faster (extra points strictly inside each
    monotone segment, or repeats along a flat one) gives identical outputs at the original points."""
    current = np.asarray(levels) * 0.05  # 0.05 A grid: repeats (flats) are common
    theta = perturbed_table1(np.random.default_rng(seed), 0.05, DENSE_0_TO_5_AMPERES)
    refined, original_index = [current[0]], [0]
    for k in range(1, current.size):
        start, end = current[k - 1], current[k]
        for i in range(1, inserts[k - 1] + 1):
            refined.append(start + (end - start) * i / (inserts[k - 1] + 1))
        refined.append(end)
        original_index.append(len(refined) - 1)
    coarse = gpi(theta, current, reading=reading)
    fine = gpi(theta, np.asarray(refined), reading=reading)
    np.testing.assert_array_equal(fine[original_index], coarse)


@FAST_SETTINGS
@given(
    current=st.lists(values_0_to_5, min_size=2, max_size=120),
    seed=st.integers(0, 2**32 - 1),
    initial_memory=st.floats(-50.0, 50.0),
)
def test_output_bounded_by_envelopes(current, seed, initial_memory):
    """Every memory lies in [L_j, U_j] (oracle), so with positive weights
    Omega + sum p_j L_j <= y <= Omega + sum p_j U_j (fast model)."""
    current = np.asarray(current)
    theta = perturbed_table1(np.random.default_rng(seed), 0.1, DENSE_0_TO_5_AMPERES)
    reference = gpi_reference(theta, current, initial_memory=initial_memory)
    lower, upper, memory = (np.asarray(x) for x in (reference.lower, reference.upper, reference.memory))
    assert np.all(lower <= memory) and np.all(memory <= upper)

    y = gpi(theta, current, initial_memory=initial_memory)
    thresholds = theta[0] * np.arange(1, N_OPERATORS + 1)
    weights = theta[1] * np.exp(-theta[2] * thresholds)
    assert np.all(weights > 0)
    rising = envelope(theta[A_SLICE], current)
    falling = envelope(theta[B_SLICE], current)
    direction_up = np.ones(current.size, dtype=bool)  # Omega's branch: the input's last motion
    for k in range(1, current.size):
        step = current[k] - current[k - 1]
        direction_up[k] = step > 0 or (step == 0 and direction_up[k - 1])
    omega = np.where(direction_up, envelope(theta[C_SLICE], current), envelope(theta[D_SLICE], current))
    low = omega + weights.sum() * rising - weights @ thresholds
    high = omega + weights.sum() * falling + weights @ thresholds
    slack = 1e-9 * oracle_scale(reference)
    assert np.all(low - slack <= y) and np.all(y <= high + slack)


@FAST_SETTINGS
@given(
    current=st.lists(values_0_to_5, min_size=2, max_size=150),
    seed=st.integers(0, 2**32 - 1),
    initial_memory=st.floats(-20.0, 20.0),
)
def test_piecewise_law_equals_clamp_form(current, seed, initial_memory):
    """Increasing envelopes and non-crossing bounds: eq. (5) == max(L, min(U, z)) exactly."""
    theta = perturbed_table1(np.random.default_rng(seed), 0.2, DENSE_0_TO_5_AMPERES)
    piecewise = gpi_reference(theta, current, initial_memory=initial_memory, law="piecewise")
    clamp = gpi_reference(theta, current, initial_memory=initial_memory, law="clamp")
    assert piecewise.memory == clamp.memory
    assert piecewise.output == clamp.output


def test_piecewise_and_clamp_differ_when_bounds_cross():
    """Control for the test above: with crossing bounds (literal reading of Table 1) the two laws differ."""
    current = np.concatenate([np.linspace(0, 5, 50), np.linspace(5, 0, 50)])
    piecewise = gpi_reference(TABLE1, current, reading="literal", law="piecewise")
    clamp = gpi_reference(TABLE1, current, reading="literal", law="clamp")
    assert piecewise.bounds_cross
    assert np.max(np.abs(np.subtract(piecewise.output, clamp.output))) > 1.0


# ----------------------------------------------------------------------------- reduction to the classical PI


def identity_limit_theta(alpha, rho, tau, linear_gain, eps):
    """GPI parameters whose envelopes are ~identity and whose Omega is ~``linear_gain * v``.

    ``(1/eps) tanh(eps v) -> v`` and ``(q/eps) tanh(eps v) -> q v`` as ``eps -> 0``.
    """
    identity = [1.0 / eps, eps, 0.0, 0.0]
    linear = [linear_gain / eps, eps, 0.0, 0.0]
    return np.array([alpha, rho, tau, *identity, *identity, *linear, *linear])


@FAST_SETTINGS
@given(
    current=st.lists(st.floats(-5.0, 5.0), min_size=2, max_size=150),
    alpha=st.floats(0.01, 1.0),
    rho=st.floats(0.1, 3.0),
    tau=st.floats(-1.0, 1.0),
    linear_gain=st.floats(-3.0, 3.0),
)
def test_gpi_reduces_to_classical_pi(current, alpha, rho, tau, linear_gain):
    """Tolerance: |(1/eps) tanh(eps v) - v| <= eps^2 |v|^3 / 3 (Taylor, alternating series)
    plus a few ulp; each play is 1-Lipschitz in its bounds, so every memory is off by at
    most that envelope error, and the output by (sum_j p_j + |q|) times it."""
    eps = 1e-5
    current = np.asarray(current)
    theta = identity_limit_theta(alpha, rho, tau, linear_gain, eps)
    thresholds = alpha * np.arange(1, N_OPERATORS + 1)
    weights = rho * np.exp(-tau * thresholds)
    v_max = np.max(np.abs(current))
    envelope_error = eps**2 * v_max**3 / 3 + 1e-14 * (1 + v_max)
    tolerance = (weights.sum() + abs(linear_gain)) * envelope_error + 1e-12 * (
        1 + weights.sum() * (v_max + thresholds[-1])
    )
    y_gpi = gpi(theta, current)
    y_pi = classical_pi(current, thresholds, weights, linear_gain=linear_gain)
    np.testing.assert_allclose(y_gpi, y_pi, rtol=0, atol=tolerance)


def test_reduction_tolerance_is_not_vacuous():
    """Away from the limit (eps = 0.3) the same comparison fails clearly."""
    current = np.concatenate([np.linspace(0, 5, 30), np.linspace(5, -5, 60), np.linspace(-5, 2, 40)])
    thresholds = 0.4 * np.arange(1, N_OPERATORS + 1)
    weights = 1.0 * np.exp(-0.2 * thresholds)
    near = gpi(identity_limit_theta(0.4, 1.0, 0.2, 1.5, 1e-5), current)
    far = gpi(identity_limit_theta(0.4, 1.0, 0.2, 1.5, 0.3), current)
    exact = classical_pi(current, thresholds, weights, linear_gain=1.5)
    assert np.max(np.abs(near - exact)) < 1e-6
    assert np.max(np.abs(far - exact)) > 1.0


@FAST_SETTINGS
@given(
    current=st.lists(st.floats(-10.0, 10.0), min_size=2, max_size=150),
    thresholds=st.lists(st.floats(0.0, 5.0), min_size=1, max_size=8),
    linear_gain=st.floats(-2.0, 2.0),
    initial=st.floats(-10.0, 10.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_classical_pi_matches_its_oracle(current, thresholds, linear_gain, initial, seed):
    weights = np.random.default_rng(seed).uniform(0.0, 2.0, len(thresholds))
    fast = classical_pi(current, thresholds, weights, linear_gain=linear_gain, initial=initial)
    slow = classical_pi_reference(current, thresholds, weights, linear_gain=linear_gain, initial=initial)
    scale = 1.0 + np.sum(weights) * (10.0 + max(thresholds) + abs(initial)) + abs(linear_gain) * 10.0
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12 * scale)


# ----------------------------------------------------------------------------- bad input


CURRENT = np.linspace(0.0, 5.0, 20)


def _with(index, value, theta=TABLE1):
    theta = np.array(theta, dtype=float)
    theta[index] = value
    return theta


@pytest.mark.parametrize(
    "theta, current, options, message",
    [
        (_with(4, np.nan), CURRENT, {}, r"theta has a non-finite value at theta\[4\] \(a1 = nan\)"),
        (_with(0, np.inf), CURRENT, {}, r"non-finite value at theta\[0\] \(alpha = inf\)"),
        (np.stack([TABLE1, _with(18, -np.inf)]), CURRENT, {}, r"non-finite value at theta\[1, 18\] \(d3"),
        (TABLE1, _with(3, np.nan, CURRENT), {}, r"current has a non-finite value at current\[3\]"),
        (np.stack([TABLE1, TABLE1]), np.stack([CURRENT, _with(7, np.inf, CURRENT)]), {}, r"current\[1, 7\]"),
        (TABLE1[:18], CURRENT, {}, r"theta must have shape \(19,\) or \(W, 19\).*got shape \(18,\)"),
        (TABLE1[None, None, :], CURRENT, {}, r"theta must have shape .*got shape \(1, 1, 19\)"),
        (np.empty((0, 19)), CURRENT, {}, r"empty batch axis"),
        (TABLE1, CURRENT[None, None, :], {}, r"current must have shape \(T,\) or \(W, T\), got shape \(1, 1, 20\)"),
        (TABLE1, CURRENT[:1], {}, r"current needs at least 2 samples, got 1"),
        (TABLE1, CURRENT[:0], {}, r"current needs at least 2 samples, got 0"),
        (np.stack([TABLE1] * 3), np.stack([CURRENT] * 2), {}, r"current has 2 rows but theta has 3"),
        (TABLE1, CURRENT, {"n_operators": 0}, r"n_operators must be >= 1, got 0"),
        (TABLE1, CURRENT, {"n_operators": -3}, r"n_operators must be >= 1, got -3"),
        (TABLE1, CURRENT, {"n_operators": 2.5}, r"n_operators must be an integer >= 1, got 2.5"),
        (TABLE1, CURRENT, {"n_operators": 12.0}, r"n_operators must be an integer >= 1, got 12.0"),
        (TABLE1, CURRENT, {"n_operators": True}, r"n_operators must be an integer >= 1, got True"),
        (TABLE1, CURRENT, {"n_operators": "12"}, r"n_operators must be an integer >= 1, got '12'"),
        (TABLE1, CURRENT, {"reading": "mirrored"}, r"reading must be one of \['literal', 'swapped'\], got 'mirrored'"),
        (TABLE1, CURRENT, {"initial_memory": np.nan}, r"initial_memory must be finite"),
        (
            np.stack([TABLE1] * 3),
            CURRENT,
            {"initial_memory": [0.0, 1.0]},
            r"initial_memory must be a scalar or have shape \(3,\)",
        ),
        (TABLE1, CURRENT, {"initial_excursion": np.inf}, r"initial_excursion must be finite"),
        (TABLE1, CURRENT, {"initial_held": np.ones(5)}, r"initial_held must be a scalar or have shape \(12,\)"),
        (TABLE1, CURRENT, {"initial_held": np.full(12, np.nan)}, r"initial_held must be finite"),
        (
            TABLE1,
            CURRENT,
            {"threshold_scale": np.ones(19)},
            r"threshold_scale must have shape \(20,\) or \(1, 20\).*got shape \(19,\)",
        ),
        (TABLE1, CURRENT, {"threshold_scale": np.zeros(20)}, r"threshold_scale must be finite and > 0"),
    ],
)
def test_bad_input_raises_clear_value_error(theta, current, options, message):
    with pytest.raises(ValueError, match=message):
        gpi(theta, current, **options)


def test_crossing_bounds_are_eq5_not_an_error():
    """Eq. (5) is defined for every theta: beyond 5 A Table 1's bounds cross, and the kernel
    still follows the piecewise law, equal to the oracle (the clamp form differs there)."""
    current = np.concatenate([np.linspace(0.0, 6.0, 60), np.linspace(6.0, 1.0, 50), np.linspace(1.0, 6.0, 50)])
    assert gpi_reference(TABLE1, current).bounds_cross
    assert_matches_oracle(TABLE1, current)
    clamp = gpi_reference(TABLE1, current, law="clamp").output
    assert np.max(np.abs(gpi(TABLE1, current) - clamp)) > 1e-3


@FAST_SETTINGS
@given(
    current=st.lists(st.floats(-5.0, 5.0), min_size=2, max_size=300),
    coefficients=st.lists(st.floats(-3.0, 3.0), min_size=8, max_size=8),
    alpha=st.floats(-0.3, 0.3).filter(lambda a: abs(a) > 1e-3),
    shift=st.floats(-2.0, 2.0).filter(lambda d: abs(d) > 1e-9),  # not exactly touching (rounding decides there)
    n_operators=st.integers(1, 15),
)
def test_any_theta_matches_the_oracle_crossing_or_not(current, coefficients, alpha, shift, n_operators):
    """Envelopes of any monotonicity and a falling offset shifted either way, so the bounds
    cross on some examples and not on others: the kernel is eq. (5) on all of them."""
    current = np.asarray(current)
    theta = TABLE1.copy()
    theta[0] = alpha
    theta[3:11] = coefficients
    theta[THETA_NAMES.index("b3")] += max_bound_excess(theta, current, n_operators) + shift
    assert_matches_oracle(theta, current, n_operators=n_operators)
    crosses = gpi_reference(theta, current, n_operators=n_operators).bounds_cross
    assert (bound_overlap(theta, current, n_operators) > 0) == crosses


def test_gpi_is_continuous_across_the_old_wall(paper_input):
    """Moving b3 through the value where the bounds start to cross changes the output
    continuously (no jump, no error): the model has no wall."""
    current = paper_input[::10]
    i = THETA_NAMES.index("b3")
    edge = TABLE1[i] + max_bound_excess(TABLE1, current)  # the bounds touch at this b3
    thetas = np.stack([_with(i, edge + d) for d in (-1e-6, 1e-6)])
    assert bound_overlap(thetas, current).tolist()[0] > 0 > bound_overlap(thetas, current).tolist()[1]
    out = gpi(thetas, current)
    assert np.max(np.abs(out[0] - out[1])) < 1e-3


def test_bound_overlap_of_table1_is_the_documented_margin():
    assert bound_overlap(TABLE1, np.linspace(0.0, 5.0, 5001)) == pytest.approx(-0.0157, abs=5e-5)
    assert bound_overlap(TABLE1, np.linspace(0.0, 6.0, 20)) > 0
    both = bound_overlap(np.stack([TABLE1, TABLE1]), CURRENT)
    assert both.shape == (2,) and both[0] == both[1]


def test_literal_reading_allows_crossing_bounds():
    out = gpi(TABLE1, CURRENT, reading="literal")
    assert gpi_reference(TABLE1, CURRENT, reading="literal").bounds_cross
    assert np.all(np.isfinite(out))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"thresholds": [-0.1, 0.2], "weights": [1.0, 1.0]}, r"thresholds must be >= 0"),
        ({"thresholds": [0.1, 0.2], "weights": [1.0]}, r"thresholds and weights must both have shape \(N,\)"),
        ({"thresholds": [0.1, np.nan], "weights": [1.0, 1.0]}, r"thresholds has a non-finite value at index 1"),
    ],
)
def test_classical_pi_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        classical_pi(CURRENT, **kwargs)


def test_classical_pi_rejects_short_or_non_finite_current():
    with pytest.raises(ValueError, match=r"T >= 2"):
        classical_pi([1.0], [0.1], [1.0])
    with pytest.raises(ValueError, match=r"current has a non-finite value at index 2"):
        classical_pi([0.0, 1.0, np.nan], [0.1], [1.0])


# ----------------------------------------------------------------------------- the paper's input


def test_paper_current_literal_reading():
    time, current = paper_current(100.0, "literal")
    assert time.shape == current.shape == (7001,)
    np.testing.assert_allclose(np.diff(time), 0.01, rtol=0, atol=1e-12)
    assert time[0] == 0.0 and time[-1] == pytest.approx(70.0, abs=1e-12)
    assert np.all(current[time < QUIET_SECONDS] == 0.0)
    peaks = np.arange(15, 70, 10) * 100  # sine maxima at 15, 25, ..., 65 s
    troughs = np.arange(10, 71, 10) * 100
    # Eq. (16) as printed multiplies the bias too: troughs stay at 0 A, peaks decay by 0.01/s after 20 s.
    np.testing.assert_allclose(current[troughs], 0.0, atol=1e-12)
    expected_peaks = 5.0 * np.where(time[peaks] > 20, 1 - 0.01 * (time[peaks] - 20), 1.0)
    np.testing.assert_allclose(current[peaks], expected_peaks, rtol=0, atol=1e-12)
    assert current[peaks[-1]] == pytest.approx(2.75, abs=1e-12)  # 65 s; the envelope reaches 2.5 A at 70 s
    assert current.max() == pytest.approx(5.0, abs=1e-12) and current.min() >= -1e-12


def test_paper_current_centred_reading():
    time, current = paper_current(100.0, "centred")
    assert current.shape == (7001,)
    assert np.all(current[time < QUIET_SECONDS] == 0.0)
    peaks = np.arange(25, 70, 10) * 100
    troughs = np.arange(30, 71, 10) * 100
    decay_p = 1 - 0.01 * (time[peaks] - 20)
    decay_t = 1 - 0.01 * (time[troughs] - 20)
    np.testing.assert_allclose(current[peaks], 2.5 + 2.5 * decay_p, atol=1e-12)
    np.testing.assert_allclose(current[troughs], 2.5 - 2.5 * decay_t, atol=1e-12)
    assert current[-1] == pytest.approx(1.25, abs=1e-12)  # trough at 70 s: 2.5 - 2.5 * 0.5
    # Peaks and troughs converge toward the 2.5 A line.
    assert np.all(np.diff(np.abs(current[peaks] - 2.5)) < 0)
    assert np.all(np.diff(np.abs(current[troughs] - 2.5)) < 0)
    # Before the decay starts the two readings agree.
    literal = paper_current(100.0, "literal")[1]
    np.testing.assert_array_equal(current[time <= 20], literal[time <= 20])


@pytest.mark.parametrize("fs", [1.0, 37.0, 250.0, 1000.0])
def test_paper_current_at_any_rate(fs):
    time, current = paper_current(fs)
    assert time.size == int(np.floor(70 * fs + 1e-9)) + 1
    np.testing.assert_allclose(np.diff(time), 1 / fs, rtol=1e-9)
    assert time[-1] <= 70.0 + 1e-9
    assert np.all(current[time < QUIET_SECONDS] == 0.0)
    # Same curve at every rate: compare with the 100 Hz samples at common instants.
    t100, c100 = paper_current(100.0)
    common = np.isclose((time * 100) % 1, 0) | np.isclose((time * 100) % 1, 1)
    index = np.rint(time[common] * 100).astype(int)
    np.testing.assert_allclose(current[common], c100[index], atol=1e-9)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"fs": 0.0}, r"fs must be a positive sampling rate"),
        ({"fs": np.nan}, r"fs must be a positive sampling rate"),
        ({"reading": "centered"}, r"reading must be one of \('literal', 'centred'\)"),
        ({"duration": 5.0}, r"duration must exceed the 10.0 s quiet segment"),
    ],
)
def test_paper_current_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        paper_current(**kwargs)


def test_a_still_input_keeps_the_branch_of_its_last_motion():
    """Eq. (13) written for dv/dt >= 0 and < 0: a still input has no direction of its own, and the
    transducer does not jump while its drive is held. After a fall, a hold stays on Omega's d
    branch (the literal reading would jump by Omega_c - Omega_d, about -1.9 um at 0 A with
    Table 1); after a rise it stays on c; the kernel equals the oracle there."""
    rise = np.linspace(0.0, 4.0, 41)
    fall = np.linspace(4.0, 0.0, 41)[1:]
    held = np.full(30, 0.0)
    current = np.concatenate([np.zeros(5), rise, fall, held, np.linspace(0.0, 3.0, 31)[1:], np.full(20, 3.0)])
    y = gpi(TABLE1, current)
    falls_end = 5 + 41 + 40 - 1
    assert np.all(y[falls_end : falls_end + 31] == y[falls_end])  # the hold after the fall: no jump
    assert np.all(y[-20:] == y[-21])  # the hold after the rise
    reference = gpi_reference(TABLE1, current)
    np.testing.assert_allclose(y, reference.output, rtol=0, atol=1e-9 * oracle_scale(reference))
    c = TABLE1[11] * np.tanh(TABLE1[12] * 0.0 + TABLE1[13]) + TABLE1[14]
    d = TABLE1[15] * np.tanh(TABLE1[16] * 0.0 + TABLE1[17]) + TABLE1[18]
    assert abs(c - d) > 1.5  # the jump the literal reading would make is not small
