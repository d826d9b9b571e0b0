r"""Several records of one transducer: one least-squares fit of shared and per-record parameters.

The transducer's physics is the same in every record (its hysteresis, heating, lag, creep);
what belongs to the run is not. :class:`JointModel` lays out one parameter vector for ``K``
records of one :class:`model.Model`:

* every parameter of the model, shared by all records; for the first record these are also
  its own run parameters;
* for each further record ``r = 2..K``: its own copy of every parameter the effects declare to
  belong to the run (:attr:`model.Parameter.per_record`: a sensor's drift, the state a run
  starts from, a virgin material's first-cycle amplitudes), named ``<name>_r<r>``, and the
  sensor's zero of that record, ``zero_r<r>`` (an output offset; the first record's is carried
  by the GPI's own offsets).

:class:`JointResiduals` concatenates each record's whitened residual, each whitened with the
record's own noise model (its own quiet start), so the likelihood is the sum over records;
:func:`fit_joint` fits it from the records' separate fits. A single record is the model itself:
nothing here runs for it.

Whether records belong together: :func:`consistency` compares the joint chi-square with the sum
of the separate ones. Under the hypothesis that they share the transducer, the excess is a
chi-square with as many degrees of freedom as the joint fit has fewer parameters; a model that
misses an effect makes every record's compromise its own and inflates the excess too, so a
record is named as disagreeing only when it also fits clearly worse jointly than alone.
"""

from __future__ import annotations

import hashlib
import math
import time as _time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from model import Model, Parameter, ParameterSet

from ..data.records import RecordError
from .lsq import POLISH_EVALUATIONS, FitResult, WhitenedResiduals, bounded_solve, fit_least_squares
from .noise import NoiseModel, NoQuietSegmentError, energised_mask, estimate_noise, whiten_rows
from .threads import single_threaded_blas

__all__ = [
    "check_records",
    "JointModel",
    "JointResiduals",
    "JointFit",
    "fit_joint",
    "joint_start",
    "joint_fit_at",
    "consistency",
    "record_suffix",
    "with_earlier_runs",
    "earlier_run_state",
    "warm_value",
    "joint_fit_from_json",
    "record_noises",
    "separate_fits",
    "joint_manifest_data",
    "leave_one_record_out",
    "predict_left_out",
]

#: A joint fit whose chi-square exceeds the separate fits' sum with a p-value below this is
#: inconsistent (the records do not share the parameters), and a record that also fits worse
#: jointly than alone by :data:`DISAGREEING_RMS_RISE` is named.
CONSISTENCY_P = 1e-6
#: The relative rise of a record's RMS from its separate fit to the joint fit that names it as
#: the one that disagrees.
DISAGREEING_RMS_RISE = 0.10


def check_records(records) -> list:
    """The records as a list, refused with the record named when they cannot be one transducer's
    records: none, other units than the first's, or one given twice (the same data)."""
    records = list(records)
    if not records:
        raise RecordError("no record given: the list of records is empty")
    first = records[0]
    units = (getattr(first, "input_unit", "A"), getattr(first, "output_unit", "um"))
    seen = {}
    for r, record in enumerate(records, start=1):
        these = (getattr(record, "input_unit", "A"), getattr(record, "output_unit", "um"))
        if these != units:
            raise RecordError(
                f"{record.source}: drive in {these[0]} and output in {these[1]}, where {first.source} has "
                f"{units[0]} and {units[1]}: the records of one transducer share their units"
            )
        key = getattr(record, "sha256", "") or None
        if key is None:
            key = (len(record.time), float(np.sum(record.displacement)), float(np.sum(record.current)))
        if key in seen:
            raise RecordError(f"{record.source}: the same data as record {seen[key]}: a record given twice")
        seen[key] = r
    return records


def record_suffix(r: int) -> str:
    """The suffix of record ``r``'s own parameters (``r`` from 1): ``_r2`` for the second."""
    return f"_r{r}"


