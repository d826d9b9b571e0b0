"""The drives a design searches: the rig's limits (:class:`RigLimits`) and the families of
drives within them (:data:`FAMILIES`, shaped by :data:`SHAPES`; :func:`drive_of`), each starting
with the quiet segment the records need for their noise (:mod:`identify.workflows.design`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..data.reversals import find_reversals
from ..fitting.noise import quiet_segment

__all__ = [
    "RigLimits",
    "FAMILIES",
    "SHAPES",
    "MAX_REST",
    "random_drive_parameters",
    "perturbed_parameters",
    "rest_seconds",
    "drive_of",
    "drive_period",
]


@dataclass(frozen=True)
class RigLimits:
    """What the rig allows the next record (defaults read from the records, :meth:`from_records`).

    Attributes
    ----------
    current_range : tuple of float
        ``(lo, hi)`` [input unit]; the quiet segments sit at ``lo``.
    max_slew : float
        Largest rate of the current [input unit/s].
    duration : float
        Length of the record [s].
    max_rms_current : float
        Largest RMS of the current over the record [input unit]: the coil's heating limit.
    fs : float
        Sampling rate [Hz].
    quiet : float
        The unenergised start [s] the noise needs.
    longest : float, optional
        The longest record the rig can take [s]. Where no drive of ``duration`` decides the tie,
        records up to this long are designed too (:data:`identify.workflows.design.LONGER`);
        default ``duration``, none longer.
    """

    current_range: tuple
    max_slew: float
    duration: float
    max_rms_current: float
    fs: float
    quiet: float
    longest: float | None = None

    def __post_init__(self):
        lo, hi = self.current_range
        problems = []
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            problems.append(f"the current range must be LO:HI with LO < HI, got {lo:g}:{hi:g}")
        for name in ("max_slew", "duration", "max_rms_current", "fs", "quiet"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                problems.append(f"{name.replace('_', ' ')} must be > 0, got {value:g}")
        if not problems and self.duration <= self.quiet + 10.0 / self.fs:
            problems.append(f"a duration of {self.duration:g} s leaves nothing after the {self.quiet:g} s quiet start")
        if not problems and self.longest is not None and not (self.longest >= self.duration):
            problems.append(
                f"the longest record ({self.longest:g} s) is shorter than the duration ({self.duration:g} s)"
            )
        if not problems and self.max_rms_current <= max(abs(lo), 0.0):
            problems.append(f"an RMS current limit of {self.max_rms_current:g} allows no drive above {lo:g}")
        if problems:
            raise ValueError("; ".join(problems))

    @classmethod
    def from_records(cls, records, **given) -> RigLimits:
        """The limits the records show (their current range, largest slew, longest duration,
        largest RMS current, sampling rate and quiet start), overridden by ``given``."""
        currents = [np.asarray(r.current, dtype=float) for r in records]
        slews = [np.abs(np.diff(c)) / np.diff(np.asarray(r.time, dtype=float)) for c, r in zip(currents, records)]
        values = {
            "current_range": (min(float(c.min()) for c in currents), max(float(c.max()) for c in currents)),
            "max_slew": max(float(np.quantile(s, 0.999)) for s in slews),
            "duration": max(float(r.time[-1] - r.time[0]) for r in records),
            "max_rms_current": max(float(np.sqrt(np.mean(c * c))) for c in currents),
            "fs": float(1.0 / np.median(np.diff(np.asarray(records[0].time, dtype=float)))),
            "quiet": max(float(r.time[quiet_segment(r.current).stop - 1] - r.time[0]) for r in records),
        }
        values.update({k: v for k, v in given.items() if v is not None})
        values["current_range"] = tuple(float(x) for x in values["current_range"])
        return cls(**values)

    @property
    def longest_record(self) -> float:
        """The longest record the rig takes [s]: :attr:`longest`, else :attr:`duration`."""
        return self.duration if self.longest is None else self.longest

    def to_dict(self) -> dict:
        return {
            "current_range": list(self.current_range),
            "max_slew": self.max_slew,
            "duration": self.duration,
            "max_rms_current": self.max_rms_current,
            "fs": self.fs,
            "quiet": self.quiet,
            "longest": self.longest_record,
        }


def _raised(t, t0, period, low, high):
    """A raised-cosine cycle from ``low`` to ``high`` and back over ``period`` starting at ``t0``."""
    return low + 0.5 * (high - low) * (1.0 - np.cos(2.0 * np.pi * (t - t0) / period))


class _Builder:
    """A drive assembled piece by piece within the limits (ramps at most at the slew limit)."""

    def __init__(self, limits: RigLimits, period: float):
        self.limits = limits
        self.period = period
        self.time = np.arange(int(math.floor(limits.duration * limits.fs + 1e-9)) + 1) / limits.fs
        self.current = np.full(self.time.size, float(limits.current_range[0]))
        self.t = limits.quiet
        self.level = float(limits.current_range[0])

    def _span(self, seconds):
        return (self.time >= self.t) & (self.time < self.t + seconds)

    def cycle(self, peak: float) -> None:
        lo = self.limits.current_range[0]
        period = max(self.period, math.pi * (peak - lo) / self.limits.max_slew)
        inside = self._span(period)
        self.current[inside] = _raised(self.time[inside], self.t, period, lo, peak)
        self.t += period
        self.level = lo

    def ramp(self, target: float) -> None:
        seconds = max(self.period / 2.0, math.pi * abs(target - self.level) / (2.0 * self.limits.max_slew))
        inside = self._span(seconds)
        phase = (self.time[inside] - self.t) / seconds
        self.current[inside] = self.level + (target - self.level) * 0.5 * (1.0 - np.cos(np.pi * phase))
        self.t += seconds
        self.level = target

    def hold(self, seconds: float) -> None:
        self.current[self._span(seconds)] = self.level
        self.t += seconds

    def finish(self):
        """``(time, current)`` with the rest at the lower current (the quiet end), or None when the
        pieces overran the duration or the drive breaks the RMS limit."""
        if self.t > self.limits.duration:
            return None
        lo = self.limits.current_range[0]
        self.current[self.time >= self.t] = lo
        if float(np.sqrt(np.mean(self.current**2))) > self.limits.max_rms_current:
            return None
        return self.time, self.current


def _hold(b: _Builder, p: dict) -> None:
    lo, hi = b.limits.current_range
    for _ in range(int(p["cycles"])):
        b.cycle(lo + p["amplitude"] * (hi - lo))
    b.ramp(lo + p["level"] * (hi - lo))
    b.hold(p["hold"] * (b.limits.duration - b.t))
    b.ramp(lo)


def _rise_again(b: _Builder, p: dict) -> None:
    lo, hi = b.limits.current_range
    n = int(p["cycles"])
    amplitudes = np.concatenate([np.linspace(1.0, p["low"], n), np.linspace(p["low"], p["high"], n)[1:]])
    for a in amplitudes:
        b.cycle(lo + a * (hi - lo))


def _steps(b: _Builder, p: dict) -> None:
    lo, hi = b.limits.current_range
    levels = p["levels"]
    dwell = p["dwell"] * (b.limits.duration - b.t) / max(len(levels), 1)
    for level in levels:
        b.ramp(lo + level * (hi - lo))
        b.hold(dwell)
    b.ramp(lo)


def _probe_blocks(b: _Builder, p: dict) -> None:
    lo, hi = b.limits.current_range
    for _ in range(int(p["blocks"])):
        b.ramp(lo + p["level"] * (hi - lo))
        b.hold(p["block"] * b.period)
        b.ramp(lo)
        b.cycle(lo + p["probe"] * (hi - lo))


#: The largest rest after the quiet start, a fraction of the time after it.
MAX_REST = 0.3


def random_drive_parameters(rng: np.random.Generator, family: str) -> dict:
    """Random shape parameters of a drive of ``family`` (:data:`FAMILIES`) for :func:`drive_of`:
    counts (cycles) and fractions of the rig's current range or of the drive's period; the
    search's candidates, drawn with ``rng``. Half the drives rest at the lower current after the
    quiet start (``rest``, a fraction of the time after it, up to :data:`MAX_REST`): a state an
    earlier run left (a coil still warm) relaxes there where the drive shows nothing else, so it
    cannot stand in for the slow effects the drive then shows."""
    rest = float(rng.uniform(0.0, MAX_REST)) if rng.random() < 0.5 else 0.0
    return {"rest": rest, **_shape_parameters(rng, family)}


#: family -> its count of pieces ``(name, lowest, highest + 1)`` and the range of each continuous
#: shape parameter (fractions of the current range, of the time left or of the period), in the order
#: they are drawn; ``levels`` is a list of as many values as the count.
SHAPES = {
    "hold": (("cycles", 1, 4), {"amplitude": (0.5, 1.0), "level": (0.4, 1.0), "hold": (0.15, 0.6)}),
    "rise_again": (("cycles", 2, 5), {"low": (0.2, 0.6), "high": (0.7, 1.0)}),
    "steps": (("levels", 2, 5), {"levels": (0.2, 1.0), "dwell": (0.3, 0.7)}),
    "probe_blocks": (("blocks", 1, 4), {"level": (0.6, 1.0), "block": (0.5, 2.0), "probe": (0.2, 0.5)}),
}


def _shape_parameters(rng: np.random.Generator, family: str) -> dict:
    """The shape parameters of a drive of ``family`` after its rest (:data:`SHAPES`)."""
    (count_name, low, high), ranges = SHAPES[family]
    count = int(rng.integers(low, high))
    params = {} if count_name in ranges else {count_name: count}
    for name, (lo, hi) in ranges.items():
        if name == count_name:
            params[name] = [float(x) for x in rng.uniform(lo, hi, count)]
        else:
            params[name] = rng.uniform(lo, hi)
    return params


def perturbed_parameters(rng: np.random.Generator, family: str, params: dict, spread: float) -> dict:
    """``params`` with every continuous shape parameter (and the rest) moved by a normal step of sd
    ``spread`` times its range (:data:`SHAPES`), held within the range; the counts kept."""
    ranges = {"rest": (0.0, MAX_REST), **SHAPES[family][1]}
    out = dict(params)
    for name, (lo, hi) in ranges.items():
        if name == "rest" and not params.get("rest", 0.0):
            continue  # a drive without a rest keeps none (half the draws have one)
        value = np.asarray(params[name], dtype=float)
        moved = np.clip(value + spread * (hi - lo) * rng.standard_normal(value.shape), lo, hi)
        out[name] = [float(x) for x in moved] if isinstance(params[name], list) else float(moved)
    return out


#: family -> how its parameters shape the drive (after the quiet start and the rest).
FAMILIES = {"hold": _hold, "rise_again": _rise_again, "steps": _steps, "probe_blocks": _probe_blocks}


def rest_seconds(params: dict, limits: RigLimits) -> float:
    """How long a drive with ``params`` rests after the quiet start [s] (0 without a rest)."""
    return float(params.get("rest", 0.0)) * (limits.duration - limits.quiet)


def drive_of(family: str, params: dict, limits: RigLimits, period: float):
    """``(time, current)`` of a family's drive with ``params``, or None outside the limits."""
    b = _Builder(limits, period)
    b.hold(rest_seconds(params, limits))
    FAMILIES[family](b, params)
    return b.finish()


def drive_period(records) -> float:
    """The records' drive period [s] (twice the median time between reversals), at least 2 s."""
    periods = []
    for r in records:
        index = np.asarray(find_reversals(np.asarray(r.current)).index)
        if index.size >= 3:
            periods.append(2.0 * float(np.median(np.diff(np.asarray(r.time)[index]))))
    return max(float(np.median(periods)) if periods else 10.0, 2.0)
