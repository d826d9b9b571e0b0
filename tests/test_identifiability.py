"""Identifiability: the GPI's exact scaling degeneracy, its normalisation, and its automatic
detection from the Fisher information."""

from __future__ import annotations

import numpy as np
import pytest

from identify.data.records import Record
from identify.fitting.identifiability import EXACT_RATIO, analyse_fit, analyse_identifiability
from identify.fitting.lsq import WhitenedResiduals, fit_least_squares
from identify.fitting.noise import NoiseModel
from identify.fitting.parametrisation import (
    NORMALISATION,
    SCALING_PARAMETERS,
    SCALING_POWERS,
    gpi_scaling,
    normalised_model,
    parameter_scales,
    pin_gpi_parameters,
    scaling_direction,
    to_normalisation,
)
from model import TABLE1, THETA_NAMES, Model, paper_current


def record(fs=10.0, seed=0, effects=()):
    time, current = paper_current(fs=fs)
    model = Model(list(effects))
    y = model(model.default_theta(), time, current)
    y = y + 0.5 * np.random.default_rng(seed).standard_normal(time.size)
    return Record(time, current, y, source="synthetic", sha256="")


@pytest.mark.parametrize("k", [0.25, 0.9, 1.7, 4.0])
def test_scaling_leaves_the_output_unchanged(k):
    """(rho, alpha, tau, a0, a3, b0, b3) -> (rho/k, k alpha, tau/k, k a0, k a3, k b0, k b3):
    same output up to round-off (1e-12 of the ~296 um range), on the full paper input."""
    time, current = paper_current()
    model = Model()
    theta = model.default_theta()
    scaled = gpi_scaling(theta, k)
    assert not np.allclose(scaled, theta)
    for name, power in zip(SCALING_PARAMETERS, SCALING_POWERS):
        i = THETA_NAMES.index(name)
        assert scaled[i] == pytest.approx(theta[i] * k**power, rel=1e-15)
    y, y_scaled = model(theta, time, current), model(scaled, time, current)
    assert np.max(np.abs(y_scaled - y)) < 1e-12 * np.ptp(y)


def test_scaling_is_not_an_invariance_without_tau_or_rho():
    """Control: scaling only the envelopes and alpha (not rho, tau) does change the output."""
    time, current = paper_current(fs=10.0)
    model = Model()
    theta = model.default_theta()
    wrong = gpi_scaling(theta, 2.0)
    wrong[THETA_NAMES.index("rho")] = theta[THETA_NAMES.index("rho")]
    assert np.max(np.abs(model(wrong, time, current) - model(theta, time, current))) > 10.0


def test_normalisation_maps_every_equivalent_vector_to_one():
    theta = Model().default_theta()
    for k in (0.3, 2.5):
        back = to_normalisation(gpi_scaling(theta, k))
        assert back[THETA_NAMES.index("alpha")] == NORMALISATION["alpha"]
        assert np.allclose(back, theta, rtol=1e-13)


def test_normalised_model_pins_alpha_at_table1():
    model = normalised_model(Model(["thermal"]))
    alpha = model.parameters["alpha"]
    assert not alpha.vary and alpha.value == TABLE1[0] == NORMALISATION["alpha"]
    pinned_by_default = ~Model(["thermal"]).parameters.vary  # thermal's start rises (a cold start)
    assert (
        model.parameters.vary.sum() == model.n_parameters - 1 - pinned_by_default.sum() and pinned_by_default.sum() == 2
    )
    assert model.effect_names == ("thermal",)
    with pytest.raises(ValueError, match="only GPI parameters"):
        pin_gpi_parameters(model, {"thermal_tau": 3.0})


def test_exact_direction_is_found_with_alpha_free():
    """Fisher eigen-analysis at Table 1, every parameter free: the smallest eigenvalue is
    ~0 (< 1e-12 of the largest, while the next is > 1e-9 of it) and its vector loads on
    exactly the 7 scaling parameters in the ratio power_j * theta_j / scale_j."""
    rec = record(fs=20.0)
    model = Model()
    theta = model.default_theta()
    residuals = WhitenedResiduals(rec, model, NoiseModel(sigma=0.5))
    result = analyse_identifiability(residuals.central_jacobian(theta), theta, model.names)
    ratios = result.eigenvalues / result.eigenvalues[-1]
    assert abs(ratios[0]) < 1e-12 and ratios[1] > 1e-9
    assert len(result.exact) == 1
    vector = result.exact[0].vector
    expected = scaling_direction(theta, model.names)
    assert abs(vector @ expected) > 1 - 1e-9
    inside = np.isin(model.names, SCALING_PARAMETERS)
    assert np.max(np.abs(vector[~inside])) < 1e-5
    assert set(result.exact[0].combination) == set(SCALING_PARAMETERS)
    # loadings in the scaling ratio: +-1 in relative units (every |theta_j| > 0.01 here)
    scales = parameter_scales(theta)
    loading = {n: w for n, w in zip(model.names, vector * np.sign(vector[model.names.index("alpha")]))}
    for name, power in zip(SCALING_PARAMETERS, SCALING_POWERS):
        i = model.names.index(name)
        assert loading[name] == pytest.approx(power * theta[i] / scales[i] / np.sqrt(7) * np.sign(theta[0]), abs=1e-6)


