r"""Sensor noise from the record's unenergised start, and the Gaussian likelihood it implies.

The quiet segment
-----------------
The paper's record starts with 10 s in which the coils carry no current; the model
output is then the constant rest level and everything the sensor shows is noise. The
segment is detected from the data, not assumed: it is the run of samples from the
first one on whose drive satisfies ``|current| <= current_tolerance`` (default
:data:`DEFAULT_CURRENT_TOLERANCE` times the largest ``|current|``, i.e. zero up to
round-off). It must hold at least :data:`MIN_QUIET_SAMPLES` samples.

Estimates
---------
In the quiet segment a straight line (least squares in time) is removed from the
displacement, which takes out the rest level and any slow sensor drift. From the
detrended values :math:`e_k` (``n`` samples):

* ``sigma`` = :math:`\sqrt{\sum e_k^2 / (n - 2)}` (two fitted line coefficients), the
  marginal standard deviation of the noise [output unit];
* ``rho`` = :math:`\sum_{k\ge1} e_k e_{k-1} / \sum_k e_k^2`, the lag-1 autocorrelation.

White or AR(1): the significance rule
-------------------------------------
Under white noise the lag-1 sample autocorrelation is approximately
:math:`N(-1/n, 1/n)` (Bartlett). The noise is called AR(1) when

.. math::  |\hat\rho + 1/n| \sqrt{n} > z_{1 - p/2}, \qquad p = 0.01 \;(z = 2.576)

(:data:`AR1_SIGNIFICANCE`), i.e. white noise is rejected at the two-sided 1 % level;
otherwise the noise is white and ``rho = 0``.

Likelihood
----------
With residuals :math:`e_k = y_k - \hat y_k` over the whole record (the quiet segment
included: the model predicts the rest level there), AR(1) noise of marginal standard
deviation :math:`\sigma` and lag-1 correlation :math:`\rho` is whitened exactly:

.. math::

    w_0 = e_0 / \sigma, \qquad
    w_k = (e_k - \rho e_{k-1}) / (\sigma\sqrt{1 - \rho^2}) \quad (k \ge 1),

so the :math:`w_k` are i.i.d. standard normal and

.. math::

    \log L = -\tfrac12 \sum_k w_k^2 - T \log\sigma - \tfrac{T-1}{2}\log(1-\rho^2)
             - \tfrac{T}{2}\log 2\pi .

White noise is the case :math:`\rho = 0`.

Uneven sampling
---------------
``rho`` is the correlation of two samples one quiet-segment step ``dt`` apart (the
median time step of the quiet segment, :attr:`NoiseModel.dt`). A record whose steps
differ from it (a record thinned by ``--every`` or by the diagnosis' working copy, which
keep every input reversal at the full rate; dropped samples; a logger with uneven time
stamps) is whitened with each step's own correlation

.. math::  r_k = \rho^{(t_k - t_{k-1}) / dt},

the exact AR(1) correlation at a whole number of steps (either sign of ``rho``) and, for
``rho > 0``, that of the Ornstein-Uhlenbeck process the AR(1) samples at any step (a
fractional step of a negative ``rho`` keeps the sign of the nearest whole step), clipped
to ``|r_k| <= 0.99`` as ``rho`` is:

.. math::

    w_k = (e_k - r_k e_{k-1}) / (\sigma\sqrt{1 - r_k^2}), \qquad
    \log L = -\tfrac12 \sum_k w_k^2 - T \log\sigma - \tfrac12 \sum_{k\ge1}\log(1-r_k^2)
             - \tfrac{T}{2}\log 2\pi .

On an even grid every ``r_k = rho`` and the formulas above are recovered bit for bit.
The whitening functions take the record's ``time`` for this (without it every step is
taken as one ``dt``).

No quiet segment
----------------
Then :func:`estimate_noise` raises :class:`NoQuietSegmentError` naming the two
documented fallbacks, and never guesses:

``noise_sigma=VALUE`` (CLI ``--noise-sigma VALUE``)
    a user-given sigma [output unit], white noise;
``noise_sigma="free"`` (CLI ``--noise-sigma free``)
    sigma is a free parameter: least squares estimates it from the residual RMS with a
    degrees-of-freedom correction, the posterior samples ``noise_log_sigma`` (the
    natural log of sigma, uniform prior, i.e. log-uniform in sigma) with the rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit, prange
from scipy.signal import lfilter

__all__ = [
    "NoiseModel",
    "NoQuietSegmentError",
    "estimate_noise",
    "energised_mask",
    "quiet_segment",
    "whiten",
    "ar1_noise",
    "whiten_rows",
    "log_likelihood",
    "log_likelihood_of_rows",
    "RowLikelihood",
    "MIN_QUIET_SAMPLES",
    "AR1_SIGNIFICANCE",
    "DEFAULT_CURRENT_TOLERANCE",
    "NOISE_SOURCES",
]

#: Fewest quiet samples accepted for a noise estimate.
MIN_QUIET_SAMPLES = 50
#: Two-sided significance level of the white-noise test on the lag-1 autocorrelation.
AR1_SIGNIFICANCE = 0.01
#: Quiet means ``|current| <= DEFAULT_CURRENT_TOLERANCE * max|current|``.
DEFAULT_CURRENT_TOLERANCE = 1e-9
#: Where a noise model's sigma comes from.
NOISE_SOURCES = ("quiet_segment", "user", "free")

_FALLBACKS = (
    "Fall back explicitly: pass --noise-sigma VALUE (a known sensor noise std in the output "
    "unit; Python: noise_sigma=VALUE) or --noise-sigma free (sigma becomes a free parameter: "
    "least squares estimates it from the residual RMS, the posterior samples noise_log_sigma; "
    'Python: noise_sigma="free").'
)


class NoQuietSegmentError(ValueError):
    """The record has no (or too short an) unenergised start to estimate the noise from."""


@dataclass(frozen=True)
class NoiseModel:
    """Gaussian sensor noise: white or AR(1).

    Parameters
    ----------
    sigma : float
        Marginal noise standard deviation [output unit, um by default]. ``NaN`` only for
        ``source="free"`` before least squares has estimated it.
    rho : float
        Lag-1 autocorrelation, ``-1 < rho < 1`` (0 for white noise).
    kind : {"white", "ar1"}
    source : {"quiet_segment", "user", "free"}
        Where ``sigma`` comes from (see the module docstring).
    quiet : slice or None
        The samples of the unenergised start used for the estimate (None unless
        ``source="quiet_segment"``).
    n_quiet : int
        Number of those samples (0 when ``quiet`` is None).
    dt : float or None
        The time step [s] that ``rho`` refers to: the quiet segment's median step (None: the
        record's steps are all taken as one step; see "Uneven sampling" in the module
        docstring and :meth:`step_correlations`).
    """

    sigma: float
    rho: float = 0.0
    kind: str = "white"
    source: str = "quiet_segment"
    quiet: slice | None = None
    n_quiet: int = 0
    dt: float | None = None

    def __post_init__(self):
        if self.kind not in ("white", "ar1"):
            raise ValueError(f"NoiseModel.kind must be 'white' or 'ar1', got {self.kind!r}")
        if self.source not in NOISE_SOURCES:
            raise ValueError(f"NoiseModel.source must be one of {NOISE_SOURCES}, got {self.source!r}")
        if not (-1.0 < self.rho < 1.0):
            raise ValueError(f"NoiseModel.rho must lie in (-1, 1), got {self.rho!r}")
        if self.kind == "white" and self.rho != 0.0:
            raise ValueError(f"white noise has rho = 0, got {self.rho!r}")
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"NoiseModel.dt must be None or a finite time step > 0 [s], got {self.dt!r}")
        if self.source == "free":
            if not (math.isnan(self.sigma) or self.sigma > 0):
                raise ValueError(f"a free noise sigma is NaN (not yet estimated) or > 0, got {self.sigma!r}")
        elif not (math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"NoiseModel.sigma must be finite and > 0, got {self.sigma!r}")

    @property
    def is_free(self) -> bool:
        """True when sigma is a free parameter of the identification."""
        return self.source == "free"

    def with_sigma(self, sigma: float) -> NoiseModel:
        """A copy with ``sigma`` replaced (e.g. the least-squares estimate of a free sigma)."""
        return replace(self, sigma=float(sigma))

    def step_correlations(self, time) -> np.ndarray | None:
        """Each step's lag-1 correlation ``r_k`` on the time grid ``time`` (module docstring,
        "Uneven sampling"), or None when every step has ``rho`` (white noise, no ``dt``, or
        an even grid at ``dt``).

        Parameters
        ----------
        time : array_like, shape (T,)
            Strictly increasing sample times [s].

        Returns
        -------
        ndarray of shape (T - 1,) or None
        """
        if self.rho == 0.0 or self.dt is None or time is None:
            return None
        steps = np.diff(np.asarray(time, dtype=float)) / self.dt
        whole = np.rint(steps)
        # time stamps written with ~10 significant digits: a step within 1e-6 of a whole
        # number of dt is that number
        exact = np.abs(steps - whole) <= 1e-6 * np.maximum(whole, 1.0)
        if exact.all() and (whole == 1.0).all():
            return None
        r = np.empty_like(steps)
        r[exact] = self.rho ** whole[exact]
        fractional = ~exact
        if fractional.any():
            sign = math.copysign(1.0, self.rho) ** np.maximum(whole[fractional], 1.0)  # the nearest whole step's
            r[fractional] = sign * abs(self.rho) ** steps[fractional]
        return np.clip(r, -0.99, 0.99)

    def correlations_on(self, time) -> np.ndarray:
        """Each step's lag-1 correlation on the time grid ``time``, shape ``(T - 1,)``:
        :meth:`step_correlations`, or ``rho`` on every step where that is None."""
        correlations = self.step_correlations(time)
        if correlations is None:
            correlations = np.full(max(np.size(time) - 1, 0), self.rho)
        return correlations

    def draw(self, time, rng, size: int | None = None) -> np.ndarray:
        """Noise of this model on the time grid ``time`` [output unit]: ``sigma`` times AR(1)
        noise of unit marginal variance with each step's correlation (:meth:`correlations_on`;
        white noise when ``rho`` is 0).

        Parameters
        ----------
        time : array_like, shape (T,)
            Strictly increasing sample times [s].
        rng : numpy.random.Generator
            Its ``T`` (or ``size * T``) standard normal draws are the innovations, the same
            draws white noise takes.
        size : int, optional
            Independent series to draw.

        Returns
        -------
        ndarray of shape (T,), or (size, T) with ``size``
        """
        time = np.asarray(time, dtype=float)
        white = rng.standard_normal((1 if size is None else size, time.size))
        eps = self.sigma * ar1_noise(white, self.correlations_on(time))
        return eps[0] if size is None else eps

    def to_dict(self) -> dict:
        """JSON-ready: sigma, rho, kind, source, n_quiet, the quiet samples [start, stop) and dt."""
        return {
            "sigma": None if math.isnan(self.sigma) else float(self.sigma),
            "rho": float(self.rho),
            "kind": self.kind,
            "source": self.source,
            "n_quiet": int(self.n_quiet),
            "quiet": None if self.quiet is None else [int(self.quiet.start), int(self.quiet.stop)],
            "dt": None if self.dt is None else float(self.dt),
        }

    @classmethod
    def from_dict(cls, d: dict) -> NoiseModel:
        """Inverse of :meth:`to_dict`."""
        quiet = d.get("quiet")
        sigma = d.get("sigma")
        return cls(
            sigma=float("nan") if sigma is None else float(sigma),
            rho=float(d.get("rho", 0.0)),
            kind=d.get("kind", "white"),
            source=d.get("source", "quiet_segment"),
            quiet=None if quiet is None else slice(int(quiet[0]), int(quiet[1])),
            n_quiet=int(d.get("n_quiet", 0)),
            dt=None if d.get("dt") is None else float(d["dt"]),
        )


def ar1_noise(white, correlations) -> np.ndarray:
    """AR(1) noise of unit marginal variance from white draws ``(S, T)``, step ``t`` with
    correlation ``correlations[t - 1]`` (white noise itself when every correlation is 0)."""
    correlations = np.asarray(correlations, dtype=float)
    if not np.any(correlations):
        return white
    if np.all(correlations == correlations[0]):  # an even grid: one recursive filter
        rho = float(correlations[0])
        innovations = np.array(white, dtype=float)
        innovations[:, 1:] *= math.sqrt(1.0 - rho * rho)
        return lfilter([1.0], [1.0, -rho], innovations, axis=1)
    eps = np.empty_like(white)
    eps[:, 0] = white[:, 0]
    for t in range(1, white.shape[1]):
        rho = correlations[t - 1]
        eps[:, t] = rho * eps[:, t - 1] + math.sqrt(1.0 - rho * rho) * white[:, t]
    return eps


def quiet_segment(current, *, current_tolerance=None) -> slice:
    """The unenergised start: samples ``0 .. n-1`` with ``|current| <= tolerance``.

    Parameters
    ----------
    current : array_like, shape (T,)
        Drive signal.
    current_tolerance : float, optional
        Largest ``|current|`` still counted as "off" [input unit]. Default
        :data:`DEFAULT_CURRENT_TOLERANCE` ``* max|current|``.

    Returns
    -------
    slice
        ``slice(0, n)``; ``n = 0`` when the first sample is already energised.
    """
    current = np.asarray(current, dtype=float)
    if current.ndim != 1:
        raise ValueError(f"current must have shape (T,), got {current.shape}")
    if current_tolerance is None:
        current_tolerance = DEFAULT_CURRENT_TOLERANCE * float(np.max(np.abs(current), initial=0.0))
    if not (np.isfinite(current_tolerance) and current_tolerance >= 0):
        raise ValueError(f"current_tolerance must be finite and >= 0, got {current_tolerance!r}")
    on = np.abs(current) > current_tolerance
    n = int(np.argmax(on)) if on.any() else current.size
    return slice(0, n)


def _ar1_is_significant(rho_hat: float, n: int, level: float = AR1_SIGNIFICANCE) -> bool:
    from scipy.stats import norm  # deferred: scipy.stats takes seconds to import; only this test needs it

    z = abs(rho_hat + 1.0 / n) * math.sqrt(n)
    return bool(z > norm.ppf(1.0 - level / 2.0))


def estimate_noise(record, *, noise_sigma=None, current_tolerance=None, min_quiet=MIN_QUIET_SAMPLES) -> NoiseModel:
    """The noise model of a record (see the module docstring for the method).

    Parameters
    ----------
    record : identify.data.records.Record
        Uses ``time``, ``current`` and ``displacement`` (all shape (T,)).
    noise_sigma : None, float or "free", default None
        None: estimate from the quiet segment (white or AR(1)). A positive float: a
        user-given sigma [output unit], white noise. ``"free"``: sigma is a free
        parameter (the returned model has ``sigma = NaN`` until least squares).
    current_tolerance : float, optional
        See :func:`quiet_segment`.
    min_quiet : int, default :data:`MIN_QUIET_SAMPLES`
        Fewest quiet samples accepted.

    Returns
    -------
    NoiseModel

    Raises
    ------
    NoQuietSegmentError
        ``noise_sigma`` is None and the record has no quiet start of ``min_quiet``
        samples, or the quiet displacement has zero spread; the message names the
        fallbacks.
    ValueError
        A ``noise_sigma`` that is neither None, ``"free"`` nor a positive finite number.
    """
    if isinstance(noise_sigma, str):
        text = noise_sigma.strip().lower()
        if text == "free":
            return NoiseModel(sigma=float("nan"), rho=0.0, kind="white", source="free")
        try:
            noise_sigma = float(text)
        except ValueError:
            raise ValueError(f"noise_sigma must be a positive number or 'free', got {noise_sigma!r}") from None
    if noise_sigma is not None:
        if isinstance(noise_sigma, bool) or not (np.isfinite(noise_sigma) and noise_sigma > 0):
            raise ValueError(f"noise_sigma must be a positive finite number or 'free', got {noise_sigma!r}")
        return NoiseModel(sigma=float(noise_sigma), rho=0.0, kind="white", source="user")

    quiet = quiet_segment(record.current, current_tolerance=current_tolerance)
    n = quiet.stop
    where = getattr(record, "source", "the record")
    if n < min_quiet:
        found = (
            "no unenergised start (the first sample already carries drive)"
            if n == 0
            else (f"an unenergised start of only {n} samples (at least {min_quiet} needed)")
        )
        raise NoQuietSegmentError(
            f"{where}: cannot estimate the sensor noise: the record has {found}; the noise is "
            f"estimated from the samples before the drive first leaves zero. {_FALLBACKS}"
        )
    t = np.asarray(record.time[quiet], dtype=float)
    y = np.asarray(record.displacement[quiet], dtype=float)
    design = np.column_stack([np.ones(n), t - t.mean()])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    detrended = y - design @ coef
    sum_sq = float(detrended @ detrended)
    # "Zero" up to round-off of the line fit, relative to the record's magnitude.
    level = 1e-9 * max(float(np.max(np.abs(record.displacement))), 1e-300)
    if not sum_sq > n * level**2:
        raise NoQuietSegmentError(
            f"{where}: the {n}-sample unenergised start has zero spread after removing a line "
            f"(a noise-free or heavily quantised record?), so it gives no noise estimate. {_FALLBACKS}"
        )
    sigma = math.sqrt(sum_sq / (n - 2))
    steps = np.diff(t)
    dt = float(np.median(steps))
    # the lag-1 pairs one dt apart (all n - 1 of them on an even grid, where the factor is 1)
    at_dt = np.abs(steps - dt) <= 1e-6 * dt
    pairs = float(detrended[1:][at_dt] @ detrended[:-1][at_dt])
    rho_hat = pairs / sum_sq * ((n - 1) / max(int(at_dt.sum()), 1))
    if _ar1_is_significant(rho_hat, n):
        rho = float(np.clip(rho_hat, -0.99, 0.99))
        return NoiseModel(sigma=sigma, rho=rho, kind="ar1", source="quiet_segment", quiet=quiet, n_quiet=n, dt=dt)
    return NoiseModel(sigma=sigma, rho=0.0, kind="white", source="quiet_segment", quiet=quiet, n_quiet=n, dt=dt)


def energised_mask(record, noise: NoiseModel | None = None) -> np.ndarray:
    """Boolean ``(T,)``: True for the samples after the unenergised start.

    Uses ``noise.quiet`` when the noise came from the quiet segment, else detects the
    zero-current start with :func:`quiet_segment` (any length, possibly none).
    """
    n_samples = len(record.current)
    quiet = noise.quiet if (noise is not None and noise.quiet is not None) else quiet_segment(record.current)
    mask = np.ones(n_samples, dtype=bool)
    mask[quiet] = False
    if not mask.any():
        raise ValueError(f"{getattr(record, 'source', 'record')}: the drive is zero throughout; nothing is energised")
    return mask


def _checked_sigma(noise: NoiseModel, sigma, caller: str) -> np.ndarray:
    """``sigma`` (or ``noise.sigma``) as an array, refused unless finite and > 0."""
    sig = np.asarray(noise.sigma if sigma is None else sigma, dtype=float)
    if not (np.isfinite(sig).all() and (sig > 0).all()):
        raise ValueError(f"{caller} needs a finite sigma > 0, got {sig!r} (a free sigma must be passed explicitly)")
    return sig


def _correlation_log_det(n_samples: int, rho: float, correlations=None) -> float:
    """The log-determinant of the unit-sigma AR(1) correlation matrix: ``(T - 1) log(1 - rho^2)``,
    or ``sum log(1 - r_k^2)`` with each step's ``correlations`` ``r_k`` on an uneven grid."""
    if correlations is None:
        return (n_samples - 1) * math.log(1.0 - rho**2)
    return float(np.sum(np.log1p(-correlations * correlations)))


