r"""Posterior sampling of the model parameters with emcee: priors, log-posterior, moves,
the walkers' start, the resumable sampling loop and its result.

Priors (:data:`PRIORS`)
-----------------------
Independent for each free parameter, supported on its bounds
(:class:`model.parameters.Parameter` ``lower``/``upper``), normalised:

``"uniform"``
    :math:`p(\theta) = 1 / (u - l)`: location-like parameters (offsets, shifts, alpha,
    tau) and everything else by default.
``"log_uniform"``
    :math:`p(\theta) = 1 / (\theta \log(u / l))`, uniform in :math:`\log\theta`: used by
    :func:`default_priors` for *scale* parameters, i.e. a strictly positive lower bound
    and bounds spanning at least two decades (``rho``, the envelope amplitudes and
    slopes ``a0, a1, b0, b1``, and any effect time constant bounded away from 0),
    because for those no particular magnitude is preferred.

With a free noise sigma the last coordinate is ``noise_log_sigma`` (natural log of
sigma in the output unit), uniform on ``[log(1e-6 span), log(span)]`` with ``span``
the measured displacement range, i.e. log-uniform in sigma.

Log-posterior
-------------
:class:`LogPosterior` is evaluated for all walkers at once (emcee ``vectorize=True``: ONE
model call per step). It returns ``-inf`` for a walker outside the bounds *before*
evaluating the model, and for one whose model output is not finite (the GPI itself is
defined for every parameter set: :mod:`model.gpi`, "The whole domain"); it never raises and
never returns NaN (a model error for the batch falls back to one row at a time; rows that
still fail get ``-inf`` and are counted in :attr:`LogPosterior.n_errors`). The likelihood is
:func:`identify.fitting.noise.log_likelihood`, evaluated in one fused pass
(:class:`identify.fitting.noise.RowLikelihood`).

Sampling
--------
:func:`sample_posterior` runs emcee's ensemble sampling (its loop as
:class:`identify.fitting.ensemble.EnsembleLoop` runs it: the same chain) with an
:class:`emcee.backends.HDFBackend` (group ``"mcmc"``; written in batches by
:class:`identify.fitting.chain_file.BufferedHDFBackend`, at least every second), so an interrupted run resumes where
it stopped (the sampler's random state is stored with each step, so the resumed chain is
the one an uninterrupted run gives, bit for bit). Ctrl-C (SIGINT) and ``kill PID``
(SIGTERM) are honoured between two steps: the completed step is written and
``KeyboardInterrupt`` raised; a second signal interrupts at once. A run that added steps
and stopped by its rule (not by a signal) rewrites the file without the space its batched
writes left unused (:func:`identify.fitting.chain_file.compact_chain_file`: the same data,
about 15 % smaller). It runs
in chunks of ``check_every`` steps (aligned to multiples of it, so stopping does not
depend on interruptions) and stops when

* the integrated autocorrelation time of every parameter changed by less than
  ``tau_rtol`` (5 %) since the previous check, and
* the chain is at least ``tau_factor`` (50) times the largest autocorrelation time,
* and then (computed only when tau passes) every parameter's split-R-hat is below
  :data:`RHAT_MAX` (1.05) and its bulk ESS at least :data:`ESS_BULK_MIN` (400), ArviZ's
  definitions on the chain after burn-in and thinning
  (:func:`identify.fitting.convergence.chain_diagnostics`),

or at ``max_steps``; then the result says plainly that it is **not converged**.
A check whose chain is shorter than ``tau_factor`` times the autocorrelation time of the
chain's prefix at the last *anchor* (nearly geometric, 19 % apart late in a run:
:func:`identify.fitting.convergence.check_anchor`) is skipped, as it would almost surely fail: each check recomputes the
autocorrelation time of the whole chain, which cost about 75 s of a 54000-step run when
every check was made. The
anchors depend only on the chain, so a resumed run checks where the uninterrupted one
does; a skipped check can only delay the stop (by at most ``tau_factor`` times the
anchor's overestimate of tau), never make it earlier.
Burn-in ``discard = 2 tau_max`` and ``thin = max(1, tau_min / 2)`` are applied to the
reported samples; the effective sample size of parameter ``j`` is
``n_walkers (n_steps - discard) / tau_j``.

The chain file's backend and reader are :mod:`identify.fitting.chain_file`; the
autocorrelation times, the tau rule, R-hat and ESS :mod:`identify.fitting.convergence`; the
moves :mod:`identify.fitting.moves`. Their public names are importable from here too, as before.

Randomness: the walkers' start uses the ``numpy.random.Generator`` passed in; emcee's
internal ``RandomState`` is seeded from the same generator; nothing touches global state.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import time as _time
from dataclasses import dataclass, field

import emcee
import numba
import numpy as np
from scipy.stats import chi2

from model import Model

from ..defaults import DEFAULT_CHECK_EVERY, DEFAULT_MAX_STEPS
from ._posterior_kernels import support_prior_theta
from .chain_file import (
    BACKEND_GROUP,
    CHAIN_DTYPE,
    CHAIN_METADATA_BYTES,
    BufferedHDFBackend,
    ChainBackend,
    ChainFileError,
    chain_info,
    compact_chain_file,
    signal_handlers,
)
from .convergence import (
    DIAGNOSTICS,
    ESS_BULK_MIN,
    RHAT_MAX,
    autocorrelation_times,
    burn_in,
    chain_diagnostics,
    check_due,
    diagnostics_verdict,
    finite_or_none,
    import_arviz,
    tau_convergence,
)
from .coordinates import CoordinateMove, IdentityCoordinates, coordinates_for
from .ensemble import EnsembleLoop
from .moves import MOVES, DifferentialMove, SnookerMove
from .noise import NoiseModel, RowLikelihood
from .parametrisation import in_record_units
from .progress import ChainProgress, progress_mode
from .threads import fastest_thread_count

__all__ = [
    "ChainFileError",
    "import_arviz",
    "chain_info",
    "PRIORS",
    "MOVES",
    "SnookerMove",
    "DifferentialMove",
    "default_priors",
    "LogPosterior",
    "PosteriorResult",
    "default_n_walkers",
    "initial_walkers",
    "sample_posterior",
    "posterior_from_backend",
    "BACKEND_GROUP",
    "ChainBackend",
    "BufferedHDFBackend",
    "BENCH_COVERAGE",
    "DEFAULT_MAX_STEPS",
    "DEFAULT_CHECK_EVERY",
    "RHAT_MAX",
    "ESS_BULK_MIN",
    "DIAGNOSTICS",
    "chain_diagnostics",
    "autocorrelation_times",
    "CHAIN_METADATA_BYTES",
    "THREAD_PROBE_SECONDS",
]


def _uniform_logpdf(x, lower, upper):
    return np.full(x.shape, -math.log(upper - lower))


def _log_uniform_logpdf(x, lower, upper):
    return -np.log(x) - math.log(math.log(upper / lower))


#: prior name -> log-density ``f(x, lower, upper)`` on ``[lower, upper]`` (vectorised in x).
PRIORS = {"uniform": _uniform_logpdf, "log_uniform": _log_uniform_logpdf}


def _moves_in(schedule, coordinates):
    """The move schedule (a move or ``[(move, weight), ...]``) proposing in ``coordinates``."""
    if isinstance(coordinates, IdentityCoordinates):
        return schedule
    if isinstance(schedule, emcee.moves.Move):
        return CoordinateMove(schedule, coordinates)
    return [(CoordinateMove(move, coordinates), weight) for move, weight in schedule]


def default_priors(model: Model) -> dict[str, str]:
    """``{name: prior}`` for every parameter of ``model`` (rule in the module docstring)."""
    kinds = {}
    for p in model.parameters:
        scale_like = p.lower > 0 and np.isfinite(p.upper) and p.upper / p.lower >= 100.0
        kinds[p.name] = "log_uniform" if scale_like else "uniform"
    return kinds


class LogPosterior:
    """Vectorised log-posterior of the free parameters (and ``noise_log_sigma`` if free).

    Parameters
    ----------
    record : Record
        ``time``, ``current``, ``displacement``, shape (T,).
    model : model.Model
        Pinned parameters (``vary=False``) stay at their values.
    noise : NoiseModel
        A free sigma (``source="free"``) adds the coordinate ``noise_log_sigma``.
    priors : dict, optional
        ``{name: prior name or callable f(x, lower, upper)}``; missing names use
        :func:`default_priors`. The support is the model's bounds; a priors file
        (:mod:`identify.fitting.priors`) gives :class:`identify.fitting.priors.Prior` objects and a model
        with its bounds.

    Attributes
    ----------
    names : tuple of str
        Coordinates sampled, shape (D,).
    lower, upper : ndarray, shape (D,)
        The prior's support.
    n_errors : int
        Rows whose evaluation raised (and were given ``-inf``).
    """

    #: One call scores every row ``(W, D) -> (W,)`` floats, never NaN, no blobs: the
    #: sampler's moves call it directly (:func:`identify.fitting.coordinates._log_probabilities`).
    vectorised_log_probability = True

    def __init__(self, record, model: Model, noise: NoiseModel, *, priors=None):
        if isinstance(model, Model):  # a joint layout (identify.fitting.joint) is converted by its maker
            model = in_record_units(model, record)  # default bounds in the record's unit prefixes
        self.time = np.asarray(record.time, dtype=float)
        self.current = np.asarray(record.current, dtype=float)
        self.data = np.asarray(record.displacement, dtype=float)
        self.model = model
        self.noise = noise
        # scored with each step's correlation r_k when the grid's steps are not all the noise's
        # one step (computed once), else every step rho
        self._likelihood = RowLikelihood(self.data, noise, time=self.time)
        self.free = np.flatnonzero(model.parameters.vary)
        self.template = model.parameters.values.copy()
        self._labelled = model.has_canonical_domain  # a labelling to keep (e.g. two thermal nodes): checked per call
        names = [model.names[i] for i in self.free]
        lower = list(model.parameters.lower[self.free])
        upper = list(model.parameters.upper[self.free])
        kinds = default_priors(model)
        kinds.update(priors or {})
        #: the priors given (``{name: name or callable}``, e.g. :class:`identify.fitting.priors.Prior`); the rest are
        # defaults
        self.priors_used = dict(priors or {})
        unknown = set(priors or {}) - set(model.names) - {"noise_log_sigma"}
        if unknown:
            raise ValueError(f"priors given for unknown parameters {sorted(unknown)}")
        self.free_sigma = noise.is_free
        if self.free_sigma:
            span = float(np.ptp(self.data))
            if not span > 0:
                raise ValueError("a free noise sigma needs a displacement that is not constant")
            names.append("noise_log_sigma")
            lower.append(math.log(1e-6 * span))
            upper.append(math.log(span))
            kinds.setdefault("noise_log_sigma", "uniform")
        self.names = tuple(names)
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.prior_names = {}
        self._prior_fns = []
        for n, lo, hi in zip(self.names, self.lower, self.upper):
            kind = kinds.get(n, "uniform")
            fn = PRIORS.get(kind) if isinstance(kind, str) else kind
            if fn is None:
                raise ValueError(f"unknown prior {kind!r} for {n}; known: {', '.join(PRIORS)}")
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise ValueError(f"parameter {n} needs finite bounds for a proper prior, got [{lo}, {hi}]")
            if kind == "log_uniform" and not lo > 0:
                raise ValueError(f"a log-uniform prior needs a positive lower bound; {n} has {lo}")
            self.prior_names[n] = kind if isinstance(kind, str) else getattr(kind, "__name__", "custom")
            self._prior_fns.append(fn)
        # The built-in priors in closed form, summed once per call: a constant (every
        # uniform and log-uniform normalisation) minus the log of the log-uniform
        # coordinates; any other prior is called as given.
        builtin = [fn in (_uniform_logpdf, _log_uniform_logpdf) for fn in self._prior_fns]
        self._log_uniform_columns = np.array(
            [j for j, fn in enumerate(self._prior_fns) if fn is _log_uniform_logpdf], dtype=int
        )
        self._prior_constant = sum(
            -math.log(hi - lo) if fn is _uniform_logpdf else -math.log(math.log(hi / lo))
            for fn, lo, hi, b in zip(self._prior_fns, self.lower, self.upper, builtin)
            if b
        )
        self._other_priors = [(j, fn) for j, (fn, b) in enumerate(zip(self._prior_fns, builtin)) if not b]
        self._compiled_prior = not self._labelled and not self._other_priors
        self.n_errors = 0

    @property
    def ndim(self) -> int:
        return len(self.names)

    def full_theta(self, x) -> np.ndarray:
        """Full model vectors ``(W, P)`` from sampled coordinates ``(W, D)``."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        theta = np.repeat(self.template[None, :], x.shape[0], axis=0)
        theta[:, self.free] = x[:, : self.free.size]
        return theta

    def in_support(self, x) -> np.ndarray:
        """Boolean ``(W,)``: finite, within the bounds and in the model's canonical labelling
        (:meth:`model.Model.in_canonical_domain`: e.g. a two-node ``thermal``'s faster node
        first, so that the mirror image of every point is not sampled too)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        ok = np.isfinite(x).all(axis=1) & (x >= self.lower).all(axis=1) & (x <= self.upper).all(axis=1)
        if self._labelled and ok.any():
            ok[ok] = self.model.in_canonical_domain(self.full_theta(x[ok]))
        return ok

    def log_prior(self, x) -> np.ndarray:
        """Log prior density ``(W,)``; ``-inf`` outside the support."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        out = np.full(x.shape[0], -np.inf)
        prior, inside, _theta = self._prior_of_rows(x)
        out[inside] = prior
        return out

    def _prior_of_rows(self, x):
        """``(prior, inside, theta)``: the log prior of the rows of ``x`` (2-D) inside the support,
        which rows those are, and their full parameter vectors (:meth:`full_theta`)."""
        if self._compiled_prior:  # box support and built-in priors: one compiled pass
            return support_prior_theta(
                x, self.lower, self.upper, self._prior_constant, self._log_uniform_columns, self.template, self.free
            )
        inside = np.flatnonzero(self.in_support(x))
        xs = x[inside]
        total = np.full(xs.shape[0], self._prior_constant)
        if self._log_uniform_columns.size:
            total -= np.log(xs[:, self._log_uniform_columns]).sum(axis=1)
        for j, fn in self._other_priors:
            total += fn(xs[:, j], self.lower[j], self.upper[j])
        return total, inside, self.full_theta(xs)

    def _evaluate_rows(self, theta):
        try:
            return self.model.evaluate(theta, self.time, self.current)
        except Exception:  # never raise for a walker: fall back to one row at a time
            y = np.zeros((theta.shape[0], self.time.size))
            valid = np.zeros(theta.shape[0], dtype=bool)
            for k in range(theta.shape[0]):
                try:
                    yk, vk = self.model.evaluate(theta[k], self.time, self.current)
                    y[k], valid[k] = yk[0], vk[0]
                except Exception:
                    self.n_errors += 1
            return y, valid

    def __call__(self, x) -> np.ndarray:
        """Log-posterior (up to the evidence) of ``(W, D)`` coordinates -> ``(W,)``; 1-D in -> float."""
        x_in = np.asarray(x, dtype=float)
        x2 = np.atleast_2d(x_in)
        out = np.full(x2.shape[0], -np.inf)
        prior, inside, theta = self._prior_of_rows(x2)
        finite = np.isfinite(prior)  # a prior of its own may be -inf inside the box: no model call there
        if not finite.all():
            prior, inside, theta = prior[finite], inside[finite], theta[finite]
        if inside.size:
            y, valid = self._evaluate_rows(theta)
            scored = np.flatnonzero(valid)
            if scored.size:
                rows = inside[scored]
                sigma = np.exp(x2[rows, -1]) if self.free_sigma else None
                total = prior[scored] + self._likelihood(y, scored, sigma)
                out[rows] = np.where(np.isfinite(total), total, -np.inf)
        return float(out[0]) if x_in.ndim == 1 else out