def with_earlier_runs(model: Model) -> Model:
    """``model`` with the run parameters of the state earlier runs left free
    (:attr:`model.Effect.earlier_run_terms`: a coil still warm from the last run), where a
    single record pins them: records of a transducer are taken one after another, and any of
    them may start where earlier runs left it."""
    parameters = model.parameters
    for effect in model.effects:
        for name in type(effect).earlier_run_parameters(parameters):
            if not parameters[name].vary:
                parameters = parameters.replace(name, vary=True)
    return model if parameters is model.parameters else model.with_parameters(parameters)


def earlier_run_state(model: Model) -> list[tuple[str, float]]:
    """``[(parameter name, off value)]`` of the state earlier runs leave in ``model``
    (:attr:`model.Effect.earlier_run_terms`: a heating's start rises), effect by effect."""
    return [
        (n, type(e).off[n]) for e in model.effects for term in type(e).earlier_run_terms for n in type(e).terms[term]
    ]


def warm_value(parameter, off: float) -> float:
    """Halfway from ``off`` to ``parameter``'s farther bound: where a start puts a state earlier
    runs left (:func:`earlier_run_state`) to meet it from inside its range.

    A record's own fit pins that state at its off value, so every start made from fits meets it
    from the cold side only; a run that starts warm and cools through the record is another basin
    of the effect's own parameters (slow time constants, a cooling of the other sign) that a cold
    start need not lead to."""
    far = parameter.upper if parameter.upper - off >= off - parameter.lower else parameter.lower
    return off + 0.5 * (far - off)


class JointModel:
    """One model's parameters laid out for ``n_records`` records (module docstring).

    Parameters
    ----------
    model : Model
        The transducer's model (its pinned parameters stay pinned in every record).
    n_records : int
        ``K >= 1``.
    zero_bound : float, default 1000.0
        The bound of every ``zero_r`` [output unit].
    """

    def __init__(self, model: Model, n_records: int, zero_bound: float = 1000.0):
        if n_records < 1:
            raise ValueError(f"a joint model needs at least one record, got {n_records}")
        self.model = model
        self.n_records = int(n_records)
        self.zero_bound = float(zero_bound)
        self.per_record = tuple(p.name for p in model.parameters if p.per_record)
        parameters = list(model.parameters)
        for r in range(2, self.n_records + 1):
            for name in self.per_record:
                p = model.parameters[name]
                parameters.append(p.with_(name=name + record_suffix(r), description=f"{p.description} (record {r})"))
            parameters.append(
                Parameter(
                    f"zero{record_suffix(r)}",
                    0.0,
                    -zero_bound,
                    zero_bound,
                    unit="um",
                    description=f"the sensor's zero of record {r} against record 1's",
                )
            )
        self.parameters = ParameterSet(parameters)
        self.names = self.parameters.names
        self.n_parameters = len(self.names)
        n_model = model.n_parameters
        self._own = [np.arange(n_model)]  # record r's model vector: columns of the joint vector
        self._zero = [None]
        columns = {name: i for i, name in enumerate(self.names)}
        for r in range(2, self.n_records + 1):
            own = np.arange(n_model)
            for name in self.per_record:
                own[model.names.index(name)] = columns[name + record_suffix(r)]
            self._own.append(own)
            self._zero.append(columns[f"zero{record_suffix(r)}"])

    def __repr__(self) -> str:
        return f"JointModel({self.model!r}, n_records={self.n_records})"

    def columns_of(self, name: str) -> tuple[int, ...]:
        """The joint vector's columns that hold the model's parameter ``name`` on the records:
        one column for a parameter the records share, one per record (record 1's first) for a
        per-record one."""
        if name not in self.model.names:
            raise KeyError(f"{name!r} is not a parameter of {self.model!r}")
        i = self.model.names.index(name)
        return tuple(dict.fromkeys(int(own[i]) for own in self._own))

    def __add__(self, effect) -> JointModel:
        return JointModel(self.model + effect, self.n_records, self.zero_bound)

    @property
    def effect_names(self) -> tuple[str, ...]:
        return self.model.effect_names

    @property
    def n_operators(self) -> int:
        return self.model.n_operators

    @property
    def reading(self) -> str:
        return self.model.reading

    @property
    def has_canonical_domain(self) -> bool:
        return self.model.has_canonical_domain

    def in_canonical_domain(self, theta) -> np.ndarray:
        """Boolean ``(W,)``: every record's vector in the model's canonical labelling."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        ok = np.ones(theta.shape[0], dtype=bool)
        for r in range(1, self.n_records + 1):
            ok &= np.asarray(self.model.in_canonical_domain(self.record_rows(theta, r)[0]), dtype=bool)
        return ok

    def default_theta(self) -> np.ndarray:
        return self.parameters.values.copy()

    def in_bounds(self, theta) -> np.ndarray:
        theta = np.atleast_2d(theta)
        return np.all((theta >= self.parameters.lower) & (theta <= self.parameters.upper), axis=1)

    def record_rows(self, theta, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Record ``r``'s (from 1) model vectors ``(W, P)`` and zeros ``(W,)`` from joint vectors ``(W, P_joint)``."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        rows = theta[:, self._own[r - 1]]
        zero = np.zeros(theta.shape[0]) if self._zero[r - 1] is None else theta[:, self._zero[r - 1]]
        return rows, zero

    def record_theta(self, theta, r: int) -> np.ndarray:
        """Record ``r``'s model vector ``(P,)`` from one joint vector (its zero not included)."""
        return self.record_rows(theta, r)[0][0]

    def joint_theta(self, thetas, zeros=None) -> np.ndarray:
        """The joint vector of per-record model vectors ``thetas`` (record 1's shared values
        from ``thetas[0]``) and zeros (default 0)."""
        theta = np.empty(self.n_parameters)
        theta[: self.model.n_parameters] = thetas[0]
        for r in range(2, self.n_records + 1):
            own = self._own[r - 1]
            extra = own >= self.model.n_parameters
            theta[own[extra]] = np.asarray(thetas[r - 1], dtype=float)[extra]
            theta[self._zero[r - 1]] = 0.0 if zeros is None else float(zeros[r - 1])
        return theta