def _gaussian_log_likelihood(quadratic, n_samples: int, sig, rho: float, correlations=None, log_det=None):
    """The module docstring's log-likelihood from its quadratic term ``sum w_k^2`` (unit-free);
    ``correlations``: each step's ``r_k`` on an uneven grid (None: every step ``rho``);
    ``log_det``: :func:`_correlation_log_det` of them when computed before."""
    if log_det is None:
        log_det = _correlation_log_det(n_samples, rho, correlations)
    return -0.5 * quadratic - n_samples * np.log(sig) - 0.5 * log_det - 0.5 * n_samples * math.log(2.0 * math.pi)


def _correlations_for(noise: NoiseModel, time, n_samples: int):
    """``noise.step_correlations(time)``, checked against the residual's ``n_samples``."""
    if time is None:
        return None
    if np.shape(time) != (n_samples,):
        raise ValueError(f"time has shape {np.shape(time)}, but the residual has {n_samples} samples")
    return noise.step_correlations(time)


def whiten(residual, noise: NoiseModel, sigma=None, *, time=None) -> np.ndarray:
    """Whitened, standardised residuals ``w`` (i.i.d. N(0, 1) under the noise model).

    Parameters
    ----------
    residual : array_like, shape (T,) or (W, T)
        Data minus model [output unit].
    noise : NoiseModel
    sigma : float or array_like of shape (W,), optional
        Overrides ``noise.sigma`` (required when the noise sigma is free).
    time : array_like of shape (T,), optional
        The samples' times [s]: each step is whitened with its own correlation when the
        grid is not the noise model's even step (module docstring, "Uneven sampling").
        Default: every step is one ``noise.dt``.

    Returns
    -------
    ndarray, same shape as ``residual`` (dimensionless)
    """
    e = np.asarray(residual, dtype=float)
    correlations = _correlations_for(noise, time, e.shape[-1]) if noise.rho != 0.0 else None
    return _whitened(e, noise, sigma, correlations)


