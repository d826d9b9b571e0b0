"""Could a record have told the true effect from a rival? The noiseless oracle.

A diagnosis names an effect only when the data put it ahead of every rival (the likelihood
gap above ``bic_significant`` and at least ``gap_z`` noise standard deviations of the gap,
:mod:`identify.diagnosis.decision`). Whether a record *can* do that is a property of its
drive, its noise and the two effects' forms, not of one noise realisation. On a bench record
the noiseless output is known, so the question has an answer:

1. Fit the model with the true effect and the model with the rival to the **noiseless**
   displacement, whitened by the noise model the diagnosis estimates from the noisy record.
2. With noise added, each fit's chi-square grows by about the number of samples ``n``, the
   same for both, so the gap a noisy record gives on average is
   ``n ln((chi2_other + n) / (chi2_true + n))`` (no charge for parameters).
3. The noise moves that gap by about ``2 ||d||``, ``d`` the whitened difference of the two
   fits' predictions (:mod:`identify.diagnosis.evidence`).

The observed gap in its noise sd is about normal around the expected ``z`` with sd 1, so
a rule that names at ``gap_z`` names the true effect on ``Phi(z - gap_z)`` of the noise
realisations. The classes (:data:`CLASSES`):

* ``data separate``: the true effect ahead by more than ``bic_significant`` and ``z`` at least
  ``gap_z`` plus the one-sided 95 % normal quantile: it is named on at least 95 % of the
  realisations;
* ``marginal``: the true effect ahead, ``z`` within that quantile of ``gap_z``: named on
  some realisations and tied on others, both honest;
* ``data tie``: closer still (a tie on at least 95 % of the realisations, or the rival
  ahead within the margins);
* ``data favour other``: the rival fits the noiseless truth better by both margins: the true
  effect's form in the library fits this physics worse than the rival does.

The fits are the diagnosis's own baseline fits (several starts, both threshold signs), so a
class can also reflect a fit that missed its best basin; ``starts`` adds parameter vectors
(e.g. the noisy record's refits) from which each model is polished as well, the lower
chi-square kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from statistics import NormalDist

import numpy as np

from model import Model

from ..diagnosis import Thresholds, fit_baseline
from ..fitting.lsq import fit_least_squares
from ..fitting.noise import NoiseModel, estimate_noise, whiten
from ..fitting.parametrisation import normalised_model

__all__ = ["CLASSES", "SHARE", "Separability", "classify", "separability"]

#: The oracle's classes, the true effect's side first.
CLASSES = ("data separate", "marginal", "data tie", "data favour other")
#: Share of noise realisations on which a ``data separate`` record is named (and a
#: ``data tie`` record tied): the margin around ``gap_z`` is its one-sided normal quantile.
SHARE = 0.95


@dataclass(frozen=True)
class Separability:
    """What a record's drive and noise can tell between a true effect and a rival.

    Attributes
    ----------
    true, other : str
        The true effect and the rival.
    chi2 : dict
        ``{name: whitened chi-square of its model fitted to the noiseless record}``.
    gap : float
        The expected likelihood gap, rival minus true (positive: the true effect ahead).
    gap_sd : float
        What the noise gives that gap (one standard deviation).
    kind : str
        One of :data:`CLASSES`.
    fits : dict
        ``{name: FitResult}``: each model's fit to the noiseless record.
    """

    true: str
    other: str
    chi2: dict
    gap: float
    gap_sd: float
    kind: str
    fits: dict

    @property
    def z(self) -> float:
        """The gap in noise standard deviations (+-inf when the sd is 0)."""
        return self.gap / self.gap_sd if self.gap_sd > 0 else math.copysign(math.inf, self.gap)


def classify(gap: float, sd: float, thresholds: Thresholds | None = None) -> str:
    """The class of :data:`CLASSES` of an expected gap ``gap`` (rival minus true) and its noise sd."""
    th = Thresholds() if thresholds is None else thresholds
    z = gap / sd if sd > 0 else math.copysign(math.inf, gap)
    margin = NormalDist().inv_cdf(SHARE)
    if gap > th.bic_significant and z >= th.gap_z + margin:
        return "data separate"
    if gap < -th.bic_significant and z <= -th.gap_z:
        return "data favour other"
    if gap > th.bic_significant and z >= th.gap_z - margin:
        return "marginal"
    return "data tie"


def _fit(clean, model: Model, noise: NoiseModel, rng, starts):
    best = fit_baseline(clean, model, noise, rng=rng)
    for theta in starts:
        theta = np.asarray(theta, dtype=float)
        if theta.shape != best.theta.shape:
            continue
        polished = fit_least_squares(clean, best.model, noise=noise, start=theta, n_starts=1)
        if polished.chi2 < best.chi2:
            best = polished
    return best


def separability(
    record,
    noiseless,
    effects,
    true: str,
    other: str,
    *,
    noise: NoiseModel | None = None,
    thresholds: Thresholds | None = None,
    rng: np.random.Generator | None = None,
    starts: dict | None = None,
) -> Separability:
    """Fit ``effects + [true]`` and ``effects + [other]`` to the noiseless record and class the gap.

    Parameters
    ----------
    record : Record
        The noisy record (its quiet start gives the noise model).
    noiseless : array_like, shape (T,)
        The generator's displacement without noise [um], on ``record``'s samples.
    effects : sequence of str
        The effects the model already has (``[]`` for the plain GPI).
    true, other : str
        The true effect and the rival (an effect, or effects joined by ``+``).
    noise : NoiseModel, optional
        Default: :func:`~identify.fitting.noise.estimate_noise` of ``record``.
    thresholds : Thresholds, optional
        The decision's margins (default ``Thresholds()``).
    rng : numpy.random.Generator, optional
        The fits' random starts (default ``default_rng(0)``).
    starts : dict, optional
        ``{name: [parameter vectors]}``: extra starts for that model's fit.

    Returns
    -------
    Separability
    """
    noiseless = np.asarray(noiseless, dtype=float)
    if noiseless.shape != record.displacement.shape:
        raise ValueError(
            f"the noiseless displacement has shape {noiseless.shape}, the record {record.displacement.shape}"
        )
    noise = estimate_noise(record) if noise is None else noise
    rng = np.random.default_rng(0) if rng is None else rng
    clean = replace(record, displacement=noiseless)
    starts = starts or {}
    fits = {
        name: _fit(clean, normalised_model(Model([*effects, *name.split("+")])), noise, rng, starts.get(name, ()))
        for name in (true, other)
    }
    n = float(noiseless.size)
    first, second = fits[true], fits[other]
    gap = n * math.log((second.chi2 + n) / (first.chi2 + n))
    d = whiten(first.residual - second.residual, noise, time=record.time)
    sd = 2.0 * float(np.sqrt(np.sum(d * d)))
    th = Thresholds() if thresholds is None else thresholds
    return Separability(
        true,
        other,
        {k: float(f.chi2) for k, f in fits.items()},
        float(gap),
        sd,
        classify(gap, sd, th),
        fits,
    )