class JointResiduals(WhitenedResiduals):
    """The records' whitened residuals concatenated, as a function of the joint free parameters
    (the interface of :class:`~identify.fitting.lsq.WhitenedResiduals`: the solvers, Jacobians
    and covariance work on it unchanged)."""

    def __init__(self, records, joint: JointModel, noises):
        if len(records) != joint.n_records or len(noises) != joint.n_records:
            raise ValueError(f"{joint!r} needs {joint.n_records} records and noise models")
        self.records = list(records)
        self.noises = list(noises)
        self.parts = []
        for record, noise in zip(self.records, self.noises):
            time = np.asarray(record.time, dtype=float)
            self.parts.append(
                (
                    time,
                    np.asarray(record.current, dtype=float),
                    np.asarray(record.displacement, dtype=float),
                    noise,
                    noise.step_correlations(time),  # each step's r_k on an uneven grid, else None
                    1.0 if noise.is_free else noise.sigma,
                )
            )
        self.bounds = np.cumsum([0] + [len(r.time) for r in self.records])
        self.data = np.concatenate([part[2] for part in self.parts])
        self.model = joint
        self.noise = self.noises[0]
        self.sigma = 1.0
        self.free = np.flatnonzero(joint.parameters.vary)
        self.template = joint.parameters.values.copy()
        self.lower = joint.parameters.lower[self.free]
        self.upper = joint.parameters.upper[self.free]
        self.n_evaluations = 0
        self._cache_x = None
        self._cache_r = None
        self._cache_valid = False

    def batch(self, x_rows) -> tuple[np.ndarray, np.ndarray]:
        thetas = self.full(np.atleast_2d(x_rows))
        out = np.empty((thetas.shape[0], self.data.size))
        valid = np.ones(thetas.shape[0], dtype=bool)
        for r, (time, current, data, noise, correlations, sigma) in enumerate(self.parts, start=1):
            rows, zero = self.model.record_rows(thetas, r)
            y, ok = self.model.model.evaluate(rows, time, current)
            w, finite = whiten_rows(data, y + zero[:, None], noise, sigma, correlations=correlations)
            out[:, self.bounds[r - 1] : self.bounds[r]] = w
            valid &= ok & finite
        self.n_evaluations += thetas.shape[0]
        return out, valid

    def record_part(self, w, r: int) -> np.ndarray:
        """Record ``r``'s (from 1) part of a concatenated residual."""
        return w[..., self.bounds[r - 1] : self.bounds[r]]