def _whitened(e, noise: NoiseModel, sigma, correlations) -> np.ndarray:
    """:func:`whiten` of the float array ``e`` with each step's ``correlations`` already
    known (None: every step ``noise.rho``)."""
    sig = _checked_sigma(noise, sigma, "whiten")
    if e.ndim == 2 and sig.ndim == 1:
        sig = sig[:, None]
    if noise.rho == 0.0:
        return e / sig
    w = np.empty_like(e)
    w[..., 0] = e[..., 0]
    if correlations is None:
        rho = noise.rho
        w[..., 1:] = (e[..., 1:] - rho * e[..., :-1]) / math.sqrt(1.0 - rho * rho)
    else:
        w[..., 1:] = (e[..., 1:] - correlations * e[..., :-1]) / np.sqrt(1.0 - correlations * correlations)
    return w / sig


@njit(cache=True, nogil=True)
def _whitened_rows(data, model_rows, rho, scale, sigma, out, finite):
    """``out[r] = whiten(data - model_rows[r])`` (scalar ``sigma``; AR(1) with ``rho``, ``scale
    = sqrt(1 - rho^2)``) with the same operations in the same order, and ``finite[r]``
    whether every value is finite: one pass, no temporaries."""
    n_samples = data.shape[0]
    for r in range(model_rows.shape[0]):
        previous = data[0] - model_rows[r, 0]
        w = previous / sigma
        out[r, 0] = w
        check = w - w  # NaN once any value is not finite
        if rho == 0.0:
            for k in range(1, n_samples):
                w = (data[k] - model_rows[r, k]) / sigma
                out[r, k] = w
                check += w - w
        else:
            for k in range(1, n_samples):
                e = data[k] - model_rows[r, k]
                w = ((e - rho * previous) / scale) / sigma
                previous = e
                out[r, k] = w
                check += w - w
        finite[r] = check == 0.0


