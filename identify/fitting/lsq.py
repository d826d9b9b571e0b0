r"""Weighted nonlinear least squares of the GPI (+ effects) on one record, with multi-start.

Objective
---------
The residuals ``e = displacement - model(theta)`` over the whole record (the quiet start
included: the model predicts the rest level there) are whitened by the noise model
(:func:`identify.fitting.noise.whiten`: divided by sigma, AR(1) filtered when the noise is
correlated), and :func:`scipy.optimize.least_squares` (dogleg with box bounds,
:data:`SOLVER_METHOD`) minimises half their sum of squares within each parameter's bounds. Pinned parameters
(``Parameter.vary = False``, e.g. the normalisation of :mod:`identify.fitting.identifiability`)
stay at their values. The GPI is defined for every parameter set (:mod:`model.gpi`, "The
whole domain"); a parameter set for which an effect gives a non-finite output gets a
constant residual of :data:`DOMAIN_PENALTY` per sample, far above any fit, so the solver
backs off.

Jacobian
--------
Forward differences, computed in ONE batched model call: ``theta`` and its ``P``
perturbed copies are evaluated as a ``(P + 1, P_full)`` batch (the forward model is
vectorised over parameter sets). Step ``h_j = sqrt(eps) * max(|theta_j|, 0.01)``,
taken downwards when it would leave the bounds. The covariance at the
optimum uses central differences (one ``(2P + 1)``-row batch, step
:data:`CENTRAL_STEP_POWER`) for accuracy.

Starts
------
``start`` (if given), then

``table1``
    Table 1 of the paper with every effect off, when the record is in A and um;
``data_scaled``
    Table 1 rescaled to the record: the slopes ``a1, b1, c1, d1`` divided by the input
    scale ``max|input| / 5`` (the paper's drive peaks at 5 A), then the output gain and
    offset fitted by linear least squares of the data on the rescaled prediction (gain
    on ``rho, c0, c3, d0, d3``, offset on ``c3, d3``); this is exact for a record that
    is a scaled copy of the paper's transducer;
``classical``
    for a model whose ``alpha`` is positive (classical-PI-like thresholds, see below):
    identical, mildly saturating envelopes ``3 tanh(0.5 v / max|v|)`` for both branches,
    ``rho = 1``, ``tau = 0.5``, a gently sloped Omega, then the output gain and offset
    fitted by linear least squares as for ``data_scaled``;
``perturbed-k``
    the best of the above with each free GPI parameter multiplied by
    ``exp(0.15 z)``, ``z ~ N(0, 1)`` from ``rng``; effect parameters measured in seconds
    (time constants) spread log-uniformly over their bounds, other effect parameters
    at their off value plus 1 % of their range times ``z``.

Every start first gets :data:`SCREEN_EVALUATIONS` solver evaluations of each method
(:data:`SOLVER_METHOD` and :data:`ALTERNATE_METHOD`); the ``n_polish`` best after dogbox's
screening, and the :data:`N_POLISH_ALTERNATE` best after trf's, then run on
from there to convergence with :data:`SOLVER_METHOD` (at most :data:`POLISH_EVALUATIONS`
evaluations, tolerances :data:`TOLERANCE`, and every run stopped once it has stalled:
:class:`StallStop`) and the best of those wins. The polished set
contains dogbox's alone, so the search only adds ends to what dogbox's ranking polishes.

Table-1-shaped starts (``table1``, ``data_scaled``, ``classical``) are made for Table 1's
12 operators; for ``N`` operators they are rescaled so the operators keep the same
threshold range and total weight (``alpha`` and ``rho`` times ``12/N``, then the exact
scaling restores a pinned ``alpha``; :func:`_rescaled_to_operators`).

Starts "agree" when their final chi-square is within 1 of the best (statistically indistinguishable
fits); a start screened out counts as not agreeing, so ``n_agree`` is a lower bound.
BLAS runs single-threaded during the fit (see :func:`identify.fitting.threads.single_threaded_blas`).

Sign of the thresholds
----------------------
The normalisation (:mod:`identify.fitting.identifiability`) pins ``|alpha|``; its sign is a
model choice the scaling cannot change. ``alpha < 0`` is the paper's Table 1 (the gap
between the envelopes makes the loop), ``alpha > 0``
the classical PI's positive thresholds (near-identical envelopes: thin loop tips, e.g.
a piezo actuator). With ``threshold_sign="auto"`` (default) and no ``start``,
:func:`fit_least_squares` fits both and keeps the lower chi-square (within
:data:`AGREE_CHI2` of each other, statistically indistinguishable, the paper's ``alpha < 0``);
its ``message`` says what the other sign reached. A given ``start`` decides the sign itself.

Covariance
----------
``sigma^2 (J^T J)^+`` on the whitened residuals (equivalently ``(J^T J)^+`` with the
residuals already divided by sigma), over the free parameters only (pinned rows and
columns are zero, their standard errors NaN). With a free sigma, sigma is estimated as
``sqrt(sum w^2 / (T - P_free))`` (residual RMS with degrees-of-freedom correction).
"""

from __future__ import annotations

import logging
import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from model import GPI_PARAMETERS, THETA_NAMES, Model

from .coordinates import GPICoordinates
from .noise import NoiseModel, energised_mask, estimate_noise, whiten_rows
from .parametrisation import gpi_scaling, in_record_units, record_unit_factors, with_threshold_sign
from .threads import fastest_thread_count, single_threaded_blas

_log = logging.getLogger(__name__)  # a child of the "identify" logger (identify.logs)

__all__ = [
    "FitResult",
    "StartOutcome",
    "fit_least_squares",
    "candidate_starts",
    "WhitenedResiduals",
    "DOMAIN_PENALTY",
    "TABLE1_N_OPERATORS",
    "PAPER_PEAK_INPUT",
    "THRESHOLD_SIGNS",
    "parameter_units",
    "StallStop",
    "bounded_solve",
]