@dataclass
class JointFit:
    """A joint least-squares fit of several records.

    Attributes
    ----------
    joint : JointModel
    theta, stderr : ndarray, shape (P_joint,)
    covariance : ndarray, shape (P_joint, P_joint)
    chi2 : float
        Whitened chi-square summed over the records.
    records : list of Record
    noises : list of NoiseModel
    fits : list of FitResult
        Each record's own fit at the joint optimum (its model vector, residual, RMS, max error).
    separate : list of FitResult
        Each record fitted alone.
    consistency : dict
        :func:`consistency`.
    seconds : float
    """

    joint: JointModel
    theta: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    chi2: float
    records: list
    noises: list
    fits: list
    separate: list
    consistency: dict = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def model(self) -> Model:
        return self.joint.model

    @property
    def rms(self) -> float:
        """RMS over every record's energised part [output unit]."""
        squares = [np.sum(f.residual[energised_mask(rec, f.noise)] ** 2) for f, rec in zip(self.fits, self.records)]
        counts = [int(np.sum(energised_mask(rec, f.noise))) for f, rec in zip(self.fits, self.records)]
        return float(math.sqrt(sum(squares) / max(sum(counts), 1)))

    def theta_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.joint.names, self.theta)}

    def to_dict(self) -> dict:
        return {
            "model": self.model.to_dict(),
            "n_records": self.joint.n_records,
            "theta": self.theta_dict(),
            "stderr": {n: (None if not np.isfinite(s) else float(s)) for n, s in zip(self.joint.names, self.stderr)},
            "chi2": float(self.chi2),
            "rms": self.rms,
            "records": [
                {
                    "source": rec.source,
                    "samples": len(rec.time),
                    "noise": f.noise.to_dict(),
                    "rms": float(f.rms),
                    "max_error_pct": float(f.max_error_pct),
                    "separate_rms": float(s.rms),
                }
                for rec, f, s in zip(self.records, self.fits, self.separate)
            ],
            "consistency": dict(self.consistency),
            "seconds": float(self.seconds),
        }

    def to_json(self) -> dict:
        """``fit.json`` of several records: record 1's own fit at the joint optimum (what a reader
        of one record's ``fit.json`` finds: the shared parameters and record 1's run), with the
        joint fit (:meth:`to_dict`, its names, vector, covariance, zero bound and the records'
        separate fits) under ``"joint"`` and the records under ``"records"``.
        :func:`joint_fit_from_json` rebuilds it."""
        joint = self.to_dict()
        joint.update(
            names=list(self.joint.names),
            theta_vector=[float(v) for v in self.theta],
            covariance=[[float(v) for v in row] for row in self.covariance],
            zero_bound=float(self.joint.zero_bound),
            separate=[f.to_dict() for f in self.separate],
        )
        return {**self.fits[0].to_dict(), "joint": joint, "records": joint["records"]}


