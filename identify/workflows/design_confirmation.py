"""Confirming a designed drive by simulation (:mod:`identify.workflows.design`: its
:class:`~identify.workflows.design.Contender` and :class:`~identify.workflows.design.DesignedDrive`).

Each contender as the truth, drawn from its posterior on the records it was fitted on
(:func:`posterior_draw`, :class:`RecordMisfit`; :func:`draw_transducer` without them), drives the proposed record with
noise; every contender is refitted on it, and the gaps and right names are counted
(:func:`confirm`).
"""

from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import norm
from scipy.stats import t as student_t

from ..data.records import Record
from ..diagnosis import Thresholds
from ..diagnosis.evidence import gap_noise_sd, likelihood_gap
from ..diagnosis.fits import embed, n_eff, with_values
from ..diagnosis.screening import screen_one
from ..fitting.joint import earlier_run_state, warm_value
from ..fitting.lsq import WhitenedResiduals
from ..fitting.lsq_solver import POLISH_EVALUATIONS, StallStop, beyond_a_tie
from ..fitting.noise import NoiseModel
from ..fitting.threads import results_side_by_side, single_threaded_blas

__all__ = [
    "CONFIRM_DRAWS",
    "RecordMisfit",
    "record_misfit",
    "draw_transducer",
    "posterior_draw",
    "rival_starts",
    "warm_start",
    "penalised_refit",
    "confirm",
    "simulated_gap",
]

#: Draws per contender in a confirmation: the contender's parameters from its fit's covariance and
#: the noise, both fresh in each draw. Their realised gaps are the calibrated prediction (their
#: mean and the next gap's sd, :func:`simulated_gap`): the linear gap holds the truth at its fit,
#: and a record's truth is only known to within that covariance.
CONFIRM_DRAWS = 6
#: The one-sided level of two standard deviations of a normal, Phi(2): the predicted sd is the half-width of
#: the two-sided interval at this level over 2 (:func:`simulated_gap`).
TWO_SIGMA_LEVEL = float(norm.cdf(2.0))
#: A confirmation's draw held to the records is shortened by halvings down to ``2**-DRAW_HALVINGS``
#: of its step before it falls back on the fit (:func:`draw_transducer`).
DRAW_HALVINGS = 12
#: The evaluations a confirmation's short refits may take: a rival's from each of its starts
#: (the lowest then converges, :func:`_refit`) and a posterior draw's (:func:`posterior_draw`).
SHORT_FIT_EVALUATIONS = 40
#: A confirmation's refit run to convergence (the lowest start's, :func:`_refit`) stops where a
#: step lowers the chi-square by less than this fraction of it: on records of 10^4-10^5 samples
#: 0.01-0.1, far under the noise sd of a gap (tens), where the solver's own default (1e-8) would
#: crawl along a rival's flat valley for hundreds of evaluations.
CONVERGED_FTOL = 1e-6


def _solve_with_zero(
    objective, jacobian, residuals: WhitenedResiduals, theta0, more=None, converge: bool = False, z0=None, below=None
) -> np.ndarray:
    """The refit both confirmations run: ``objective`` of ``(free parameters, sensor zero,
    more)`` from ``theta0``'s free values, a zero of 0 and ``more``'s start (or from ``z0``, all
    of them: where an earlier run of the same refit ended), within the parameters' box (the zero
    free), short or to convergence (:func:`_trf_solve`, a short run stopped early where it cannot
    end ``below`` a chi-square). ``more``: ``(start, lower, upper)`` of further unknowns after the
    zero, or None. Its end."""
    start = [np.clip(theta0[residuals.free], residuals.lower, residuals.upper), [0.0]]
    lower = [residuals.lower, [-np.inf]]
    upper = [residuals.upper, [np.inf]]
    if more is not None:
        start.append(np.clip(more[0], more[1], more[2]))
        lower.append(more[1])
        upper.append(more[2])
    box = (np.concatenate(lower), np.concatenate(upper))
    start = np.concatenate(start) if z0 is None else np.clip(z0, *box)
    return _trf_solve(objective, jacobian, start, *box, converge=converge, below=below)


