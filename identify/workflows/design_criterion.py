r"""The design's criterion (:mod:`identify.workflows.design`): the chi-square gap a drive shows
between two contenders once the rival is refitted to mimic the truth, linearised.

Around a point ``theta_b`` of the rival, with ``d`` the whitened difference of the truth's and the
rival's predictions on the proposed drive, ``J`` the rival's whitened Jacobian there (its free
parameters and the new record's sensor zero), ``F`` the information the records hold on the
rival's transducer and ``o = theta_b - theta_fit`` the point's offset from the rival's fit:

.. math::  \Delta = -(J^\top J + F)^{+} (J^\top d + F o), \qquad
           \mathrm{gap} = \lVert d + J\Delta \rVert^2 + (o + \Delta)^\top F (o + \Delta),

the rival's best mimicry near ``theta_b`` (its misfit on the new record beside its departure
from what the records say). At the fit (``o = 0``) this is the Gauss-Newton step of the rival's
refit. The rival's best mimicry is a global minimum, and a slow effect's fit can mimic the truth
on a new drive from another basin (another time constant, another onset), which the
linearisation at its fit does not see: it credits the drive with a gap the rival closes. The
confirmations' nonlinear refits (:func:`identify.workflows.design_confirmation.confirm`) find
such basins; each joins the points (:class:`RivalBasins`), and the gap is the smallest over them:
the rival's set of points grows with each solution of the inner problem found, as in the
cutting-plane algorithms for semi-infinite (maximin) problems (Blankenship and Falk, *J. Optim.
Theory Appl.* 19, 1976). The noise moves the gap by about ``2 ||d + J Delta||`` at the point
that gives it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..data.records import Record
from ..diagnosis import Thresholds
from ..fitting.lsq import WhitenedResiduals
from ..fitting.noise import NoiseModel

__all__ = [
    "RivalBasins",
    "DesignedDrive",
    "discrimination",
    "p_right",
    "evaluate",
    "DECISIVE",
    "linear_rank",
    "confirmed_share",
    "confirmed_rank",
    "simulation_text",
    "decisive",
    "weakest_right_name",
]

#: A weakest chance of a right name below this is not decisive: the design then designs longer
#: records, up to the rig's longest (:data:`identify.workflows.design.LONGER`), or, where the rig
#: allows none, says what longer ones would give.
DECISIVE = 0.9


class RivalBasins:
    """Where each rival's nonlinear refits ended while mimicking each truth, by ``(truth, rival)``
    name: the points besides its fit around which :func:`discrimination` linearises its mimicry."""

    def __init__(self):
        self.points = {}

    def add(self, truth: str, rival: str, theta) -> None:
        """Keep ``theta`` (a full vector ``(P,)``) for the pair unless an equal one is kept."""
        kept = self.points.setdefault((truth, rival), [])
        theta = np.array(theta, dtype=float)
        if not any(np.array_equal(theta, k) for k in kept):
            kept.append(theta)

    def of(self, truth: str, rival: str) -> list:
        """The pair's points (empty where none was found)."""
        return list(self.points.get((truth, rival), ()))

    def of_truth(self, truth: str) -> dict:
        """Every rival's points for ``truth``, by rival name."""
        return {rival: list(points) for (t, rival), points in self.points.items() if t == truth}

    def __len__(self) -> int:
        return sum(len(v) for v in self.points.values())


def _predicted(c, time, current) -> np.ndarray | None:
    y, valid = c.model.evaluate(c.theta, time, current)
    return y[0] if valid[0] else None


def _linear_mimicry(residuals: WhitenedResiduals, theta, centre, info, zero) -> tuple[float, float] | None:
    """``(gap, noise sd)`` of the rival linearised around ``theta`` (module docstring), None where
    its prediction there is not finite."""
    x = np.clip(theta[residuals.free], residuals.lower, residuals.upper)
    d = residuals(x)
    if not np.all(np.isfinite(d)):
        return None
    jac = np.hstack([residuals.jacobian(x), zero])
    offset = np.append(x - centre, 0.0)
    step = -np.linalg.pinv(jac.T @ jac + info, rcond=1e-12) @ (jac.T @ d + info @ offset)
    r = d + jac @ step
    moved = offset + step
    return float(r @ r + moved @ info @ moved), 2.0 * float(np.sqrt(r @ r))


def discrimination(truth, rival, time, current, noise: NoiseModel, basins=()) -> tuple[float, float]:
    """``(gap, noise sd of the gap)``: the chi-square gap the proposed drive shows between ``truth``
    and ``rival`` once the rival is refitted to mimic it, linearised around its fit and around each
    of ``basins`` (full vectors ``(P,)`` where its refits ended), the smallest kept (module docstring)."""
    y_true = _predicted(truth, time, current)
    if y_true is None:
        return 0.0, 0.0
    record = Record(time, current, y_true, source="the proposed drive", sha256="")
    residuals = WhitenedResiduals(record, rival.model, noise)
    free = residuals.free
    zero = np.full((time.size, 1), -1.0 / noise.sigma)  # the new record's sensor zero
    info = np.zeros((free.size + 1, free.size + 1))
    info[:-1, :-1] = rival.info[np.ix_(free, free)]
    centre = rival.theta[free]
    found = [_linear_mimicry(residuals, np.asarray(t, dtype=float), centre, info, zero) for t in (rival.theta, *basins)]
    found = [f for f in found if f is not None]
    return min(found, key=lambda f: f[0]) if found else (0.0, 0.0)