def default_n_walkers(ndim: int) -> int:
    """About twice the dimension, even, at least 32."""
    n = max(32, 2 * int(ndim))
    return n + (n % 2)


#: Smallest eigenvalue of the walkers' start correlation matrix, relative to the largest
#: (standard deviation 1e-3 of the largest along any combination); see :func:`initial_walkers`.
MIN_CORRELATION_EIGENVALUE = 1e-6


def _full_rank(covariance) -> np.ndarray:
    """``covariance`` with its correlation eigenvalues raised to :data:`MIN_CORRELATION_EIGENVALUE` x the largest.

    Unchanged when it already satisfies that; the variances (diagonal) are kept.
    """
    sd = np.sqrt(np.diag(covariance))
    correlation = covariance / np.outer(sd, sd)
    eigenvalues, eigenvectors = np.linalg.eigh(correlation)
    smallest = MIN_CORRELATION_EIGENVALUE * eigenvalues[-1]
    if eigenvalues[0] >= smallest:
        return covariance
    raised = (eigenvectors * np.maximum(eigenvalues, smallest)) @ eigenvectors.T
    rescale = 1.0 / np.sqrt(np.diag(raised))  # back to unit diagonal: keep the variances
    raised = raised * np.outer(rescale, rescale)
    return raised * np.outer(sd, sd)


