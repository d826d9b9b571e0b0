r"""The evidence of a diagnosis: plain numbers the decision is a function of.

:class:`Evidence` holds the baseline's residual (its RMS, the noise sigma, its adequacy) and,
for every explanation the search finished on the whole record (a single candidate effect, or
a pair), an :class:`Explanation`: its chi-square, delta BIC against the baseline, adequacy,
RMS, and where its part of the fit lies. Between every two explanations a :class:`Gap` says
how far apart their fits are in likelihood and what the record's noise gives that gap.

The gap between two fits :math:`b` (the better) and :math:`o`, with whitened residuals
:math:`w_b, w_o` and :math:`d = w_o - w_b`, is the likelihood ratio
:math:`n_\mathrm{eff} \ln(\chi^2_o / \chi^2_b)` (in units of twice the log-likelihood, the
effective sample size of the better fit: a correlated residual carries less information than
its count; no charge for parameters). Its noise: the chi-square gap is
:math:`\sum (w_o^2 - w_b^2) = \sum d^2 + 2 \sum d\, w_b`, whose noise part :math:`2\sum d\,e` has
the standard deviation :math:`2 \sigma_w \lVert d \rVert` for fixed predictions
(:math:`\sigma_w^2 = \chi^2_b / n`), scaled like the gap. This compares two non-nested models by
the spread of their pointwise differences (Vuong 1989): when one model is the truth the gap is
about :math:`\lVert d\rVert^2` and its ratio to the sd :math:`\lVert d\rVert / 2`; when two
approximations that differ widely fit about equally well, the ratio is small and another
realisation of the noise could reverse their order, however large the gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .adequacy import Adequacy

__all__ = ["Explanation", "Gap", "Evidence", "gap_between", "gaps_among", "gap_noise_sd", "likelihood_gap"]


@dataclass(frozen=True)
class Explanation:
    """One explanation the search finished on the whole record: effects added to the baseline.

    Attributes
    ----------
    name : str
        ``"thermal"`` or ``"creep+training"``.
    chi2 : float
        Whitened chi-square on the whole record.
    n_eff : float
        Effective sample size of its residual.
    delta_bic : float
        Against the baseline (its parameters charged, in its best form): whether it is needed.
    adequate : bool
        Its residual passes the noise tests.
    rms : float
        Residual RMS over the energised part [output units].
    explained : float
        Fraction of the baseline's excess it removes.
    first_loading_share : float or None
        Share of its part of the fit in the first loading.
    """

    name: str
    chi2: float
    n_eff: float
    delta_bic: float
    adequate: bool
    rms: float
    explained: float = 0.0
    first_loading_share: float | None = None

    @property
    def effects(self) -> tuple[str, ...]:
        return tuple(self.name.split("+"))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "chi2": float(self.chi2),
            "n_eff": float(self.n_eff),
            "delta_bic": float(self.delta_bic),
            "adequate": bool(self.adequate),
            "rms": float(self.rms),
            "explained": float(self.explained),
            "first_loading_share": self.first_loading_share,
        }


@dataclass(frozen=True)
class Gap:
    """How far apart two explanations' fits are: ``gap`` (likelihood, ``other`` minus ``better``,
    >= 0) and ``noise_sd``, what the record's noise gives that gap (module docstring)."""

    better: str
    other: str
    gap: float
    noise_sd: float

    @property
    def z(self) -> float:
        """The gap in noise standard deviations (inf when the sd is 0)."""
        return self.gap / self.noise_sd if self.noise_sd > 0 else math.inf

    def to_dict(self) -> dict:
        return {"better": self.better, "other": self.other, "gap": float(self.gap), "noise_sd": float(self.noise_sd)}


def likelihood_gap(chi2: float, chi2_other: float, n_eff: float) -> float:
    """The likelihood gap ``n_eff ln(chi2_other / chi2)`` of a fit of chi-square ``chi2`` over one of
    ``chi2_other`` (both profiled over the noise scale; positive when the first fits better)."""
    return float(n_eff) * math.log(max(chi2_other, 1e-300) / max(chi2, 1e-300))


def gap_noise_sd(better, other, n_eff: float) -> float:
    """What the noise gives the likelihood gap between two fits with whitened residuals
    ``better`` and ``other`` (shape (T,) each), scaled by the better one's effective size."""
    better = np.asarray(better, dtype=float)
    d = np.asarray(other, dtype=float) - better
    chi2_b = float(better @ better)
    if not chi2_b > 0:
        return 0.0
    sigma_w = math.sqrt(chi2_b / better.size)
    return 2.0 * sigma_w * math.sqrt(float(d @ d)) * float(n_eff) / chi2_b


def gap_between(a: Explanation, w_a, b: Explanation, w_b) -> Gap:
    """The :class:`Gap` of two explanations and their whitened residuals, the better (lower
    chi-square) first."""
    if b.chi2 < a.chi2:
        a, w_a, b, w_b = b, w_b, a, w_a
    return Gap(a.name, b.name, likelihood_gap(a.chi2, b.chi2, a.n_eff), gap_noise_sd(w_a, w_b, a.n_eff))


def gaps_among(explanations, whitened) -> tuple:
    """The :class:`Gap` between every two of ``explanations`` (each with its whitened residual
    in ``whitened``, the same order), in the order of the pairs ``(i, j)``, ``i < j``."""
    n = len(explanations)
    return tuple(
        gap_between(explanations[i], whitened[i], explanations[j], whitened[j])
        for i in range(n)
        for j in range(i + 1, n)
    )


@dataclass(frozen=True)
class Evidence:
    """Everything the decision looks at (module docstring).

    Attributes
    ----------
    sigma : float
        The noise sigma [output units].
    baseline_rms : float
        The baseline's residual RMS over the energised part.
    baseline : Adequacy
        The baseline residual's noise tests.
    explanations : tuple of Explanation
        Every single candidate and pair finished on the whole record.
    gaps : tuple of Gap
        Between every two explanations.
    strength : dict
        ``{effect: delta BIC alone}`` of every single candidate with a gain (finished, or on the
        working copy): which member of a pair is the stronger alone.
    first_cycle : tuple of str
        First-cycle physics the model already has.
    targeted : bool
        The baseline passed the noise tests and candidates were refitted for their targeted
        scores.
    """

    sigma: float
    baseline_rms: float
    baseline: Adequacy
    explanations: tuple = ()
    gaps: tuple = ()
    strength: dict = field(default_factory=dict)
    first_cycle: tuple = ()
    targeted: bool = False

    def explanation(self, name: str) -> Explanation | None:
        return next((e for e in self.explanations if e.name == name), None)

    def gap(self, a: str, b: str) -> Gap | None:
        """The gap between explanations ``a`` and ``b`` (either order), or None."""
        return next((g for g in self.gaps if {g.better, g.other} == {a, b}), None)

    def lead(self, a: str, b: str) -> float | None:
        """How far explanation ``a`` fits ahead of ``b``: their likelihood gap, negative where ``b``
        fits better; None where the evidence holds no gap of the two."""
        g = self.gap(a, b)
        if g is None:
            return None
        return float(g.gap if g.better == a else -g.gap)

    def to_dict(self) -> dict:
        return {
            "sigma": float(self.sigma),
            "baseline_rms": float(self.baseline_rms),
            "baseline": self.baseline.to_dict(),
            "explanations": [e.to_dict() for e in self.explanations],
            "gaps": [g.to_dict() for g in self.gaps],
            "strength": {k: float(v) for k, v in self.strength.items()},
            "first_cycle": list(self.first_cycle),
            "targeted": bool(self.targeted),
        }