@njit(cache=True, nogil=True)
def _whitened_rows_uneven(data, model_rows, correlations, scales, sigma, out, finite):
    """:func:`_whitened_rows` with each step's own correlation ``correlations[k - 1]`` and
    ``scales[k - 1] = sqrt(1 - correlations[k - 1]^2)`` (an uneven grid)."""
    n_samples = data.shape[0]
    for r in range(model_rows.shape[0]):
        previous = data[0] - model_rows[r, 0]
        w = previous / sigma
        out[r, 0] = w
        check = w - w
        for k in range(1, n_samples):
            e = data[k] - model_rows[r, k]
            w = ((e - correlations[k - 1] * previous) / scales[k - 1]) / sigma
            previous = e
            out[r, k] = w
            check += w - w
        finite[r] = check == 0.0


def whiten_rows(
    data, model_rows, noise: NoiseModel, sigma, *, time=None, correlations=None
) -> tuple[np.ndarray, np.ndarray]:
    """``(whiten(data - model_rows, noise, sigma, time=time), finite)`` for rows ``(W, T)`` and
    a scalar ``sigma``: the same values bit for bit, in one pass (the least squares' hot
    path), with ``finite`` ``(W,)`` whether each row is finite throughout. ``correlations``:
    ``noise.step_correlations(time)`` computed once by a caller that whitens on the same grid
    again and again (then ``time`` is not read)."""
    sig = float(_checked_sigma(noise, sigma, "whiten_rows"))
    data = np.ascontiguousarray(data, dtype=np.float64)
    model_rows = np.ascontiguousarray(np.atleast_2d(model_rows), dtype=np.float64)
    out = np.empty(model_rows.shape)
    finite = np.empty(model_rows.shape[0], dtype=np.bool_)
    rho = float(noise.rho)
    if correlations is None and rho != 0.0:
        correlations = _correlations_for(noise, time, data.shape[0])
    if correlations is None:
        _whitened_rows(data, model_rows, rho, math.sqrt(1.0 - rho * rho), sig, out, finite)
    else:
        scales = np.sqrt(1.0 - correlations * correlations)
        _whitened_rows_uneven(data, model_rows, correlations, scales, sig, out, finite)
    return out, finite