def _trf_solve(objective, jacobian, start, lower, upper, converge: bool = False, below=None) -> np.ndarray:
    """The end of a least squares of ``objective`` from ``start`` within ``[lower, upper]``:
    ``trf`` with Jacobian scaling, short (:data:`SHORT_FIT_EVALUATIONS` evaluations) or with
    ``converge`` until a step gains less than :data:`CONVERGED_FTOL` of the cost (at most
    :data:`~identify.fitting.lsq_solver.POLISH_EVALUATIONS` evaluations).

    With ``below`` (a chi-square another run of the same refit reached), a run also stops once it
    can no longer end below it: its chi-square less what it would still gain at its last
    :data:`~identify.fitting.lsq_solver.STALL_ITERATIONS` iterations' pace over every evaluation
    it has left stays above ``below``, or it has stalled
    (:class:`~identify.fitting.lsq_solver.StallStop`, the rule of
    :func:`~identify.fitting.lsq_solver.beyond_a_tie` with no margin). Least-squares descents
    slow as they go, so that pace overstates what is still to come: a run stopped so would not
    have been the lowest, and only the lowest goes on (:func:`_refit`)."""
    max_nfev, ftol = (POLISH_EVALUATIONS, CONVERGED_FTOL) if converge else (SHORT_FIT_EVALUATIONS, 1e-8)
    rule = contextlib.nullcontext() if below is None else beyond_a_tie(below, 0.0, 1.0)
    with single_threaded_blas(), rule:  # small dense algebra: threads only compete with the model
        sol = least_squares(
            objective,
            start,
            jac=jacobian,
            bounds=(lower, upper),
            method="trf",
            max_nfev=max_nfev,
            x_scale="jac",
            ftol=ftol,
            callback=None if below is None else StallStop(max_nfev=max_nfev),
        )
    return sol.x


def _ended(theta0, free, z) -> np.ndarray:
    """``theta0`` with the free values of a refit's end ``z`` (the free parameters first; its sensor
    zero and any further unknowns after them, dropped)."""
    theta = np.array(theta0, dtype=float)
    theta[free] = z[: free.size]
    return theta


def penalised_refit(
    c, record: Record, noise: NoiseModel, theta0, converge: bool = False
) -> tuple[float, np.ndarray, np.ndarray]:
    """``c`` refitted on ``record`` (its transducer held by the records' information, the inverse of
    its covariance; the new run's parameters and sensor zero free), from ``theta0``, by a short
    bounded least squares (at most 40 evaluations), or with ``converge`` one run to convergence:
    ``(chi2 with the penalty, whitened residual (T,), the full vector it ends at (P,))``."""
    chi2, w, _, end, _ = _penalised(c, record, noise, theta0, converge)
    return chi2, w, end


def _penalised(c, record: Record, noise: NoiseModel, theta0, converge: bool = False, z0=None, below=None) -> tuple:
    """:func:`penalised_refit`, from ``z0`` where given (the solver's end of an earlier run of
    this refit: its free values and zero), stopped early where it cannot end ``below`` a
    chi-square (:func:`_trf_solve`), as a joint refit's ``(chi2, whitened residual, n_eff,
    the full vector it ends at, the solver's end)``: no effective sample size (None), its gap
    being a chi-square difference."""
    residuals = WhitenedResiduals(record, c.model, noise)
    free = residuals.free
    info = c.info[np.ix_(free, free)]
    values, vectors = np.linalg.eigh(0.5 * (info + info.T))
    root = (vectors * np.sqrt(np.clip(values, 0.0, None))).T  # root.T @ root = info
    centre = c.theta[free]
    scale = 1.0 / noise.sigma

    def objective(z):
        x, zero = z[:-1], z[-1]
        return np.concatenate([residuals(x) - zero * scale, root @ (x - centre)])

    def jacobian(z):  # the residuals' own batched Jacobian, the zero's column and the penalty's rows
        jac = np.zeros((record.time.size + root.shape[0], z.size))
        jac[: record.time.size, :-1] = residuals.jacobian(z[:-1])
        jac[: record.time.size, -1] = -scale
        jac[record.time.size :, :-1] = root
        return jac

    z = _solve_with_zero(objective, jacobian, residuals, theta0, converge=converge, z0=z0, below=below)
    r = objective(z)
    return float(r @ r), r[: record.time.size], None, _ended(theta0, free, z), z


