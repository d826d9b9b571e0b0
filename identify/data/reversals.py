"""Input reversals and the drive's geometry, on plain arrays: where the drive turns, the
branch each sample lies on, the time since the last reversal and the input rate.

Shared by the record loader (:func:`identify.data.records.keep_every` keeps every
reversal), the diagnosis (:mod:`identify.diagnosis.residuals`) and the figures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "as_1d",
    "Reversals",
    "default_min_swing",
    "find_reversals",
    "branch_direction",
    "time_since_reversal",
    "input_rate",
]


def as_1d(name, values, size=None) -> np.ndarray:
    """``values`` as a finite 1-D float array (of ``size`` samples when given); a ValueError names ``name``."""
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if size is not None and arr.size != size:
        raise ValueError(f"{name} has {arr.size} samples, expected {size}")
    if not np.isfinite(arr).all():
        k = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name} has a non-finite value at sample {k}")
    return arr


# -- reversals and the input's geometry ----------------------------------------------------


@dataclass(frozen=True)
class Reversals:
    """Turning points of the drive.

    Attributes
    ----------
    index : ndarray of int, shape (R,)
        Sample index of each reversal, increasing. On a plateau the *last* sample of
        the plateau is taken (where the input starts moving the other way).
    kind : ndarray of int, shape (R,)
        ``+1`` for a peak (maximum, the input turns down), ``-1`` for a trough.
    min_swing : float
        The swing [input units] a turn had to exceed to count.
    """

    index: np.ndarray
    kind: np.ndarray
    min_swing: float

    def __len__(self):
        return int(self.index.size)

    @property
    def peaks(self) -> np.ndarray:
        """Indices of the peaks, shape (P,)."""
        return self.index[self.kind > 0]

    @property
    def troughs(self) -> np.ndarray:
        """Indices of the troughs, shape (Q,)."""
        return self.index[self.kind < 0]


#: A reversal is confirmed once the input has moved back by this fraction of its range ...
SWING_FRACTION = 0.02
#: ... and by this many times the input's own noise sd (the range of 1000 noise samples stays below it).
SWING_NOISE_MULTIPLE = 10.0


def default_min_swing(current) -> float:
    """The swing [input units] that confirms a reversal: the larger of :data:`SWING_FRACTION`
    times the input's range and :data:`SWING_NOISE_MULTIPLE` times its noise sd.

    The noise sd is estimated robustly from the second differences (``1.4826 MAD / sqrt(6)``;
    a sampled drive's curvature is negligible against its noise at the rates used), so a
    noiseless drive gets 2 % of its range.
    """
    v = np.asarray(current, dtype=float)
    span = float(v.max() - v.min()) if v.size else 0.0
    second = np.diff(v, 2)
    noise = 1.4826 * float(np.median(np.abs(second - np.median(second)))) / np.sqrt(6.0) if second.size else 0.0
    return max(SWING_FRACTION * span, SWING_NOISE_MULTIPLE * noise)


def find_reversals(current, min_swing=None) -> Reversals:
    """Peaks and troughs of the drive by a zig-zag rule.

    A candidate extremum becomes a reversal once the input has moved away from it by
    more than ``min_swing``; smaller wiggles (measurement noise on a read-back current)
    are ignored. The quiet start (constant input) followed by the first rise gives a
    trough at the last quiet sample.

    Parameters
    ----------
    current : array_like, shape (T,)
        Drive [A].
    min_swing : float, optional
        Minimum confirming swing [A]; default :func:`default_min_swing`: 2 % of the
        input's range, or ten times the input's own noise sd where that is larger (a
        read-back current), so noise never splits a branch.

    Returns
    -------
    Reversals
        Empty when the input never moves by more than ``min_swing``.
    """
    v = as_1d("current", current)
    span = float(v.max() - v.min()) if v.size else 0.0
    if min_swing is None:
        min_swing = default_min_swing(v)
    if not (np.isfinite(min_swing) and min_swing >= 0):
        raise ValueError(f"min_swing must be a finite number >= 0, got {min_swing!r}")
    if span == 0.0 or v.size < 3:
        return Reversals(np.zeros(0, dtype=int), np.zeros(0, dtype=int), float(min_swing))
    index, kind = [], []
    hi_i = lo_i = 0
    hi = lo = v[0]
    direction = 0  # +1 looking for a peak, -1 looking for a trough, 0 undecided
    for k in range(1, v.size):
        x = v[k]
        if direction >= 0 and x >= hi:
            hi, hi_i = x, k
        if direction <= 0 and x <= lo:
            lo, lo_i = x, k
        if direction == 0:
            if x - lo > min_swing and x > v[lo_i]:
                index.append(lo_i)
                kind.append(-1)
                direction, hi, hi_i = +1, x, k
            elif hi - x > min_swing and x < v[hi_i]:
                index.append(hi_i)
                kind.append(+1)
                direction, lo, lo_i = -1, x, k
        elif direction > 0 and hi - x > min_swing:
            index.append(hi_i)
            kind.append(+1)
            direction, lo, lo_i = -1, x, k
        elif direction < 0 and x - lo > min_swing:
            index.append(lo_i)
            kind.append(-1)
            direction, hi, hi_i = +1, x, k
    return Reversals(np.asarray(index, dtype=int), np.asarray(kind, dtype=int), float(min_swing))


def branch_direction(n_samples, reversals: Reversals) -> np.ndarray:
    """The branch each sample lies on: ``+1`` rising, ``-1`` falling, ``0`` before the first reversal.

    Between a trough and the next peak the input rises; after the last reversal the
    direction continues.

    Returns
    -------
    ndarray of int8, shape (T,)
    """
    direction = np.zeros(int(n_samples), dtype=np.int8)
    for i, (k, kind) in enumerate(zip(reversals.index, reversals.kind)):
        stop = reversals.index[i + 1] if i + 1 < len(reversals) else n_samples
        direction[k + 1 : stop + 1] = -kind  # after a peak (+1) the input falls
    return direction


def time_since_reversal(time, reversals: Reversals) -> np.ndarray:
    """Seconds since the most recent reversal at or before each sample.

    Returns
    -------
    ndarray, shape (T,)
        [s]; NaN before the first reversal (undefined there).
    """
    t = as_1d("time", time)
    out = np.full(t.size, np.nan)
    if len(reversals) == 0:
        return out
    last = np.searchsorted(reversals.index, np.arange(t.size), side="right") - 1
    ok = last >= 0
    out[ok] = t[ok] - t[reversals.index[last[ok]]]
    return out


def input_rate(time, current) -> np.ndarray:
    """Rate of change of the drive, ``dI/dt`` [A/s], central differences, shape (T,)."""
    t = as_1d("time", time)
    v = as_1d("current", current, t.size)
    if t.size < 2:
        raise ValueError("input_rate needs at least 2 samples")
    return np.gradient(v, t)