def _record_fit(
    record, model: Model, theta, zero: float, noise: NoiseModel, template: FitResult, covariance=None
) -> FitResult:
    """Record's own :class:`FitResult` at a joint optimum (its vector, residual, RMS, max error;
    with ``covariance`` ``(P, P)``, the joint covariance of its vector's columns, also its
    covariance and standard errors)."""
    uncertainty = {}
    if covariance is not None:
        covariance = np.asarray(covariance, dtype=float)
        stderr = np.full(model.n_parameters, np.nan)
        vary = model.parameters.vary
        stderr[vary] = np.sqrt(np.clip(np.diag(covariance)[vary], 0.0, None))
        uncertainty = {"covariance": covariance, "stderr": stderr}

    y = model(theta, record.time, record.current) + zero
    residual = np.asarray(record.displacement, dtype=float) - y
    energised = energised_mask(record, noise)
    span = float(np.ptp(record.displacement))
    w = whiten_rows(
        np.asarray(record.displacement, dtype=float), y[None, :], noise, 1.0 if noise.is_free else noise.sigma
    )[0][0]
    dof = max(residual.size - int(model.parameters.vary.sum()), 1)
    return replace(
        template,
        model=model,
        theta=np.asarray(theta, dtype=float),
        residual=residual,
        rms=float(np.sqrt(np.mean(residual[energised] ** 2))),
        max_error_pct=float(100.0 * np.max(np.abs(residual[energised])) / span) if span > 0 else math.inf,
        reduced_chi2=float(w @ w) / dof,
        noise=noise,
        **uncertainty,
    )


def consistency(joint_fit_chi2: float, separate, joint: JointModel, fits, records) -> dict:
    """Do the records share the transducer? ``{"statistic", "dof", "p", "consistent",
    "disagreeing", "message"}``: the joint chi-square's excess over the separate fits' sum
    against a chi-square of as many degrees of freedom as the joint fit has fewer free
    parameters; the record whose RMS rises most from its separate fit is named when the test
    fails and that rise exceeds :data:`DISAGREEING_RMS_RISE`."""
    k = joint.n_records
    separate_free = sum(int(f.vary.sum()) for f in separate)
    dof = max(separate_free - int(joint.parameters.vary.sum()), 1)
    excess = float(joint_fit_chi2 - sum(f.chi2 for f in separate))
    p = float(stats.chi2.sf(max(excess, 0.0), dof)) if k > 1 else 1.0
    rises = [(f.rms / s.rms - 1.0 if s.rms > 0 else 0.0) for f, s in zip(fits, separate)]
    worst = int(np.argmax(rises)) if rises else 0
    disagreeing = None
    if k > 1 and p < CONSISTENCY_P and rises[worst] > DISAGREEING_RMS_RISE:
        disagreeing = records[worst].source
    message = ""
    if disagreeing is not None:
        message = (
            f"the records do not look like one transducer: the joint fit's chi-square exceeds the separate fits' "
            f"by {excess:.0f} ({dof} degrees of freedom, p = {p:.1e}), and {disagreeing} fits "
            f"{100 * rises[worst]:.0f} % worse in RMS jointly ({fits[worst].rms:.4g}) than alone "
            f"({separate[worst].rms:.4g}): another transducer, other units, a sensor re-zeroed with a gain change, "
            "or a physical effect the model misses that acts differently on the records' drives (diagnose them "
            "together)"
        )
    return {
        "statistic": excess,
        "dof": dof,
        "p": p,
        "consistent": disagreeing is None,
        "disagreeing": disagreeing,
        "rms_rise": [float(x) for x in rises],
        "message": message,
    }