def _joint_refit(
    c,
    record: Record,
    noise: NoiseModel,
    theta0,
    misfit: RecordMisfit,
    every_run_warm=False,
    converge=False,
    z0=None,
    below=None,
):
    """``c`` refitted on ``record`` and the records already taken together, from ``theta0``: the
    transducer shared, every record's own parameters and sensor zero free, the earlier records'
    starting from their fits (what the joint diagnosis fits: a transducer moved to another basin
    needs another start state of each run, a heating's start rise, and holding the earlier runs'
    at their fits credits the rival with a misfit the joint diagnosis would not leave); with
    ``every_run_warm``, the earlier records' state earlier runs left starting where ``theta0``
    puts the new record's (:func:`warm_start`); short (stopped early where it cannot end
    ``below`` a chi-square, :func:`_trf_solve`), or with ``converge`` to convergence; from ``z0``
    where given (the solver's end of an earlier run of this refit). ``(chi2, whitened
    residual over every record, the earlier ones first, effective sample size summed per record,
    the full vector it ends at, the solver's end)``."""
    residuals = WhitenedResiduals(record, c.model, noise)
    free = residuals.free
    shared = np.flatnonzero(misfit.shared[free])  # the transducer's columns among the free ones
    own = np.flatnonzero(~misfit.shared[free])  # each run's own
    columns = np.concatenate([shared, own])
    # the records' residuals with caches of this refit's own (refits of two truths run side by side)
    earlier = [(res.copy(), theta_r[free].copy()) for res, theta_r in misfit.parts]
    if every_run_warm:
        state = np.flatnonzero(np.isin(free, _state_columns(c.model)))  # among the free ones
        for _, x_r in earlier:
            x_r[state] = np.asarray(theta0, dtype=float)[free[state]]
    n_x = free.size
    block = own.size + 1  # an earlier record's own parameters, then its sensor zero
    scale = 1.0 / noise.sigma
    sizes = [res.data.size for res, _ in earlier] + [record.time.size]

    def at(z):  # each earlier record's free vector (the transducer of z's, its own from its block) and zero
        for k, (_, x_r) in enumerate(earlier):
            first = n_x + 1 + k * block
            x_r[shared] = z[shared]
            x_r[own] = z[first : first + own.size]
        return [(res, x_r, z[n_x + (k + 1) * block]) for k, (res, x_r) in enumerate(earlier)]

    def objective(z):
        parts = [res(x_r) - zero_r / res.sigma for res, x_r, zero_r in at(z)]
        return np.concatenate(parts + [residuals(z[:n_x]) - z[n_x] * scale])

    def jacobian(z):
        jac = np.zeros((sum(sizes), z.size))
        row = 0
        for k, (res, x_r, _) in enumerate(at(z)):
            rows = slice(row, row + res.data.size)
            part = res.jacobian(x_r, columns)
            first = n_x + 1 + k * block
            jac[rows, shared] = part[:, : shared.size]
            jac[rows, first : first + own.size] = part[:, shared.size :]
            jac[rows, first + own.size] = -1.0 / res.sigma
            row += res.data.size
        jac[row:, :n_x] = residuals.jacobian(z[:n_x])
        jac[row:, n_x] = -scale
        return jac

    lower = np.concatenate([residuals.lower[own], [-np.inf]])
    upper = np.concatenate([residuals.upper[own], [np.inf]])
    more = (
        np.concatenate([np.concatenate([x_r[own], [0.0]]) for _, x_r in earlier] or [np.zeros(0)]),
        np.tile(lower, len(earlier)),
        np.tile(upper, len(earlier)),
    )
    z = _solve_with_zero(objective, jacobian, residuals, theta0, more, converge, z0, below)
    w = objective(z)
    n = sum(n_eff(part) for part in np.split(w, np.cumsum(sizes)[:-1]))
    return float(w @ w), w, float(n), _ended(theta0, free, z), z


def rival_starts(c, record: Record, noise: NoiseModel) -> list:
    """Where a rival's refit on a new ``record`` starts: its fit, then, for each effect of its
    explanation, its fit with that effect's parameters where the screening of the new record puts
    them (:func:`identify.diagnosis.screening.screen_one` from the fit less the effect): its shape
    at the best grid point, its gains off.

    A slow effect's fit on the first record sits in the basin that record's drive chose (a time
    constant, an onset). On a new drive the rival's best mimicry of the truth can lie in another
    basin, which the joint diagnosis finds from its own searches of the new record; a refit from
    the fit alone stays in the old one and credits the design with a gap the rival would close.
    The gains start off, not at the screening's step, because the step is the new record's alone
    and can take a sign the records together refuse. Full vectors ``(P,)``.
    """
    starts = [np.asarray(c.theta, dtype=float)]
    for effect in c.model.effect_names:
        if effect not in c.name.split("+"):
            continue  # an effect of the model diagnosed, not of this explanation
        base = c.model.without(effect)
        screening = screen_one(record, base, embed(c.model, c.theta, base, drop_extra=True), noise, effect)
        if screening.grid_point:
            start = with_values(c.model, c.theta, screening.grid_point)
            if c.model.in_bounds(start)[0]:
                _add_start(starts, start)
    return starts


