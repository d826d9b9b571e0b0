r"""The generalized Prandtl-Ishlinskii (GPI) model of the seed paper, and the classical PI.

Equations (numbers as in the paper)
-----------------------------------
Input current :math:`v(t)` [A] sampled at :math:`t_0 < t_1 < \dots`.
Two tanh envelopes, eqs. (6) and (7):

.. math::  \gamma_a(v) = a_0 \tanh(a_1 v + a_2) + a_3, \qquad
           \gamma_b(v) = b_0 \tanh(b_1 v + b_2) + b_3 .

``N`` generalized play operators with thresholds and weights, eqs. (8)-(10):

.. math::  r_j = \alpha j, \qquad p_j = \rho\, e^{-\tau r_j}, \qquad j = 1 \dots N

(the weights carry no ``dr`` factor: eq. (12) is a plain sum).
Each operator follows eq. (5), with a *rising* envelope :math:`\gamma_\uparrow` and
a *falling* envelope :math:`\gamma_\downarrow`:

.. math::

    z_j(t_k) = \begin{cases}
        \max(\gamma_\uparrow(v_k) - r_j,\ z_j(t_{k-1})) & v_k > v_{k-1} \\
        \min(\gamma_\downarrow(v_k) + r_j,\ z_j(t_{k-1})) & v_k < v_{k-1} \\
        z_j(t_{k-1}) & v_k = v_{k-1}
    \end{cases}

Initial memory (the paper does not print one; see the reading below):

.. math::  z_j(t_0) = \max\big(\gamma_\uparrow(v_0) - r_j,\ \min(\gamma_\downarrow(v_0) + r_j,\ z^{0})\big),
           \quad z^0 = 0 .

A memory *held* beyond those bounds (:math:`h_j`, added after the clamp; 0 in the paper) is
kept until the first motion against it: the play law only moves a memory when a bound
passes it, so a memory above its upper bound stays there on rising runs and is cut at
the first falling one (``initial_held``; the ``initial_state`` effect).

The direction-dependent term, eq. (13), with the backward difference
:math:`\Delta v_k = v_k - v_{k-1}`:

.. math::  \Omega_k = \begin{cases} c_0 \tanh(c_1 v_k + c_2) + c_3 & \text{the input last moved up} \\
                                    d_0 \tanh(d_1 v_k + d_2) + d_3 & \text{the input last moved down} \end{cases}

The paper writes the branches for :math:`dv/dt \ge 0` and :math:`dv/dt < 0`. A still input
(:math:`\Delta v_k = 0`) has no direction of its own, and a transducer does not jump while its
drive is held: it keeps the branch of its last motion (the first samples, before any motion,
count as rising). Where the input never holds after a fall (the paper's drive) the two
readings are the same; at a hold after a fall the literal one would jump by
:math:`\Omega_c - \Omega_d` (about -1.9 um with Table 1 at 0 A) with nothing moving.

Output, eq. (12): :math:`y_k = \Omega_k + \sum_j p_j z_j(t_k)` [um].

Readings of the paper
---------------------
``"swapped"`` (default)
    Rising branch along eq. (6) (:math:`\gamma_\uparrow = \gamma_a`), falling along
    eq. (7) (:math:`\gamma_\downarrow = \gamma_b`): the labels of (6) and (7) are swapped
    relative to eq. (5). Thresholds :math:`r_j = \alpha j` with :math:`\alpha < 0` exactly as
    printed in Table 1. With Table 1 the response rests at -0.56 um with the coils off and
    peaks at 295.7 um, which matches the paper's "model output is 0 when not energised".
``"literal"``
    Rising branch along eq. (7), falling along eq. (6), as eq. (5) labels them. With
    Table 1 the response rests at 217 um, swings from about -569 to +650 um on the
    paper's input: not a transducer. Kept for comparison.

The whole domain
----------------
Eq. (5) is defined, and continuous in theta, for every parameter set: the kernel applies
the piecewise law as printed, for every theta and both readings. Where the lower bound
:math:`\gamma_\uparrow(v) - r_j` exceeds the upper bound :math:`\gamma_\downarrow(v) + r_j`
(the bounds *cross*; Table 1 is 0.0157 A from that at 5 A for ``j = 12``) an operator is no
longer a clamp: at a reversal its memory drops (or rises) by the overlap. That is a
property of a parameter set, not an error; :func:`bound_overlap` measures it.
:func:`gpi` raises only for malformed input.

With increasing envelopes and bounds that do not cross, the piecewise law (5) equals the
clamp form ``z = max(L, min(U, z_prev))`` used by most GPI codes (tested); where they
cross the two differ, and this module computes eq. (5).

The kernel is compiled with numba, parallel over the batch axis, and never
materialises a ``(W, T, N)`` array: it keeps ``N`` memory values per parameter set and
writes only the ``(W, T)`` output. Per parameter set it first evaluates, for every
sample, the envelope the input moves along and the Omega branch, in a loop LLVM
vectorises (a branch-free ``tanh`` within 4 ulp of libm's, :func:`model.gpi_kernels.fast_tanh`), then runs
the recursion over the memories. ``benchmarks/forward.py`` measures speed and memory.
"""

