"""Is a residual the sensor's noise? The decision thresholds and the adequacy rule.

A residual is *adequate* unless one of the noise tests of :mod:`identify.diagnosis.residuals`
(variance, Ljung-Box, low-frequency block means, and the mean by output level where the
model's output is known) has a standardised excess ``z`` above
:attr:`Thresholds.z_critical` **and** the non-noise part that test sees is at least
:attr:`Thresholds.structure_floor` noise sigmas RMS: a long record resolves structure of a few
per cent of sigma, which is detectable but negligible. The tests' nulls include the error of
the noise reference fitted on a short quiet segment, so their ``z`` is close to normal on pure
noise (``benchmarks/noise_test_calibration.py``).

The practical size (:func:`practical_size`) says whether what a candidate explains matters
against the noise: the RMS must fall by :attr:`Thresholds.practical_rms_change` and the
structure explained, ``sqrt(RMS0^2 - RMS1^2)``, must reach the structure floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .residuals import ResidualProfile

__all__ = ["Thresholds", "Adequacy", "assess_adequacy", "rms_change_and_size", "excess_over_noise"]


@dataclass(frozen=True)
class Thresholds:
    """The diagnosis' decision thresholds.

    Parameters
    ----------
    z_critical : float, default 5.0
        Standardised excess above which a noise test counts as failed (one-sided normal tail
        3e-7; each test's null includes the error of the noise reference fitted on the quiet
        segment).
    structure_floor : float, default 0.1
        Smallest RMS of the non-noise part, in noise sigmas, that counts as a misfit (0.1 sigma
        adds 0.5 % to the residual RMS).
    bic_significant : float, default 10.0
        Evidence asked of the data, in units of twice the log-likelihood: a gain above it is
        "very strong" evidence (Kass and Raftery, 1995; odds of about exp(5)). Used for a
        likelihood gap between two explanations, and for the nested question whether an
        effect (or an optional term, or a pair's second member) is needed at all, where its
        parameters are charged (BIC).
    gap_z : float, default 2.5
        A gap between two explanations' fits must also exceed this many standard deviations of
        what the record's noise gives that gap (:func:`identify.diagnosis.evidence.gap_noise_sd`):
        two approximations of physics that is in neither's exact form can differ widely and fit
        about equally well, and then their order is the noise's, however large the gap. 2.5: a
        one-sided normal tail of 0.6 %, the odds that ``bic_significant`` stands for.
    explained_minor : float, default 0.25
        Pairs are searched when the best single candidate explains at least this fraction of
        the baseline's excess (a pair rests on what its members explain alone).
    max_refits : int, default 3
        Candidates (and pairs) finished on the whole record whatever their short refits on the
        working copy gained, as long as they beat the baseline there: a short refit is a lower
        bound on what a candidate explains, and two candidates that explain a record about
        equally well come out of it in either order. Beyond them, every one whose short refit
        gains more than ``bic_significant`` is finished too.
    try_pairs : bool, default True
        Search pairs of candidates (when no single one repairs the model, and beside one that
        does, where a pair that is needed decides).
    targeted_refits : bool, default True
        When the residual passes the noise tests, still refit the candidates whose screening
        promises a significant gain: a score aimed at one effect's signature has more power
        than the omnibus tests.
    practical_rms_change : float, default 0.01
        A finding must matter against the noise: the RMS must fall by at least this fraction
        (about the relative standard error of an RMS over a 100 Hz record's energised part,
        ``1/sqrt(2 n)``) and the structure explained must reach ``structure_floor``.
    """

    z_critical: float = 5.0
    structure_floor: float = 0.1
    bic_significant: float = 10.0
    gap_z: float = 2.5
    explained_minor: float = 0.25
    max_refits: int = 3
    try_pairs: bool = True
    targeted_refits: bool = True
    practical_rms_change: float = 0.01

    def __post_init__(self):
        for name in ("z_critical", "structure_floor", "bic_significant", "gap_z", "practical_rms_change"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (np.isfinite(value) and value >= 0):
                raise ValueError(f"Thresholds.{name} must be a finite number >= 0, got {value!r}")
        value = self.explained_minor
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not 0.0 <= value <= 1.0:
            raise ValueError(f"Thresholds.explained_minor must lie in [0, 1], got {value!r}")
        refits = self.max_refits
        if isinstance(refits, bool) or not isinstance(refits, (int, np.integer)) or refits < 0:
            raise ValueError(f"Thresholds.max_refits must be an integer >= 0, got {refits!r}")

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Adequacy:
    """Is a residual consistent with the quiet segment's noise?

    Attributes
    ----------
    adequate : bool
    failed : tuple of str
        Tests whose ``z`` exceeds the threshold (whatever the size floor says).
    z : dict of str -> float
        Each test's standardised excess.
    structure_rms : float
        RMS of the slowly varying non-noise part [output units].
    excess_rms : float
        ``sqrt`` of the residual's mean square in excess of the noise variance [output units].
    size_ratio : float
        The misfit of the failed tests over the noise sigma (the largest of the failed ones;
        0 when none failed).
    excess_kind : str
        Which measure quantifies the misfit: ``"low_frequency"`` (slow structure),
        ``"variance"`` (extra variance that is not slow), ``"ljung_box"`` (correlation only),
        ``"level"`` (a mean that depends on the output level) or ``"none"``.
    excess : float
        The misfit in that measure (a variance [units^2], or the Ljung-Box excess).
    """

    adequate: bool
    failed: tuple
    z: dict
    structure_rms: float
    excess_rms: float
    size_ratio: float
    excess_kind: str
    excess: float

    def to_dict(self) -> dict:
        return {
            "adequate": bool(self.adequate),
            "failed": list(self.failed),
            "z": {k: float(v) for k, v in self.z.items()},
            "structure_rms": float(self.structure_rms),
            "excess_rms": float(self.excess_rms),
            "size_ratio": float(self.size_ratio),
            "excess_kind": self.excess_kind,
            "excess": float(self.excess),
        }


#: The tests in the order the misfit's measure is taken from (the first failed).
TESTS = ("low_frequency", "variance", "ljung_box", "level")


def _excess_measure(profile: ResidualProfile, kind: str) -> float:
    tests = profile.tests
    if kind == "level" and "level" not in tests:
        return 0.0
    if kind in ("low_frequency", "variance", "level"):
        return float(tests[kind].structure_variance)
    if kind == "ljung_box":
        lb = tests["ljung_box"]
        return float(max(lb.statistic - lb.null_mean, 0.0))
    return 0.0


def assess_adequacy(profile: ResidualProfile, thresholds: Thresholds = Thresholds(), excess_kind=None) -> Adequacy:
    """Apply the adequacy rule (module docstring) to a residual profile.

    Parameters
    ----------
    profile : ResidualProfile
    thresholds : Thresholds
    excess_kind : str, optional
        Force the excess measure (to compare a refit with its baseline in the same measure);
        default: the first failed of :data:`TESTS`.
    """
    tests = profile.tests
    sigma = profile.noise.sigma
    z = {name: float(t.z) for name, t in tests.items()}
    failed = tuple(name for name in TESTS if name in z and z[name] > thresholds.z_critical)
    structure_rms = math.sqrt(tests["low_frequency"].structure_variance)
    excess_rms = math.sqrt(tests["variance"].structure_variance)
    # each failed test's misfit in its own measure: slow structure for the low-frequency
    # test, the mean by output level for the level test, the excess variance for the others
    # (the Ljung-Box statistic has no size)
    size_of = {"low_frequency": structure_rms, "variance": excess_rms, "ljung_box": excess_rms}
    if "level" in tests:
        size_of["level"] = math.sqrt(tests["level"].structure_variance)
    size_ratio = max((size_of[name] for name in failed), default=0.0) / sigma
    if excess_kind is None:
        excess_kind = failed[0] if failed else "none"
    adequate = not (failed and size_ratio >= thresholds.structure_floor)
    return Adequacy(
        adequate, failed, z, structure_rms, excess_rms, size_ratio, excess_kind, _excess_measure(profile, excess_kind)
    )


def rms_change_and_size(rms0: float, rms1: float, sigma: float) -> tuple[float, float]:
    """``(relative RMS change, explained structure in sigmas)`` from RMS ``rms0`` to ``rms1``:
    ``(RMS0 - RMS1) / RMS0`` and ``sqrt(RMS0^2 - RMS1^2) / sigma``."""
    rms0, rms1 = float(rms0), float(rms1)
    change = (rms0 - rms1) / rms0 if rms0 > 0 else 0.0
    size = math.sqrt(max(rms0 * rms0 - rms1 * rms1, 0.0)) / float(sigma)
    return change, size


def excess_over_noise(rms: float, sigma: float) -> float:
    """A residual's RMS in excess of the noise, ``sqrt(max(RMS^2 - sigma^2, 0)) / sigma``: a
    finding must explain structure that is there (a residual at or below the noise sigma holds
    none; a candidate that lowers it further fits the noise)."""
    rms, sigma = float(rms), float(sigma)
    return math.sqrt(max(rms * rms - sigma * sigma, 0.0)) / sigma
