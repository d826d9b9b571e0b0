r"""Slow, obviously correct scalar oracles for the GPI (eqs. (5)-(13)) and the classical PI (eqs. (1)-(4)).

Plain Python: one loop over time, one over operators, :mod:`math` scalars, no numpy.
Each line follows the equations as :mod:`model.gpi`'s docstring states them, so the
fast numba kernel can be checked against it sample by sample.

GPI, for one parameter set ``theta`` (Table 1 order) and input samples ``v_0 .. v_{T-1}``:

* envelopes ``gamma_a(v) = a0 tanh(a1 v + a2) + a3`` (eq. 6), ``gamma_b`` likewise with
  ``b`` (eq. 7); reading ``"swapped"``: rising = ``gamma_a``, falling = ``gamma_b``;
  reading ``"literal"``: rising = ``gamma_b``, falling = ``gamma_a``;
* ``r_j = alpha * j`` and ``p_j = rho * exp(-tau * r_j)`` for ``j = 1 .. N`` (eqs. 8-10);
* lower bound ``L_j(v) = rising(v) - r_j``, upper bound ``U_j(v) = falling(v) + r_j``;
* initial memory ``z_j(t_0) = max(L_j(v_0), min(U_j(v_0), z0))``;
* eq. (5) for ``k >= 1``: ``max(L_j(v_k), z)`` if ``v_k > v_{k-1}``, ``min(U_j(v_k), z)``
  if ``v_k < v_{k-1}``, else ``z`` unchanged (``law="piecewise"``); or the clamp form
  ``max(L_j(v_k), min(U_j(v_k), z))`` at every sample (``law="clamp"``);
* ``Omega_k`` = c-branch of eq. (13) where the input last moved up (``v_k > v_{k-1}``, or it
  is still and last moved up, or has not moved yet), else the d-branch;
* ``y_k = Omega_k + sum_j p_j z_j(t_k)`` (eq. 12).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ReferenceGPI", "gpi_reference", "classical_pi_reference", "LAWS"]

#: Operator update laws the oracle knows: eq. (5) as printed, and the clamp form.
LAWS = ("piecewise", "clamp")


@dataclass(frozen=True)
class ReferenceGPI:
    """Everything the oracle computed for one parameter set.

    Attributes
    ----------
    output : list of float, length T
        ``y_k`` [um].
    omega : list of float, length T
        ``Omega_k`` [um], eq. (13).
    memory : list of list of float, T x N
        ``z_j(t_k)``: ``memory[k][j - 1]``.
    lower, upper : list of list of float, T x N
        ``L_j(v_k)`` and ``U_j(v_k)``.
    weights : list of float, length N
        ``p_j``.
    bounds_cross : bool
        True when ``L_j(v_k) > U_j(v_k)`` for some sample and operator.
    """

    output: list
    omega: list
    memory: list
    lower: list
    upper: list
    weights: list
    bounds_cross: bool


def _tanh_form(k0, k1, k2, k3, v):
    return k0 * math.tanh(k1 * v + k2) + k3


def gpi_reference(
    theta,
    current,
    n_operators=12,
    reading="swapped",
    initial_memory=0.0,
    law="piecewise",
    threshold_scale=None,
    initial_held=None,
):
    """The GPI response of one parameter set, computed the slow and plain way.

    Parameters
    ----------
    theta : sequence of float, length 19
        Table 1 order: alpha, rho, tau, a0..a3, b0..b3, c0..c3, d0..d3.
    current : sequence of float, length T >= 1
        Input samples [A].
    n_operators : int, default 12
    reading : {"swapped", "literal"}, default "swapped"
    initial_memory : float, default 0.0
        ``z0``, clamped into ``[L_j(v_0), U_j(v_0)]``.
    law : {"piecewise", "clamp"}, default "piecewise"
    threshold_scale : sequence of float, length T, optional
        Factor on every threshold at each sample after the first (the initial memory is
        clamped with the thresholds of eq. (8); the weights stay those of eq. (8)).
    initial_held : sequence of float, length ``n_operators``, optional
        Added to each operator's clamped initial memory (not clamped).

    Returns
    -------
    ReferenceGPI
    """
    if law not in LAWS:
        raise ValueError(f"law must be one of {LAWS}, got {law!r}")
    theta = [float(x) for x in theta]
    current = [float(x) for x in current]
    alpha, rho, tau = theta[0], theta[1], theta[2]
    a = theta[3:7]
    b = theta[7:11]
    c = theta[11:15]
    d = theta[15:19]
    if reading == "swapped":
        rising_coefficients, falling_coefficients = a, b
    elif reading == "literal":
        rising_coefficients, falling_coefficients = b, a
    else:
        raise ValueError(f"unknown reading {reading!r}")

    thresholds = [alpha * j for j in range(1, n_operators + 1)]
    weights = [rho * math.exp(-tau * r) for r in thresholds]

    output, omega, memory, lower, upper = [], [], [], [], []
    bounds_cross = False
    z = [0.0] * n_operators
    for k, v in enumerate(current):
        rising = _tanh_form(*rising_coefficients, v)
        falling = _tanh_form(*falling_coefficients, v)
        factor = 1.0 if threshold_scale is None or k == 0 else float(threshold_scale[k])
        lower_k = [rising - r * factor for r in thresholds]
        upper_k = [falling + r * factor for r in thresholds]
        for j in range(n_operators):
            if lower_k[j] > upper_k[j]:
                bounds_cross = True

        if k == 0:
            for j in range(n_operators):
                z[j] = max(lower_k[j], min(upper_k[j], float(initial_memory)))
                if initial_held is not None:
                    z[j] += float(initial_held[j])
            omega_k = _tanh_form(*c, v)
            on_rising = True
        else:
            v_previous = current[k - 1]
            for j in range(n_operators):
                if law == "clamp":
                    z[j] = max(lower_k[j], min(upper_k[j], z[j]))
                elif v > v_previous:
                    z[j] = max(lower_k[j], z[j])
                elif v < v_previous:
                    z[j] = min(upper_k[j], z[j])
                # v == v_previous: memory unchanged
            if v != v_previous:
                on_rising = v > v_previous  # a still input keeps the branch of its last motion
            omega_k = _tanh_form(*(c if on_rising else d), v)

        y = omega_k
        for j in range(n_operators):
            y += weights[j] * z[j]
        output.append(y)
        omega.append(omega_k)
        memory.append(list(z))
        lower.append(lower_k)
        upper.append(upper_k)

    return ReferenceGPI(output, omega, memory, lower, upper, weights, bounds_cross)


def classical_pi_reference(current, thresholds, weights, linear_gain=0.0, initial=0.0):
    """Classical PI, eqs. (1)-(4), with the play operator in the piecewise form of eq. (1).

    ``F_r(t_0) = max(v_0 - r, min(v_0 + r, initial))``; for ``k >= 1``:
    ``max(v_k - r, F)`` if the input rose, ``min(v_k + r, F)`` if it fell, else ``F``.
    ``y_k = linear_gain * v_k + sum_j p_j F_{r_j}(t_k)``.

    Parameters
    ----------
    current : sequence of float, length T
    thresholds, weights : sequence of float, length N
    linear_gain : float, default 0
    initial : float, default 0

    Returns
    -------
    list of float, length T
    """
    current = [float(x) for x in current]
    thresholds = [float(x) for x in thresholds]
    weights = [float(x) for x in weights]
    plays = [max(current[0] - r, min(current[0] + r, float(initial))) for r in thresholds]
    output = []
    for k, v in enumerate(current):
        if k > 0:
            for j, r in enumerate(thresholds):
                if v > current[k - 1]:
                    plays[j] = max(v - r, plays[j])
                elif v < current[k - 1]:
                    plays[j] = min(v + r, plays[j])
        y = linear_gain * v
        for j in range(len(thresholds)):
            y += weights[j] * plays[j]
        output.append(y)
    return output