from __future__ import annotations

import numpy as np

from .gpi_kernels import gpi_kernel, initial_operator_memory, kernel_array, operator_thresholds_and_weights, play_kernel
from .parameters import Parameter, ParameterSet

__all__ = [
    "THETA_NAMES",
    "TABLE1",
    "GPI_PARAMETERS",
    "READINGS",
    "gpi",
    "bound_overlap",
    "classical_pi",
    "envelope",
    "distinct_rows",
    "gpi_rows",
    "gpi_grouped",
    # the kernels' public names, re-exported from model.gpi_kernels where they were before
    "operator_thresholds_and_weights",
    "initial_operator_memory",
    "kernel_array",
]

#: Table 1's order of the 19 GPI parameters.
THETA_NAMES = (
    "alpha",
    "rho",
    "tau",
    "a0",
    "a1",
    "a2",
    "a3",
    "b0",
    "b1",
    "b2",
    "b3",
    "c0",
    "c1",
    "c2",
    "c3",
    "d0",
    "d1",
    "d2",
    "d3",
)

#: Table 1 of the paper, in :data:`THETA_NAMES` order.
TABLE1 = np.array(
    [
        -0.1993,
        5.6438,
        0.0714,
        8.5043,
        0.5140,
        -0.0612,
        -6.1533,
        3.3505,
        1.3916,
        -0.9146,
        3.6876,
        1.5687,
        6.6176,
        -11.5359,
        25.7303,
        2.1349,
        7.1117,
        -9.2777,
        28.1546,
    ]
)

_DESCRIPTIONS = {
    "alpha": ("A", "threshold step: r_j = alpha * j (eq. 9)"),
    "rho": ("um/A", "weight scale: p_j = rho * exp(-tau r_j) (eq. 8)"),
    "tau": ("1/A", "weight decay rate (eq. 8)"),
    "a0": ("A", "rising envelope amplitude (eq. 6)"),
    "a1": ("1/A", "rising envelope slope (eq. 6)"),
    "a2": ("", "rising envelope shift (eq. 6)"),
    "a3": ("A", "rising envelope offset (eq. 6)"),
    "b0": ("A", "falling envelope amplitude (eq. 7)"),
    "b1": ("1/A", "falling envelope slope (eq. 7)"),
    "b2": ("", "falling envelope shift (eq. 7)"),
    "b3": ("A", "falling envelope offset (eq. 7)"),
    "c0": ("um", "Omega rising-branch amplitude (eq. 13)"),
    "c1": ("1/A", "Omega rising-branch slope (eq. 13)"),
    "c2": ("", "Omega rising-branch shift (eq. 13)"),
    "c3": ("um", "Omega rising-branch offset (eq. 13)"),
    "d0": ("um", "Omega falling-branch amplitude (eq. 13)"),
    "d1": ("1/A", "Omega falling-branch slope (eq. 13)"),
    "d2": ("", "Omega falling-branch shift (eq. 13)"),
    "d3": ("um", "Omega falling-branch offset (eq. 13)"),
}