def fit_joint(
    records, model: Model, noises=None, *, n_starts: int = 4, rng=None, separate=None, progress=None
) -> JointFit:
    """Least squares of ``model`` on several records at once (module docstring).

    Each record is fitted alone first (:func:`identify.fitting.lsq.fit_least_squares`, unless
    ``separate`` gives those fits); every separate fit then starts the joint fit (its shared
    parameters for all records, each record's own run parameters from its own fit where the
    threshold signs agree, the zeros from the records' mean residuals), polished on the joint
    residual; the lowest joint chi-square wins.

    Parameters
    ----------
    records : sequence of Record
        Two or more records of one transducer, in the same units.
    model : Model
        The transducer's model (normalised: :func:`identify.fitting.parametrisation.normalised_model`).
    noises : sequence of NoiseModel, optional
        Each record's noise; default its own quiet start (:func:`identify.fitting.noise.estimate_noise`).
    n_starts : int, default 4
        Starts of each separate fit.
    rng : numpy.random.Generator, optional
    separate : sequence of FitResult, optional
        The records' separate fits, when already made.
    progress : callable(str), optional

    Returns
    -------
    JointFit
    """
    say = progress or (lambda message: None)
    t0 = _time.perf_counter()
    rng = np.random.default_rng(0) if rng is None else rng
    records = check_records(records)
    noises = [_noise_of(r) for r in records] if noises is None else list(noises)
    if separate is None:
        separate = separate_fits(records, model, noises, n_starts=n_starts, rng=rng, progress=progress)
    span = max(float(np.max(np.abs(r.displacement))) for r in records)
    say(f"least squares of the {len(records)} records together")
    best = None
    for donor in separate:
        joint = JointModel(donor.model, len(records), zero_bound=max(10.0 * span, 1.0))
        start = joint_start(joint, donor, separate, records)
        residuals = JointResiduals(records, joint, noises)
        x0 = np.clip(start[residuals.free], residuals.lower, residuals.upper)
        with single_threaded_blas():
            sol = bounded_solve(residuals, x0, POLISH_EVALUATIONS)
        chi2 = 2.0 * float(sol.cost)
        if best is None or chi2 < best[0]:
            best = (chi2, residuals, sol.x)
    chi2, residuals, x = best
    return joint_fit_at(residuals, x, separate, t0)


def joint_fit_from_json(content: dict, records, noises=None) -> JointFit:
    """The :class:`JointFit` stored by :meth:`JointFit.to_json`, on the same ``records`` (their
    noises: default each one's quiet start); its covariance and per-record fits are recomputed
    at the stored vector (deterministic)."""
    stored = content["joint"]
    records = check_records(records)
    if len(records) != int(stored["n_records"]):
        raise ValueError(f"the stored joint fit has {stored['n_records']} records, {len(records)} were given")
    model = FitResult.from_dict(content).model
    separate = [FitResult.from_dict(d) for d in stored["separate"]]
    noises = [_noise_of(r) for r in records] if noises is None else list(noises)
    joint = JointModel(model, len(records), zero_bound=float(stored["zero_bound"]))
    if list(joint.names) != list(stored["names"]):
        raise ValueError("the stored joint fit's parameters are not this model's")
    residuals = JointResiduals(records, joint, noises)
    theta = np.asarray(stored["theta_vector"], dtype=float)
    fit = joint_fit_at(residuals, theta[residuals.free], separate, _time.perf_counter())
    fit.seconds = float(stored.get("seconds", 0.0))
    return fit


def record_noises(records) -> list:
    """Each record's noise from its own quiet start (:func:`identify.fitting.noise.estimate_noise`);
    a record without one is a ValueError naming it."""
    return [_noise_of(r) for r in records]


def separate_fits(records, model: Model, noises, *, n_starts: int = 4, rng=None, progress=None) -> list:
    """Each record fitted alone (:func:`identify.fitting.lsq.fit_least_squares`). The first
    record's fit is also the first start of every further record's, and its thresholds' sign
    is theirs: the records share the transducer, so the sign the first record chose holds for
    all (each further record then searches one sign instead of two; its own ``n_starts`` are
    still tried)."""
    say = progress or (lambda message: None)
    rng = np.random.default_rng(0) if rng is None else rng
    fits = []
    for r, (record, noise) in enumerate(zip(records, noises), start=1):
        say(f"least squares of record {r} of {len(records)} alone ({record.source})")
        start = None if not fits else fits[0].theta
        fit_model = model if not fits else fits[0].model
        fits.append(fit_least_squares(record, fit_model, noise=noise, start=start, n_starts=n_starts, rng=rng))
    return fits