def log_likelihood(residual, noise: NoiseModel, sigma=None, *, time=None) -> np.ndarray:
    """Gaussian log-likelihood of residuals under the noise model (formula in the module docstring).

    Parameters
    ----------
    residual : array_like, shape (T,) or (W, T)
    noise : NoiseModel
    sigma : float or array_like of shape (W,), optional
        Overrides ``noise.sigma`` (required when the noise sigma is free).
    time : array_like of shape (T,), optional
        The samples' times [s] (see :func:`whiten`).

    Returns
    -------
    float or ndarray of shape (W,)
    """
    e = np.asarray(residual, dtype=float)
    correlations = _correlations_for(noise, time, e.shape[-1]) if noise.rho != 0.0 else None
    w = _whitened(e, noise, sigma, correlations)
    sig = np.asarray(noise.sigma if sigma is None else sigma, dtype=float)
    return _gaussian_log_likelihood(np.sum(w * w, axis=-1), e.shape[-1], sig, noise.rho, correlations)


@njit(cache=True, parallel=True, fastmath={"reassoc"})
def _whitened_sum_of_squares(data, model_rows, rows, rho, out):
    """``out[i] = sum_k w_k^2`` for the residual ``data - model_rows[rows[i]]`` whitened with
    unit sigma (AR(1) with ``rho``; white for 0), in one pass and without temporaries.

    The rows run on numba's threads, in order (each thread mostly reads rows the model's
    kernel wrote on its core just before). Each row's sum is one loop over its samples whose
    additions the compiler may reorder (``fastmath={"reassoc"}``, nothing else: NaN and inf
    propagate as usual) into vector lanes: a sequential chain of additions waits for each
    one's latency, a third of the speed. The order is the compiled loop's, so a row's value
    does not depend on the rows beside it or on the thread count; it agrees with the
    sequential sum to rounding (and may differ in the last bits between machines with other
    vector widths)."""
    n_samples = data.shape[0]
    for i in prange(rows.shape[0]):
        y = model_rows[rows[i]]
        first = data[0] - y[0]
        previous = first
        total = 0.0
        for k in range(1, n_samples):
            e = data[k] - y[k]
            innovation = e - rho * previous
            total += innovation * innovation
            previous = e
        out[i] = first * first + total / (1.0 - rho * rho)