# Broad default bounds: the support of the identification prior. Envelope amplitudes
# and slopes are positive (a0 tanh(a1 v + a2) = (-a0) tanh(-a1 v - a2) is an exact
# sign symmetry, removed by this choice, and increasing envelopes make the operator
# rate independent). The envelope units assume the input is in A and the output in
# um; records in other unit prefixes (mA, nm, ...) get them widened to their scale by
# identify.fitting.parametrisation.in_record_units (docs/method.md).
_BOUNDS = {
    # Either sign: alpha < 0 is the paper's (Table 1) reading, alpha > 0 the classical PI's
    # positive thresholds, which thin loop tips (e.g. piezo actuators) need. The
    # identification pins |alpha| and chooses the sign (identify.fitting.lsq).
    "alpha": (-2.0, 2.0),
    "rho": (1e-3, 1e3),
    "tau": (-5.0, 5.0),
    "a0": (1e-3, 100.0),
    "a1": (1e-3, 20.0),
    "a2": (-20.0, 20.0),
    "a3": (-100.0, 100.0),
    "b0": (1e-3, 100.0),
    "b1": (1e-3, 20.0),
    "b2": (-20.0, 20.0),
    "b3": (-100.0, 100.0),
    "c0": (-1e3, 1e3),
    "c1": (-50.0, 50.0),
    "c2": (-100.0, 100.0),
    "c3": (-1e4, 1e4),
    "d0": (-1e3, 1e3),
    "d1": (-50.0, 50.0),
    "d2": (-100.0, 100.0),
    "d3": (-1e4, 1e4),
}

#: The 19 GPI parameters with Table 1 values, default bounds and units.
GPI_PARAMETERS = ParameterSet(
    Parameter(name, float(value), *_BOUNDS[name], unit=_DESCRIPTIONS[name][0], description=_DESCRIPTIONS[name][1])
    for name, value in zip(THETA_NAMES, TABLE1)
)

#: reading name -> True when the rising branch follows eq. (6) (the ``a`` envelope).
READINGS = {"swapped": True, "literal": False}


def envelope(coefficients, v):
    """``k0 * tanh(k1 * v + k2) + k3``: the form of eqs. (6), (7) and (13).

    Parameters
    ----------
    coefficients : array_like, shape (..., 4)
    v : array_like, broadcastable against ``coefficients[..., 0]``
    """
    k = np.asarray(coefficients, dtype=float)
    return k[..., 0] * np.tanh(k[..., 1] * v + k[..., 2]) + k[..., 3]


def _per_set(values, n_sets, name):
    """A scalar or one value per parameter set, as a contiguous ``(W,)`` array."""
    array = np.asarray(values, dtype=float)
    if array.shape not in ((), (1,), (n_sets,)):
        raise ValueError(
            f"{name} must be a scalar or have shape ({n_sets},) (one value per parameter set), got shape {array.shape}"
        )
    if not np.isfinite(array).all():
        raise ValueError(f"{name} must be finite")
    return np.ascontiguousarray(np.broadcast_to(array, (n_sets,)))


_NO_HELD = np.zeros((1, 1))


def _held(initial_held, n_sets, n_operators):
    """``initial_held`` as the kernel takes it: ``(1, 1)`` for none (0 everywhere), else a
    contiguous ``(W, N)`` array (a scalar, one value per operator ``(N,)`` shared by the
    batch, or ``(W, N)``)."""
    array = np.asarray(initial_held, dtype=float)
    if array.shape not in ((), (n_operators,), (n_sets, n_operators)):
        raise ValueError(
            f"initial_held must be a scalar or have shape ({n_operators},) (one value per operator) or "
            f"({n_sets}, {n_operators}) (per parameter set and operator), got shape {array.shape}"
        )
    if not np.isfinite(array).all():
        raise ValueError("initial_held must be finite")
    if not array.any():
        return _NO_HELD
    return np.ascontiguousarray(np.broadcast_to(array, (n_sets, n_operators)))


def _refuse_non_finite_current(current2, one_d):
    """ValueError naming the first non-finite sample of the 2-D ``current2`` (``current[k]``
    when the caller's input was 1-D, else ``current[r, k]``)."""
    if not np.isfinite(current2).all():
        r, k = np.argwhere(~np.isfinite(current2))[0]
        where = f"current[{k}]" if one_d else f"current[{r}, {k}]"
        raise ValueError(f"current has a non-finite value at {where} ({current2[r, k]})")