#: The walkers start in the Laplace approximation's typical set: a draw is redrawn when its
#: log-posterior lies more than ``chi2.ppf(1 - TYPICAL_SET_TAIL, D) / 2`` below the least-squares
#: solution's, a drop a Gaussian posterior's own draws reach with probability ``TYPICAL_SET_TAIL``.
TYPICAL_SET_TAIL = 1e-6


def initial_walkers(
    log_post: LogPosterior, mean, covariance, n_walkers, rng, *, max_rounds=200, coordinates="gpi"
) -> np.ndarray:
    """Walkers drawn from the least-squares Laplace approximation, in the sampler coordinates,
    each redrawn until its log-posterior lies in that approximation's typical set.

    Parameters
    ----------
    log_post : LogPosterior
    mean : array_like, shape (D,)
        The least-squares solution in sampled coordinates.
    covariance : array_like, shape (D, D)
        Its covariance (e.g. the Jacobian-based one). A variance below
        ``(1e-3 max(|mean|, 1e-3 (upper - lower)))^2`` is raised by that floor.
    n_walkers : int
    rng : numpy.random.Generator
    max_rounds : int, default 200
        Redraw rounds; every 20 rounds without success the covariance is halved. Walkers still
        missing after them take the highest of the draws below the typical set.
    coordinates : str or callable, default "gpi"
        Where the approximation is Gaussian (:data:`identify.fitting.coordinates.COORDINATES`):
        ``covariance`` is carried there by the map's Jacobian at ``mean`` (also the map's
        reference point: :class:`identify.fitting.coordinates.GPICoordinates`) and the draws are
        mapped back. In the parameters a curved posterior's linearised covariance reaches far
        outside it (an amplitude and an offset that trade along a ridge, a near-singular
        direction raised to full rank), so its draws can lie thousands of log-units below the
        solution and the chain's first steps become a search
        (``benchmarks/initial_walkers.py``).

    Returns
    -------
    ndarray, shape (n_walkers, D)

    Raises
    ------
    ValueError
        When ``mean`` itself is outside the support or too few draws land inside it.

    Notes
    -----
    A covariance that is singular in some direction (a pseudo-inverse drops the least
    determined combinations, giving them zero variance) has the eigenvalues of its
    correlation matrix raised to at least :data:`MIN_CORRELATION_EIGENVALUE` times the
    largest: otherwise every walker lies in a subspace that ensemble moves can never
    leave (and emcee refuses the start as linearly dependent), so the sampler would
    never explore exactly the directions the data constrain least. A raised direction may
    reach far outside the posterior; the typical-set test takes those draws back.
    """
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    cov = 0.5 * (cov + cov.T)
    # A parameter the data do not constrain at the optimum (e.g. an effect's time
    # constant while its amplitude is 0) has (near-)zero variance in a pseudo-inverse
    # covariance; give it a small spread so the walkers are linearly independent.
    floor = (1e-3 * np.maximum(np.abs(mean), 1e-3 * (log_post.upper - log_post.lower))) ** 2
    idx = np.arange(mean.size)
    cov[idx, idx] = np.where(np.diag(cov) < floor, np.diag(cov) + floor, np.diag(cov))
    top = log_post(mean[None, :])[0]
    if not np.isfinite(top):
        raise ValueError("the least-squares solution has a log-posterior of -inf (outside the support or domain)")
    lowest = top - 0.5 * chi2.ppf(1.0 - TYPICAL_SET_TAIL, mean.size)
    coords, centre, cov = _laplace_in_coordinates(coordinates_for(coordinates, log_post, mean), log_post, mean, cov)
    cov = _full_rank(cov)
    walkers = np.empty((n_walkers, mean.size))
    missing = np.arange(n_walkers)
    reserve, reserve_lp = np.empty((0, mean.size)), np.empty(0)  # finite draws below the typical set
    shrink = 1.0
    for round_ in range(max_rounds):
        draws = coords.inverse(rng.multivariate_normal(centre, shrink * cov, size=missing.size, method="eigh"))
        with np.errstate(invalid="ignore"):
            lp = np.full(missing.size, -np.inf)
            finite = np.isfinite(draws).all(axis=1)
            lp[finite] = log_post(draws[finite])
        good = lp >= lowest
        walkers[missing[good]] = draws[good]
        missing = missing[~good]
        if missing.size == 0:
            return walkers
        below = np.isfinite(lp) & ~good
        reserve, reserve_lp = np.vstack([reserve, draws[below]]), np.concatenate([reserve_lp, lp[below]])
        if (round_ + 1) % 20 == 0:
            shrink *= 0.5
    if reserve_lp.size < missing.size:
        raise ValueError(f"could not place {missing.size} of {n_walkers} walkers inside the posterior's support")
    walkers[missing] = reserve[np.argsort(-reserve_lp, kind="stable")[: missing.size]]
    return walkers


