r"""Drive currents: the paper's, eqs. (14)-(17), and one that separates the slow effects.

.. math::

    v(t) = \begin{cases} 0 & 0 \le t < 10\ \mathrm{s} \\
                         2.5 \sin(0.2\pi t - \pi/2) + 2.5 & 10 \le t \le 70\ \mathrm{s} \end{cases}

Eq. (16) multiplies by :math:`1 - 0.01 (t - 20)` from 20 s on. Two readings:

``"literal"`` (default)
    As printed: the whole signal, bias included, is multiplied, so the troughs stay at
    0 A while the peaks fall from 5 A to 2.5 A at 70 s.
``"centred"``
    As the text says ("amplitude asymptotically decreasing to line at 2.5 A"): only the
    sine's amplitude decays, :math:`2.5 + (v - 2.5)(1 - 0.01 (t - 20))`, so peaks and
    troughs close in on 2.5 A (3.75 A and 1.25 A at 70 s).

:func:`hold_current` is a second drive of the same rig (0-5 A, the paper's 0.1 Hz and its
quiet start) for the effects the paper's drive leaves tied: cycles whose amplitude falls and
rises again (heating follows the power; a training does not come back), a hold at a high
current (creep keeps moving, heating settles), and a long quiet end with the coils off
(heating relaxes, a sensor drift goes on).
"""

from __future__ import annotations

import numpy as np

__all__ = ["paper_current", "hold_current", "DRIVES", "drive_current", "INPUT_READINGS", "QUIET_SECONDS"]

INPUT_READINGS = ("literal", "centred")
#: Length of the unenergised start of the paper's record [s].
QUIET_SECONDS = 10.0


def paper_current(fs=100.0, reading="literal", duration=70.0):
    """The paper's drive current sampled at ``fs``.

    Parameters
    ----------
    fs : float, default 100.0
        Sampling rate [Hz]; the samples are ``t = k / fs`` for ``0 <= t <= duration``.
        At 100 Hz and 70 s that is 7001 samples.
    reading : {"literal", "centred"}, default "literal"
        How eq. (16)'s decay applies; see the module docstring.
    duration : float, default 70.0
        Record length [s], ``> 10``.

    Returns
    -------
    time : ndarray, shape (T,)  [s]
    current : ndarray, shape (T,)  [A]
    """
    if reading not in INPUT_READINGS:
        raise ValueError(f"reading must be one of {INPUT_READINGS}, got {reading!r}")
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sampling rate in Hz, got {fs!r}")
    if not (np.isfinite(duration) and duration > QUIET_SECONDS):
        raise ValueError(f"duration must exceed the {QUIET_SECONDS} s quiet segment, got {duration!r}")
    n = int(np.floor(duration * fs + 1e-9)) + 1
    if n < 2:
        raise ValueError(f"fs={fs} Hz gives fewer than 2 samples over {duration} s")
    time = np.arange(n) / fs
    sine = 2.5 * np.sin(0.2 * np.pi * time - np.pi / 2) + 2.5
    decay = np.where(time > 20.0, 1.0 - 0.01 * (time - 20.0), 1.0)
    if reading == "literal":
        energised = sine * decay
    else:
        energised = 2.5 + (sine - 2.5) * decay
    current = np.where(time < QUIET_SECONDS, 0.0, energised)
    return time, current


def hold_current(fs=100.0, peaks=(5.0, 3.5, 2.0, 3.5), hold_level=4.5, hold_seconds=15.0, quiet_end=35.0):
    """A drive with holds and a quiet end (module docstring), sampled at ``fs``.

    After the 10 s quiet start: one 0.1 Hz raised-cosine cycle per entry of ``peaks`` [A]
    (their amplitude falls, then rises again), a 5 s half cycle up to ``hold_level``, the hold
    for ``hold_seconds``, a 5 s half cycle down to 0 A and ``quiet_end`` seconds at 0 A. With
    the defaults 110 s (11001 samples at 100 Hz).

    Returns
    -------
    time : ndarray, shape (T,)  [s]
    current : ndarray, shape (T,)  [A]
    """
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sampling rate in Hz, got {fs!r}")
    peaks = [float(p) for p in peaks]
    if not peaks or min(peaks) <= 0 or max(peaks + [hold_level]) > 5.0 or hold_level <= 0:
        raise ValueError("the peaks and the hold level must lie in (0, 5] A")
    if hold_seconds < 0 or quiet_end < 0:
        raise ValueError("hold_seconds and quiet_end must be >= 0")
    cycles_end = QUIET_SECONDS + 10.0 * len(peaks)
    hold_start = cycles_end + 5.0
    hold_end = hold_start + hold_seconds
    duration = hold_end + 5.0 + quiet_end
    n = int(np.floor(duration * fs + 1e-9)) + 1
    time = np.arange(n) / fs
    current = np.zeros(n)
    for k, peak in enumerate(peaks):
        t0 = QUIET_SECONDS + 10.0 * k
        inside = (time >= t0) & (time < t0 + 10.0)
        current[inside] = 0.5 * peak * (1.0 - np.cos(0.2 * np.pi * (time[inside] - t0)))
    up = (time >= cycles_end) & (time < hold_start)
    current[up] = 0.5 * hold_level * (1.0 - np.cos(0.2 * np.pi * (time[up] - cycles_end)))
    current[(time >= hold_start) & (time < hold_end)] = hold_level
    down = (time >= hold_end) & (time < hold_end + 5.0)
    current[down] = 0.5 * hold_level * (1.0 + np.cos(0.2 * np.pi * (time[down] - hold_end)))
    return time, current


#: The drives of the virtual bench by name.
DRIVES = ("paper", "holds")


def drive_current(drive="paper", fs=100.0, reading="literal", duration=70.0):
    """``(time, current)`` of a named drive (:data:`DRIVES`): the paper's (``reading``,
    ``duration``) or :func:`hold_current`."""
    if drive == "paper":
        return paper_current(fs=fs, reading=reading, duration=duration)
    if drive == "holds":
        return hold_current(fs=fs)
    raise ValueError(f"drive must be one of {DRIVES}, got {drive!r}")