def _state_columns(model) -> np.ndarray:
    """The columns of ``model``'s vector holding the state earlier runs leave
    (:func:`identify.fitting.joint.earlier_run_state`)."""
    return np.array([model.names.index(n) for n, _ in earlier_run_state(model)], dtype=int)


def warm_start(c) -> np.ndarray | None:
    """Where a rival's refit starts warm: its fit with every state earlier runs leave (a
    heating's start rises, the model's or the explanation's) at its
    :func:`~identify.fitting.joint.warm_value`, halfway into its range, and the explanation's
    own effects that hold such a state at their off values otherwise; None where the model holds
    no such state. A full vector ``(P,)``.

    Every other start holds that state where a record's own fit pins it, off, and the solver meets
    it from the cold side only; a run that starts warm and cools through the new record is another
    basin of the effect (slow time constants, a cooling of the other sign), the one the joint
    diagnosis reaches from the same start (:func:`identify.diagnosis.joint.started_warm`). Refitted
    on every record together, the earlier records start warm too (:func:`_refit`)."""
    state = earlier_run_state(c.model)
    if not state:
        return None
    warm = np.asarray(c.theta, dtype=float)
    for effect in c.model.effects:
        if type(effect).earlier_run_terms and effect.name in c.name.split("+"):
            base = c.model.without(effect.name)
            warm = embed(base, embed(c.model, warm, base, drop_extra=True), c.model)
    return with_values(c.model, warm, {n: warm_value(c.model.parameters[n], off) for n, off in state})


def _add_start(starts: list, start) -> None:
    """Append ``start`` to ``starts`` unless an equal vector is there already."""
    if not any(np.array_equal(start, s) for s in starts):
        starts.append(start)


def _joint_pair(truth, rival, misfits, every_record: bool) -> bool:
    """Whether the pair is refitted on every record together (both have their records' misfits)."""
    return every_record and truth.name in misfits and rival.name in misfits


def _refit(c, record: Record, noise: NoiseModel, starts, joint: bool, misfits, warm=None) -> tuple:
    """``c`` refitted on ``record`` from each of ``starts`` and from ``warm`` (:func:`warm_start`,
    where given) by short refits, and the lowest of them continued from its end until it
    converges (:data:`CONVERGED_FTOL`, at most
    :data:`~identify.fitting.lsq_solver.POLISH_EVALUATIONS` evaluations): on every record
    together (:func:`_joint_refit`, from ``warm`` with every record started warm) or held by the
    records' information (:func:`penalised_refit`). The gap a design predicts is the one the
    joint diagnosis will see, which fits every explanation to convergence; a rival stopped short
    of its best mimicry of the truth would count as further behind than it is.
    ``(chi2, whitened residual, n_eff or None, the vector it ends at)``."""
    if joint:
        misfit = misfits[c.name]
        runs = [functools.partial(_joint_refit, c, record, noise, s, misfit) for s in starts]
        if warm is not None:
            runs.append(functools.partial(_joint_refit, c, record, noise, warm, misfit, True))
    else:
        runs = [
            functools.partial(_penalised, c, record, noise, s) for s in [*starts, *([] if warm is None else [warm])]
        ]
    if len(runs) == 1:
        return runs[0](converge=True)[:4]
    short = []
    for run in runs:  # each stopped once it cannot end below the lowest before it
        short.append(run(below=min((out[0] for out in short), default=None)))
    lowest = int(np.argmin([out[0] for out in short]))
    return runs[lowest](converge=True, z0=short[lowest][-1])[:4]


def _rival_chain(rival, truth, simulated, noise: NoiseModel, misfits, every_record, seeds) -> list:
    """``rival`` refitted on each of ``truth``'s ``simulated`` records in turn (``[(theta,
    record)]``): from :func:`rival_starts`, its :func:`warm_start` and from where its refit ended
    in the draw before (in the first draw from where earlier confirmations found it closest to this
    truth, ``seeds``, lists by rival name); then the draws before the last refitted once more from
    where the last ended, the lower kept (a basin a later draw found, tried on the earlier ones).
    One :func:`_refit` result per draw."""
    joint = _joint_pair(truth, rival, misfits, every_record)
    warm = warm_start(rival)  # the rival's alone: the same in every draw
    fits, carried = [], None
    for _, record in simulated:
        starts = []  # where it ended before first: mostly the lowest, the reference the others stop at
        for start in [
            *(seeds.get(rival.name, ()) if carried is None else [carried]),
            *rival_starts(rival, record, noise),
        ]:
            _add_start(starts, start)
        fits.append(_refit(rival, record, noise, starts, joint, misfits, warm))
        carried = fits[-1][-1]
    for k, (_, record) in enumerate(simulated[:-1]):
        if not np.array_equal(fits[k][-1], carried):
            again = _refit(rival, record, noise, [carried], joint, misfits)
            if again[0] < fits[k][0]:
                fits[k] = again
    return fits