def _laplace_in_coordinates(coords, log_post, mean, cov):
    """``(coords, centre, covariance)``: ``mean`` and ``cov`` carried into the sampler coordinates
    by the map's Jacobian at ``mean`` (central differences), or the parameters themselves
    (:class:`IdentityCoordinates`) where the map or its Jacobian is not finite there."""
    identity = IdentityCoordinates(), mean, cov
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        centre = coords.forward(mean[None, :])[0]
        if not np.isfinite(centre).all():
            return identity
        steps = 1e-6 * np.maximum(np.abs(mean), 1e-3 * np.minimum(log_post.upper - log_post.lower, 1.0))
        shifted = mean + np.diag(steps)
        lowered = mean - np.diag(steps)
        jacobian = ((coords.forward(shifted) - coords.forward(lowered)) / (2.0 * steps)[:, None]).T
    if not np.isfinite(jacobian).all():
        return identity
    carried = jacobian @ cov @ jacobian.T
    return coords, centre, 0.5 * (carried + carried.T)


@dataclass
class PosteriorResult:
    """Summary of an emcee run (see the module docstring for the definitions).

    Parameters
    ----------
    names : tuple of str
        Sampled coordinates, shape (D,).
    converged : bool
    message : str
        Plain words, e.g. "converged: ..." or "NOT CONVERGED: ...".
    n_walkers, n_steps, discard, thin : int
    acceptance_fraction : float
        Mean over walkers.
    tau : ndarray, shape (D,)
        Integrated autocorrelation times [steps].
    ess : ndarray, shape (D,)
        Effective sample sizes.
    samples : ndarray, shape (N, D)
        Flat samples after burn-in and thinning.
    log_prob : ndarray, shape (N,)
    seconds : float
        Sampling wall time in this call [s].
    n_errors : int
        Walker evaluations that raised and got ``-inf``.
    """

    names: tuple
    converged: bool
    message: str
    n_walkers: int
    n_steps: int
    discard: int
    thin: int
    acceptance_fraction: float
    tau: np.ndarray
    ess: np.ndarray
    samples: np.ndarray = field(repr=False)
    log_prob: np.ndarray = field(repr=False)
    seconds: float = 0.0
    n_errors: int = 0
    rhat: np.ndarray | None = None
    ess_bulk: np.ndarray | None = None
    ess_tail: np.ndarray | None = None
    mcse_mean: np.ndarray | None = None
    mcse_sd: np.ndarray | None = None

    def diagnostic(self, name: str, j: int):
        """Diagnostic ``name`` (one of :data:`DIAGNOSTICS`) of coordinate ``j``; None when absent or not finite."""
        values = getattr(self, name)
        return None if values is None else finite_or_none(values[j])

    @property
    def tau_max(self) -> float:
        return float(np.max(self.tau))

    def quantiles(self, q=(0.025, 0.5, 0.975)) -> np.ndarray:
        """Quantiles ``(len(q), D)`` of the flat samples."""
        return np.quantile(self.samples, q, axis=0)

    def to_dict(self) -> dict:
        """The ``posterior`` block of ``summary.json``."""
        return {
            "converged": bool(self.converged),
            "message": self.message,
            "n_walkers": int(self.n_walkers),
            "n_steps": int(self.n_steps),
            "discard": int(self.discard),
            "thin": int(self.thin),
            "acceptance_fraction": float(self.acceptance_fraction),
            "tau_max": finite_or_none(self.tau_max),
            "rhat_max": None if self.rhat is None else finite_or_none(np.max(self.rhat)),
            "ess_bulk_min": None if self.ess_bulk is None else finite_or_none(np.min(self.ess_bulk)),
            "ess_tail_min": None if self.ess_tail is None else finite_or_none(np.min(self.ess_tail)),
            "rule": {"rhat_max": RHAT_MAX, "ess_bulk_min": ESS_BULK_MIN},
            "n_samples": int(self.samples.shape[0]),
            "n_errors": int(self.n_errors),
            "seconds": float(self.seconds),
        }