def p_right(gap: float, sd: float, th: Thresholds) -> float:
    """The probability that the diagnosis names the truth: the gap beyond ``bic_significant`` and
    ``gap_z`` of its noise sd (:mod:`identify.workflows.design`)."""
    if not sd > 0:
        return 1.0 if gap > th.bic_significant else 0.0
    return float(stats.norm.cdf((gap - max(th.bic_significant, th.gap_z * sd)) / sd))


@dataclass
class DesignedDrive:
    """One proposed drive with its predicted discrimination."""

    family: str
    params: dict
    time: np.ndarray
    current: np.ndarray
    pairs: list = field(default_factory=list)
    value: float = 0.0
    confirmed: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "family": self.family,
            "params": {k: (v if not isinstance(v, float) else float(v)) for k, v in self.params.items()},
            "samples": int(self.time.size),
            "rms_current": float(np.sqrt(np.mean(self.current**2))),
            "pairs": [dict(p) for p in self.pairs],
            "value": float(self.value),
            "confirmed": [dict(c) for c in self.confirmed],
        }


def evaluate(
    drive: DesignedDrive,
    contenders,
    noise: NoiseModel,
    th: Thresholds,
    step: int = 1,
    basins: RivalBasins | None = None,
) -> DesignedDrive:
    """Every ordered pair's predicted gap, its sd and the chance of a right name on ``drive`` (on
    every ``step``-th sample, each rival also linearised around the ``basins`` found for the pair);
    the drive's value is the smallest chance (maximin)."""
    pairs = []
    time, current = drive.time[::step], drive.current[::step]
    for truth in contenders:
        for rival in contenders:
            if rival is truth:
                continue
            found = basins.of(truth.name, rival.name) if basins is not None else ()
            gap, sd = discrimination(truth, rival, time, current, noise, found)
            pairs.append(
                {"truth": truth.name, "rival": rival.name, "gap": gap, "noise_sd": sd, "p_right": p_right(gap, sd, th)}
            )
    drive.pairs = pairs
    drive.value = min((p["p_right"] for p in pairs), default=0.0)
    return drive


def linear_rank(drive: DesignedDrive):
    """Best first: the highest smallest chance of a right name, then the largest smallest gap."""
    return -drive.value, -min((p["gap"] for p in drive.pairs), default=0.0)


def _truth_shares(drive: DesignedDrive) -> dict:
    """Each confirmed truth's share of right names, by name (empty without a confirmation)."""
    return {c["truth"]: c["right_names"] / c["draws"] for c in drive.confirmed if c["draws"]}


def confirmed_share(drive: DesignedDrive) -> tuple[float, str | None]:
    """The smallest share of right names over the confirmation's truths and that truth
    (``(1.0, None)`` without a confirmation)."""
    shares = _truth_shares(drive)
    if not shares:
        return 1.0, None
    truth = min(shares, key=shares.get)
    return shares[truth], truth


def confirmed_rank(drive: DesignedDrive):
    """The confirmed drives, best first: the highest smallest share of right names in the
    simulation (the nonlinear refits, the parameters' uncertainty), then the highest next smallest
    and so on (leximin: where no drive names the weakest truth, the one that names the most of the
    others), then :func:`linear_rank`."""
    return (tuple(-s for s in sorted(_truth_shares(drive).values())) or (-1.0,), *linear_rank(drive))


def simulation_text(drive: DesignedDrive) -> str:
    """The sentence the design's reason ends with: how often the simulation put the truth ahead,
    the weakest truth named where that is less than always ("" without a confirmation)."""
    share, truth = confirmed_share(drive)
    if truth is None:
        return ""
    draws = max(c["draws"] for c in drive.confirmed)
    right = min(c["right_names"] for c in drive.confirmed if c["truth"] == truth)
    simulated = (
        " Simulated with each contender's parameters drawn from its posterior on the records and fresh noise,"
        " the truth was ahead"
    )
    if share >= 1.0:
        return f"{simulated} in all {draws} draws of every contender."
    return (
        f"{simulated} in only {right} of {draws} draws where '{truth}' was the truth: the linear prediction is "
        "optimistic there."
    )


def decisive(drive: DesignedDrive) -> bool:
    """Does ``drive`` decide the tie: its weakest pair's linear chance of a right name and, where
    it was confirmed by simulation, its weakest truth's share of right names at least
    :data:`DECISIVE`?"""
    return weakest_right_name(drive) >= DECISIVE


def weakest_right_name(drive: DesignedDrive) -> float:
    """The smaller of the drive's weakest linear chance and its confirmed weakest share."""
    return min(float(drive.value), confirmed_share(drive)[0])