def _prepare(theta, current, n_operators, reading, initial_memory):
    """Validate and normalise inputs; return 2-D contiguous arrays and flags."""
    if reading not in READINGS:
        raise ValueError(f"reading must be one of {sorted(READINGS)}, got {reading!r}")
    if isinstance(n_operators, bool) or not isinstance(n_operators, (int, np.integer)):
        raise ValueError(f"n_operators must be an integer >= 1, got {n_operators!r}")
    if n_operators < 1:
        raise ValueError(f"n_operators must be >= 1, got {n_operators}")
    theta = np.asarray(theta, dtype=float)
    single = theta.ndim == 1
    if theta.ndim not in (1, 2) or theta.shape[-1] != len(THETA_NAMES):
        raise ValueError(f"theta must have shape (19,) or (W, 19) in Table 1 order, got shape {theta.shape}")
    theta2 = np.ascontiguousarray(np.atleast_2d(theta))
    if theta2.shape[0] < 1:
        raise ValueError("theta has an empty batch axis (W = 0)")
    bad = ~np.isfinite(theta2)
    if bad.any():
        w, i = np.argwhere(bad)[0]
        where = f"theta[{w}, {i}]" if not single else f"theta[{i}]"
        raise ValueError(f"theta has a non-finite value at {where} ({THETA_NAMES[i]} = {theta2[w, i]})")

    current = np.asarray(current, dtype=float)
    if current.ndim not in (1, 2):
        raise ValueError(f"current must have shape (T,) or (W, T), got shape {current.shape}")
    current2 = np.ascontiguousarray(np.atleast_2d(current))
    if current2.shape[1] < 2:
        raise ValueError(f"current needs at least 2 samples, got {current2.shape[1]}")
    if current2.shape[0] not in (1, theta2.shape[0]):
        raise ValueError(
            f"current has {current2.shape[0]} rows but theta has {theta2.shape[0]}: a 2-D current needs one row per "
            "parameter set"
        )
    if current.ndim == 2:
        single = False
    _refuse_non_finite_current(current2, one_d=current.ndim == 1)

    z0 = _per_set(initial_memory, theta2.shape[0], "initial_memory")
    return theta2, current2, int(n_operators), READINGS[reading], z0, single


def _threshold_scale(threshold_scale, n_sets, n_samples):
    """``threshold_scale`` as the kernel takes it: ``(1, 1)`` for none, else ``(1 or W, T)``."""
    if threshold_scale is None:
        return np.ones((1, 1))
    scale = np.asarray(threshold_scale, dtype=float)
    scale2 = np.atleast_2d(scale)
    if scale.ndim not in (1, 2) or scale2.shape[1] != n_samples or scale2.shape[0] not in (1, n_sets):
        raise ValueError(
            f"threshold_scale must have shape ({n_samples},) or ({n_sets}, {n_samples}) (a factor per sample), "
            f"got shape {scale.shape}"
        )
    if not (np.isfinite(scale2).all() and (scale2 > 0).all()):
        raise ValueError("threshold_scale must be finite and > 0")
    if n_samples == 1:  # pragma: no cover - gpi needs 2 samples
        return np.ones((1, 1))
    return np.ascontiguousarray(scale2)