#: Whitened residual per sample returned for a parameter set whose model output is not finite.
DOMAIN_PENALTY = 1e5
#: Peak drive of the paper's record [A]; the input scale of the data-driven start.
PAPER_PEAK_INPUT = 5.0
#: Central-difference step ``eps**CENTRAL_STEP_POWER * max(|theta|, 0.01)``. Smaller than the
#: textbook ``eps**(1/3)`` on purpose: the play operators' clamps make the output only
#: piecewise smooth, and a step that straddles a kink at some sample mixes the two
#: branches' slopes differently for each parameter; with 0.45 (steps ~1e-7 relative) the
#: GPI's exact scaling degeneracy shows as an eigenvalue ~1e-17 of the largest (1e-10 with 1/3).
CENTRAL_STEP_POWER = 0.45
#: Solver evaluations each start gets in the screening phase.
SCREEN_EVALUATIONS = 20
#: How many of the best screened starts are run to convergence. Twenty evaluations rank the
#: starts only roughly: on an independent clean record (every second sample) the start that
#: reaches the global optimum was ranked third after screening (chi-square 3529 from the two
#: best, 3431 with four), and on the SMA record 1 of 5 seeds missed the best basin with 2
#: polished starts and none with 4.
N_POLISH = 4
#: How many of the best starts after a screening with :data:`ALTERNATE_METHOD` are run to
#: convergence too (from that screening's end, with :data:`SOLVER_METHOD`; a start among
#: dogbox's best as well is then polished from both ends). Dogbox's large first steps can
#: throw a start that lies in the global optimum's basin into a degenerate region, where it
#: ranks last: on an independent clean record at 1 kHz the Table-1 start did, and from trf's
#: screening it reached the global optimum.
N_POLISH_ALTERNATE = 2
#: :func:`scipy.optimize.least_squares` method. "dogbox" rather than "trf": on the bundled
#: record (plain GPI fitted to data with a hidden thermal effect, a curved valley) dogbox
#: reached the optimum in 44 evaluations (0.7 s) where trf crawled for 750 evaluations
#: (16 s) and stopped 25 higher in chi-square; on clean records both agree.
SOLVER_METHOD = "dogbox"
#: Second method for starts whose dogbox optimum put a GPI parameter on a box bound: the
#: trust-region-reflective method stays inside the box and reached the global optimum where
#: dogbox ended in such a degenerate limit (an independent clean record with crossing operator
#: bounds: chi-square 11655 against the truth's 7158; trf 7136 from the same start).
ALTERNATE_METHOD = "trf"
#: Cap on the solver evaluations of each polished start (a misspecified model can crawl
#: along a flat valley for thousands of steps; the result then says "not converged").
POLISH_EVALUATIONS = 400
#: Relative tolerances of the solver (ftol, xtol, gtol): a chi-square change of 1e-8
#: relative is far below 1, the statistically meaningful scale.
TOLERANCE = 1e-8
#: A solver run stops as stalled when its last :data:`STALL_ITERATIONS` iterations together
#: lowered the chi-square by less than :data:`STALL_CHI2` (an absolute amount of the whitened
#: chi-square, the same for every record size: a likelihood ratio of exp(0.05)). The relative
#: tolerances cannot see this: in a curved valley each step gains more than ``ftol`` of the
#: chi-square, so a misspecified model crawls on to the evaluation cap. Measured (diagnoses of
#: a 1 kHz record and of the worst-case bench record, every solver run's chi-square per
#: iteration): a dogbox run gained 3 in chi-square in 370 evaluations (62 s at 70001
#: samples), and the rule's chi-square at the stop was at most 1.8 above the run's end in
#: all but one of 550 runs (a plateau that dropped by 18 after 190 iterations, in a
#: baseline of the sign that lost by 9,300).
STALL_ITERATIONS = 10
#: See :data:`STALL_ITERATIONS`.
STALL_CHI2 = 0.1
#: Solver status of a run stopped as stalled (:class:`StallStop`; scipy's status of a callback's stop).
STALLED = -2
#: Starts whose chi-square is within this of the best count as agreeing.
AGREE_CHI2 = 1.0
#: Operators of Table 1's fit (the paper's N); Table-1-shaped starts for another N are rescaled.
TABLE1_N_OPERATORS = 12
_SLOPES = ("a1", "b1", "c1", "d1")
#: ``threshold_sign`` option -> the signs of ``alpha`` fitted.
THRESHOLD_SIGNS = {"auto": (-1, 1), "negative": (-1,), "positive": (1,)}


@dataclass(frozen=True)
class StartOutcome:
    """How one least-squares start ended.

    Parameters
    ----------
    label : str
        ``"user"``, ``"table1"``, ``"data_scaled"`` or ``"perturbed-k"``.
    chi2 : float
        Sum of squared whitened residuals at the end (``2 * cost``); ``inf`` when the
        start gave a non-finite model output.
    n_evaluations : int
        Residual evaluations used.
    success : bool
    message : str
    """

    label: str
    chi2: float
    n_evaluations: int
    success: bool
    message: str


