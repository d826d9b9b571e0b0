"""Progress of the emcee chain with an honest estimate of the steps still needed.

The chain stops when it is ``tau_factor`` (50) times its largest integrated
autocorrelation time long (and the other rules of :mod:`identify.fitting.posterior` pass), or at
the step cap. A bar counting to the cap (60000 steps by default) shows the cap's ETA, not
the run's; here the goal is the *projected* length ``tau_factor x tau_max``, re-estimated
whenever the sampler computes tau (at its convergence checks), capped at ``max_steps``.
Before the first estimate the goal is unknown and only steps and speed are shown.

Two forms (:func:`progress_mode`):

``"bar"``
    a tqdm bar on stderr (in a terminal): steps done, the projected total and its ETA,
    the current tau_max and the cap.
``"lines"``
    outside a terminal (``nohup``, a notebook, a batch's log file): one log line every
    ``interval`` seconds (default :data:`DEFAULT_INTERVAL`, or the environment variable
    :data:`INTERVAL_VARIABLE`), e.g.
    ``emcee: step 1500 (cap 60000), 152 steps/s; tau_max 71.3 steps -> about 3565 steps
    needed (50 x tau), about 14 s to go``.
"""

from __future__ import annotations

import math
import os
import sys
import time

from ..logs import get_logger

__all__ = ["ChainProgress", "progress_mode", "DEFAULT_INTERVAL", "INTERVAL_VARIABLE"]

#: Seconds between two progress lines outside a terminal.
DEFAULT_INTERVAL = 10.0
#: Environment variable overriding :data:`DEFAULT_INTERVAL` (a number of seconds > 0).
INTERVAL_VARIABLE = "IDENTIFY_PROGRESS_SECONDS"


def progress_mode(progress) -> str:
    """``"bar"``, ``"lines"`` or ``"off"`` for a ``progress`` argument.

    Parameters
    ----------
    progress : bool or None
        True: a bar; False: nothing; None: a bar when stderr is a terminal or in a Jupyter
        notebook, else lines.
    """
    if progress is None:
        isatty = getattr(sys.stderr, "isatty", None)
        in_notebook = "ipykernel" in sys.modules  # a Jupyter cell shows a bar redrawn on stderr
        return "bar" if in_notebook or (isatty is not None and isatty()) else "lines"
    return "bar" if progress else "off"


def _interval_from_environment() -> float:
    text = os.environ.get(INTERVAL_VARIABLE, "")
    try:
        value = float(text)
    except ValueError:
        return DEFAULT_INTERVAL
    return value if math.isfinite(value) and value > 0 else DEFAULT_INTERVAL


class ChainProgress:
    """Progress of one :func:`identify.fitting.posterior.sample_posterior` call.

    Parameters
    ----------
    done : int
        Steps the chain holds already (a resumed run).
    max_steps : int
        The cap [steps].
    tau_factor : float
        Chain length needed, in autocorrelation times (50).
    mode : {"bar", "lines", "off"}
        See the module docstring and :func:`progress_mode`.
    interval : float, optional
        Seconds between lines (mode ``"lines"``); default from :data:`INTERVAL_VARIABLE`
        or :data:`DEFAULT_INTERVAL`.
    log : callable, optional
        ``log(str)`` for the lines; default the ``identify.posterior`` logger at INFO.
    clock : callable, default time.monotonic
        Seconds; replaceable in tests.
    """

    def __init__(self, *, done, max_steps, tau_factor, mode, interval=None, log=None, clock=time.monotonic):
        if mode not in ("bar", "lines", "off"):
            raise ValueError(f"mode must be 'bar', 'lines' or 'off', got {mode!r}")
        self.mode = mode
        self.start_done = self.done = int(done)
        self.max_steps = int(max_steps)
        self.tau_factor = float(tau_factor)
        self.interval = float(interval) if interval is not None else _interval_from_environment()
        self._log = log or get_logger("posterior").info
        self._clock = clock
        self._t0 = self._last_line = clock()
        self.tau_max = math.nan
        self.bar = None
        if mode == "bar":
            from tqdm import tqdm  # deferred: ~0.15 s to import, only for a bar on a terminal

            self.bar = tqdm(total=None, initial=self.done, desc="emcee", unit="step", file=sys.stderr)
            self.bar.set_postfix_str(f"tau not estimated yet; cap {self.max_steps}", refresh=False)

    @property
    def projected(self) -> int | None:
        """Projected chain length [steps]: ``tau_factor x tau_max``, at least the steps done
        and at most the cap; None before tau is estimated."""
        if not math.isfinite(self.tau_max):
            return None
        return int(min(self.max_steps, max(self.done, math.ceil(self.tau_factor * self.tau_max))))

    @property
    def rate(self) -> float:
        """Steps per second in this call (NaN before the first step)."""
        seconds = self._clock() - self._t0
        steps = self.done - self.start_done
        return steps / seconds if steps > 0 and seconds > 0 else math.nan

    def estimate(self, tau_max: float) -> None:
        """A new autocorrelation-time estimate [steps] (at a convergence check): updates the goal."""
        tau_max = float(tau_max)
        if not math.isfinite(tau_max):
            return
        self.tau_max = tau_max
        if self.bar is not None:
            self.bar.total = self.projected
            needed = math.ceil(self.tau_factor * tau_max)
            self.bar.set_postfix_str(
                f"tau_max {tau_max:.1f} -> need ~{needed} ({self.tau_factor:g} tau)"
                + (f" > cap {self.max_steps}" if needed > self.max_steps else f"; cap {self.max_steps}"),
                refresh=False,
            )
            self.bar.refresh()

    def update(self, n: int = 1) -> None:
        """``n`` more steps done."""
        self.done += int(n)
        if self.bar is not None:
            if self.bar.total is not None and self.done > self.bar.total:
                self.bar.total = self.done  # past the projection: the next check re-estimates
            self.bar.update(n)
        elif self.mode == "lines":
            now = self._clock()
            if now - self._last_line >= self.interval:
                self._last_line = now
                self._log(self.line())

    def line(self) -> str:
        """The progress line (mode ``"lines"``)."""
        rate = self.rate
        text = f"emcee: step {self.done} (cap {self.max_steps}), " + (
            f"{rate:.3g} steps/s" if math.isfinite(rate) else "speed not measured yet"
        )
        projected = self.projected
        if projected is None:
            return text + "; tau not estimated yet (first estimate at a convergence check)"
        needed = max(self.done, math.ceil(self.tau_factor * self.tau_max))
        text += f"; tau_max {self.tau_max:.1f} steps -> about {needed} steps needed ({self.tau_factor:g} x tau)"
        if needed > self.max_steps:
            text += f", more than the cap: it stops NOT CONVERGED at {self.max_steps} unless tau falls"
        if math.isfinite(rate) and projected > self.done:
            text += f", about {(projected - self.done) / rate:.0f} s to go"
        return text

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