def gpi(
    theta,
    current,
    n_operators=12,
    reading="swapped",
    initial_memory=0.0,
    threshold_scale=None,
    initial_excursion=0.0,
    initial_held=0.0,
):
    """Generalized Prandtl-Ishlinskii response, eqs. (5)-(13), for one or many parameter sets.

    Defined for every finite parameter set (see "The whole domain" in the module
    docstring): operator bounds that cross are a property of ``theta``, not an error.

    Parameters
    ----------
    theta : array_like, shape (19,) or (W, 19)
        GPI parameters in Table 1's order (:data:`THETA_NAMES`). A 2-D ``theta`` is a
        batch, e.g. all emcee walkers (``vectorize=True``).
    current : array_like, shape (T,) or (W, T)
        Drive current [A], ``T >= 2`` samples. A 1-D input is shared by the whole batch;
        a 2-D input gives each parameter set its own (e.g. after a lag filter).
    n_operators : int, default 12
        Number of play operators ``N`` (the paper uses 12).
    reading : {"swapped", "literal"}, default "swapped"
        Which envelope the rising branch follows; see the module docstring.
    initial_memory : float or array_like of shape (W,), default 0.0
        The level :math:`z^0` each operator's memory starts from at ``t_0``;
        0 is the paper's state. Used by the ``initial_state`` effect.
    threshold_scale : array_like of shape (T,) or (W, T), optional
        A factor > 0 on every threshold at each sample: the play width in force there
        (``training``'s virgin width fading with the travel). The initial memory is
        clamped with the thresholds of eq. (8) (the state the record starts from is
        ``initial_memory``'s, not re-clamped by the width; the first factor is not used).
        None: the thresholds of eq. (8) throughout.
    initial_excursion : float or array_like of shape (W,), default 0.0
        The last reversal before ``t_0`` [A, drive units]: before the record the drive went
        from :math:`v_0` to :math:`v_0 + e` and back, and the memory clamped from
        ``initial_memory`` followed it (the operators narrower than about half the
        excursion keep its trace). 0: no excursion (the memory is the clamped level).
        Used by the ``initial_state`` effect.
    initial_held : float or array_like of shape (N,) or (W, N), default 0.0
        Memory held beyond the bounds at ``t_0`` [A, envelope units], operator by operator:
        added to the memory after the clamp and the excursion, not clamped (a state the
        drive cannot leave, from another history: a pre-strain at mounting, another
        temperature). The play law keeps it until the first motion against it. 0: none
        (the paper). Used by the ``initial_state`` effect.

    Returns
    -------
    y : ndarray, shape (T,) or (W, T)
        Displacement [um]; 1-D when ``theta`` and ``current`` are both 1-D.

    Raises
    ------
    ValueError
        Malformed input only: non-finite or wrongly shaped ``theta``/``current``/
        ``initial_memory``/``initial_excursion``/``initial_held``, fewer than 2 samples,
        ``n_operators < 1``, an unknown reading.
    """
    theta2, current2, n_operators, rising_is_a, z0, single = _prepare(
        theta, current, n_operators, reading, initial_memory
    )
    excursion = _per_set(initial_excursion, theta2.shape[0], "initial_excursion")
    held = _held(initial_held, theta2.shape[0], n_operators)
    scale = _threshold_scale(threshold_scale, theta2.shape[0], current2.shape[1])
    if scale.shape[0] > 1:
        single = False
    n_sets = theta2.shape[0]
    row_of = np.zeros(n_sets, dtype=np.int64) if current2.shape[0] == 1 else np.arange(n_sets, dtype=np.int64)
    scale_of = np.zeros(n_sets, dtype=np.int64) if scale.shape[0] == 1 else np.arange(n_sets, dtype=np.int64)
    out, inverse = gpi_rows(theta2, current2, row_of, n_operators, rising_is_a, z0, excursion, scale, scale_of, held)
    if single:
        return out[0]
    return out if out.shape[0] == n_sets else out[inverse]


# the one-set batch's plan, passed only to the kernel, which reads them (numba types a
# read-only array apart, so they are not flagged read-only); never returned to a caller
_ONE_ROW = np.zeros(1, dtype=np.int64)
_NO_SLOT = np.full(1, -1, dtype=np.int64)
_NO_ROWS = np.zeros(0, dtype=np.int64)
_NO_SUMS = np.empty((0, 1))


def distinct_rows(*columns):
    """The distinct rows of a batch, by their values bit for bit.

    Parameters
    ----------
    *columns : array_like, each of shape (W,) or (W, k)
        The batch's columns (cast to float).

    Returns
    -------
    first : ndarray of int, shape (U,)
        The first row of each distinct row, in the order they first appear.
    group : ndarray of int, shape (W,)
        Which of them each row is (``first[group[w]]`` holds the same values as ``w``).
    """
    n_rows = len(columns[0])
    if n_rows == 1:
        return np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64)
    table = np.ascontiguousarray(np.column_stack([np.asarray(c, dtype=float) for c in columns]))
    keys = table.view(np.dtype((np.void, table.dtype.itemsize * table.shape[1]))).ravel().tolist()
    seen: dict = {}
    group = np.fromiter((seen.setdefault(key, len(seen)) for key in keys), dtype=np.int64, count=n_rows)
    first = np.full(len(seen), n_rows, dtype=np.int64)
    np.minimum.at(first, group, np.arange(n_rows))
    return first, group


