r"""The inverse of the GPI model (plus effects): the drive that makes the model follow a target.

Given a desired output trajectory :math:`y^*_k` at sample times :math:`t_k` and a model
(GPI plus any library effect), :func:`invert` returns a drive :math:`i_k` within
``[lo, hi]`` such that the model's output on that drive equals :math:`y^*_k` wherever the
model can produce it, for one parameter set or a batch (posterior draws), in one numba
kernel parallel over the batch. Pure: no I/O, no plotting.

Method: a per-sample 1-D root find carried forward with the model's state
-------------------------------------------------------------------------------
The model is causal and its state after sample ``k-1`` is finite-dimensional: the ``N``
operator memories, the previous drive and Omega branch (GPI, :mod:`model.gpi`); the
lag filter's output, the first-cycle travel (``training``); the creep modes; the
temperature rise (``thermal``). Given that state, the output at sample ``k`` is a scalar
function :math:`y_k(i)` of the present current alone, and on each *side* it is monotone:

* the drive the hysteresis sees, :math:`u_k(i)`, is increasing in :math:`i` (``lag``:
  affine, :math:`u_k = i(1 - g) + \dots` with the exact step of
  :func:`model.effects.first_order_lowpass`, gain :math:`g < 1`; ``training``: the
  soft-thresholded, scaled excursion, increasing except for extreme settings);
* **rising side** :math:`u_k \ge u_{k-1}` (Omega's ``c`` branch, eq. 13):
  :math:`y = \Omega_c(u) + \sum_j p_j \max(z_j, \gamma_\uparrow(u) - r_j)`, nondecreasing
  in :math:`u` for increasing envelopes, positive weights and an increasing
  :math:`\Omega_c`; **falling side** :math:`u_k < u_{k-1}`: the same with ``min``,
  :math:`\gamma_\downarrow + r_j` and :math:`\Omega_d`;
* output-stage effects are increasing in the GPI output at the present sample
  (``creep``: :math:`1 - A + A\,\overline{(1 - \text{gain})} > 0`; ``thermal``:
  :math:`1 - S\vartheta > 0`; ``sensor_drift``: an offset). ``thermal`` also depends on the
  present current directly, through :math:`(i/5\,\mathrm{A})^2` in one exact filter step
  (weight about :math:`h/2\tau_T`, 2.5e-4 at 100 Hz and 20 s), which can make the output
  very slightly non-monotone where the GPI is flat; the search still returns a root
  where the target is crossed.

So sample by sample, the inverse solves :math:`y_k(i) = y^*_k` on one side by a
bracketed search in the current (an expanding probe from the previous current, then
Brent's method; the edge of a side located on the
input stage alone; the details in :mod:`model.inverse_search`), commits the state with the
current found, and moves on. Each root is found to ``ytol`` in the output (default
``1e-12 (1 + max|y*|)``, rounding level): the model driven by the returned current
reproduces a target it could produce to rounding (``tests/test_inverse.py``).

Side (direction) choice and the Omega switch at a reversal
-----------------------------------------------------------
The side is chosen from the target: rising when :math:`y^*_k > y^*_{k-1}`, falling when
it decreases, the side of the previous sample when it is flat (after a sample that was not
reached exactly: the sign of :math:`y^*_k - y_{k-1}`). At a reversal Omega switches branch
(eq. 13: ``c`` for :math:`\Delta u \ge 0`, ``d`` for :math:`\Delta u < 0`) with memory
unchanged, so the output jumps by :math:`\Omega_d(u) - \Omega_c(u)` (Table 1: +1.9 to
+3.0 um at a peak, the opposite at a trough) the moment the drive reverses. The search
handles this explicitly: on the new side the output starts from the jumped value, and
the root lies where the operators have moved enough to take the jump back (a step of the
current at the reversal; with Table 1's sign every target reversal is reachable this way).
When the jump has the other sign, targets just past the reversal lie in a gap neither
side can produce: then both sides are searched and the output closer to the target wins
(never more than half the jump away); the sample is flagged :data:`STATUS_BRANCH`. A
still drive keeps Omega on the branch of its last motion (:mod:`model.gpi`), so a hold of the
target is a hold of the current.

Current limits and unreachable targets
--------------------------------------
The current stays in ``[lo, hi]`` (the rig's 0-5 A by default). A target sample beyond
what the model produces at a limit (on the chosen side, after trying the other) gets the
limit and the remaining error; it is flagged :data:`STATUS_SATURATED`. The caller decides
whether that is an error (``python -m identify compensate`` refuses such targets).

Effects with dynamics
---------------------
``lag``, ``creep`` and ``thermal`` are inverted exactly in their general forms, each with
its own state in the per-sample step: the current found at sample ``k`` is the one whose
*filtered* drive (lag) and whose heating (thermal, both nodes) give the target; creep's
modes (the saturating spectrum and the logarithmic ones, these with the part held to the
leg's end) are advanced with the strain found. A lag's dead time (``lag_delay`` not 0) is
refused: the current at a sample acts on the output only a dead time later, which no
per-sample step can reach. A lag is inverted exactly too, which means the current leads the
drive (:math:`i \approx u + \tau_L \dot u`) and steps where the drive has a kink; the exact
step of a first-order filter with an input linear between samples has a zero near -1 in the
sample domain, so a step in :math:`u` makes :math:`i` ring with alternating sign, decaying
as :math:`(-1 + h/3\tau_L)^k`: real, but the current limits may bind. ``training`` (its
drive, width and strain parts) and ``initial_state`` (its level, prior excursion and held
memory) are inverted as identified (the compensation starts from the model's initial state).
``sensor_drift`` is supported here (an offset per sample, whatever its form: the effect's
own output on a zero displacement), but it is a property of the sensor, not of the
transducer (the workflows leave it out of a compensation). An effect without an inverse step
here raises a :class:`ValueError` naming it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .composite import Model
from .effects.creep import CREEP_MODES, creep_time_constants, log_creep_time_constants
from .gpi import READINGS, THETA_NAMES
from .inverse_search import inverse_kernel

__all__ = [
    "invert",
    "InverseResult",
    "SUPPORTED_EFFECTS",
    "STATUS_EXACT",
    "STATUS_SATURATED",
    "STATUS_BRANCH",
    "STATUS_NAMES",
    "DEFAULT_CURRENT_RANGE",
]

#: Effects :func:`invert` knows the state and step of.
SUPPORTED_EFFECTS = ("lag", "training", "initial_state", "creep", "thermal", "sensor_drift")
#: The target is reproduced to ``ytol``.
STATUS_EXACT = 0
#: The current sits at a limit and the target is not reached.
STATUS_SATURATED = 1
#: Not reached within the limits for another reason: a gap at an Omega branch switch.
STATUS_BRANCH = 2
STATUS_NAMES = {STATUS_EXACT: "exact", STATUS_SATURATED: "saturated", STATUS_BRANCH: "branch"}
#: The rig's current range [A] (the paper's 5 A excitation, coils never driven negative).
DEFAULT_CURRENT_RANGE = (0.0, 5.0)


@dataclass(frozen=True, eq=False)
class InverseResult:
    """The drive found by :func:`invert`, and what the model does with it.

    Attributes
    ----------
    current : ndarray, shape (W, T) or (T,)
        The drive [input unit], within ``current_range``; 1-D for a 1-D ``theta``.
    output : ndarray, shape like ``current``
        The model's output on that drive [output unit] as the kernel computed it
        (equal to :meth:`model.Model.evaluate` to rounding).
    status : ndarray of int8, shape like ``current``
        Per sample: :data:`STATUS_EXACT`, :data:`STATUS_SATURATED` or :data:`STATUS_BRANCH`.
    target : ndarray, shape (T,)
    current_range : (float, float)
    ytol : float
        Output tolerance of the root finds.
    evaluations : ndarray of int64, shape (W,)
        Model steps evaluated per parameter set (about 10-20 per sample).
    """

    current: np.ndarray
    output: np.ndarray
    status: np.ndarray
    target: np.ndarray
    current_range: tuple
    ytol: float
    evaluations: np.ndarray

    @property
    def error(self) -> np.ndarray:
        """``output - target`` [output unit]."""
        return self.output - self.target

    @property
    def exact(self) -> np.ndarray:
        """Boolean like ``status``: reproduced to ``ytol``."""
        return self.status == STATUS_EXACT


# --------------------------------------------------------------------------------------
# Python entry
# --------------------------------------------------------------------------------------
def _effect_columns(model: Model, theta2: np.ndarray, name: str, width: int, off) -> np.ndarray:
    if name in model.effect_names:
        return np.array(theta2[:, model.effect_slice(name)], dtype=float, order="C")
    return np.array(np.broadcast_to(np.asarray(off, dtype=float), (theta2.shape[0], width)), dtype=float, order="C")


def invert(model: Model, theta, time, target, *, current_range=DEFAULT_CURRENT_RANGE, ytol=None) -> InverseResult:
    """The drive within ``current_range`` that makes ``model`` follow ``target`` (method: module docstring).

    Parameters
    ----------
    model : Model
        GPI plus effects from :data:`SUPPORTED_EFFECTS`.
    theta : array_like, shape (P,) or (W, P)
        Full parameter vectors (``model.names`` order); a batch is inverted in one
        parallel call (e.g. posterior draws).
    time : array_like, shape (T,)
        Sample times [s], strictly increasing (the dynamic effects use them).
    target : array_like, shape (T,)
        Desired output [output unit], ``T >= 2``.
    current_range : (float, float), default (0, 5)
        ``(lo, hi)`` limits of the drive [input unit], ``lo < hi``.
    ytol : float, optional
        Output tolerance of each root find; default ``1e-12 (1 + max|target|)``.

    Returns
    -------
    InverseResult

    Raises
    ------
    ValueError
        Malformed arguments, or an effect without an inverse step here (named).
    """
    if not isinstance(model, Model):
        raise ValueError(f"model must be a model.Model, got {type(model).__name__}")
    unsupported = [e for e in model.effect_names if e not in SUPPORTED_EFFECTS]
    if unsupported:
        raise ValueError(
            f"no inverse for the effect(s) {', '.join(map(repr, unsupported))}: model.inverse knows "
            f"{', '.join(SUPPORTED_EFFECTS)}"
        )
    theta = np.asarray(theta, dtype=float)
    single = theta.ndim == 1
    theta2 = np.ascontiguousarray(np.atleast_2d(theta))
    if theta2.ndim != 2 or theta2.shape[1] != model.n_parameters or theta2.shape[0] < 1:
        raise ValueError(
            f"theta must have shape ({model.n_parameters},) or (W, {model.n_parameters}) for {model!r}, got "
            f"{theta.shape}"
        )
    if not np.isfinite(theta2).all():
        raise ValueError("theta has a non-finite value")
    time = np.ascontiguousarray(time, dtype=float)
    target = np.ascontiguousarray(target, dtype=float)
    if time.ndim != 1 or target.shape != time.shape or time.size < 2:
        raise ValueError(f"time and target must both have shape (T,) with T >= 2, got {time.shape} and {target.shape}")
    if not (np.isfinite(time).all() and np.isfinite(target).all()):
        raise ValueError("time and target must be finite")
    if not (np.diff(time) > 0).all():
        raise ValueError("time must be strictly increasing")
    try:
        lo, hi = (float(x) for x in current_range)
    except (TypeError, ValueError):
        raise ValueError(f"current_range must be two numbers (lo, hi), got {current_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"current_range must satisfy lo < hi (finite), got {current_range!r}")
    if ytol is None:
        ytol = 1e-9 * (1.0 + float(np.max(np.abs(target))))
    ytol = float(ytol)
    if not (ytol > 0 and math.isfinite(ytol)):
        raise ValueError(f"ytol must be a positive finite number, got {ytol!r}")

    n_sets = theta2.shape[0]
    gpi_theta = np.ascontiguousarray(theta2[:, : len(THETA_NAMES)])
    z0 = np.ascontiguousarray(_effect_columns(model, theta2, "initial_state", 2, [0.0, 0.0])[:, :2])  # level, excursion
    held = np.zeros((n_sets, int(model.n_operators)))
    if "initial_state" in model.effect_names:
        effect = model.effects[model.effect_names.index("initial_state")]
        held = np.ascontiguousarray(
            effect.initial_held(theta2[:, model.effect_slice("initial_state")], model.n_operators)
        )
    lag = _effect_columns(model, theta2, "lag", 2, [0.0, 0.0])
    if np.any(lag[:, 1] != 0.0):
        rows = np.flatnonzero(lag[:, 1] != 0.0)
        raise ValueError(
            f"no inverse for lag's dead time (lag_delay = {lag[rows[0], 1]:.4g} s in parameter set {int(rows[0])}): "
            "the current at a sample acts on the output only a dead time later, which a per-sample inverse "
            "cannot reach; model.inverse inverts the first-order lag (lag_tau) alone"
        )
    lag_tau = np.ascontiguousarray(lag[:, 0])
    has_training = "training" in model.effect_names
    training = _effect_columns(model, theta2, "training", 6, [0.0, 0.0, 2.0, 1.0, 0.0, 0.0])
    if has_training and not ((training[:, 2] > 0).all() and (training[:, 3] > 0).all() and (training[:, 1] >= 0).all()):
        raise ValueError("training: training_threshold >= 0 and training_travel, training_shape > 0 are required")
    creep_on = "creep" in model.effect_names
    creep = _effect_columns(model, theta2, "creep", 6, [0.0, 1.0, 1.0, 0.0, 0.1, 0.0])
    if creep_on:
        saturating = creep_time_constants(creep[:, 1], creep[:, 2])
        if saturating.shape[1] != CREEP_MODES:  # pragma: no cover - consistency
            raise ValueError("creep modes mismatch")
        log_taus, n_log = log_creep_time_constants(creep[:, 4], float(time[-1] - time[0]))
        log_taus = np.where(np.arange(log_taus.shape[1])[None, :] < n_log[:, None], log_taus, 1.0)
        creep_taus = np.ascontiguousarray(np.hstack([saturating, log_taus]))
        creep_params = np.ascontiguousarray(
            np.column_stack(
                [
                    creep[:, 0],
                    np.full(n_sets, float(saturating.shape[1])),
                    creep[:, 3],
                    n_log.astype(float),
                    creep[:, 5],
                ]
            )
        )
    else:
        creep_taus = np.ones((n_sets, 1))
        creep_params = np.zeros((n_sets, 5))
    thermal_on = "thermal" in model.effect_names
    thermal = _effect_columns(model, theta2, "thermal", 8, [30.0, 0.0, 0.0, 300.0, 0.0, 0.0, 0.0, 0.0])
    # the sensor drift is an offset per sample whatever its form: the effect's own output on 0
    drift = np.zeros((n_sets, time.size))
    if "sensor_drift" in model.effect_names:
        effect = model.effects[model.effect_names.index("sensor_drift")]
        drift = np.ascontiguousarray(
            effect.output(theta2[:, model.effect_slice("sensor_drift")], time, np.zeros_like(time), drift), dtype=float
        )

    current = np.empty((n_sets, time.size))
    output = np.empty((n_sets, time.size))
    status = np.empty((n_sets, time.size), dtype=np.int8)
    evaluations = np.zeros(n_sets, dtype=np.int64)
    inverse_kernel(
        gpi_theta,
        int(model.n_operators),
        READINGS[model.reading],
        z0,
        held,
        lag_tau,
        has_training,
        training,
        creep_on,
        creep_params,
        creep_taus,
        thermal_on,
        thermal,
        drift,
        time,
        target,
        lo,
        hi,
        ytol,
        current,
        output,
        status,
        evaluations,
    )
    if single:
        current, output, status = current[0], output[0], status[0]
    return InverseResult(current, output, status, target, (lo, hi), ytol, evaluations)
