r"""Design the next experiment: the drive that decides between the explanations a record leaves tied.

When the diagnosis ends ``tied``, the way forward is another record of the same transducer.
Which one to take is optimal experiment design for model discrimination: for each ordered
pair of contenders (``a`` the truth, ``b`` its rival), the proposed record is worth the
chi-square gap it would show *after the rival is refitted to mimic the truth* on the new record
and the records already taken together (T-optimality, Atkinson and Fedorov 1975; with the
rival's parameters held by what the records already say, a Bayesian reading close to the
KL-optimality of Lopez-Fidalgo, Tommasi and Trandafir 2007). Linearised around the rival's fit,
with ``d`` the whitened difference of the two predictions on the proposed drive, ``J`` the
rival's whitened Jacobian there (the transducer's parameters, the run's own parameters and
sensor zero of the new record) and ``F`` the information the records already hold on the
rival's transducer parameters (the inverse of their covariance; none on the new run's):

.. math::  \Delta = -(J^\top J + F)^{+} J^\top d, \qquad
           \mathrm{gap} = \lVert d + J\Delta \rVert^2 + \Delta^\top F \Delta,

and the noise moves that gap by about ``2 ||d + J Delta||`` (the rule of
:mod:`identify.diagnosis.evidence`). The diagnosis names the truth when the gap exceeds
``bic_significant`` and ``gap_z`` of its noise sd, so the predicted probability of a right name is
:math:`\Phi((\mathrm{gap} - \max(10, 2.5\,\mathrm{sd}))/\mathrm{sd})`. The design maximises the
smallest of these over the ordered pairs (maximin: the drive must decide every tie).

The search runs over a few families of drives with a handful of shape parameters each, all
within the rig's limits (:class:`RigLimits`: current range, slew, duration, RMS current as the
heating limit, sampling rate) and starting with the quiet segment the records need for their
noise (half of them resting at the lower current after it, where a state an earlier run left
relaxes alone): ``hold`` (cycles, a hold at a constant current, a quiet end), ``rise_again`` (the
amplitude falls and rises again, a quiet end), ``steps`` (a staircase of held currents) and
``probe_blocks`` (blocks of high power between small probe cycles). The best few are confirmed
by simulation: each contender, drawn from its posterior on the records (:func:`posterior_draw`),
drives the proposed record with noise; every rival is refitted on
it nonlinearly, held by the records' information, from its fit and from where the new record's
screening puts its effects (:func:`rival_starts`), and the right names are counted
(:func:`confirm`). Where those refits end is where each rival mimics each truth best; every drive
is then ranked again with each rival also linearised there
(:mod:`identify.workflows.design_criterion`), and the best drive not yet confirmed is confirmed
too. The confirmed drive with the highest smallest share of right names (leximin over the
truths) is proposed, confirmed again on every sample with every contender refitted on the new record and
the records already taken together (the joint diagnosis's fit and gap): its realised gaps (their
mean and the next gap's sd) are the calibrated prediction beside the linear one.

A drive decides when its weakest pair's linear chance and its weakest truth's simulated share of
right names both reach :data:`DECISIVE`. Where none of the duration limit does and the rig can
take longer records (:attr:`RigLimits.longest`), the design is made again at twice and four times
the duration (capped at the longest), until one decides; of those designed, the drive with the
most right names in the simulation is proposed, the shorter record where they are equal. A longer
record gives the slow effects more time to show (to heat and cool, to creep, to drift) and the
rivals more to mimic, so only the simulation says whether it decides.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field, replace

import numpy as np

from model import Model, get_effect

from ..data.records import Record
from ..diagnosis import Thresholds, diagnose
from ..diagnosis.joint import joint_fit_with_earlier_runs
from ..fitting.joint import check_records, fit_joint, with_earlier_runs
from ..fitting.lsq import fit_least_squares
from ..fitting.noise import NoiseModel, estimate_noise
from ..fitting.parametrisation import normalised_model
from ..fitting.terms import select_terms
from ..logs import ordinal
from .design_confirmation import (
    RecordMisfit,
    confirm,
    draw_transducer,
    penalised_refit,
    posterior_draw,
    record_misfit,
    rival_starts,
    simulated_gap,
    warm_start,
)
from .design_criterion import (
    DECISIVE,
    DesignedDrive,
    RivalBasins,
    confirmed_rank,
    decisive,
    discrimination,
    evaluate,
    linear_rank,
    p_right,
    simulation_text,
    weakest_right_name,
)
from .design_drives import (
    FAMILIES,
    MAX_REST,
    SHAPES,
    RigLimits,
    drive_of,
    drive_period,
    perturbed_parameters,
    random_drive_parameters,
    rest_seconds,
)

__all__ = [
    "RigLimits",
    "Contender",
    "contender",
    "contenders_of",
    "fit_with_earlier_runs",
    "DesignedDrive",
    "Design",
    "FAMILIES",
    "design",
    "design_drive",
    "discrimination",
    "p_right",
    "RivalBasins",
    "random_drive_parameters",
    "perturbed_parameters",
    "refine",
    "SHAPES",
    "MAX_REST",
    "drive_of",
    "drive_period",
    "rest_seconds",
    "confirm",
    "RecordMisfit",
    "record_misfit",
    "draw_transducer",
    "posterior_draw",
    "rival_starts",
    "warm_start",
    "penalised_refit",
    "simulated_gap",
    "longer_records",
    "longer_durations",
    "decisive",
]

#: Drives evaluated per family in the search.
DRIVES_PER_FAMILY = 40
#: Best drives confirmed by simulation.
CONFIRMED = 3
#: Of these, the last ones chosen after the drives are ranked again with every rival also
#: linearised where the first confirmations' refits of it ended (:class:`RivalBasins`): the
#: linear criterion around the fits alone misses the basins from which a rival mimics the truth.
BASIN_ROUND = 1
#: Perturbed shapes tried around each of the best drives of the random search
#: (:func:`refine`), and the perturbation's sd as a share of each parameter's range: random
#: shapes leave the neighbourhood of the best ones unexplored, where the criterion is smooth.
REFINE_TRIALS = 24
REFINE_SPREAD = 0.15
#: Samples of a drive in the search and the confirmations that rank the best few: longer drives
#: are evaluated on every k-th sample (the same drive; the best ones again on every sample, and
#: the chosen one confirmed on every sample: a gap measured on fewer samples and scaled up is
#: only as good as the scale, which a feature the decimation misses makes arbitrary).
DESIGN_SAMPLES = 1500
#: The longer durations tried when the chosen drive is not decisive, as multiples of the limit.
LONGER = (2.0, 4.0)


@dataclass(frozen=True)
class Contender:
    """One explanation to tell apart: its model, its vector for a new record (the transducer and the
    run parameters as the records showed them), and the information the records hold on its
    transducer parameters (``info``, over the model's columns; zero where the records say nothing
    about a new record: the run's own parameters, the pinned ones)."""

    name: str
    model: Model
    theta: np.ndarray
    info: np.ndarray
    covariance: np.ndarray
    #: Each record's fitted vector ``(P,)`` and sensor zero, in the records' order (empty where
    #: not known): what a draw of the transducer is held to (:func:`record_misfit`).
    runs: tuple = ()
    #: ``(theta, covariance)`` the confirmation draws the truth from, when not the fit's: the fit
    #: with the optional terms its record does not support pinned off (:func:`draws_without_unsupported_terms`).
    draws_from: tuple | None = None


def contender(name: str, model: Model, theta, covariance, runs=None, draws_from=None) -> Contender:
    """A :class:`Contender` from a fit: its vector and covariance over ``model``'s columns; the
    information on the transducer is the inverse of the covariance of its shared parameters (the
    run's own parameters say nothing about a new record). ``runs``: each record's fitted vector
    and sensor zero (default: one record, fitted at ``theta``); ``draws_from``: the ``(theta,
    covariance)`` the confirmation draws from (default the fit's). The contender's model frees the
    state earlier runs left (:func:`identify.fitting.joint.with_earlier_runs`): the new record is
    refitted as the joint diagnosis fits it."""
    covariance = np.asarray(covariance, dtype=float)
    theta = np.asarray(theta, dtype=float)
    model = with_earlier_runs(model)
    per_record = np.array([p.per_record for p in model.parameters])
    shared = np.flatnonzero((np.diag(covariance) > 0) & ~per_record)
    info = np.zeros_like(covariance)
    if shared.size:
        info[np.ix_(shared, shared)] = np.linalg.pinv(covariance[np.ix_(shared, shared)], rcond=1e-12, hermitian=True)
    runs = ((theta, 0.0),) if runs is None else tuple((np.asarray(t, dtype=float), float(z)) for t, z in runs)
    if draws_from is not None:
        draws_from = (np.asarray(draws_from[0], dtype=float), np.asarray(draws_from[1], dtype=float))
    return Contender(name, model, theta, info, covariance, runs, draws_from)


def draws_without_unsupported_terms(record: Record, fit) -> tuple | None:
    """``(theta, covariance)`` of ``fit`` (a single record's :class:`~identify.fitting.lsq.FitResult`)
    with the optional terms ``record`` does not support pinned off (:func:`identify.fitting.terms.select_terms`,
    the test the study makes before its posterior); None when every term is supported.

    A term the record does not support (a sensor's ambient cycle, a warm-up) fits to about nothing,
    and its parameters trade along flat and curved directions with the rest of the effect: the
    covariance's draws wander along them, each still fitting the record, but they extrapolate to a
    new drive far apart (a long-period sine and the drift's parabola that cancel over the record
    no longer do over a longer one). The record holds no evidence for those terms, so the
    prediction's truth is drawn without them; every contender is still refitted with them.
    """
    pruned = select_terms(record, fit)
    if pruned is fit:
        return None
    return pruned.theta, pruned.covariance


def _joint_runs(jf) -> list:
    """Each record's vector and zero of a joint fit ``jf``."""
    rows = [jf.joint.record_rows(jf.theta, r) for r in range(1, jf.joint.n_records + 1)]
    return [(vectors[0], zeros[0]) for vectors, zeros in rows]


def contenders_of(diagnosis, names=None, record: Record | None = None) -> list:
    """The contenders of a diagnosis: its tied explanations (or ``names``), each from its fit (the
    joint fit's for several records). With the single ``record`` diagnosed, each draws from its fit
    without the terms the record does not support (:func:`draws_without_unsupported_terms`)."""
    wanted = list(names) if names is not None else list(diagnosis.tied)
    if len(wanted) < 2:
        raise ValueError(
            f"the diagnosis is '{diagnosis.status}', not a tie: give the explanations to tell apart (--candidates a,b)"
        )
    joint_fits = getattr(diagnosis, "joint_fits", None)
    found = []
    for name in wanted:
        if joint_fits is not None and name in joint_fits:
            found.append(_joint_contender(name, joint_fits[name]))
            continue
        entry = next((c for c in [*diagnosis.ranking, *diagnosis.pairs_tried] if c.effect == name), None)
        if entry is None or entry.fit is None:
            known = sorted(c.effect for c in [*diagnosis.ranking, *diagnosis.pairs_tried] if c.fit is not None)
            raise ValueError(
                f"'{name}' was not fitted by the diagnosis; the fitted explanations are {', '.join(known)}"
            )
        if record is None:
            found.append(contender(name, entry.fit.model, entry.fit.theta, entry.fit.covariance))
        else:
            found.append(_record_contender(name, record, entry.fit))
    return found


def _joint_contender(name: str, jf) -> Contender:
    """The contender of a joint fit ``jf``: record 1's vector and covariance, every record's run."""
    n = jf.model.n_parameters
    return contender(name, jf.model, jf.joint.record_theta(jf.theta, 1), jf.covariance[:n, :n], _joint_runs(jf))


def _record_contender(name: str, record: Record, fit) -> Contender:
    """The contender of a single ``record``'s fit, held as the joint diagnosis fits the record
    (:func:`fit_with_earlier_runs`), drawn without the terms it does not support
    (:func:`draws_without_unsupported_terms`)."""
    fit = fit_with_earlier_runs(record, fit)
    draws_from = draws_without_unsupported_terms(record, fit)
    return contender(name, fit.model, fit.theta, fit.covariance, draws_from=draws_from)


def fit_with_earlier_runs(record: Record, fit):
    """``fit`` (a single record's :class:`~identify.fitting.lsq.FitResult`) refitted from itself with
    the state earlier runs left free (:func:`identify.fitting.joint.with_earlier_runs`), as the
    joint diagnosis of this record and the next will fit it; ``fit`` where nothing is freed or the
    refit is no better. The design then holds the record's own run at what the joint diagnosis
    can reach (a heating that starts warm can stand in for a drift on it)."""
    model = with_earlier_runs(fit.model)
    if model is fit.model:
        return fit
    refit = fit_least_squares(record, model, noise=fit.noise, start=fit.theta, n_starts=1)
    return refit if refit.chi2 < fit.chi2 else fit


# -- the design --------------------------------------------------------------------------------


@dataclass
class Design:
    """The proposed next record and what it is expected to decide."""

    contenders: list
    limits: RigLimits
    best: DesignedDrive
    ranked: list
    noise_sigma: float
    reason: str
    seconds: float = 0.0
    #: Where the best drive is not decisive: the best drive found at each longer duration
    #: (:data:`LONGER`), ``{"duration", "family", "value"}`` (linear prediction only).
    longer: list = field(default_factory=list)
    #: The durations designed in full (the limit, then longer ones up to the rig's longest record
    #: while none decided), ``{"duration", "family", "value"}`` with the best drive's weakest right
    #: name (the smaller of its linear chance and its simulated share).
    durations: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "contenders": [c.name for c in self.contenders],
            "limits": self.limits.to_dict(),
            "noise_sigma": float(self.noise_sigma),
            "best": self.best.to_dict(),
            "others": [d.to_dict() for d in self.ranked[1:]],
            "reason": self.reason,
            "longer": [dict(x) for x in self.longer],
            "durations": [dict(x) for x in self.durations],
            "seconds": float(self.seconds),
        }