def gpi_rows(
    theta,
    current,
    row_of,
    n_operators,
    rising_is_a,
    initial_memory,
    initial_excursion,
    threshold_scale,
    scale_of,
    initial_held=_NO_HELD,
):
    """The kernel on a prepared batch: each distinct parameter set once.

    ``theta`` (W, 19), ``initial_memory`` and ``initial_excursion`` (W,), ``initial_held``
    (W, N) or (1, 1) for none, as :func:`gpi` validates them; set ``w`` reads input row ``current[row_of[w]]`` (of an
    ``(R, T)`` array) and width row ``threshold_scale[scale_of[w]]`` (of an ``(S, T)``
    array, or ``(1, 1)`` for none).

    Sets that are the same in every input are computed once; sets that differ from
    another only in Omega's parameters share its memories (:func:`model.gpi_kernels.gpi_kernel`). Both are
    exact: each row is the one its set gives alone.

    Returns
    -------
    out : ndarray, shape (U, T)
        The response of each distinct set, in the order they first appear.
    inverse : ndarray of int, shape (W,)
        The row of ``out`` of each set.
    """
    n_samples = current.shape[1]
    if theta.shape[0] == 1:  # one set: a leader without followers
        out = np.empty((1, n_samples))
        gpi_kernel(
            kernel_array(theta),
            kernel_array(current),
            kernel_array(row_of),
            n_operators,
            rising_is_a,
            kernel_array(initial_memory),
            kernel_array(initial_excursion),
            kernel_array(initial_held),
            kernel_array(threshold_scale),
            kernel_array(scale_of),
            _ONE_ROW,
            _NO_SLOT,
            _NO_ROWS,
            _ONE_ROW,
            _NO_SUMS,
            out,
        )
        return out, np.zeros(1, dtype=np.int64)
    held_columns = (initial_held,) if initial_held.shape[1] > 1 else ()
    unique, inverse = distinct_rows(theta, row_of, initial_memory, initial_excursion, scale_of, *held_columns)
    play_first, play_group = distinct_rows(
        theta[unique, :11],
        row_of[unique],
        initial_memory[unique],
        initial_excursion[unique],
        scale_of[unique],
        *(held[unique] for held in held_columns),
    )
    leader_of = play_first[play_group]  # the first distinct set with the same memories
    is_leader = leader_of == np.arange(unique.size)
    leaders = np.flatnonzero(is_leader)
    followers = np.flatnonzero(~is_leader)
    slot = np.full(unique.size, -1, dtype=np.int64)
    shared = np.unique(leader_of[followers])
    slot[shared] = np.arange(shared.size)
    sums = np.empty((shared.size, n_samples))
    out = np.empty((unique.size, n_samples))
    gpi_kernel(
        kernel_array(theta[unique]),
        kernel_array(current),
        kernel_array(row_of[unique]),
        n_operators,
        rising_is_a,
        kernel_array(initial_memory[unique]),
        kernel_array(initial_excursion[unique]),
        kernel_array(initial_held[unique] if held_columns else initial_held),
        kernel_array(threshold_scale),
        kernel_array(scale_of[unique]),
        leaders,
        slot,
        followers,
        kernel_array(leader_of),
        sums,
        out,
    )
    return out, inverse


def gpi_grouped(
    theta,
    current,
    row_of,
    n_operators=12,
    reading="swapped",
    initial_memory=0.0,
    threshold_scale=None,
    initial_excursion=0.0,
    initial_held=0.0,
):
    """:func:`gpi` for a batch whose parameter sets share input rows, without copying them per set.

    Parameters
    ----------
    theta : array_like, shape (W, 19)
    current : array_like, shape (R, T)
        The distinct drives [A].
    row_of : array_like of int, shape (W,)
        The drive (and width) row of each set, in ``0 .. R-1``.
    n_operators, reading, initial_memory, initial_excursion, initial_held
        As :func:`gpi`.
    threshold_scale : array_like of shape (R, T), optional
        The width rows, indexed by ``row_of`` too.

    Returns
    -------
    out : ndarray, shape (U, T)
        The response of each distinct parameter set (:func:`gpi_rows`).
    inverse : ndarray of int, shape (W,)
        The row of ``out`` of each set: ``out[inverse]`` is :func:`gpi`'s output.
    """
    theta2, _, n_operators, rising_is_a, z0, _ = _prepare(theta, np.zeros(2), n_operators, reading, initial_memory)
    n_sets = theta2.shape[0]
    current2 = np.ascontiguousarray(np.atleast_2d(np.asarray(current, dtype=float)))
    row_of = np.asarray(row_of, dtype=np.int64)
    if current2.ndim != 2 or current2.shape[1] < 2:
        raise ValueError(f"current must have shape (R, T) with T >= 2, got shape {np.shape(current)}")
    if row_of.shape != (n_sets,) or (row_of < 0).any() or (row_of >= current2.shape[0]).any():
        raise ValueError(f"row_of must have shape ({n_sets},) with values in 0..{current2.shape[0] - 1}")
    _refuse_non_finite_current(current2, one_d=False)
    excursion = _per_set(initial_excursion, n_sets, "initial_excursion")
    held = _held(initial_held, n_sets, n_operators)
    if threshold_scale is None:
        scale, scale_of = np.ones((1, 1)), np.zeros(n_sets, dtype=np.int64)
    else:
        scale = _threshold_scale(threshold_scale, current2.shape[0], current2.shape[1])
        scale_of = row_of if scale.shape[0] > 1 else np.zeros(n_sets, dtype=np.int64)
    return gpi_rows(theta2, current2, row_of, n_operators, rising_is_a, z0, excursion, scale, scale_of, held)