def _noise_of(record) -> NoiseModel:
    """The record's noise from its own quiet start; the error names the record."""
    try:
        return estimate_noise(record)
    except NoQuietSegmentError:
        raise NoQuietSegmentError(
            f"{record.source}: no unenergised start to estimate this record's sensor noise from; several records "
            "are each whitened with the noise of their own quiet start, so every record needs one (a record "
            "without one can be studied alone, with --noise-sigma VALUE or free)"
        ) from None
    except ValueError as exc:
        raise ValueError(f"{record.source}: {exc}") from None


def joint_start(joint: JointModel, donor: FitResult, separate, records) -> np.ndarray:
    """The joint start of ``donor`` (one record's fit): its transducer parameters for every record,
    each record's run parameters from its own fit in ``separate`` where that has ``donor``'s
    threshold sign, the zeros from the mean residuals. Shape ``(joint.n_parameters,)``."""
    model = joint.model
    thetas = []
    for fit in separate:
        theta = np.array(donor.theta, dtype=float)
        same_sign = fit.model.parameters["alpha"].value == model.parameters["alpha"].value
        if same_sign and fit is not donor:
            for name in joint.per_record:
                theta[model.names.index(name)] = fit.theta[fit.model.names.index(name)]
        thetas.append(theta)
    thetas[0] = np.array(donor.theta, dtype=float) if separate[0] is donor else thetas[0]
    means = [float(np.mean(rec.displacement - model(th, rec.time, rec.current))) for rec, th in zip(records, thetas)]
    zeros = [m - means[0] for m in means]
    return np.clip(joint.joint_theta(thetas, zeros), joint.parameters.lower, joint.parameters.upper)


def joint_fit_at(residuals: JointResiduals, x, separate, t0: float | None = None) -> JointFit:
    """The :class:`JointFit` at free vector ``x`` of ``residuals`` (``separate``: the records' own fits)."""
    t0 = _time.perf_counter() if t0 is None else t0
    joint = residuals.model
    theta = residuals.full(x)
    w = residuals(x)
    chi2 = float(w @ w)
    with single_threaded_blas():
        jac = residuals.central_jacobian(x)
    cov_free = np.linalg.pinv(jac.T @ jac, rcond=1e-15, hermitian=True)
    free = residuals.free
    covariance = np.zeros((joint.n_parameters, joint.n_parameters))
    covariance[np.ix_(free, free)] = cov_free
    stderr = np.full(joint.n_parameters, np.nan)
    stderr[free] = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    fits = []
    for r, (record, noise, fit) in enumerate(zip(residuals.records, residuals.noises, separate), start=1):
        rows, zero = joint.record_rows(theta, r)
        own = joint._own[r - 1]
        fits.append(_record_fit(record, joint.model, rows[0], float(zero[0]), noise, fit, covariance[np.ix_(own, own)]))
    check = consistency(chi2, separate, joint, fits, residuals.records)
    return JointFit(
        joint,
        theta,
        stderr,
        covariance,
        chi2,
        residuals.records,
        residuals.noises,
        fits,
        separate,
        check,
        _time.perf_counter() - t0,
    )


def joint_manifest_data(records) -> dict:
    """The manifest's ``data`` of several records: record 1's file, a SHA-256 over every record's
    (in order: any record changed, added, removed or moved is another run) and one entry per record."""
    digest = hashlib.sha256("\n".join(str(r.sha256) for r in records).encode()).hexdigest()
    return {
        "file": str(records[0].source),
        "sha256": digest,
        "n_samples": int(sum(len(r.time) for r in records)),
        "notes": [f"{r.source}: {note}" for r in records for note in getattr(r, "notes", ())],
        "records": [{"file": str(r.source), "sha256": r.sha256, "n_samples": len(r.time)} for r in records],
    }


#: The predictive band's level of the leave-one-record-out validation.
LORO_LEVEL = 0.95


def _zero_from_quiet_start(record, y, noise) -> float:
    """The left-out record's sensor zero against the prediction: the mean difference over its
    unenergised start, where the transducer rests and the data say nothing of its physics."""
    quiet = ~energised_mask(record, noise)
    if not quiet.any():
        return 0.0
    return float(np.mean(np.asarray(record.displacement, dtype=float)[quiet] - y[quiet]))