def _evaluated_drive(
    family: str,
    params: dict,
    contenders,
    limits: RigLimits,
    noise: NoiseModel,
    th: Thresholds,
    period: float,
    step: int,
    basins: RivalBasins | None = None,
) -> DesignedDrive | None:
    """The drive of ``family`` with ``params`` evaluated on every ``step``-th sample (:func:`evaluate`,
    with the rivals' ``basins``), or None outside the limits (:func:`drive_of`)."""
    made = drive_of(family, params, limits, period)
    if made is None:
        return None
    return evaluate(DesignedDrive(family, params, *made), contenders, noise, th, step, basins)


def search(
    contenders,
    limits: RigLimits,
    noise: NoiseModel,
    th: Thresholds,
    rng,
    period: float,
    per_family=DRIVES_PER_FAMILY,
    say=None,
    step: int = 1,
    basins: RivalBasins | None = None,
) -> list:
    """Drives of every family drawn within the limits and evaluated (on every ``step``-th sample,
    with the rivals' ``basins``), best first."""
    say = say or (lambda message: None)
    drives = []
    for family in FAMILIES:
        say(f"searching the '{family}' drives ({per_family} shapes)")
        for _ in range(per_family):
            drive = _evaluated_drive(
                family, random_drive_parameters(rng, family), contenders, limits, noise, th, period, step, basins
            )
            if drive is not None:
                drives.append(drive)
    if not drives:
        raise ValueError(
            "no drive of any family fits the limits (the duration, the RMS current limit or the slew leave no "
            "room after the quiet start): loosen --duration, --max-rms-current or --max-slew"
        )
    drives.sort(key=linear_rank)
    return drives