@dataclass
class FitResult:
    """A least-squares fit (fields as in docs/CONTRACTS.md, plus start bookkeeping).

    Parameters
    ----------
    model : model.Model
        The model fitted, with any pinned parameters.
    theta : ndarray, shape (P,)
        Best parameter vector, full, in ``model.names`` order.
    stderr : ndarray, shape (P,)
        Jacobian-based standard errors; NaN for pinned parameters.
    covariance : ndarray, shape (P, P)
        Jacobian-based covariance; zero rows/columns for pinned parameters.
    vary : ndarray of bool, shape (P,)
        False = pinned.
    residual : ndarray, shape (T,)
        Data minus model [output unit].
    rms : float
        Residual RMS over the energised part [output unit].
    max_error_pct : float
        Largest ``|residual|`` over the energised part, in % of the measured
        displacement range (max - min).
    reduced_chi2 : float
        ``sum w^2 / (T - P_free)`` with ``w`` the whitened residuals (1 for a perfect
        noise model).
    noise : NoiseModel
        The noise model used (a free sigma replaced by its estimate).
    n_starts : int
        Starts run.
    success : bool
        The best start's solver reported convergence.
    message : str
        The best start's solver message.
    seconds : float
        Wall time of the whole fit [s].
    n_agree : int
        Starts within chi-square 1 of the best.
    starts : list of StartOutcome
    terms : list of dict
        The optional effect terms tested by :func:`identify.fitting.terms.select_terms`
        (effect, term, parameters, chi-square change, BIC penalty, whether pinned off);
        empty when none was tested.
    """

    model: Model
    theta: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    vary: np.ndarray
    residual: np.ndarray
    rms: float
    max_error_pct: float
    reduced_chi2: float
    noise: NoiseModel
    n_starts: int
    success: bool
    message: str
    seconds: float
    n_agree: int = 1
    starts: list[StartOutcome] = field(default_factory=list)
    terms: list[dict] = field(default_factory=list)

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.names

    @property
    def chi2(self) -> float:
        """Sum of squared whitened residuals at the optimum."""
        return float(self.reduced_chi2 * (self.residual.size - int(self.vary.sum())))

    def theta_dict(self) -> dict[str, float]:
        return self.model.theta_dict(self.theta)

    def to_dict(self) -> dict:
        """JSON-ready (NaN written as None): everything needed to rebuild the fit."""
        return {
            "names": list(self.names),
            "units": [p.unit for p in self.model.parameters],
            "model": self.model.to_dict(),
            "theta": _floats(self.theta),
            "stderr": _floats(self.stderr),
            "covariance": [_floats(row) for row in self.covariance],
            "vary": [bool(v) for v in self.vary],
            "lower": _floats(self.model.parameters.lower),
            "upper": _floats(self.model.parameters.upper),
            "residual": _floats(self.residual),
            "rms": float(self.rms),
            "max_error_pct": float(self.max_error_pct),
            "reduced_chi2": float(self.reduced_chi2),
            "noise": self.noise.to_dict(),
            "n_starts": int(self.n_starts),
            "n_agree": int(self.n_agree),
            "success": bool(self.success),
            "message": str(self.message),
            "seconds": float(self.seconds),
            "starts": [
                {
                    "label": s.label,
                    "chi2": _float(s.chi2),
                    "n_evaluations": s.n_evaluations,
                    "success": s.success,
                    "message": s.message,
                }
                for s in self.starts
            ],
            "terms": [dict(t) for t in self.terms],
        }

    @classmethod
    def from_dict(cls, d: dict) -> FitResult:
        """Inverse of :meth:`to_dict` (the model is rebuilt with the same pins)."""
        theta = _array(d["theta"])
        vary = np.asarray(d["vary"], dtype=bool)
        base = Model.from_dict(d["model"])
        if tuple(d["names"]) != base.names:
            raise ValueError(f"fit names {d['names']} do not match the model {base!r}")
        lower = _array(d["lower"]) if "lower" in d else base.parameters.lower
        upper = _array(d["upper"]) if "upper" in d else base.parameters.upper
        settings = []  # every parameter's pin and bounds as stored (GPI and effects alike)
        for i, p in enumerate(base.parameters):
            value = float(theta[i]) if not vary[i] else min(max(p.value, lower[i]), upper[i])
            settings.append(p.with_(value=value, vary=bool(vary[i]), lower=float(lower[i]), upper=float(upper[i])))
        model = base.with_parameters(settings)
        starts = [
            StartOutcome(
                s["label"], _unfloat(s["chi2"], math.inf), int(s["n_evaluations"]), bool(s["success"]), s["message"]
            )
            for s in d.get("starts", [])
        ]
        return cls(
            model=model,
            theta=theta,
            stderr=_array(d["stderr"]),
            covariance=np.array([_array(r) for r in d["covariance"]]).reshape(theta.size, theta.size),
            vary=vary,
            residual=_array(d["residual"]),
            rms=float(d["rms"]),
            max_error_pct=float(d["max_error_pct"]),
            reduced_chi2=float(d["reduced_chi2"]),
            noise=NoiseModel.from_dict(d["noise"]),
            n_starts=int(d["n_starts"]),
            success=bool(d["success"]),
            message=str(d["message"]),
            seconds=float(d["seconds"]),
            n_agree=int(d.get("n_agree", 1)),
            starts=starts,
            terms=[dict(t) for t in d.get("terms", [])],
        )