def bound_overlap(theta, current, n_operators=12, reading="swapped"):
    """How far the operator bounds cross on ``current``: ``max_k (rising(v_k) - falling(v_k)) - 2 min_j r_j``.

    Negative: every operator is a clamp ``max(L, min(U, z))`` on this input (its lower
    bound ``rising - r_j`` stays below its upper bound ``falling + r_j``); positive: the
    bounds of at least one operator cross by that much [input unit], and eq. (5) then
    drops an operator's memory by the overlap at a reversal. A descriptive property of a
    parameter set (the model is defined either way).

    Parameters
    ----------
    theta : array_like, shape (19,) or (W, 19)
    current : array_like, shape (T,)
    n_operators : int, default 12
    reading : {"swapped", "literal"}, default "swapped"

    Returns
    -------
    float or ndarray of shape (W,)
    """
    theta2, current2, n_operators, rising_is_a, _, single = _prepare(theta, current, n_operators, reading, 0.0)
    if current2.shape[0] != 1:
        raise ValueError("bound_overlap takes a 1-D current shared by the batch")
    a, b = theta2[:, 3:7], theta2[:, 7:11]
    rising, falling = (a, b) if rising_is_a else (b, a)
    v = current2[0][None, :]
    gap = np.max(envelope(rising[:, None, :], v) - envelope(falling[:, None, :], v), axis=1)
    thresholds = theta2[:, :1] * np.arange(1, n_operators + 1)[None, :]
    out = gap - 2.0 * thresholds.min(axis=1)
    return float(out[0]) if single else out


def classical_pi(current, thresholds, weights, linear_gain=0.0, initial=0.0):
    """Classical Prandtl-Ishlinskii model, eqs. (1)-(4), discretised as a sum of plays.

    .. math::  F_{r}[v](t_k) = \\max(v_k - r, \\min(v_k + r, F_r(t_{k-1}))), \\qquad
               y_k = q\\, v_k + \\sum_j p_j F_{r_j}[v](t_k)

    Parameters
    ----------
    current : array_like, shape (T,)
        Input, ``T >= 2`` samples.
    thresholds : array_like, shape (N,)
        Play thresholds ``r_j >= 0``.
    weights : array_like, shape (N,)
        Density weights ``p_j``.
    linear_gain : float, default 0
        ``q``: the linear term :math:`\\omega(v) = q v` of eq. (4).
    initial : float or array_like of shape (N,), default 0
        Initial play outputs (clamped into ``[v_0 - r, v_0 + r]``).

    Returns
    -------
    y : ndarray, shape (T,)
    """
    v = np.asarray(current, dtype=float)
    r = np.asarray(thresholds, dtype=float)
    p = np.asarray(weights, dtype=float)
    if v.ndim != 1 or v.size < 2:
        raise ValueError(f"current must have shape (T,) with T >= 2, got shape {v.shape}")
    if r.ndim != 1 or r.shape != p.shape or r.size < 1:
        raise ValueError(f"thresholds and weights must both have shape (N,), N >= 1; got {r.shape} and {p.shape}")
    if (r < 0).any():
        raise ValueError("classical PI thresholds must be >= 0")
    for name, arr in (("current", v), ("thresholds", r), ("weights", p)):
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} has a non-finite value at index {int(np.flatnonzero(~np.isfinite(arr))[0])}")
    z0 = np.broadcast_to(np.asarray(initial, dtype=float), r.shape)  # the kernel call makes it contiguous and writeable
    plays = np.empty((v.size, r.size))
    play_kernel(kernel_array(v), kernel_array(r), kernel_array(z0), plays)
    return float(linear_gain) * v + plays @ p
