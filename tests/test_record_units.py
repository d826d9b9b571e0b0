"""Default bounds follow the record's unit prefixes (identify.fitting.parametrisation.in_record_units)."""

import dataclasses

import numpy as np
import pytest

from identify.bench.synthetic import simulate
from identify.fitting.lsq import fit_least_squares
from identify.fitting.parametrisation import in_record_units, normalised_model, prefix_factor, record_unit_factors
from identify.fitting.posterior import LogPosterior
from model import Model


@pytest.mark.parametrize(
    "ratio, factor", [(1.0, 1.0), (0.05, 1.0), (20.0, 1.0), (1000.0, 1000.0), (700.0, 1000.0), (1e-3, 1e-3), (0.0, 1.0)]
)
def test_factors_are_whole_si_prefix_steps(ratio, factor):
    assert prefix_factor(ratio) == factor


@pytest.fixture(scope="module")
def records():
    record = simulate(fs=20.0, seed=3, noise_sigma=0.5).record
    converted = dataclasses.replace(
        record, current=record.current * 1e3, displacement=record.displacement * 1e3, input_unit="mA", output_unit="nm"
    )
    return record, converted


def test_a_record_at_the_papers_scale_keeps_the_model(records):
    record, converted = records
    model = normalised_model(Model(["thermal"]))
    assert record_unit_factors(record) == (1.0, 1.0)
    assert in_record_units(model, record) is model
    assert record_unit_factors(converted) == (1e3, 1e3)


def test_bounds_scale_by_dimension_and_only_once(records):
    _, converted = records
    model = normalised_model(Model(["thermal"]))
    scaled = in_record_units(model, converted)
    before, after = model.parameters, scaled.parameters
    assert after["a1"].lower == pytest.approx(before["a1"].lower / 1e3)  # per input unit
    assert after["a1"].upper == before["a1"].upper  # widened, never narrowed
    assert after["a1"].value == pytest.approx(before["a1"].value / 1e3)
    assert after["rho"].upper == pytest.approx(before["rho"].upper * 1e3)  # output per threshold unit
    assert after["rho"].lower == before["rho"].lower
    assert after["c3"].lower == pytest.approx(before["c3"].lower * 1e3)  # output unit
    assert after["a0"].upper == before["a0"].upper and after["alpha"].value == before["alpha"].value  # thresholds fixed
    assert after["thermal_expansion"].upper == pytest.approx(before["thermal_expansion"].upper * 1e3)  # um
    assert after["thermal_tau"].upper == before["thermal_tau"].upper  # s
    assert in_record_units(scaled, converted).parameters == after  # idempotent
    custom = model.parameters.replace("rho", lower=0.5, upper=50.0)  # a user's bounds stay
    import copy

    user = copy.copy(model)
    user.parameters = custom
    assert in_record_units(user, converted).parameters["rho"].upper == 50.0


def test_a_record_in_ma_and_nm_fits_as_well_as_in_a_and_um(records):
    record, converted = records
    model = normalised_model(Model())
    fit = fit_least_squares(record, model, n_starts=4, rng=np.random.default_rng(0))
    fit_mn = fit_least_squares(converted, model, n_starts=4, rng=np.random.default_rng(0))
    assert fit_mn.reduced_chi2 == pytest.approx(fit.reduced_chi2, rel=2e-3)
    rho = fit_mn.theta[model.names.index("rho")]
    assert rho == pytest.approx(1e3 * fit.theta[model.names.index("rho")], rel=0.02)
    assert rho > model.parameters["rho"].upper  # outside the A/um default bounds: the rescaling was needed
    log_post = LogPosterior(converted, fit_mn.model, fit_mn.noise)
    assert np.isfinite(log_post(fit_mn.theta[log_post.free]))