def _float(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _floats(a):
    return [_float(x) for x in np.asarray(a, dtype=float).ravel()]


def _unfloat(x, missing=math.nan):
    return missing if x is None else float(x)


def _array(values):
    return np.array([_unfloat(v) for v in values], dtype=float)


def parameter_units(model: Model, record=None) -> list[str]:
    r"""Units of ``model.names``, with the record's input/output units substituted.

    The GPI's declared units assume a drive in A and an output in um. For a record in
    other units (e.g. V and um for a piezo) they are rewritten by dimensional analysis:
    the slopes ``a1, b1, c1, d1`` are per input unit; the envelopes
    :math:`\gamma(v) = a_0 \tanh(a_1 v + a_2) + a_3` are compared with the thresholds
    :math:`r_j = \alpha j`, and the paper gives both the input's unit, so ``alpha, a0,
    a3, b0, b3`` are in the input unit, ``tau`` per input unit and ``rho`` output per
    input unit; ``c0, c3, d0, d3`` are in the output unit.
    """
    in_unit = getattr(record, "input_unit", "A") if record is not None else "A"
    out_unit = getattr(record, "output_unit", "um") if record is not None else "um"
    units = []
    for p in model.parameters:
        unit = p.unit
        if p.name in _SLOPES or p.name == "tau":
            unit = f"1/{in_unit}"
        elif p.name in ("alpha", "a0", "a3", "b0", "b3"):
            unit = in_unit
        elif p.name in ("c0", "c3", "d0", "d3"):
            unit = out_unit
        elif p.name == "rho":
            unit = f"{out_unit}/{in_unit}"
        units.append(unit)
    return units


@njit(cache=True)
def difference_columns(rows, base, steps, columns, out):
    """Forward differences laid out as a Jacobian: ``out[k, j] = (rows[j + 1, k] - base[k]) / steps[j]``
    for each ``j`` in ``columns`` (``rows`` of shape ``(P + 1, T)``, ``out`` ``(T, P)``; other
    columns untouched).

    The same two operations per value as numpy's ``((rows[1:] - base) / steps[:, None]).T``,
    so the same bits, written in blocks of samples: numpy's transposed copy of the
    ``(P, T)`` differences strides through memory and costs about ten times as much at
    70001 samples."""
    n_samples = base.shape[0]
    block = 64
    for k0 in range(0, n_samples, block):
        k1 = min(k0 + block, n_samples)
        for j in columns:
            step = steps[j]
            for k in range(k0, k1):
                out[k, j] = (rows[j + 1, k] - base[k]) / step


class WhitenedResiduals:
    """Whitened residuals of a record as a function of the free parameters.

    Parameters
    ----------
    record : Record
        Supplies ``time``, ``current``, ``displacement`` (shape (T,)).
    model : model.Model
    noise : NoiseModel
        A free sigma is treated as 1 here (the scale does not move the optimum).

    Attributes
    ----------
    free : ndarray of int, shape (P_free,)
        Columns of the full vector that vary.
    template : ndarray, shape (P,)
        The full vector's pinned values.
    n_evaluations : int
        Model rows evaluated so far.
    """

    def __init__(self, record, model: Model, noise: NoiseModel):
        self.time = np.asarray(record.time, dtype=float)
        self.current = np.asarray(record.current, dtype=float)
        self.data = np.asarray(record.displacement, dtype=float)
        self.model = model
        self.noise = noise
        # the time grid for the whitening when its steps are not all the noise's one step
        # (a thinned record: each step its own correlation), else None (checked once here)
        self._uneven_time = None if noise.step_correlations(self.time) is None else self.time
        self.sigma = 1.0 if noise.is_free else noise.sigma
        self.free = np.flatnonzero(model.parameters.vary)
        self.template = model.parameters.values.copy()
        self.lower = model.parameters.lower[self.free]
        self.upper = model.parameters.upper[self.free]
        self.n_evaluations = 0
        self._cache_x = None
        self._cache_r = None

    def full(self, x) -> np.ndarray:
        """Full vector(s) ``(…, P)`` from free values ``(…, P_free)``."""
        x = np.asarray(x, dtype=float)
        out = np.broadcast_to(self.template, x.shape[:-1] + self.template.shape).copy()
        out[..., self.free] = x
        return out

    def batch(self, x_rows) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals ``(B, T)`` and validity ``(B,)`` for free vectors ``(B, P_free)``."""
        thetas = self.full(np.atleast_2d(x_rows))
        y, valid = self.model.evaluate(thetas, self.time, self.current)
        self.n_evaluations += thetas.shape[0]
        w, finite = whiten_rows(self.data, y, self.noise, self.sigma, time=self._uneven_time)
        valid = valid & finite
        return w, valid

    def __call__(self, x) -> np.ndarray:
        """Residual vector ``(T,)``; :data:`DOMAIN_PENALTY` everywhere where the output is not finite."""
        x = np.asarray(x, dtype=float)
        if self._cache_x is not None and np.array_equal(x, self._cache_x):
            return self._cache_r
        w, valid = self.batch(x[None, :])
        r = w[0] if valid[0] else np.full(self.data.size, DOMAIN_PENALTY)
        self._cache_x, self._cache_r = x.copy(), r
        return r

    def _steps(self, x, power):
        return np.finfo(float).eps ** power * np.maximum(np.abs(x), 0.01)

    def jacobian(self, x) -> np.ndarray:
        """Forward-difference Jacobian ``(T, P_free)`` from one ``(P_free + 1)``-row batch."""
        x = np.asarray(x, dtype=float)
        n_free = x.size
        steps = self._steps(x, 0.5)
        steps = np.where(x + steps > self.upper, -steps, steps)
        rows = np.repeat(x[None, :], n_free + 1, axis=0)
        rows[1:][np.arange(n_free), np.arange(n_free)] += steps
        w, valid = self.batch(rows)
        base = w[0] if valid[0] else self(x)
        jac = np.empty((self.data.size, n_free))
        difference_columns(w, base, steps, np.arange(n_free), jac)
        bad = [j for j in range(n_free) if not valid[j + 1]]
        jac[:, bad] = 0.0
        if bad and valid[0]:
            # Non-finite output on the forward step: step backward instead, in one more batch.
            back = np.repeat(x[None, :], len(bad), axis=0)
            back[np.arange(len(bad)), bad] -= steps[bad]
            back = np.clip(back, self.lower, self.upper)
            wb, vb = self.batch(back)
            for k, j in enumerate(bad):
                delta = back[k, j] - x[j]
                if vb[k] and delta != 0:
                    jac[:, j] = (wb[k] - base) / delta
        return jac

    def central_jacobian(self, x) -> np.ndarray:
        """Central-difference Jacobian ``(T, P_free)`` from one ``(2 P_free + 1)``-row batch.

        Falls back to one-sided differences for a column whose up or down step leaves
        the bounds or gives a non-finite output.
        """
        x = np.asarray(x, dtype=float)
        n_free = x.size
        steps = self._steps(x, CENTRAL_STEP_POWER)
        up = np.repeat(x[None, :], n_free, axis=0)
        down = up.copy()
        idx = np.arange(n_free)
        up[idx, idx] = np.minimum(x + steps, self.upper)
        down[idx, idx] = np.maximum(x - steps, self.lower)
        w, valid = self.batch(np.vstack([x[None, :], up, down]))
        base, w_up, w_down = w[0], w[1 : n_free + 1], w[n_free + 1 :]
        v_up, v_down = valid[1 : n_free + 1], valid[n_free + 1 :]
        jac = np.zeros((self.data.size, n_free))
        for j in range(n_free):
            hu, hd = up[j, j] - x[j], x[j] - down[j, j]
            if v_up[j] and v_down[j] and hu > 0 and hd > 0:
                jac[:, j] = (w_up[j] - w_down[j]) / (hu + hd)
            elif v_up[j] and hu > 0:
                jac[:, j] = (w_up[j] - base) / hu
            elif v_down[j] and hd > 0:
                jac[:, j] = (base - w_down[j]) / hd
        return jac


def _rescaled_to_operators(theta: np.ndarray, model: Model) -> np.ndarray:
    """A Table-1-shaped ``theta`` (made for :data:`TABLE1_N_OPERATORS` operators) for ``model.n_operators``.

    The ``N`` operators keep the 12 operators' threshold range and total weight:
    ``alpha`` and ``rho`` times ``12 / N`` (a finer discretisation of the same density
    ``p(r)``). When ``alpha`` is pinned (the normalisation), the exact scaling (k = N / 12,
    :func:`identify.fitting.parametrisation.gpi_scaling`) then brings it back to its pinned value:
    ``rho`` times ``(12/N)**2``, ``tau`` times ``12/N``, ``a0, a3, b0, b3`` times ``N/12``.
    The output is unchanged up to the discretisation of the density. Returns a new
    array, shape (P,); ``theta`` itself when ``N`` is 12.
    """
    n_operators = model.n_operators
    if n_operators == TABLE1_N_OPERATORS:
        return theta
    ratio = TABLE1_N_OPERATORS / n_operators
    i_alpha, i_rho = THETA_NAMES.index("alpha"), THETA_NAMES.index("rho")
    out = np.array(theta, dtype=float)
    out[i_alpha] *= ratio
    out[i_rho] *= ratio
    if not model.parameters["alpha"].vary:
        out = gpi_scaling(out, 1.0 / ratio)
        out[i_alpha] = theta[i_alpha]  # exactly the pinned value
    return out


def _table1_theta(model: Model) -> np.ndarray:
    """Table 1 (with the model's pinned alpha and effects off), for ``model.n_operators``."""
    return _rescaled_to_operators(model.default_theta(), model)


def _data_scaled_theta(record, model: Model) -> np.ndarray | None:
    """Table 1 rescaled to the record's input and output ranges (see module docstring)."""
    theta = _table1_theta(model)
    names = model.names
    peak = float(np.max(np.abs(record.current)))
    if not peak > 0:
        return None
    # the model's default slopes are already per the record's input unit prefix (in_record_units)
    input_scale = peak / PAPER_PEAK_INPUT / record_unit_factors(record)[0]
    for n in _SLOPES:
        i = names.index(n)
        if model.parameters[i].vary:
            theta[i] = theta[i] / input_scale
    return _fit_gain_and_offset(record, model, theta)


def _fit_gain_and_offset(record, model: Model, theta: np.ndarray) -> np.ndarray | None:
    """Scale ``rho, c0, c3, d0, d3`` and shift ``c3, d3`` so the prediction best matches the data
    in linear least squares; None when the output is not finite or the gain is not > 0."""
    names = model.names
    theta = np.clip(theta, model.parameters.lower, model.parameters.upper)
    y, valid = model.evaluate(theta, record.time, record.current)
    if not valid[0]:
        return None
    design = np.column_stack([np.ones(y.shape[1]), y[0]])
    (offset, gain), *_ = np.linalg.lstsq(design, record.displacement, rcond=None)
    if not (np.isfinite(gain) and gain > 0):
        return None
    for n in ("rho", "c0", "c3", "d0", "d3"):
        theta[names.index(n)] *= gain
    for n in ("c3", "d3"):
        theta[names.index(n)] += offset
    return np.clip(theta, model.parameters.lower, model.parameters.upper)


def _classical_theta(record, model: Model) -> np.ndarray | None:
    """Start for positive thresholds: identical mildly saturating envelopes (module docstring)."""
    names = model.names
    alpha = model.parameters["alpha"].value
    peak = float(np.max(np.abs(record.current)))
    if not (alpha > 0 and peak > 0):
        return None
    theta = model.default_theta()
    scale = alpha / abs(float(GPI_PARAMETERS["alpha"].value))  # envelopes scale with |alpha|
    values = {"rho": 1.0 / scale, "tau": 0.5 / scale}
    for branch in ("a", "b"):
        values.update({f"{branch}0": 3.0 * scale, f"{branch}1": 0.5 / peak, f"{branch}2": 0.0, f"{branch}3": 0.0})
    for branch in ("c", "d"):
        values.update({f"{branch}0": 1.0, f"{branch}1": 1.0 / peak, f"{branch}2": 0.0, f"{branch}3": 0.0})
    for n, v in values.items():
        i = names.index(n)
        if model.parameters[i].vary:
            theta[i] = v
    return _fit_gain_and_offset(record, model, _rescaled_to_operators(theta, model))


def _is_time_constant(parameter) -> bool:
    return parameter.unit == "s" and parameter.upper > 0


def _perturbed_theta(base: np.ndarray, model: Model, rng: np.random.Generator, spread: float) -> np.ndarray:
    theta = base.copy()
    n_gpi = len(THETA_NAMES)
    lower, upper = model.parameters.lower, model.parameters.upper
    for i, p in enumerate(model.parameters):
        if not p.vary:
            continue
        z = rng.standard_normal()
        if i < n_gpi:
            theta[i] = base[i] * math.exp(spread * z)
        elif _is_time_constant(p):
            lo = max(p.lower, 1e-3 * p.upper)
            theta[i] = math.exp(rng.uniform(math.log(lo), math.log(p.upper)))
        else:
            width = (p.upper - p.lower) if np.isfinite(p.upper - p.lower) else 1.0
            theta[i] = base[i] + 0.01 * width * z
    return np.clip(theta, lower, upper)


def candidate_starts(record, model: Model, *, n_starts=8, rng=None, start=None) -> list[tuple[str, np.ndarray]]:
    """The multi-start list ``[(label, theta), ...]`` (full vectors within the bounds, finite output).

    Parameters
    ----------
    record : Record
    model : model.Model
    n_starts : int, default 8
        Total number of starts (deterministic ones first, then rng-perturbed).
    rng : numpy.random.Generator, optional
        Default ``numpy.random.default_rng(0)``.
    start : array_like, shape (P,), optional
        A user start, tried first.
    """
    if isinstance(n_starts, bool) or not isinstance(n_starts, (int, np.integer)) or n_starts < 1:
        raise ValueError(f"n_starts must be an integer >= 1, got {n_starts!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    pinned = ~model.parameters.vary
    template = model.parameters.values

    def valid(theta):
        if not model.in_bounds(theta)[0]:
            return False
        return bool(model.evaluate(theta, record.time, record.current)[1][0])

    starts: list[tuple[str, np.ndarray]] = []
    if start is not None:
        theta = np.asarray(start, dtype=float)
        if theta.shape != (model.n_parameters,):
            raise ValueError(f"start must have shape ({model.n_parameters},) for {model!r}, got {theta.shape}")
        theta = np.where(pinned, template, theta)
        if not valid(theta):
            raise ValueError("the given start lies outside the parameter bounds or gives a non-finite model output")
        starts.append(("user", theta))
    if getattr(record, "input_unit", "A") == "A" and getattr(record, "output_unit", "um") == "um":
        theta = np.clip(_table1_theta(model), model.parameters.lower, model.parameters.upper)
        if valid(theta):
            starts.append(("table1", theta))
    scaled = _data_scaled_theta(record, model)
    if scaled is not None and valid(scaled):
        starts.append(("data_scaled", scaled))
    classical = _classical_theta(record, model)
    if classical is not None and valid(classical):
        starts.append(("classical", classical))
        scaled = classical
    if not starts:
        raise ValueError(
            "no valid least-squares start: Table 1 (rescaled to the record) gives a non-finite model "
            "output on this input; pass an explicit start"
        )
    base = starts[-1][1] if scaled is not None else starts[0][1]
    starts = starts[:n_starts]
    k = 0
    while len(starts) < n_starts:
        spread = 0.15
        for _attempt in range(50):
            theta = _perturbed_theta(base, model, rng, spread)
            if valid(theta):
                break
            spread *= 0.8
        else:
            theta = None
        k += 1
        if theta is not None:
            starts.append((f"perturbed-{k}", theta))
        if k > 4 * n_starts:
            break
    return starts


class StallStop:
    """Callback of :func:`scipy.optimize.least_squares` that stops a stalled run.

    After every iteration it records the chi-square ``sum(fun**2)`` at the accepted point
    (``fun``: the whitened residuals) and raises :class:`StopIteration` once the last
    ``window`` iterations together lowered it by less than ``chi2`` (the solver then returns
    status :data:`STALLED`; :func:`solver_verdict` reads that as converged).

    Parameters
    ----------
    window : int, default :data:`STALL_ITERATIONS`
    chi2 : float, default :data:`STALL_CHI2`
        Absolute chi-square (whitened residuals).
    """

    def __init__(self, window: int = STALL_ITERATIONS, chi2: float = STALL_CHI2):
        self.window, self.chi2 = int(window), float(chi2)
        self.history: list[float] = []

    def __call__(self, intermediate_result) -> None:
        f = np.asarray(intermediate_result.fun, dtype=float)
        self.history.append(float(f @ f))
        if len(self.history) > self.window and self.history[-1 - self.window] - self.history[-1] < self.chi2:
            raise StopIteration


def solver_verdict(sol, stall: StallStop | None = None) -> tuple[bool, str]:
    """``(success, message)`` of a :func:`scipy.optimize.least_squares` result, a stall
    counting as converged with its own message, which states the rule of ``stall`` (the
    :class:`StallStop` the run was given; default the default rule)."""
    if sol.status == STALLED:
        stall = StallStop() if stall is None else stall
        return True, (
            f"stalled: the chi-square fell by less than {stall.chi2:g} over the last {stall.window} iterations"
        )
    return bool(sol.success), str(sol.message)


def bounded_solve(residuals: WhitenedResiduals, x0, max_nfev, method=SOLVER_METHOD, tolerance=TOLERANCE):
    """One bounded solver run on ``residuals`` from free vector ``x0``: ``method`` with
    Jacobian scaling, relative tolerances ``tolerance`` and the stall rule (:class:`StallStop`).
    The diagnosis' short refits and polishes run it too."""
    return least_squares(
        residuals,
        x0,
        jac=residuals.jacobian,
        bounds=(residuals.lower, residuals.upper),
        method=method,
        x_scale="jac",
        ftol=tolerance,
        xtol=tolerance,
        gtol=tolerance,
        max_nfev=max_nfev,
        callback=StallStop(),
    )


def _converged(residuals: WhitenedResiduals, sol, note: str = "") -> _PolishedStart:
    """``sol`` run on to convergence with :data:`SOLVER_METHOD` when it stopped at its
    evaluation cap (status 0), as a :class:`_PolishedStart` (``note`` appended to the message)."""
    if sol.status == 0:
        sol = bounded_solve(residuals, sol.x, POLISH_EVALUATIONS)
    success, message = solver_verdict(sol)
    return _PolishedStart(np.asarray(sol.x, dtype=float), 2.0 * float(sol.cost), success, f"{message}{note}")


def _gpi_at_bound(residuals: WhitenedResiduals, x) -> list[str]:
    """Names of the free GPI parameters of free vector ``x`` that sit on a box bound."""
    n_gpi = len(THETA_NAMES)
    names = []
    for j, column in enumerate(residuals.free):
        if column >= n_gpi:
            continue
        lo, hi = residuals.lower[j], residuals.upper[j]
        tol = 1e-9 * max(1.0, hi - lo)
        if x[j] <= lo + tol or x[j] >= hi - tol:
            names.append(residuals.model.names[column])
    return names


@dataclass(frozen=True)
class _PolishedStart:
    """End of one polished start: free vector, exact chi-square, solver verdict."""

    x: np.ndarray
    chi2: float
    success: bool
    message: str


def fit_least_squares(
    record,
    model: Model,
    *,
    noise=None,
    start=None,
    n_starts=8,
    rng=None,
    verbose=False,
    n_polish=N_POLISH,
    threshold_sign="auto",
) -> FitResult:
    """Least-squares fit of ``model`` to ``record`` (method in the module docstring).

    Parameters are those of :func:`_fit_one_sign`, plus

    threshold_sign : {"auto", "negative", "positive"}, default "auto"
        Sign of the pinned ``alpha`` (module docstring, "Sign of the thresholds"). Applies
        when ``alpha`` is pinned and the reading is "swapped"; "auto" fits both signs
        unless ``start`` is given (its ``alpha`` decides). Ignored when ``alpha`` is free.

    Returns
    -------
    FitResult
        The better fit; ``fit.model`` carries the chosen sign.
    """
    from dataclasses import replace

    if threshold_sign not in THRESHOLD_SIGNS:
        raise ValueError(f"threshold_sign must be one of {sorted(THRESHOLD_SIGNS)}, got {threshold_sign!r}")
    options = dict(noise=noise, start=start, n_starts=n_starts, rng=rng, verbose=verbose, n_polish=n_polish)
    alpha = model.parameters["alpha"]
    if alpha.vary or model.reading != "swapped":
        return _fit_one_sign(record, model, **options)
    if start is not None:
        start_alpha = float(np.asarray(start, dtype=float)[model.names.index("alpha")])
        signs = (1 if start_alpha > 0 else -1,)
    else:
        signs = THRESHOLD_SIGNS[threshold_sign]
    fits, failures = [], []
    for sign in signs:
        try:
            fits.append(_fit_one_sign(record, with_threshold_sign(model, sign), **options))
        except ValueError as exc:
            if "no valid least-squares start" not in str(exc):
                raise
            failures.append(f"alpha {'>' if sign > 0 else '<'} 0: {exc}")
    if not fits:
        raise ValueError("; ".join(failures))

    # Compare the whitened chi-square in the caller's noise units: with a free sigma each
    # fit's reduced chi-square is 1 by construction, so rescale by its own sigma estimate.
    def mean_square(f):
        return f.reduced_chi2 * f.noise.sigma**2

    best = min(fits, key=mean_square)
    # Within AGREE_CHI2 of each other the two signs fit equally well (e.g. on the paper's own
    # transducer both signs can reach the same chi-square): keep the paper's sign then.
    dof = best.residual.size - int(best.vary.sum())
    tied = [f for f in fits if (mean_square(f) - mean_square(best)) * dof / best.noise.sigma**2 <= AGREE_CHI2]
    tie_note = ""
    if len(tied) > 1:
        best = min(tied, key=lambda f: f.model.parameters["alpha"].value)
        tie_note = f"; the signs agree within chi-square {AGREE_CHI2:g}, so the paper's (alpha < 0) is kept"
    if len(signs) > 1:
        notes = [
            f"alpha {'>' if f.model.parameters['alpha'].value > 0 else '<'} 0 reached reduced chi-square "
            f"{f.reduced_chi2:.4g}, residual RMS {f.rms:.4g}"
            for f in fits
        ] + failures
        chosen = "positive" if best.model.parameters["alpha"].value > 0 else "negative"
        best = replace(best, message=f"{best.message}; threshold sign {chosen} chosen ({'; '.join(notes)}){tie_note}")
    return best


def _fit_one_sign(
    record, model: Model, *, noise=None, start=None, n_starts=8, rng=None, verbose=False, n_polish=N_POLISH
) -> FitResult:
    """Least-squares fit of ``model`` as given (its pinned parameters, alpha's sign included).

    The steps: the checks (:func:`_checked_residuals`), the starts
    (:func:`candidate_starts`), the search from them (:func:`_run_starts`: screen, polish,
    the alternate method at a bound) and the fit's statistics (:func:`_fit_result`).

    Parameters
    ----------
    record : identify.data.records.Record
        ``time`` [s], ``current`` [input unit], ``displacement`` [output unit], shape (T,).
    model : model.Model
        The model; parameters with ``vary=False`` stay pinned.
    noise : NoiseModel, optional
        Default :func:`identify.fitting.noise.estimate_noise` ``(record)`` (raises when the
        record has no quiet start: pass a user or free noise model then).
    start : array_like, shape (P,), optional
        Extra start, tried first.
    n_starts : int, default 8
        Number of starts (see :func:`candidate_starts`).
    rng : numpy.random.Generator, optional
        For the perturbed starts; default ``numpy.random.default_rng(0)``.
    verbose : bool, default False
        One line per start logged at INFO (``identify.fitting.lsq``); at DEBUG when False (shown by ``-v``).
    n_polish : int, default :data:`N_POLISH`
        How many of the best screened starts are run to convergence.

    Returns
    -------
    FitResult
    """
    model = in_record_units(model, record)  # default bounds in the record's unit prefixes
    t0 = _time.perf_counter()
    noise, residuals = _checked_residuals(record, model, noise)
    starts = candidate_starts(record, model, n_starts=n_starts, rng=rng, start=start)
    best, outcomes = _run_starts(residuals, starts, n_polish, verbose)
    return _fit_result(record, model, residuals, noise, best, outcomes, len(starts), t0)


def _checked_residuals(record, model: Model, noise) -> tuple[NoiseModel, WhitenedResiduals]:
    """``(noise, whitened residuals)``, refusing a fit with nothing free or too few samples."""
    noise = estimate_noise(record) if noise is None else noise
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise must be a NoiseModel, got {type(noise).__name__}")
    residuals = WhitenedResiduals(record, model, noise)
    free = residuals.free
    if free.size == 0:
        raise ValueError("every parameter is pinned: nothing to fit")
    n_samples = residuals.data.size
    if n_samples <= free.size:
        raise ValueError(f"{n_samples} samples cannot determine {free.size} free parameters")
    return noise, residuals


class _StartLog:
    """The outcome of every start, in order, and the best polished end so far."""

    def __init__(self, verbose: bool):
        self.level = logging.INFO if verbose else logging.DEBUG
        self.outcomes: list[StartOutcome] = []
        self.ends: list[tuple[str, _PolishedStart]] = []
        self.best = None

    def screened_out(self, label, sol, n_eval):
        message = f"screened out after {SCREEN_EVALUATIONS} evaluations (not run to convergence)"
        self.outcomes.append(StartOutcome(label, 2.0 * float(sol.cost), n_eval, solver_verdict(sol)[0], message))

    def keep(self, label, end: _PolishedStart, n_eval):
        self.outcomes.append(StartOutcome(label, end.chi2, n_eval, end.success, end.message))
        self.ends.append((label, end))
        _log.log(self.level, f"  polish {label:<14} chi2 = {end.chi2:.6g}  ({end.message})")
        if self.best is None or end.chi2 < self.best.chi2:
            self.best = end


def _run_starts(residuals, starts, n_polish: int, verbose: bool) -> tuple[_PolishedStart, list]:
    """``(best end, outcomes)`` of the search from ``starts``, with numba's fastest thread count
    and single-threaded BLAS: phase 1 screens every start with a few steps of each solver
    method, phase 2 runs the most promising to convergence (module docstring), phase 3
    (:func:`_polish_at_bound`), phase 4 (:func:`_polish_in_coordinates`)."""
    import numba

    free = residuals.free
    threads_before = numba.get_num_threads()
    x_probe = np.repeat(np.clip(starts[0][1][free], residuals.lower, residuals.upper)[None, :], free.size + 1, axis=0)
    fastest_thread_count(residuals.batch, x_probe)
    log = _StartLog(verbose)
    try:
        with single_threaded_blas():
            # Phase 1: screen every start with a few steps of each method.
            screened, origins, alternate = [], [], []
            for label, theta0 in starts:
                x0 = np.clip(theta0[free], residuals.lower, residuals.upper)
                before = residuals.n_evaluations
                sol = bounded_solve(residuals, x0, SCREEN_EVALUATIONS)
                sol_alternate = bounded_solve(residuals, x0, SCREEN_EVALUATIONS, method=ALTERNATE_METHOD)
                screened.append((label, sol, residuals.n_evaluations - before))
                alternate.append(sol_alternate)
                origins.append(x0)
                _log.log(
                    log.level,
                    f"  screen {label:<14} chi2 = {2 * sol.cost:.6g} ({SOLVER_METHOD}), "
                    f"{2 * sol_alternate.cost:.6g} ({ALTERNATE_METHOD})",
                )
            # Phase 2: run the most promising ends to convergence: the n_polish best after
            # dogbox's screening, and the N_POLISH_ALTERNATE best after trf's.
            order = sorted(range(len(screened)), key=lambda k: screened[k][1].cost)
            polish = set(order[:n_polish])
            order_alternate = sorted(range(len(screened)), key=lambda k: alternate[k].cost)
            polish_alternate = set(order_alternate[:N_POLISH_ALTERNATE]) if n_polish > 0 else set()
            for k, (label, sol, n_eval) in enumerate(screened):
                if k not in polish | polish_alternate:
                    log.screened_out(label, sol, n_eval)
                    continue
                if k in polish:
                    before = residuals.n_evaluations
                    end = _converged(residuals, sol)
                    log.keep(label, end, n_eval + residuals.n_evaluations - before)
                if k in polish_alternate:
                    before = residuals.n_evaluations
                    end = _converged(residuals, alternate[k], f" (run on from {ALTERNATE_METHOD}'s screening)")
                    screening = 0 if k in polish else n_eval  # the screening's evaluations, counted once
                    log.keep(
                        f"{label} ({ALTERNATE_METHOD} screening)", end, screening + residuals.n_evaluations - before
                    )
            _polish_at_bound(residuals, screened, origins, polish, log)
            _polish_in_coordinates(residuals, log)
    finally:
        numba.set_num_threads(threads_before)
    return log.best, log.outcomes


def _polish_at_bound(residuals, screened, origins, polish, log: _StartLog) -> None:
    """Phase 3: an optimum with a GPI parameter on its box bound is a degenerate limit (e.g.
    an Omega branch whose tanh is stretched into a line: c0 at -1000, c1 -> 0), into which
    dogbox's large steps can fall; the same starts are then polished from their origin with
    the interior, reflective method (trf) too, finished by dogbox."""
    gpi_at_bound = _gpi_at_bound(residuals, log.best.x)
    if not gpi_at_bound:
        return
    note = f" ({ALTERNATE_METHOD} from the start: the {SOLVER_METHOD} optimum had {', '.join(gpi_at_bound)} on a bound)"
    for k in sorted(polish):
        before = residuals.n_evaluations
        sol = bounded_solve(residuals, origins[k], POLISH_EVALUATIONS, method=ALTERNATE_METHOD)
        end = _converged(residuals, sol, note)
        log.keep(f"{screened[k][0]} ({ALTERNATE_METHOD})", end, residuals.n_evaluations - before)


class _ResidualsInCoordinates:
    """The whitened residuals as a function of the sampler coordinates ``u``
    (:mod:`identify.fitting.coordinates`), for an unbounded solver: a ``u`` whose parameters
    leave their box (or the map's range) gets :data:`DOMAIN_PENALTY`, so the step is refused."""

    def __init__(self, residuals: WhitenedResiduals, coordinates):
        self.residuals = residuals
        self.coordinates = coordinates

    def parameters(self, u_rows) -> tuple[np.ndarray, np.ndarray]:
        """Free vectors ``(B, P_free)`` of coordinate rows ``(B, P_free)`` and whether each is usable."""
        x = self.coordinates.inverse(np.atleast_2d(u_rows))
        res = self.residuals
        inside = np.isfinite(x).all(axis=1) & (x >= res.lower).all(axis=1) & (x <= res.upper).all(axis=1)
        return np.where(inside[:, None], x, np.clip(np.nan_to_num(x), res.lower, res.upper)), inside

    def __call__(self, u) -> np.ndarray:
        x, inside = self.parameters(u)
        return self.residuals(x[0]) if inside[0] else np.full(self.residuals.data.size, DOMAIN_PENALTY)

    def jacobian(self, u) -> np.ndarray:
        """Forward differences in ``u`` from one batch (a column whose step leaves the box: zero)."""
        u = np.asarray(u, dtype=float)
        steps = np.finfo(float).eps ** 0.5 * np.maximum(np.abs(u), 0.01)
        rows = np.repeat(u[None, :], u.size + 1, axis=0)
        rows[1:][np.arange(u.size), np.arange(u.size)] += steps
        x, inside = self.parameters(rows)
        w, valid = self.residuals.batch(x)
        usable = inside & valid
        jac = np.zeros((self.residuals.data.size, u.size))
        if usable[0]:
            difference_columns(w, w[0], steps, np.flatnonzero(usable[1:]), jac)
        return jac


def _polish_in_coordinates(residuals: WhitenedResiduals, log: _StartLog) -> None:
    """Phase 4: every polished end once more, in the sampler coordinates
    (:class:`identify.fitting.coordinates.GPICoordinates`: total weight and threshold moment,
    the envelopes' values over the input range, the tanh centres), kept where it lowers the
    chi-square.

    In the parameters the GPI's valleys are curved (the weights trade against the
    envelopes' amplitudes along products, a tanh's slope against its offset along a ratio);
    a solver following one takes many short steps and can stop at its evaluation cap far
    from the floor. In the sampler coordinates those valleys are nearly straight: on the
    SMA record (``docs/realdata.md``) the ends that had stopped at the cap reached lower
    optima in 25-40 steps. The solver is trf without bounds in ``u``; a step whose
    parameters leave their box is refused through :data:`DOMAIN_PENALTY`.
    """
    coordinates = GPICoordinates.for_model(residuals.model, residuals.time, residuals.current)
    if not getattr(coordinates, "blocks", ()):
        return
    in_u = _ResidualsInCoordinates(residuals, coordinates)
    for label, end in list(log.ends):
        before = residuals.n_evaluations
        try:
            u0 = coordinates.forward(end.x[None, :])[0]
        except (ValueError, FloatingPointError):
            continue
        if not np.isfinite(u0).all():
            continue
        sol = least_squares(
            in_u,
            u0,
            jac=in_u.jacobian,
            method=ALTERNATE_METHOD,
            x_scale="jac",
            ftol=TOLERANCE,
            xtol=TOLERANCE,
            gtol=TOLERANCE,
            max_nfev=POLISH_EVALUATIONS,
            callback=StallStop(),
        )
        x, inside = in_u.parameters(sol.x)
        if not inside[0]:
            continue
        chi2 = 2.0 * float(sol.cost)  # the residual at sol.x is the parameters' (inside the box), as in _converged
        if chi2 < end.chi2:
            success, message = solver_verdict(sol)
            polished = _PolishedStart(x[0], chi2, success, f"{message} (again in the sampler coordinates)")
            log.keep(f"{label} (coordinates)", polished, residuals.n_evaluations - before)


def _canonical(residuals: WhitenedResiduals, x) -> np.ndarray:
    """Free vector ``x`` in the model's canonical labelling (:meth:`model.Model.canonical_theta`,
    e.g. a two-node ``thermal`` with the faster node first): the same output, so the same
    optimum, in the half of the parameter space the posterior samples."""
    theta = residuals.full(x)
    canonical = residuals.model.canonical_theta(theta)
    if np.array_equal(canonical, theta):
        return x
    mapped = canonical[residuals.free]
    return mapped if np.isfinite(residuals(mapped)).all() else x


def _fit_result(
    record, model: Model, residuals, noise: NoiseModel, best: _PolishedStart, outcomes, n_starts: int, t0: float
) -> FitResult:
    """The :class:`FitResult` at ``best``: a free sigma estimated from the chi-square, the
    covariance from the central Jacobian, the residual, RMS and maximum error on the energised part."""
    free = residuals.free
    n_samples = residuals.data.size
    x_best = _canonical(residuals, best.x)
    w = residuals(x_best)
    chi2 = float(w @ w)
    dof = n_samples - free.size
    if noise.is_free:
        sigma_hat = math.sqrt(chi2 / dof)
        noise = noise.with_sigma(sigma_hat)
        scale2 = sigma_hat**2
    else:
        scale2 = 1.0
    with single_threaded_blas():
        jac = residuals.central_jacobian(x_best)
    cov_free = scale2 * np.linalg.pinv(jac.T @ jac, rcond=1e-15, hermitian=True)
    n_par = model.n_parameters
    covariance = np.zeros((n_par, n_par))
    covariance[np.ix_(free, free)] = cov_free
    stderr = np.full(n_par, np.nan)
    stderr[free] = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))

    theta = residuals.full(x_best)
    y = model(theta, record.time, record.current)
    residual = np.asarray(record.displacement, dtype=float) - y
    energised = energised_mask(record, noise)
    span = float(np.ptp(record.displacement))
    rms = float(np.sqrt(np.mean(residual[energised] ** 2)))
    max_error_pct = float(100.0 * np.max(np.abs(residual[energised])) / span) if span > 0 else math.inf
    reduced_chi2 = chi2 / scale2 / dof
    # a start polished again (phases 3 and 4 label it "<start> (<how>)") is still one start
    n_agree = len({o.label.split(" (")[0] for o in outcomes if (o.chi2 - best.chi2) / scale2 <= AGREE_CHI2})
    return FitResult(
        model=model,
        theta=theta,
        stderr=stderr,
        covariance=covariance,
        vary=model.parameters.vary.copy(),
        residual=residual,
        rms=rms,
        max_error_pct=max_error_pct,
        reduced_chi2=float(reduced_chi2),
        noise=noise,
        n_starts=n_starts,
        success=bool(best.success),
        message=str(best.message),
        seconds=_time.perf_counter() - t0,
        n_agree=int(n_agree),
        starts=outcomes,
    )
