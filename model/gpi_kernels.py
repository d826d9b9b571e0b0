"""The GPI's numba kernels: the compiled loops behind :mod:`model.gpi`'s public face.

What is here, and nothing else:

- :func:`fast_tanh`, the branch-free ``tanh`` within 4 ulp of libm's that lets the
  per-sample loops vectorise, and the envelope form ``k0 tanh(k1 v + k2) + k3`` built on it;
- :func:`operator_thresholds_and_weights` (eqs. (8)-(9)) and :func:`initial_operator_memory`
  (eq. (8) and a prior excursion), shared with the inverse (:mod:`model.inverse_step`,
  :mod:`model.inverse_search`);
- :func:`gpi_kernel`, eq. (5) for a batch of parameter sets, parallel over the batch, with
  its helpers (the branch values, the input's directions, the weighted memory sum);
- :func:`play_kernel`, the classical Prandtl-Ishlinskii plays of :func:`model.gpi.classical_pi`;
- :func:`kernel_array`, through which every kernel call of the model passes its arrays (one
  compiled version per kernel).

The equations, the readings and the conventions are stated in :mod:`model.gpi`'s docstring;
validation of the inputs and the batch plan (which sets share their memories) live there too.
Every function here takes arrays already checked and shaped by its caller.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, types
from numba.extending import intrinsic

__all__ = [
    "fast_tanh",
    "operator_thresholds_and_weights",
    "initial_operator_memory",
    "gpi_kernel",
    "play_kernel",
    "kernel_array",
]


# exp(-y) = 2^-n exp(r) with n = round(y / ln 2) and r = n ln2 - y, |r| <= ln2 / 2; the
# split of ln 2 is fdlibm's (n * _LN2_HI is exact for n < 2048).
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e00
#: Beyond ``2|x| = 40`` tanh(x) is 1 - 8.5e-18, i.e. 1.0 in double precision.
_TANH_SATURATES = 40.0


@intrinsic
def _float_with_bits(typingctx, bits):
    """The float64 whose IEEE 754 bits are the int64 ``bits`` (a bitcast: no arithmetic)."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))

    return types.float64(types.int64), codegen


@njit(cache=True, inline="always")
def _power_of_two(k):
    """``2.0 ** k`` exactly for an integer ``-1022 <= k <= 1023``: the exponent field ``k + 1023``
    and a zero mantissa, in two integer operations that vectorise (a loop of ``ldexp`` calls does
    not)."""
    return _float_with_bits((k + 1023) << 52)


@njit(cache=True, inline="always", error_model="numpy")
def fast_tanh(x):
    """``tanh(x)`` within 4 ulp of libm's, in straight-line arithmetic that LLVM vectorises.

    A loop of libm ``tanh`` or ``exp`` calls runs one value at a time (about 16 ns each on
    the 2-core benchmark machine); this form has no call, no table and no data-dependent
    branch, so a loop over samples runs 8 values per AVX-512 instruction (about 2.5 ns
    each). With ``y = min(2|x|, 40)`` and ``t = exp(-y) = s (1 + r q(r))``, where
    ``s = 2^-n`` is written as its exponent bits (exact) and ``q(r) = (e^r - 1)/r`` is its
    degree-12 Taylor polynomial (truncation 1.2e-17 relative on ``|r| <= ln2/2``),
    ``tanh|x| = (1 - t)/(1 + t)`` with ``1 - t = (1 - s) - s r q``: for ``n = 0`` this is
    ``-r q`` with no cancellation, so the relative accuracy holds near 0 too. The sign is
    restored last, so the result is odd. Callers must compile with
    ``error_model="numpy"`` (numba's Python error model puts a zero-division check on the
    division, which stops vectorisation).
    """
    y = min(2.0 * abs(x), _TANH_SATURATES)
    n = int(y * _INV_LN2 + 0.5)
    r = (n * _LN2_HI - y) + n * _LN2_LO
    q = 1.0 / 6227020800.0
    q = q * r + 1.0 / 479001600.0
    q = q * r + 1.0 / 39916800.0
    q = q * r + 1.0 / 3628800.0
    q = q * r + 1.0 / 362880.0
    q = q * r + 1.0 / 40320.0
    q = q * r + 1.0 / 5040.0
    q = q * r + 1.0 / 720.0
    q = q * r + 1.0 / 120.0
    q = q * r + 1.0 / 24.0
    q = q * r + 1.0 / 6.0
    q = q * r + 0.5
    q = q * r + 1.0
    s = _power_of_two(-n)  # exact
    srq = s * (r * q)
    magnitude = ((1.0 - s) - srq) / ((1.0 + s) + srq)
    return magnitude if x >= 0.0 else -magnitude


@njit(cache=True, inline="always", error_model="numpy")
def _tanh_env(k0, k1, k2, k3, v):
    return k0 * fast_tanh(k1 * v + k2) + k3