@njit(cache=True, parallel=True, fastmath={"reassoc"})
def _whitened_sum_of_squares_uneven(data, model_rows, rows, correlations, out):
    """:func:`_whitened_sum_of_squares` with each step's own correlation (an uneven grid), the
    rows on numba's threads (each row's sum the same as alone, its additions in vector lanes)."""
    n_samples = data.shape[0]
    for i in prange(rows.shape[0]):
        y = model_rows[rows[i]]
        previous = data[0] - y[0]
        total = previous * previous
        for k in range(1, n_samples):
            e = data[k] - y[k]
            c = correlations[k - 1]
            innovation = e - c * previous
            total += innovation * innovation / (1.0 - c * c)
            previous = e
        out[i] = total


def log_likelihood_of_rows(
    data, model_rows, rows, noise: NoiseModel, sigma=None, *, time=None, correlations=None
) -> np.ndarray:
    """:func:`log_likelihood` of ``data - model_rows[rows]``, fused (the sampler's hot path).

    Parameters
    ----------
    data : ndarray, shape (T,)
        Measured output [output unit].
    model_rows : ndarray, shape (W, T)
        Model outputs.
    rows : ndarray of int, shape (R,)
        Which rows to score.
    noise : NoiseModel
    sigma : array_like of shape (R,), optional
        Per-row sigma (required when the noise sigma is free).
    time : array_like of shape (T,), optional
        The samples' times [s] (see :func:`whiten`).
    correlations : ndarray of shape (T - 1,), optional
        ``noise.step_correlations(time)`` computed once by a caller that scores on the same
        grid again and again (then ``time`` is not read), as for :func:`whiten_rows`.

    Returns
    -------
    ndarray, shape (R,)
        Equal to ``log_likelihood(data - model_rows[rows], noise, sigma, time=time)`` up to
        rounding (one pass, no (R, T) temporaries).

    See Also
    --------
    RowLikelihood : the same for one record scored again and again, its checks and constants
        computed once.
    """
    return RowLikelihood(data, noise, time=time, correlations=correlations)(model_rows, rows, sigma)