#: Measured 95 % interval coverage on the virtual bench (``benchmarks/interval_coverage.py
#: --records 200``, 2026-11-24: clean 50 Hz records whose truths are Table 1 with ``b3``
#: within +-0.25 A, on both sides of where the operator bounds start to cross): least squares
#: +-1.96 stderr vs posterior equal-tailed intervals, mean of the per-record fractions and
#: its standard error across records. Quoted by the report (docs/method.md, docs/benchmarks.md).
BENCH_COVERAGE = {
    "least_squares": 0.934,
    "least_squares_se": 0.007,
    "posterior": 0.933,
    "posterior_se": 0.008,
    "nominal": 0.95,
    "n_records": 200,
    "n_intervals": 3600,
}


def posterior_from_backend(
    path,
    names,
    *,
    converged=None,
    message="",
    tau_factor=50.0,
    tau_rtol=0.05,
    check_every=None,
    seconds=0.0,
    n_errors=0,
    tau_cache=None,
    diagnostics_cache=None,
) -> PosteriorResult:
    """Summarise the chain stored in ``path`` (HDF5 backend, group :data:`BACKEND_GROUP`).

    ``converged``/``message`` default to the convergence rule applied to the stored
    chain; ``tau_cache`` (chain length -> tau) reuses autocorrelation times already
    computed, ``diagnostics_cache`` (``(steps, discard, thin)`` -> :func:`chain_diagnostics`)
    the R-hat/ESS of the check that stopped the chain.
    """
    backend = ChainBackend(str(path), name=BACKEND_GROUP, read_only=True)
    chain = backend.get_chain()
    log_prob_chain = backend.get_log_prob()
    n_steps, n_walkers, ndim = chain.shape
    if n_steps == 0:
        raise ValueError(f"{path}: the chain is empty")
    check_every = check_every or max(1, n_steps // 2)
    ok, tau, _change, msg = tau_convergence(chain, check_every, tau_factor, tau_rtol, tau_cache)
    discard, thin = burn_in(tau, n_steps)
    diag = (diagnostics_cache or {}).get((n_steps, discard, thin))
    if diag is None:
        diag = chain_diagnostics(chain[discard::thin])
    diag_ok, diag_msg = diagnostics_verdict(diag)
    if converged is None:
        converged = ok and diag_ok
    if not message:
        message = ("converged: " if converged else "NOT CONVERGED: ") + msg + "; " + diag_msg
    samples = chain[discard::thin].reshape(-1, ndim)
    log_prob = log_prob_chain[discard::thin].reshape(-1)
    ess = n_walkers * (n_steps - discard) / tau
    acceptance = float(np.mean(backend.accepted / n_steps))
    return PosteriorResult(
        names=tuple(names),
        converged=bool(converged),
        message=message,
        n_walkers=n_walkers,
        n_steps=n_steps,
        discard=discard,
        thin=thin,
        acceptance_fraction=acceptance,
        tau=tau,
        ess=ess,
        samples=samples,
        log_prob=log_prob,
        seconds=seconds,
        n_errors=n_errors,
        **diag,
    )


def sample_posterior(
    log_post: LogPosterior,
    initial,
    backend_path,
    rng: np.random.Generator,
    *,
    n_walkers=None,
    max_steps=DEFAULT_MAX_STEPS,
    check_every=DEFAULT_CHECK_EVERY,
    tau_factor=50.0,
    tau_rtol=0.05,
    moves="de",
    coordinates="gpi",
    reference=None,
    progress=None,
    log=None,
) -> PosteriorResult:
    """Run (or resume) emcee until converged or ``max_steps`` (rules in the module docstring).

    Parameters
    ----------
    log_post : LogPosterior
    initial : callable or array_like
        Walker start ``(n_walkers, D)``, or a callable ``f(n_walkers, rng)`` returning
        one; used only when the backend holds no steps yet.
    backend_path : path-like
        The HDF5 file (``DIR/chain.h5``); an existing chain of the same shape is resumed.
    rng : numpy.random.Generator
        Seeds emcee's internal RandomState (and the walker start).
    n_walkers : int, optional
        Default :func:`default_n_walkers` ``(D)``, or the backend's when resuming.
    max_steps : int, default :data:`DEFAULT_MAX_STEPS` (60000, as ``study``)
        Cap on the chain length [steps], counting resumed steps.
    check_every : int, default 500
        Convergence check interval [steps].
    tau_factor, tau_rtol : float, default 50, 0.05
    moves : str, default "de"
        A key of :data:`MOVES`: ``"de"`` (differential evolution 80 %, DE snooker
        20 %) or ``"stretch"`` (emcee's default). On the 18-parameter GPI posterior of a
        7001-sample record the DE moves' autocorrelation time was about a third of the
        stretch move's (71 vs 200 steps after 3000 steps, 36 walkers).
    coordinates : str or callable, default "gpi"
        Where the moves propose (:mod:`identify.fitting.coordinates`): ``"gpi"`` maps
        the GPI parameters to near-Gaussian coordinates (total weight, envelope values
        at three inputs, log amplitudes, Omega's centres), ``"identity"`` proposes in the parameters
        themselves, a callable ``f(log_post)`` gives other coordinates. The chain, the
        log-posterior and the priors stay in the parameters whatever the choice; only
        the mixing changes.
    reference : array_like, shape (D,), optional
        A point near the posterior for the sampler coordinates' choices (the least-squares
        solution: :class:`identify.fitting.coordinates.GPICoordinates`); pass the same one
        when resuming, so that the moves are the same.
    progress : bool, optional
        True: a tqdm bar on stderr whose total is the projected chain length
        ``tau_factor x tau_max``, re-estimated at each check (:mod:`identify.fitting.progress`);
        False: none; None (default): the bar when stderr is a terminal, else a log line
        (``identify.posterior`` logger, INFO) every 10 s with the step, steps/s, tau_max and
        the projected length.
    log : callable, optional
        ``log(str)`` for one line per check.

    Returns
    -------
    PosteriorResult
    """
    if moves not in MOVES:
        raise ValueError(f"unknown move {moves!r}; known: {', '.join(MOVES)}")
    if isinstance(max_steps, bool) or int(max_steps) < 1 or int(check_every) < 1:
        raise ValueError(f"max_steps and check_every must be >= 1, got {max_steps!r}, {check_every!r}")
    max_steps, check_every = int(max_steps), int(check_every)
    log = log or (lambda _msg: None)
    path = os.fspath(backend_path)
    # The emcee seed and the walker-start generator are drawn first, so they do not
    # depend on whether this call starts or resumes.
    emcee_seed = int(rng.integers(2**32))
    start_rng = rng.spawn(1)[0]
    backend, n_walkers, resuming = _open_chain(path, log_post.ndim, n_walkers)
    loop = EnsembleLoop(
        log_post,
        n_walkers,
        log_post.ndim,
        _moves_in(MOVES[moves](), coordinates_for(coordinates, log_post, reference)),
        backend,
        np.random.RandomState(emcee_seed),
    )
    state = _start_state(loop, initial, resuming, start_rng, emcee_seed, log)

    bar = ChainProgress(
        done=backend.iteration, max_steps=max_steps, tau_factor=tau_factor, mode=progress_mode(progress)
    )

    threads_before = numba.get_num_threads()
    last_probe = -math.inf
    tau_cache: dict[int, np.ndarray] = {}
    diagnostics_cache: dict[tuple, dict] = {}  # (steps, discard, thin) -> chain_diagnostics of the check
    chain = _ChainInMemory(backend.get_chain() if resuming else np.empty((0, n_walkers, log_post.ndim)), max_steps)
    t0 = _time.perf_counter()
    start_steps = backend.iteration
    try:
        while True:
            done = backend.iteration
            if chain.n_steps != done:  # pragma: no cover - a bookkeeping error must not go unnoticed
                raise RuntimeError(f"in-memory chain has {chain.n_steps} steps, the backend {done}")
            stop, converged, message = _check(
                chain.view(), max_steps, check_every, tau_factor, tau_rtol, tau_cache, bar, log, diagnostics_cache
            )
            if stop:
                break
            if _time.perf_counter() - last_probe >= THREAD_PROBE_SECONDS:
                fastest_thread_count(log_post, np.asarray(state.coords))
                last_probe = _time.perf_counter()
            steps = min(check_every - done % check_every, max_steps - done)
            state, block = _run_chunk(loop, state, steps, bar)
            chain.append(block)
            backend.flush()
    finally:
        numba.set_num_threads(threads_before)
        backend.flush()  # also on Ctrl-C: no completed step is lost
        bar.close()
    if backend.iteration > start_steps:  # the chain is finished: its file without the batched writes' leftovers
        try:
            before, after = compact_chain_file(path)
            log(f"{path}: {after / 1e6:.1f} MB ({before / 1e6:.1f} MB before compaction)")
        except OSError as exc:  # a full disk, say: the file as written is complete, only larger
            log(f"{path} left as written, not compacted ({type(exc).__name__}: {exc})")
    return posterior_from_backend(
        path,
        log_post.names,
        converged=converged,
        message=message,
        tau_factor=tau_factor,
        tau_rtol=tau_rtol,
        check_every=check_every,
        seconds=_time.perf_counter() - t0,
        n_errors=log_post.n_errors,
        tau_cache=tau_cache,
        diagnostics_cache=diagnostics_cache,
    )


#: Seconds of sampling between two measurements of the fastest numba thread count
#: (:func:`identify.fitting.threads.fastest_thread_count`, before a chunk of steps): a machine's
#: load changes over seconds, and each measurement evaluates the walkers six times, half of them
#: at the slower count (measured before every 500-step chunk it was 2 % of the sampling time).
THREAD_PROBE_SECONDS = 5.0


def _open_chain(path, ndim, n_walkers):
    """The backend of ``path``, the number of walkers, and whether it holds steps to resume
    (a stored chain of another shape is refused; an empty one is reset)."""
    backend = BufferedHDFBackend(path, name=BACKEND_GROUP)
    resuming = backend.initialized and backend.iteration > 0
    if resuming:
        stored_walkers, stored_dim = backend.shape
        if stored_dim != ndim or (n_walkers is not None and n_walkers != stored_walkers):
            raise ValueError(
                f"{path} holds a chain of {stored_walkers} walkers x {stored_dim} parameters, "
                f"not {n_walkers or 'any'} x {ndim}: a different run (use a new folder or --force)"
            )
        n_walkers = stored_walkers
    n_walkers = default_n_walkers(ndim) if n_walkers is None else int(n_walkers)
    if n_walkers < 2 * ndim or n_walkers % 2:
        raise ValueError(f"n_walkers must be even and >= 2 x {ndim} (the dimension), got {n_walkers}")
    if not resuming:  # a new file, or one without steps
        backend.reset(n_walkers, ndim)
    return backend, n_walkers, resuming


def _start_state(loop, initial, resuming, start_rng, emcee_seed, log):
    """The walkers to continue from (checked by :meth:`EnsembleLoop.start`): the stored last
    step (with its random state) when resuming, else ``initial`` with emcee's generator seeded
    from ``emcee_seed``."""
    if resuming:
        log(f"resuming the chain in {loop.backend.filename} at step {loop.backend.iteration}")
        # emcee's linear-independence check is for a start we made; walkers the sampler itself
        # moved may lie along a near-exact degeneracy of the posterior and must not stop the run
        return loop.start(loop.backend.get_last_sample(), check_independence=False)  # carries the stored random state
    coords = initial(loop.n_walkers, start_rng) if callable(initial) else np.asarray(initial, dtype=float)
    if coords.shape != (loop.n_walkers, loop.ndim):
        raise ValueError(f"initial walkers must have shape ({loop.n_walkers}, {loop.ndim}), got {coords.shape}")
    return loop.start(emcee.State(coords, random_state=np.random.RandomState(emcee_seed).get_state()))


class _ChainInMemory:
    """The chain in memory for the convergence checks: read from the file once (a resumed
    run), then extended in place with each chunk's steps (capacity doubling, so a check
    reads a view and never copies the chain); re-reading the whole HDF5 chain at every
    check cost seconds per check late in a 50000-step run."""

    def __init__(self, chain, max_steps):
        self._buffer = chain
        self.n_steps = chain.shape[0]
        self._max_steps = max_steps

    def view(self):
        return self._buffer[: self.n_steps]

    def append(self, block):
        # the chain as the file stores it (CHAIN_DTYPE): the checks of an uninterrupted run read
        # the same values as those of a run resumed from the file
        block = np.asarray(block).astype(CHAIN_DTYPE).astype(float)
        stored, buffer = self.n_steps, self._buffer
        if stored + len(block) > buffer.shape[0]:
            capacity = max(stored + len(block), min(self._max_steps, 2 * buffer.shape[0]))
            grown = np.empty((capacity,) + buffer.shape[1:])
            grown[:stored] = buffer[:stored]
            self._buffer = buffer = grown
        buffer[stored : stored + len(block)] = block
        self.n_steps = stored + len(block)


def _check(chain, max_steps, check_every, tau_factor, tau_rtol, tau_cache, bar, log, diagnostics_cache=None):
    """The convergence check at the chain's current length: ``(stop, converged, message)``
    (a check runs at multiples of ``check_every`` when due, and at ``max_steps``). The
    R-hat/ESS it computes is kept in ``diagnostics_cache`` under ``(steps, discard, thin)``
    for the final summary (:func:`posterior_from_backend`), which reads the same chain."""
    done = chain.shape[0]
    on_check = done > 0 and done % check_every == 0
    due = done >= max_steps or on_check and check_due(chain, check_every, tau_factor, tau_cache)
    if on_check and tau_cache and not due:  # the anchor's tau: the projection of a skipped check
        bar.estimate(np.max(tau_cache[max(tau_cache)]))
    if not due:
        return False, False, ""
    ok, tau, change, msg = tau_convergence(chain, check_every, tau_factor, tau_rtol, tau_cache)
    bar.estimate(np.max(tau))
    log(f"step {done}: {msg}")
    diag_msg = ""
    if ok:  # tau says converged: R-hat and bulk ESS must agree (computed only then)
        discard, thin = burn_in(tau, done)
        diag = chain_diagnostics(chain[discard::thin])
        if diagnostics_cache is not None:
            diagnostics_cache[(done, discard, thin)] = diag
        diag_ok, diag_msg = diagnostics_verdict(diag)
        log(f"step {done}: {diag_msg}")
        if diag_ok:
            return True, True, "converged: " + msg + "; " + diag_msg
    if done >= max_steps:
        return (
            True,
            False,
            f"NOT CONVERGED: stopped at the cap of {max_steps} steps; " + msg + ("; " + diag_msg if diag_msg else ""),
        )
    return False, False, ""


def _run_chunk(loop, state, steps, bar):
    """``steps`` steps of ``loop`` from ``state``: the last state and the positions ``(steps, W, D)``.
    Ctrl-C / SIGTERM stop between two steps, with every completed step written."""
    positions = np.empty((steps,) + np.shape(state.coords))
    last = state
    with _stop_between_steps() as stop:
        for i, last in enumerate(loop.steps(state, steps)):
            positions[i] = last.coords
            bar.update(1)
            if stop.requested:  # Ctrl-C / SIGTERM: this step is complete and stored
                loop.backend.flush()
                raise KeyboardInterrupt(f"sampling stopped by {stop.requested} after step {loop.backend.iteration}")
    return last, positions


class _StopRequest:
    requested: str = ""


@contextlib.contextmanager
def _stop_between_steps():
    """Turn SIGINT (Ctrl-C) and SIGTERM (``kill PID``) into a request honoured after the
    current step, so no step is cut in half inside emcee (which would print the
    interrupted likelihood call's traceback); a second signal interrupts at once.
    Main thread only (elsewhere signals cannot be handled and nothing changes)."""
    stop = _StopRequest()

    def request(signum, frame):
        if stop.requested:
            raise KeyboardInterrupt(signal.Signals(signum).name)
        stop.requested = signal.Signals(signum).name

    # a signal the process ignores (SIGINT of a background job) stays ignored
    with signal_handlers(request):
        yield stop