def refine(
    drive: DesignedDrive,
    contenders,
    limits: RigLimits,
    noise: NoiseModel,
    th: Thresholds,
    rng,
    period: float,
    step: int = 1,
    trials: int = REFINE_TRIALS,
    basins: RivalBasins | None = None,
) -> DesignedDrive:
    """The best drive found by a local search from ``drive``: ``trials`` times a shape perturbed
    from the best so far (:func:`perturbed_parameters`, :data:`REFINE_SPREAD`, its counts kept),
    kept when it ranks higher (:func:`linear_rank`, on every ``step``-th sample, with the rivals'
    ``basins``)."""
    best = drive
    for _ in range(trials):
        params = perturbed_parameters(rng, best.family, best.params, REFINE_SPREAD)
        candidate = _evaluated_drive(best.family, params, contenders, limits, noise, th, period, step, basins)
        if candidate is not None and linear_rank(candidate) < linear_rank(best):
            best = candidate
    return best


def longer_records(
    contenders,
    limits: RigLimits,
    noise: NoiseModel,
    th: Thresholds,
    rng,
    period: float,
    per_family: int,
    say=None,
    basins: RivalBasins | None = None,
) -> list:
    """The best drive at each of the :data:`LONGER` multiples of the duration limit (a search of
    ``per_family`` shapes per family on every k-th sample, the best again on every sample; the
    linear prediction with the rivals' ``basins``, no simulation): ``[{"duration", "family",
    "value"}]``, the durations at which no drive fits the other limits left out."""
    rows = []
    for factor in LONGER:
        longer = replace(limits, duration=limits.duration * factor)
        try:
            best = search(contenders, longer, noise, th, rng, period, per_family, say, _search_step(longer), basins)[0]
        except ValueError:
            continue
        evaluate(best, contenders, noise, th, basins=basins)
        rows.append({"duration": float(longer.duration), "family": best.family, "value": float(best.value)})
    return rows