class RowLikelihood:
    """:func:`log_likelihood_of_rows` of one record: the data, the noise's checks and the
    correlation's log-determinant prepared once, each call the kernel and the closed form.

    Parameters
    ----------
    data : ndarray, shape (T,)
        Measured output [output unit].
    noise : NoiseModel
    time : array_like of shape (T,), optional
        The samples' times [s] (an uneven grid's step correlations; see :func:`whiten`).
    correlations : ndarray of shape (T - 1,), optional
        ``noise.step_correlations(time)`` when computed before (then ``time`` is not read).
    """

    def __init__(self, data, noise: NoiseModel, *, time=None, correlations=None):
        self.data = np.ascontiguousarray(data, dtype=np.float64)
        self.noise = noise
        n_samples = self.data.shape[0]
        if correlations is None and noise.rho != 0.0:
            correlations = _correlations_for(noise, time, n_samples)
        self.correlations = None if correlations is None else np.ascontiguousarray(correlations, dtype=np.float64)
        self._rho = float(noise.rho)
        self._log_det = _correlation_log_det(n_samples, noise.rho, self.correlations)
        # the noise's own sigma when usable, checked once (a free one not yet estimated is NaN)
        usable = noise.sigma is not None and math.isfinite(noise.sigma) and noise.sigma > 0
        self._sigma = _checked_sigma(noise, None, "log_likelihood_of_rows") if usable else None

    def __call__(self, model_rows, rows, sigma=None) -> np.ndarray:
        """Log-likelihoods ``(R,)`` of ``data - model_rows[rows]`` (``model_rows`` ``(W, T)``,
        ``rows`` ``(R,)`` ints); ``sigma`` ``(R,)`` overrides the noise's (required when free)."""
        if sigma is None and self._sigma is not None:
            sig = self._sigma
        else:
            sig = _checked_sigma(self.noise, sigma, "log_likelihood_of_rows")
        model_rows = np.ascontiguousarray(model_rows, dtype=np.float64)
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        sum_of_squares = np.empty(rows.shape[0])
        if self.correlations is None:
            _whitened_sum_of_squares(self.data, model_rows, rows, self._rho, sum_of_squares)
        else:
            _whitened_sum_of_squares_uneven(self.data, model_rows, rows, self.correlations, sum_of_squares)
        n_samples = self.data.shape[0]
        return _gaussian_log_likelihood(sum_of_squares / sig**2, n_samples, sig, self._rho, log_det=self._log_det)