def _gap(truth, rival, fitted: dict, misfits, every_record) -> tuple[float, float]:
    """``(gap, sd)`` of ``rival`` against ``truth`` from one draw's refits: on every record together,
    the joint diagnosis's likelihood gap ``n_eff ln(chi2_rival / chi2_truth)`` and its noise sd
    (:mod:`identify.diagnosis.evidence`); otherwise the chi-square gap on the new record and
    ``2 |r_rival - r_truth|``."""
    joint = _joint_pair(truth, rival, misfits, every_record)
    chi2_t, w_t, n_t, _ = fitted[(truth.name, joint)]
    chi2_r, w_r, _, _ = fitted[(rival.name, joint)]
    if joint:
        return likelihood_gap(chi2_t, chi2_r, n_t), gap_noise_sd(w_t, w_r, n_t)
    return chi2_r - chi2_t, 2.0 * float(np.linalg.norm(w_r - w_t))


def confirm(
    drive,
    contenders,
    noise: NoiseModel,
    th: Thresholds,
    rng,
    draws=CONFIRM_DRAWS,
    step: int = 1,
    misfits=None,
    every_record: bool = True,
    basins=None,
) -> list:
    """Each contender as the truth, drawn (:func:`posterior_draw`), drives the proposed record
    (every ``step``-th sample) with noise; every contender is refitted on it
    (:func:`penalised_refit`); a right name is the truth ahead of every rival by the decision's
    margins. Per ordered pair: the realised gaps and the share of right names (on the decimated
    record when ``step > 1``: fewer samples, less to tell the contenders apart by). ``misfits``:
    each contender's :func:`record_misfit` by name, on which its draws are made (:func:`posterior_draw`); where
    both contenders of a pair have one and ``every_record``, both are refitted on every record
    together and the gap is the joint diagnosis's; without ``every_record`` (a quicker ranking) on
    the new record, held by the records' information.

    A rival's refit starts from its fit, from where the new record's screening puts its effects
    (:func:`rival_starts`) and from where its refit ended in the truth's previous draw, and the
    draws before the last are refitted once more from where the last ended: the lowest is kept, so
    that a basin one draw finds is the rival's in every draw (as the joint diagnosis's search would
    find it on whichever record is measured). ``basins``
    (:class:`~identify.workflows.design_criterion.RivalBasins`), where given, holds where earlier
    confirmations found each rival closest to each truth: the rival's first draw starts there too
    (a basin one drive revealed is the rival's on the next); this confirmation adds, for each
    pair, the vector where the rival's refit came closest to the truth (its lowest gap over the
    draws), a point around which the search's criterion linearises that rival too.

    Every truth's records are drawn first, in the generator's order; on every sample the refits
    then run side by side (:func:`identify.fitting.threads.results_side_by_side`: two at once,
    each fit on one core as it would run alone), as independent actions (:func:`_refit_actions`:
    each rival's chain over a truth's draws, each truth's refit of one draw), so that the two
    workers end close together whatever the number of contenders."""
    misfits = misfits or {}
    time, current = drive.time[::step], drive.current[::step]
    simulated = [_simulated_records(truth, draws, time, current, noise, rng, misfits) for truth in contenders]
    keys, actions = _refit_actions(contenders, simulated, noise, misfits, every_record, basins)
    # on every sample the model's kernels (which release the GIL) take most of a refit; on a
    # decimated record the solver's Python does, and two refits side by side wait for each other
    done = results_side_by_side(actions) if step == 1 else [action() for action in actions]
    results = dict(zip(keys, done))
    refitted = [
        _draw_fits(t, records, contenders, results, misfits, every_record) for t, records in zip(contenders, simulated)
    ]
    rows = []
    for truth, runs in zip(contenders, refitted):
        realised = {rival.name: [] for rival in contenders if rival is not truth}
        right = 0
        closest = {}  # per rival: (its lowest gap over the draws, where its refit ended there)
        for _, fitted in runs:
            ok = True
            for rival in contenders:
                if rival is truth:
                    continue
                gap, sd = _gap(truth, rival, fitted, misfits, every_record)
                realised[rival.name].append(gap)
                ok &= gap > th.bic_significant and (sd == 0 or gap / sd > th.gap_z)
                if rival.name not in closest or gap < closest[rival.name][0]:
                    joint = _joint_pair(truth, rival, misfits, every_record)
                    closest[rival.name] = (gap, fitted[(rival.name, joint)][-1])
            right += ok
        if basins is not None:
            for rival, (_, end) in closest.items():
                basins.add(truth.name, rival, end)
        for rival, gaps in realised.items():
            mean, sd = simulated_gap(gaps)
            rows.append(
                {
                    "truth": truth.name,
                    "rival": rival,
                    "realised_gaps": [float(g) for g in gaps],
                    "gap": mean,
                    "gap_sd": sd,
                    "right_names": right,
                    "draws": draws,
                }
            )
    return rows