def test_normalised_problem_has_no_exact_direction():
    rec = record(fs=20.0)
    model = normalised_model(Model())
    residuals = WhitenedResiduals(rec, model, NoiseModel(sigma=0.5))
    theta = model.default_theta()
    x = theta[residuals.free]
    result = analyse_identifiability(residuals.central_jacobian(x), x, [model.names[i] for i in residuals.free])
    assert result.exact == []
    assert result.eigenvalues[0] / result.eigenvalues[-1] > EXACT_RATIO
    assert np.isfinite(result.condition_number)


def test_analyse_fit_reports_the_scaling_and_near_directions():
    rec = record(fs=10.0, seed=3)
    fit = fit_least_squares(rec, normalised_model(Model()), n_starts=2)
    result = analyse_fit(fit, rec)
    assert result.normalisation == {"alpha": NORMALISATION["alpha"]}
    assert len(result.exact) == 1 and set(result.exact[0].combination) == set(SCALING_PARAMETERS)
    assert "alpha" not in result.names  # the near analysis is of the normalised problem
    for direction in result.near:
        assert direction.relative_std > 0.05 or direction.ratio < 1e-8
        assert abs(np.linalg.norm(direction.vector) - 1) < 1e-12
        assert max(abs(w) for w in direction.combination.values()) == max(direction.combination.values())
    d = result.to_dict()
    assert set(d) >= {"normalisation", "exact", "near"}
    assert all(set(item) >= {"eigenvalue", "combination"} for item in d["exact"] + d["near"])
    assert "EXACT degeneracy" in result.describe()


def test_omega_sign_flip_is_exact_and_removed_by_the_normalisation():
    """(c0, c1, c2) -> -(c0, c1, c2) (and the same for d) leaves the output unchanged
    (tanh is odd), so the normalisation bounds c1, d1 > 0."""
    time, current = paper_current(fs=10.0)
    model = Model()
    theta = model.default_theta()
    flipped = theta.copy()
    for name in ("c0", "c1", "c2", "d0", "d1", "d2"):
        flipped[THETA_NAMES.index(name)] *= -1
    assert model.in_bounds(flipped)[0]  # allowed by the model's own bounds
    assert np.max(np.abs(model(flipped, time, current) - model(theta, time, current))) < 1e-12 * 300
    normalised = normalised_model(model)
    assert not normalised.in_bounds(flipped)[0] and normalised.in_bounds(theta)[0]
    assert normalised.parameters["c1"].lower > 0 and normalised.parameters["d1"].lower > 0


#: A least-squares optimum of the plain GPI on ``simulate(fs=5.0, seed=4)`` (operator bounds
#: crossing by 0.05 A), full precision: the optimum sits on a kink of the output, and the
#: central-difference Jacobian straddles it at some sample.
ON_A_KINK = [
    -0.1993,
    5.368413917504415,
    0.08811572446321304,
    8.48501838879839,
    0.510738605759516,
    -0.07050528754995748,
    -6.027167517446105,
    3.3591999552580685,
    1.4119062624186147,
    -0.9102081263168071,
    3.713911057355315,
    2.1045031244118095,
    3.855273550938752,
    -6.712651859418651,
    24.820831651958677,
    2.616140718884239,
    4.486055891429685,
    -5.657917151568709,
    27.25770393811432,
]


def _kink_problem():
    from identify.bench.synthetic import simulate

    rec = simulate(fs=5.0, seed=4).record
    model = Model()
    theta = np.array(ON_A_KINK)
    residuals = WhitenedResiduals(rec, model, NoiseModel(sigma=0.5))
    return residuals, theta, residuals.central_jacobian(theta), model.names


def test_the_scaling_is_exact_at_an_optimum_on_a_kink():
    """The eigenvalues alone miss the scaling there (ratio ~1e-9, not ~1e-16); the finite
    invariance check lists it, with eigenvalue 0, and finds nothing else exact."""
    from identify.fitting.identifiability import exact_directions

    residuals, theta, jac, names = _kink_problem()
    by_eigenvalues = analyse_identifiability(jac, theta, names)
    assert by_eigenvalues.eigenvalues[0] / by_eigenvalues.eigenvalues[-1] > 1e3 * EXACT_RATIO
    assert by_eigenvalues.exact == []
    exact = exact_directions(residuals, theta, jac, names, 8)
    assert len(exact) == 1
    assert set(exact[0].combination) == set(SCALING_PARAMETERS) and exact[0].eigenvalue == 0.0
    assert abs(exact[0].vector @ scaling_direction(theta, names)) == pytest.approx(1.0, abs=1e-12)


def test_the_scaling_is_not_listed_when_the_output_is_not_invariant(monkeypatch):
    """The listing rests on the finite check: with a scaling that is not a symmetry (alpha
    alone scaled) the check fails and only the eigenvalues decide."""
    import identify.fitting.identifiability as ident

    residuals, theta, jac, names = _kink_problem()
    assert ident.invariant_under_scaling(residuals, theta)

    def alpha_only(theta, k):
        out = np.array(theta, dtype=float)
        out[0] *= k
        return out

    monkeypatch.setattr(ident, "gpi_scaling", alpha_only)
    assert not ident.invariant_under_scaling(residuals, theta)
    assert ident.exact_directions(residuals, theta, jac, names, 8) == []