@njit(cache=True, inline="always")
def _weighted_sum(weights, memory):
    """``sum_j weights[j] * memory[j]`` in four interleaved partial sums (fixed order, so
    deterministic; four independent add chains instead of one long one)."""
    n = weights.shape[0]
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    j = 0
    while j + 4 <= n:
        s0 += weights[j] * memory[j]
        s1 += weights[j + 1] * memory[j + 1]
        s2 += weights[j + 2] * memory[j + 2]
        s3 += weights[j + 3] * memory[j + 3]
        j += 4
    while j < n:
        s0 += weights[j] * memory[j]
        j += 1
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, inline="always")
def operator_thresholds_and_weights(alpha, rho, tau, n_operators):
    """Thresholds ``r_j = alpha j`` and weights ``p_j = rho exp(-tau r_j)``, ``j = 1..N`` (eqs. (8)-(9))."""
    thresholds = np.empty(n_operators)
    weights = np.empty(n_operators)
    for j in range(n_operators):
        thresholds[j] = alpha * (j + 1)
        weights[j] = rho * np.exp(-tau * thresholds[j])
    return thresholds, weights


@njit(cache=True, error_model="numpy")
def _branch_values(
    current, rising, row, ru0, ru1, ru2, ru3, rd0, rd1, rd2, rd3, c0, c1, c2, c3, d0, d1, d2, d3, env, omega
):
    """Per sample ``k >= 1``: ``env[k]``, the envelope the input moves along (rising if
    ``dv > 0``, else falling; unused when ``dv = 0``), and ``omega[k]``, Omega's branch
    (``c`` where ``rising[row, k]``, the input last moved up: :func:`_directions`);
    ``omega[0]`` is the rising branch.

    Both are selected per sample with no branch, so this loop vectorises (see
    :func:`fast_tanh`); it holds all of the kernel's per-sample transcendental work.
    """
    n_samples = current.shape[1]
    omega[0] = _tanh_env(c0, c1, c2, c3, current[row, 0])
    env[0] = 0.0
    for k in range(1, n_samples):
        v = current[row, k]
        up = v - current[row, k - 1] > 0.0
        env[k] = _tanh_env(ru0 if up else rd0, ru1 if up else rd1, ru2 if up else rd2, ru3 if up else rd3, v)
        on_rising = rising[row, k] > 0
        omega[k] = _tanh_env(
            c0 if on_rising else d0, c1 if on_rising else d1, c2 if on_rising else d2, c3 if on_rising else d3, v
        )


@njit(cache=True)
def _directions(current):
    """``(direction, rising)``, each ``(R, T)`` int8, shared by every parameter set that reads
    row ``r``: ``direction`` +1 where ``current[r, k] > current[r, k-1]``, -1 where below, 0
    where equal (and at ``k = 0``): the branch each sample takes; ``rising`` 1 where the input
    last moved up (or has not moved yet), 0 where it last moved down: Omega's branch."""
    n_rows, n_samples = current.shape
    direction = np.zeros((n_rows, n_samples), dtype=np.int8)
    rising = np.ones((n_rows, n_samples), dtype=np.int8)
    for r in range(n_rows):
        for k in range(1, n_samples):
            dv = current[r, k] - current[r, k - 1]
            direction[r, k] = 1 if dv > 0.0 else (-1 if dv < 0.0 else 0)
            rising[r, k] = 1 if dv > 0.0 else (0 if dv < 0.0 else rising[r, k - 1])
    return direction, rising


@njit(cache=True, inline="always", error_model="numpy")
def initial_operator_memory(level, threshold, rising_env, falling_env, excursion, excursion_env):
    """One operator's memory at ``t_0``: clamped from ``level`` between its bounds at ``v_0``
    (eq. (8)), then carried along a prior excursion ``v_0 -> v_0 + e -> v_0`` by the play law.

    ``rising_env``, ``falling_env``: the envelopes at ``v_0``; ``excursion_env``: the rising
    envelope at ``v_0 + e`` for ``e > 0``, the falling one for ``e < 0`` (not read at 0).
    Shared by the forward kernel and the inverse's first step (:mod:`model.inverse_step`).
    """
    lower = rising_env - threshold
    upper = falling_env + threshold
    memory = max(lower, min(upper, level))
    if excursion > 0.0:
        memory = min(max(memory, excursion_env - threshold), upper)
    elif excursion < 0.0:
        memory = max(min(memory, excursion_env + threshold), lower)
    return memory