def _simulated_records(truth, draws: int, time, current, noise: NoiseModel, rng, misfits) -> list:
    """``[(theta, record)]``: ``draws`` transducers of ``truth`` (:func:`posterior_draw` on its
    records' misfit, :func:`draw_transducer` without one) driven by ``current`` with the records'
    noise (:meth:`NoiseModel.draw`: its correlation too, on the sampled ``time``: white noise
    simulated for a correlated sensor and whitened is ``(1 + rho^2) / (1 - rho^2)`` times its
    variance, and a likelihood gap, the noise scale profiled out, shrinks by about that factor); a
    draw whose output is not finite dropped."""
    misfit = misfits.get(truth.name)
    if misfit is None:
        thetas = [draw_transducer(truth, rng) for _ in range(draws)]
    else:
        thetas = misfit.posterior_draws(truth, draws, rng)
    simulated = []
    for theta in thetas:
        y, valid = truth.model.evaluate(theta, time, current)
        if not valid[0]:
            continue
        data = y[0] + noise.draw(time, rng)  # the sensor noise as estimated: white or AR(1)
        simulated.append((theta, Record(time, current, data, source="simulated next record", sha256="")))
    return simulated


def _seeds(truth, basins) -> dict:
    """Where earlier confirmations found each rival closest to ``truth``, by rival name (empty
    without ``basins``)."""
    return {} if basins is None else basins.of_truth(truth.name)


def _refit_actions(contenders, simulated, noise: NoiseModel, misfits, every_record, basins) -> tuple[list, list]:
    """The refits of a confirmation as independent actions and the keys of their results: per
    truth (``simulated``: its ``[(theta, record)]`` per contender), each rival's chain over the
    draws (:func:`_rival_chain`, keys ``("chain", truth, rival)``) and the truth's own refit on each
    draw from its draw (keys ``("truth", truth, draw, joint)``), the chains first: the longest
    actions start first, so that two workers end close together."""
    chains, truths = [], []
    for truth, records in zip(contenders, simulated):
        seeds = _seeds(truth, basins)
        for rival in contenders:
            if rival is not truth:
                chains.append(
                    (
                        ("chain", truth.name, rival.name),
                        functools.partial(_rival_chain, rival, truth, records, noise, misfits, every_record, seeds),
                    )
                )
        for joint in sorted({_joint_pair(truth, r, misfits, every_record) for r in contenders if r is not truth}):
            for k, (theta, record) in enumerate(records):
                truths.append(
                    (
                        ("truth", truth.name, k, joint),
                        functools.partial(_refit, truth, record, noise, [theta], joint, misfits),
                    )
                )
    keys, actions = zip(*(chains + truths))
    return list(keys), list(actions)


def _draw_fits(truth, records, contenders, results: dict, misfits, every_record) -> list:
    """``[(record, fitted)]`` of ``truth``'s simulated ``records``: ``fitted`` every contender's
    refit on that draw by ``(name, joint)``, gathered from the confirmation's ``results`` by key
    (:func:`_refit_actions`)."""
    runs = []
    for k, (_, record) in enumerate(records):
        fitted = {}
        for rival in contenders:
            if rival is truth:
                continue
            joint = _joint_pair(truth, rival, misfits, every_record)
            fitted[(truth.name, joint)] = results[("truth", truth.name, k, joint)]
            fitted[(rival.name, joint)] = results[("chain", truth.name, rival.name)][k]
        runs.append((record, fitted))
    return runs


