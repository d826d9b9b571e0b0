"""The solvers' LAPACK calls without the GIL: the originals' results, bit for bit (``trf``'s SVD
of a tall Jacobian: its singular values and ``V`` bit for bit, ``U^T f`` to the last bits)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import scipy.optimize._lsq.dogbox as dogbox
import scipy.optimize._lsq.trf as trf

from identify.fitting.lapack import ImplicitU, lstsq, release_the_gil_in_least_squares, svd, trf_svd


def _matrix(kind, rng):
    if kind == "tall":
        return rng.normal(size=(3500, 21))
    if kind == "scaled columns":
        return rng.normal(size=(700, 12)) * np.exp(3.0 * rng.normal(size=12))
    if kind == "rank deficient":
        a = rng.normal(size=(400, 8))
        a[:, 7] = 2.0 * a[:, 0]  # exactly dependent, as the GPI's scaling degeneracy makes a Jacobian
        return a
    if kind == "wide":
        return rng.normal(size=(6, 15))
    if kind == "one by one":
        return np.array([[3.0]])
    raise ValueError(kind)


KINDS = ["tall", "scaled columns", "rank deficient", "wide", "one by one"]


@pytest.mark.parametrize("kind", KINDS)
def test_the_svd_is_scipys_bit_for_bit(kind):
    a = _matrix(kind, np.random.default_rng(3))
    for ours, theirs in zip(svd(a, full_matrices=False), scipy.linalg.svd(a, full_matrices=False)):
        assert ours.shape == theirs.shape and np.array_equal(ours, theirs)


@pytest.mark.parametrize("kind", KINDS)
def test_trfs_svd_keeps_the_singular_values_and_v_and_u_transposed_times_a_vector(kind):
    rng = np.random.default_rng(7)
    a = _matrix(kind, rng)
    f = rng.normal(size=a.shape[0])
    u, s, vh = scipy.linalg.svd(a, full_matrices=False)
    u_ours, s_ours, vh_ours = trf_svd(a, full_matrices=False)
    assert isinstance(u_ours, ImplicitU) == (kind in ("tall", "scaled columns", "rank deficient"))
    assert np.array_equal(s_ours, s) and np.array_equal(vh_ours, vh)
    scale = np.abs(u.T @ f).max()
    assert np.allclose(u_ours.T.dot(f), u.T @ f, rtol=0.0, atol=1e-13 * scale)
    assert np.allclose(u_ours.T @ np.stack([f, 2 * f], axis=1), u.T @ np.stack([f, 2 * f], axis=1), atol=1e-13 * scale)
    assert np.asarray(u_ours).shape == u.shape and np.allclose(np.asarray(u_ours), u, rtol=0.0, atol=1e-13)


@pytest.mark.parametrize("kind", KINDS)
def test_the_least_squares_solution_is_numpys_bit_for_bit(kind):
    rng = np.random.default_rng(4)
    a = _matrix(kind, rng)
    b = rng.normal(size=a.shape[0])
    x, _, rank, s = lstsq(a, b, rcond=-1)
    x_np, _, rank_np, s_np = np.linalg.lstsq(a, b, rcond=-1)
    assert np.array_equal(x, x_np) and rank == rank_np and np.array_equal(s, s_np)


def test_what_the_fast_path_does_not_take_goes_to_the_original():
    a = np.random.default_rng(5).normal(size=(30, 4))
    b = a[:, 0]
    with pytest.raises(ValueError, match="infs or NaNs"):  # scipy's own check and message
        svd(np.where(a > 1.0, np.nan, a), full_matrices=False)
    assert svd(a)[0].shape == (30, 30)  # full matrices: scipy's
    full = lstsq(a, b)  # numpy's default rcond: numpy's call, residuals included
    assert full[1].shape == (1,) and np.array_equal(full[0], np.linalg.lstsq(a, b)[0])
    x, *_ = lstsq(a, np.stack([b, b], axis=1), rcond=-1)  # several right-hand sides: numpy's
    assert x.shape == (4, 2)


@pytest.mark.parametrize("method", ["dogbox", "trf"])
def test_a_least_squares_run_is_the_same_with_the_calls_released(method, monkeypatch):
    """SciPy's solver with its own LAPACK wrappers and with ours: the same run, bit for bit."""
    rng = np.random.default_rng(6)
    t = np.linspace(0.0, 4.0, 500)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 * np.sin(3.0 * t) + 0.01 * rng.normal(size=t.size)

    def residual(p):
        return p[0] * np.exp(-p[1] * t) + p[2] * np.sin(p[3] * t) - y

    def run():
        return scipy.optimize.least_squares(
            residual, [1.0, 1.0, 1.0, 2.8], bounds=([0, 0, -5, 0], [10, 10, 5, 10]), method=method, x_scale="jac"
        )

    assert release_the_gil_in_least_squares()
    assert dogbox.lstsq is lstsq and trf.svd is trf_svd
    released = run()
    monkeypatch.setattr(dogbox, "lstsq", np.linalg.lstsq)
    monkeypatch.setattr(trf, "svd", scipy.linalg.svd)
    original = run()
    assert released.nfev == original.nfev
    if method == "dogbox":
        assert np.array_equal(released.x, original.x) and released.cost == original.cost
    else:  # U^T f differs in the last bits (trf_svd)
        assert np.allclose(released.x, original.x, rtol=1e-12) and np.isclose(released.cost, original.cost, rtol=1e-12)