@njit(cache=True, error_model="numpy")
def _omega_values(current, rising, row, c0, c1, c2, c3, d0, d1, d2, d3, omega):
    """``omega`` of :func:`_branch_values` alone (the same expression, so the same bits):
    what a parameter set that shares its memories with another still computes."""
    n_samples = current.shape[1]
    omega[0] = _tanh_env(c0, c1, c2, c3, current[row, 0])
    for k in range(1, n_samples):
        v = current[row, k]
        on_rising = rising[row, k] > 0
        omega[k] = _tanh_env(
            c0 if on_rising else d0, c1 if on_rising else d1, c2 if on_rising else d2, c3 if on_rising else d3, v
        )


@njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def gpi_kernel(
    theta,
    current,
    row_of,
    n_operators,
    rising_is_a,
    initial_memory,
    initial_excursion,
    initial_held,
    threshold_scale,
    scale_of,
    leaders,
    slot,
    followers,
    leader_of,
    sums,
    out,
):
    """Fill ``out[w, :]`` with the GPI response of ``theta[w]``, eq. (5) for every parameter set.

    Parameter set ``w`` reads input row ``current[row_of[w]]`` and threshold-scale row
    ``threshold_scale[scale_of[w]]``.

    The sets split in two (:func:`model.gpi.gpi_rows`): each of ``leaders`` runs the recursion
    over its memories; each of ``followers`` differs from its leader ``leader_of[w]`` only
    in Omega's parameters (``c``, ``d``), so its memories are the leader's, sample for
    sample. A leader with followers stores in ``sums[slot[w]]`` the weighted memory sum it
    adds to Omega at every sample; a follower evaluates its own Omega and adds that sum:
    the same additions on the same values, so its output is the one its own recursion
    would give, bit for bit (tested), at the cost of one tanh per sample instead of two
    and no recursion. Finite-difference Jacobians perturb each Omega parameter alone.

    Two passes per leader: :func:`_branch_values` evaluates, for every sample, the
    envelope the input moves along and Omega's branch (vectorised over samples); the
    recursion then updates the ``N`` memories and sums them. A sample equal to its
    predecessor repeats the previous output (memory and Omega's branch are unchanged),
    exactly.

    The recursion reads each sample's direction from :func:`_directions` (computed once
    per input row) and updates each memory and adds its weighted value in the same loop,
    four operators at a time into the four partial sums of :func:`_weighted_sum` (the
    same additions in the same order: the output is that of a separate update and sum,
    bit for bit, at about half the cost).

    ``threshold_scale`` of shape ``(1, 1)`` leaves the thresholds as they are; of shape
    ``(S, T)`` it scales every threshold at each sample (a time-varying play
    width: the thresholds used by the update at sample ``k >= 1`` are ``r_j s_k``; the
    initial memory is clamped with those of eq. (8)).

    ``initial_excursion[w]`` (:math:`e`, 0: none) is the last reversal before ``t_0``: the
    clamped memory is carried along the input path :math:`v_0 \to v_0 + e \to v_0` by
    the play law (one rising then one falling update for :math:`e > 0`, the mirror for
    :math:`e < 0`; exact for the monotone tanh envelopes, whose extreme on the path lies
    at an end).

    ``initial_held[w, j]`` is added to operator ``j``'s memory after the clamp and the
    excursion (a memory held beyond the bounds; ``initial_held`` of shape ``(1, 1)``: none,
    read as 0 for every set).
    """
    n_samples = current.shape[1]
    held = initial_held.shape[1] > 1
    scaled = threshold_scale.shape[1] > 1
    directions, rising = _directions(current)
    for i in prange(leaders.shape[0]):
        w = leaders[i]
        row = row_of[w]
        store = slot[w]
        th = theta[w]
        alpha = th[0]
        rho = th[1]
        tau = th[2]
        if rising_is_a:
            ru0, ru1, ru2, ru3 = th[3], th[4], th[5], th[6]
            rd0, rd1, rd2, rd3 = th[7], th[8], th[9], th[10]
        else:
            ru0, ru1, ru2, ru3 = th[7], th[8], th[9], th[10]
            rd0, rd1, rd2, rd3 = th[3], th[4], th[5], th[6]
        c0, c1, c2, c3 = th[11], th[12], th[13], th[14]
        d0, d1, d2, d3 = th[15], th[16], th[17], th[18]

        base_thresholds, weights = operator_thresholds_and_weights(alpha, rho, tau, n_operators)
        thresholds = base_thresholds.copy()  # those in force at the present sample
        scale_row = scale_of[w]
        memory = np.empty(n_operators)
        # operators summed four at a time (set here: hoisted out of the prange loop it cost 25 %)
        n4 = n_operators - n_operators % 4

        env = np.empty(n_samples)
        omega = np.empty(n_samples)
        _branch_values(
            current, rising, row, ru0, ru1, ru2, ru3, rd0, rd1, rd2, rd3, c0, c1, c2, c3, d0, d1, d2, d3, env, omega
        )

        v = current[row, 0]
        rising_env = _tanh_env(ru0, ru1, ru2, ru3, v)
        falling_env = _tanh_env(rd0, rd1, rd2, rd3, v)
        excursion = initial_excursion[w]
        excursion_env = 0.0
        if excursion > 0.0:
            excursion_env = _tanh_env(ru0, ru1, ru2, ru3, v + excursion)
        elif excursion < 0.0:
            excursion_env = _tanh_env(rd0, rd1, rd2, rd3, v + excursion)
        for j in range(n_operators):
            memory[j] = initial_operator_memory(
                initial_memory[w], thresholds[j], rising_env, falling_env, excursion, excursion_env
            )
            if held:
                memory[j] += initial_held[w, j]
        total = _weighted_sum(weights, memory)
        if store >= 0:
            sums[store, 0] = total
        out[w, 0] = omega[0] + total

        for k in range(1, n_samples):
            d = directions[row, k]
            if d == 0:  # a still input: memories and Omega's branch as at the sample before
                out[w, k] = out[w, k - 1]
                continue
            moving_env = env[k]
            if scaled:
                for j in range(n_operators):
                    thresholds[j] = base_thresholds[j] * threshold_scale[scale_row, k]
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            s3 = 0.0
            if d > 0:
                for j in range(0, n4, 4):
                    m0 = max(memory[j], moving_env - thresholds[j])
                    m1 = max(memory[j + 1], moving_env - thresholds[j + 1])
                    m2 = max(memory[j + 2], moving_env - thresholds[j + 2])
                    m3 = max(memory[j + 3], moving_env - thresholds[j + 3])
                    memory[j] = m0
                    memory[j + 1] = m1
                    memory[j + 2] = m2
                    memory[j + 3] = m3
                    s0 += weights[j] * m0
                    s1 += weights[j + 1] * m1
                    s2 += weights[j + 2] * m2
                    s3 += weights[j + 3] * m3
                for j in range(n4, n_operators):
                    m0 = max(memory[j], moving_env - thresholds[j])
                    memory[j] = m0
                    s0 += weights[j] * m0
            else:
                for j in range(0, n4, 4):
                    m0 = min(memory[j], moving_env + thresholds[j])
                    m1 = min(memory[j + 1], moving_env + thresholds[j + 1])
                    m2 = min(memory[j + 2], moving_env + thresholds[j + 2])
                    m3 = min(memory[j + 3], moving_env + thresholds[j + 3])
                    memory[j] = m0
                    memory[j + 1] = m1
                    memory[j + 2] = m2
                    memory[j + 3] = m3
                    s0 += weights[j] * m0
                    s1 += weights[j + 1] * m1
                    s2 += weights[j + 2] * m2
                    s3 += weights[j + 3] * m3
                for j in range(n4, n_operators):
                    m0 = min(memory[j], moving_env + thresholds[j])
                    memory[j] = m0
                    s0 += weights[j] * m0
            total = (s0 + s1) + (s2 + s3)
            if store >= 0:
                sums[store, k] = total
            out[w, k] = omega[k] + total

    for i in range(followers.shape[0]):  # serial: a second parallel region costs a thread wake-up per call
        w = followers[i]
        row = row_of[w]
        source = slot[leader_of[w]]
        th = theta[w]
        omega = np.empty(n_samples)
        _omega_values(current, rising, row, th[11], th[12], th[13], th[14], th[15], th[16], th[17], th[18], omega)
        out[w, 0] = omega[0] + sums[source, 0]
        for k in range(1, n_samples):
            if directions[row, k] == 0:
                out[w, k] = out[w, k - 1]
                continue
            out[w, k] = omega[k] + sums[source, k]


def kernel_array(values):
    """``values`` as a C-contiguous, writeable ndarray of its own dtype (a copy only where
    it is neither).

    numba compiles one version of a kernel per type of its arguments, and a read-only array
    (a ``broadcast_to`` view, which ``ascontiguousarray`` passes through unchanged when the
    shapes already match) is another type than a writeable one: every kernel call passes
    its arrays through here, so each kernel is compiled once, not once per mix of read-only
    arguments (the GPI's parallel kernel had been compiled in ten versions by the tests).
    The values are the same, so are the results.
    """
    array = np.asarray(values)
    if array.flags.c_contiguous and array.flags.writeable:
        return array
    return np.array(array, order="C")


@njit(cache=True)
def play_kernel(current, thresholds, initial, out):
    n_ops = thresholds.shape[0]
    memory = np.empty(n_ops)
    for j in range(n_ops):
        memory[j] = max(current[0] - thresholds[j], min(current[0] + thresholds[j], initial[j]))
        out[0, j] = memory[j]
    for k in range(1, current.shape[0]):
        v = current[k]
        for j in range(n_ops):
            memory[j] = max(v - thresholds[j], min(v + thresholds[j], memory[j]))
            out[k, j] = memory[j]