def simulated_gap(gaps) -> tuple[float | None, float | None]:
    """The prediction a confirmation gives for one ordered pair: the mean of its realised ``gaps``
    and the sd of the next gap predicted from them (None where fewer than two draws gave a gap).

    The draws vary the truth's parameters and the noise together. Their sample sd ``s`` from ``n``
    draws is itself uncertain (by about a third at six), and the next record's gap is a new draw
    beside the ``n``: its predictive interval is ``mean +- t s sqrt(1 + 1/n)`` with Student's ``t``
    of ``n - 1`` degrees of freedom. The sd returned is that interval's half-width at the two-sigma
    level (95.45 %) over 2, so that ``mean +- 2 sd`` is the interval the next gap falls in that
    often were the draws normal: ``s sqrt(1 + 1/n) t_{n-1}(0.97725) / 2``.
    """
    gaps = np.asarray(gaps, dtype=float)
    if gaps.size < 2:
        return None, None
    n = gaps.size
    widening = math.sqrt(1.0 + 1.0 / n) * float(student_t.ppf(TWO_SIGMA_LEVEL, n - 1)) / 2.0
    return float(gaps.mean()), float(gaps.std(ddof=1)) * widening


class RecordMisfit:
    """How much worse than a contender's fit its vectors fit the records it was fitted on
    (:func:`record_misfit`): called with vectors ``(B, P)`` (in the first record, the whole vector:
    the contender's vector is that record's; in each later record, their shared parameters with the
    record's own as fitted), the chi-square rise summed over the records ``(B,)`` (inf where the
    model is not finite); ``base`` is the records' chi-square where the draws are centred (the fit,
    or the contender's ``draws_from``)."""

    def __init__(self, c, records, noises):
        self.shared = ~np.array([p.per_record for p in c.model.parameters])
        self._parts = []
        for (theta_r, zero_r), record, noise in zip(c.runs, records, noises):
            zeroed = replace(record, displacement=np.asarray(record.displacement) - zero_r) if zero_r else record
            self._parts.append((WhitenedResiduals(zeroed, c.model, noise), theta_r))
        self.base = float(self.chi2(_draw_centre(c)[0])[0])
        self._draws = []

    def posterior_draws(self, c, n: int, rng) -> list:
        """The first ``n`` of the contender ``c``'s posterior draws on these records
        (:func:`posterior_draw`), each made once: every drive a design confirms is simulated with
        the same transducers (common random numbers, so that drives compare on the same draws and
        each draw's refit is paid once), with fresh noise."""
        while len(self._draws) < n:
            self._draws.append(posterior_draw(c, rng, self))
        return self._draws[:n]

    def chi2(self, thetas) -> np.ndarray:
        """The records' chi-square ``(B,)`` of vectors ``(B, P)``."""
        thetas = np.atleast_2d(thetas)
        total = np.zeros(thetas.shape[0])
        for k, (residuals, theta_r) in enumerate(self._parts):
            # the first record's run parameters are the contender's (a draw moves them too); a later
            # record keeps its own as fitted
            taken = slice(None) if k == 0 else self.shared
            rows = np.repeat(theta_r[None, :], thetas.shape[0], axis=0)
            rows[:, taken] = thetas[:, taken]
            w, valid = residuals.batch(rows[:, residuals.free])
            total += np.where(valid, np.einsum("ij,ij->i", w, w), np.inf)
        return total

    def __call__(self, thetas) -> np.ndarray:
        return self.chi2(thetas) - self.base

    @property
    def parts(self) -> list:
        """Each record's ``(WhitenedResiduals, fitted vector (P,))``."""
        return list(self._parts)


def record_misfit(c, records, noises) -> RecordMisfit | None:
    """The :class:`RecordMisfit` of ``c`` on ``records`` (each with its noise model); None where
    ``c`` does not carry one fitted run per record."""
    if len(c.runs) != len(records) or not records:
        return None
    return RecordMisfit(c, list(records), list(noises))


def _draw_centre(c) -> tuple[np.ndarray, np.ndarray]:
    """``(theta, covariance)`` a contender's draws come from: its ``draws_from`` where set, else its fit's."""
    theta, cov = c.draws_from if c.draws_from is not None else (c.theta, c.covariance)
    return np.array(theta, dtype=float), np.asarray(cov, dtype=float)