def longer_text(rows) -> str:
    """The sentence on longer records ("" when there are none)."""
    if not rows:
        return ""
    return f" Longer records (beyond --duration) would raise that chance to {_chances_at(rows)}."


def _search_step(limits: RigLimits) -> int:
    """Every how many samples a drive of ``limits`` is evaluated in the search (:data:`DESIGN_SAMPLES`)."""
    return max(1, math.ceil(limits.duration * limits.fs / DESIGN_SAMPLES))


def _chances_at(rows) -> str:
    """``"34 % at 120 s, 71 % at 240 s"``: each row's ``value`` at its ``duration``."""
    return ", ".join(f"{100 * r['value']:.0f} % at {r['duration']:.0f} s" for r in rows)


def design_drive(
    contenders,
    records,
    noise: NoiseModel,
    *,
    limits: RigLimits | None = None,
    thresholds=None,
    rng=None,
    per_family=DRIVES_PER_FAMILY,
    n_confirm=CONFIRMED,
    progress=None,
    noises=None,
) -> Design:
    """The next record that best decides between ``contenders`` (module docstring).

    Parameters
    ----------
    contenders : sequence of Contender
        Two or more explanations to tell apart (:func:`contenders_of`).
    records : sequence of Record
        The records already taken (the limits' defaults, the drive's period).
    noise : NoiseModel
        The sensor's noise (its sigma and correlation) for the next record.
    limits : RigLimits, optional
        Default :meth:`RigLimits.from_records`.
    thresholds : Thresholds, optional
    rng : numpy.random.Generator, optional
    per_family : int
        Drives drawn per family.
    n_confirm : int
        Best drives confirmed by simulation (on the search's decimated samples); the one of them
        with the highest smallest share of right names is chosen and confirmed again on every
        sample, its realised gaps the calibrated prediction.
    progress : callable(str), optional
    noises : sequence of NoiseModel, optional
        Each record's noise, which holds the confirmation's draws to the records
        (:func:`record_misfit`); default estimated from each record's quiet start.

    Returns
    -------
    Design
    """
    t0 = _time.perf_counter()
    say = progress or (lambda message: None)
    th = Thresholds() if thresholds is None else thresholds
    rng = np.random.default_rng(0) if rng is None else rng
    if len(contenders) < 2:
        raise ValueError("a design needs two or more contenders to tell apart")
    limits = RigLimits.from_records(records) if limits is None else limits
    misfits = _misfits(contenders, records, noises)
    period = drive_period(records)
    best, ranked, basins = _drive_at(contenders, limits, noise, th, rng, period, per_family, n_confirm, misfits, say)
    chosen, tried = limits, [_weakest_row(best, limits)]
    for duration in longer_durations(limits):
        if decisive(best):
            break
        say(
            f"the weakest right name at {tried[-1]['duration']:g} s is {100 * tried[-1]['value']:.0f} %: designing a "
            f"{duration:g} s record (the rig's longest is {limits.longest:g} s)"
        )
        longer_limits = replace(limits, duration=duration)
        found = _drive_at(contenders, longer_limits, noise, th, rng, period, per_family, n_confirm, misfits, say)
        tried.append(_weakest_row(found[0], longer_limits))
        if confirmed_rank(found[0]) < confirmed_rank(best):
            (best, ranked, basins), chosen = found, longer_limits
    worst = min(best.pairs, key=lambda p: p["p_right"])
    reason = (
        f"The '{best.family}' drive{_rest_text(best, chosen)} separates every pair: its weakest, "
        f"'{worst['truth']}' against "
        f"'{worst['rival']}', shows a gap of {worst['gap']:.0f} (noise sd {worst['noise_sd']:.3g}) after the rival "
        f"is refitted to mimic it, a {100 * worst['p_right']:.0f} % chance that the joint diagnosis names the right "
        f"one.{simulation_text(best)}{durations_text(tried, chosen)}"
    )
    longer = []
    if best.value < DECISIVE and len(tried) == 1:
        say(f"the weakest chance is {100 * best.value:.0f} %: searching longer records")
        search_args = (contenders, limits, noise, th, rng, period)
        longer = longer_records(*search_args, max(per_family // 4, 1), say, basins)
        reason += longer_text(longer)
    seconds = _time.perf_counter() - t0
    return Design(list(contenders), chosen, best, ranked, float(noise.sigma), reason, seconds, longer, tried)


def longer_durations(limits: RigLimits) -> list:
    """The durations beyond ``limits.duration`` a design may try: the :data:`LONGER` multiples,
    capped at the rig's longest record (none when it is not longer)."""
    found = []
    for factor in LONGER:
        duration = min(limits.duration * factor, limits.longest_record)
        if duration > (found[-1] if found else limits.duration) * (1 + 1e-9):
            found.append(duration)
    return found


def _weakest_row(drive: DesignedDrive, limits: RigLimits) -> dict:
    return {"duration": float(limits.duration), "family": drive.family, "value": weakest_right_name(drive)}


def durations_text(rows, chosen: RigLimits) -> str:
    """The sentence on the durations designed in full, where more than one was ("" otherwise)."""
    if len(rows) < 2:
        return ""
    return (
        f" Designed at {len(rows)} durations, the best drive's weakest right name (the smaller of the linear chance"
        f" and the simulation's share) was {_chances_at(rows)}; the record proposed is {chosen.duration:.0f} s"
        " long, the duration whose drive the simulation names right most often."
    )


def _drive_at(contenders, limits: RigLimits, noise, th, rng, period, per_family, n_confirm, misfits, say):
    """The best drive within ``limits`` and the drives ranked, best first (module docstring:
    the search, refined, confirmed by simulation, ranked again with the rivals' basins, the
    chosen one confirmed on every sample)."""
    step = _search_step(limits)
    search_args = (contenders, limits, noise, th, rng, period)
    basins = RivalBasins()  # where the confirmations' refits of each rival ended
    first = n_confirm - BASIN_ROUND if n_confirm > BASIN_ROUND else n_confirm
    ranked = search(*search_args, per_family, say, step)
    used = ranked[: max(first, 1)]
    say(f"refining the best {len(used)} drives' shapes")
    top = _best_refined(used, search_args, step, None, say)
    _confirm_drives(top[:first], contenders, noise, th, rng, step, misfits, basins, say)
    if n_confirm > first and len(basins):
        say(f"ranking the drives again with the {len(basins)} points where the rivals' refits ended")
        fresh = [d for d in ranked if all(d is not u for u in used)]
        for drive in fresh:
            evaluate(drive, contenders, noise, th, step, basins)
        for drive in top:
            evaluate(drive, contenders, noise, th, basins=basins)
        fresh = sorted(fresh, key=linear_rank)[: n_confirm - first]
        used = used + fresh
        more = _best_refined(fresh, search_args, step, basins, say)
        _confirm_drives(more, contenders, noise, th, rng, step, misfits, basins, say)
        top += more
    top.sort(key=confirmed_rank)
    ranked = top + [d for d in ranked if all(d is not u for u in used)]
    best = ranked[0]
    if step > 1 and n_confirm > 0:
        say(f"confirming the chosen '{best.family}' drive by simulation on every sample")
        best.confirmed = confirm(best, contenders, noise, th, rng, misfits=misfits, basins=basins)
        evaluate(best, contenders, noise, th, basins=basins)
    return best, ranked, basins


def _best_refined(drives, search_args, step: int, basins, say) -> list:
    """Each of ``drives`` refined (:func:`refine`, with the rivals' ``basins``), evaluated on every
    sample, best first."""
    contenders, _, noise, th, _, _ = search_args
    top = [refine(d, *search_args, step, basins=basins) for d in drives]
    if step > 1:
        say(f"the best {len(top)} drives on every sample")
        for drive in top:
            evaluate(drive, contenders, noise, th, basins=basins)
    return sorted(top, key=linear_rank)


def _confirm_drives(drives, contenders, noise, th, rng, step: int, misfits, basins, say) -> None:
    """Confirm each of ``drives`` by simulation on every ``step``-th sample (:func:`confirm`), the
    rivals' refits' ends added to ``basins``: on every record together only where no final
    confirmation follows."""
    every = f" (every {ordinal(step)} sample)" if step > 1 else ""
    for drive in drives:
        say(f"confirming a '{drive.family}' drive by simulation{every}")
        drive.confirmed = confirm(
            drive, contenders, noise, th, rng, step=step, misfits=misfits, every_record=step == 1, basins=basins
        )


def _rest_text(drive: DesignedDrive, limits: RigLimits) -> str:
    """``", after a rest of N s at the lower current,"`` where the drive rests after its quiet start."""
    seconds = rest_seconds(drive.params, limits)
    return f", after a rest of {seconds:.3g} s at the lower current," if seconds > 0.0 else ""


def _misfits(contenders, records, noises) -> dict:
    """Each contender's :func:`record_misfit` by name (none where a record has no noise estimate)."""
    if noises is None:
        try:
            noises = [estimate_noise(r) for r in records]
        except ValueError:
            return {}
    found = {c.name: record_misfit(c, list(records), list(noises)) for c in contenders}
    return {name: m for name, m in found.items() if m is not None}


def _explanation_model(name: str, model: Model) -> Model:
    """``model`` plus the effects of explanation ``name`` (``"creep"``, ``"creep+sensor_drift"``);
    an unknown effect or one already in the model is a ValueError naming it."""
    for effect in name.split("+"):
        get_effect(effect)
        if effect in model.effect_names:
            raise ValueError(f"candidate '{name}': '{effect}' is already in the model {model!r}")
    return model + name.split("+")


def fitted_contenders(records, model: Model, names, noises, *, n_starts: int = 4, rng=None, say=None) -> list:
    """Each explanation of ``names`` fitted by least squares on the records (jointly when several)
    as a :class:`Contender`."""
    say = say or (lambda message: None)
    found, sign = [], "auto"
    for name in names:
        model_e = _explanation_model(name, model)
        say(f"least squares with '{name}'")
        if len(records) == 1:
            # The thresholds' sign describes the loop's shape (identify.fitting.lsq), which the
            # explanations told apart here share: the first fits both signs, the others keep its.
            fit = fit_least_squares(
                records[0], model_e, noise=noises[0], n_starts=n_starts, rng=rng, threshold_sign=sign
            )
            sign = _sign_name(fit.model)
            found.append(_record_contender(name, records[0], fit))
        else:
            jf = joint_fit_with_earlier_runs(fit_joint(records, model_e, noises, n_starts=n_starts, rng=rng))
            found.append(_joint_contender(name, jf))
    return found


def _sign_name(model: Model) -> str:
    alpha = model.parameters["alpha"]
    if alpha.vary or model.reading != "swapped":
        return "auto"
    return "positive" if alpha.value > 0 else "negative"


def design(
    records,
    model=None,
    candidates=None,
    *,
    limits: RigLimits | None = None,
    diagnosis=None,
    thresholds=None,
    rng=None,
    n_starts: int = 4,
    per_family=DRIVES_PER_FAMILY,
    n_confirm=CONFIRMED,
    progress=None,
) -> Design:
    """The next record to take: the drive that best decides between the explanations the records
    leave tied (module docstring).

    Parameters
    ----------
    records : Record or sequence of Record
        The records of the transducer taken so far.
    model : Model or sequence of str, optional
        The model diagnosed (default the normalised plain GPI).
    candidates : sequence of str, optional
        The explanations to tell apart (``"creep"``, ``"thermal+lag"``); default the tie of the
        records' diagnosis (run here unless ``diagnosis`` is given).
    limits : RigLimits, optional
        Default :meth:`RigLimits.from_records`.
    diagnosis : Diagnosis or JointDiagnosis, optional
        The records' diagnosis, when already made.
    thresholds : Thresholds, optional
    rng : numpy.random.Generator, optional
    n_starts : int, default 4
        Least-squares starts of each candidate's fit (with ``candidates``).
    per_family, n_confirm : int
        Drives drawn per family; best drives confirmed by simulation.
    progress : callable(str), optional

    Returns
    -------
    Design
    """
    say = progress or (lambda message: None)
    rng = np.random.default_rng(0) if rng is None else rng
    records = check_records([records] if isinstance(records, Record) else records)
    if model is None or not isinstance(model, Model):
        model = normalised_model(Model([] if model is None else list(model)))
    noises = []
    for record in records:
        try:
            noises.append(estimate_noise(record))
        except ValueError as exc:
            raise ValueError(f"{record.source}: {exc}") from None
    limits = RigLimits.from_records(records) if limits is None else limits
    if candidates is not None:
        candidates = list(candidates)
        if len(candidates) < 2:
            raise ValueError(f"--candidates needs two or more explanations to tell apart, got {candidates}")
        for name in candidates:
            _explanation_model(name, model)
        contenders = fitted_contenders(records, model, candidates, noises, n_starts=n_starts, rng=rng, say=say)
    else:
        if diagnosis is None:
            say("diagnosing the records")
            diagnosis = diagnose(records if len(records) > 1 else records[0], model, rng=rng, progress=say)
        contenders = contenders_of(diagnosis, record=records[0] if len(records) == 1 else None)
    return design_drive(
        contenders,
        records,
        noises[0],
        limits=limits,
        thresholds=thresholds,
        rng=rng,
        per_family=per_family,
        n_confirm=n_confirm,
        progress=say,
        noises=noises,
    )