def predict_left_out(record, noise, model: Model, theta, covariance, rng, n_draws: int = 200) -> dict:
    """Predict ``record`` from another fit (its model vector ``theta`` ``(P,)`` and covariance
    ``(P, P)``): the 95 % predictive band of the model's output under the fit's Laplace
    approximation plus the record's own noise; the record's sensor zero from its quiet start.

    Returns
    -------
    dict
        ``rms`` [output unit] and ``rms_sigma`` (in the record's noise sigmas) of the energised
        part, ``inside_95`` (share of energised samples inside the band), ``max_error_pct``,
        ``zero``, ``n_draws``.
    """
    theta = np.asarray(theta, dtype=float)
    vary = np.asarray(model.parameters.vary, dtype=bool)
    cov = np.asarray(covariance, dtype=float)[np.ix_(vary, vary)]
    cov = 0.5 * (cov + cov.T)
    rows = np.repeat(theta[None, :], n_draws, axis=0)
    rows[:, vary] = rng.multivariate_normal(theta[vary], cov, size=n_draws, method="eigh")
    rows = np.clip(rows, model.parameters.lower, model.parameters.upper)
    y_hat = model(theta, record.time, record.current)
    draws, valid = model.evaluate(rows, record.time, record.current)
    draws = draws[np.asarray(valid, dtype=bool)]
    zero = _zero_from_quiet_start(record, y_hat, noise)
    data = np.asarray(record.displacement, dtype=float)
    energised = energised_mask(record, noise)
    residual = data - (y_hat + zero)
    half = stats.norm.ppf(0.5 + LORO_LEVEL / 2.0) * np.sqrt(np.var(draws, axis=0) + noise.sigma**2)
    span = float(np.ptp(data))
    rms = float(np.sqrt(np.mean(residual[energised] ** 2)))
    return {
        "rms": rms,
        "rms_sigma": rms / noise.sigma if noise.sigma > 0 else math.nan,
        "inside_95": float(np.mean(np.abs(residual[energised]) <= half[energised])),
        "max_error_pct": float(100.0 * np.max(np.abs(residual[energised])) / span) if span > 0 else math.nan,
        "zero": zero,
        "n_draws": int(draws.shape[0]),
    }


def leave_one_record_out(fit: JointFit, rng=None, progress=None) -> list[dict]:
    """Each record predicted from the others' fit (one record alone: its separate fit; several:
    their joint fit, polished from their separate fits). Pointwise leave-one-out over samples is
    not valid for a time series whose residuals are correlated: the record is the unit.

    Returns
    -------
    list of dict
        Per left-out record: ``record`` (from 1), ``source``, ``trained_on`` and
        :func:`predict_left_out`'s figures. The run parameters a record declares its own
        (:attr:`JointModel.per_record`) are the first training record's.
    """
    say = progress or (lambda message: None)
    rng = np.random.default_rng(0) if rng is None else rng
    out = []
    k = fit.joint.n_records
    for left in range(k):
        others = [i for i in range(k) if i != left]
        say(f"leave one record out: predicting record {left + 1} ({fit.records[left].source}) from the others")
        if len(others) == 1:
            train = fit.separate[others[0]]
            model, theta, cov = train.model, train.theta, train.covariance
        else:
            train = fit_joint(
                [fit.records[i] for i in others],
                fit.model,
                [fit.noises[i] for i in others],
                separate=[fit.separate[i] for i in others],
                rng=rng,
            )
            own = train.joint._own[0]
            model, theta, cov = train.model, train.theta[own], train.covariance[np.ix_(own, own)]
        prediction = predict_left_out(fit.records[left], fit.noises[left], model, theta, cov, rng)
        out.append(
            {
                "record": left + 1,
                "source": str(fit.records[left].source),
                "trained_on": [str(fit.records[i].source) for i in others],
                **prediction,
            }
        )
    return out