def posterior_draw(c, rng, misfit: RecordMisfit) -> np.ndarray:
    """A draw of the contender's parameters from its posterior on the records it was fitted on, by
    randomised maximum likelihood: the records' whitened residuals shifted by fresh standard normal
    noise and the parameters refitted to them from the draw's centre (a short bounded least
    squares), the parameters the covariance pins held.

    Where the model is linear in its parameters the refit's end is an exact posterior draw (flat
    prior within the bounds); where it is not, the end follows the records' curved valleys of equal
    misfit, which a draw from the covariance (:func:`draw_transducer`) leaves along straight lines:
    a slow effect's loose time constants trade off nonlinearly with the hysteresis's, and the
    transducers the records cannot tell from the fit can lie many of the covariance's standard
    deviations away. Falls back on :func:`draw_transducer` where the refit's end is not finite.
    (Oliver, He and Reynolds 1996; Bardsley et al. 2014, randomize-then-optimize.)"""
    theta, cov = _draw_centre(c)
    moving = np.flatnonzero(np.diag(cov) > 0)
    lower, upper = c.model.parameters.lower, c.model.parameters.upper
    if not moving.size:
        return np.clip(theta, lower, upper)
    parts = []
    for k, (residuals, theta_r) in enumerate(misfit.parts):
        taken = moving if k == 0 else moving[misfit.shared[moving]]
        columns = np.searchsorted(residuals.free, taken)  # among the record's free values
        which = np.searchsorted(moving, taken)  # among the draw's
        row = np.array(theta if k == 0 else theta_r, dtype=float)
        res = residuals.copy()
        shift = rng.standard_normal(res.data.size)
        parts.append((res, row, taken, columns, which, shift))

    def rows_at(x):
        for res, row, taken, columns, which, shift in parts:
            row[taken] = x[which]
            yield res, row[res.free], columns, which, shift

    def objective(x):
        return np.concatenate([res(x_r) - shift for res, x_r, _, _, shift in rows_at(x)])

    def jacobian(x):
        blocks = []
        for res, x_r, columns, which, _ in rows_at(x):
            block = np.zeros((res.data.size, x.size))
            block[:, which] = res.jacobian(x_r, columns)
            blocks.append(block)
        return np.concatenate(blocks)

    start = np.clip(theta[moving], lower[moving], upper[moving])
    drawn = np.array(theta, dtype=float)
    drawn[moving] = _trf_solve(objective, jacobian, start, lower[moving], upper[moving])
    if not np.isfinite(misfit(drawn[None])[0]):
        return draw_transducer(c, rng, misfit)
    return drawn


def draw_transducer(c, rng, misfit=None) -> np.ndarray:
    """A draw of the contender's parameters from its fit's covariance (from its ``draws_from``, the fit
    without the terms its record does not support, where set), within two standard deviations along
    each of the covariance's own axes (a poorly determined combination is not sent to a bound).

    The run's own parameters (a sensor's drift, a training state) are drawn too: the next run's are
    taken to be like the first record's, and that record's fit knows them only to within its
    covariance. Held at the fit, they would give every draw the same drift on the new record, and a
    prediction whose spread leaves out what is least known about the next run.

    With ``misfit`` (:func:`record_misfit`) the draw is held to the records it was fitted on: a
    covariance is the fit's linearisation, and along a loosely determined nonlinear combination (a
    slow effect's time constants) its step can leave the records far behind. A draw ``z`` (in the
    covariance's axes) would raise the records' chi-square by ``|z|^2`` were the model linear; the
    draw keeps its direction and goes as far along it as the records allow that rise (the largest
    of the step's halvings, then refined between it and the next), the fit itself where none does.
    """
    theta, cov = _draw_centre(c)
    free = np.flatnonzero(np.diag(cov) > 0)
    lower, upper = c.model.parameters.lower, c.model.parameters.upper
    if not free.size:
        return np.clip(theta, lower, upper)
    sub = cov[np.ix_(free, free)]
    values, vectors = np.linalg.eigh(0.5 * (sub + sub.T))
    z = np.clip(rng.standard_normal(free.size), -2.0, 2.0)  # in the covariance's own axes
    step = np.zeros_like(theta)
    step[free] = vectors @ (np.sqrt(np.clip(values, 0.0, None)) * z)
    if misfit is None:
        return np.clip(theta + step, lower, upper)
    allowed = float(z @ z)

    def farthest(scales):
        rows = np.clip(theta + scales[:, None] * step, lower, upper)
        ok = np.flatnonzero(misfit(rows) <= allowed)
        return (scales[ok].max(), rows[ok[np.argmax(scales[ok])]]) if ok.size else (None, None)

    scale, row = farthest(0.5 ** np.arange(DRAW_HALVINGS + 1))
    if scale is None:
        return np.clip(theta, lower, upper)
    if scale < 1.0:
        finer, finer_row = farthest(np.linspace(scale, 2.0 * scale, 9)[1:-1])
        if finer is not None and finer > scale:
            row = finer_row
    return row
