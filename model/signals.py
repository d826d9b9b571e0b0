r"""The paper's drive current, eqs. (14)-(17), at any sampling rate.

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
"""

from __future__ import annotations

import numpy as np

__all__ = ["paper_current", "INPUT_READINGS", "QUIET_SECONDS"]

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
