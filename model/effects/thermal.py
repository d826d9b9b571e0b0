"""``thermal`` (output stage): Joule heating of the coil and the sample with its core, a two-node network.

Holds :class:`Thermal` (with its mirror symmetry, :meth:`Thermal.swap_nodes`), its kernel
(both nodes' filters, tabulated per distinct sample step, four parameter sets in lockstep),
:func:`thermal_rise` and :data:`REFERENCE_CURRENT`.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..gpi_kernels import kernel_array
from ..parameters import Parameter, ParameterSet
from ._filters import MAX_DISTINCT_STEPS, distinct_steps, first_order_lowpass, lowpass_step, lowpass_table
from .base import Effect

__all__ = ["Thermal", "thermal_rise", "REFERENCE_CURRENT"]

#: Current [A] at which the normalised heating (i / i_ref)^2 is 1: the paper's 5 A excitation.
REFERENCE_CURRENT = 5.0


@njit(cache=True, inline="always")
def _thermal_output(y, s, e, s2, e2, rise, rise2, second):
    """The displacement ``y`` with the network's effect at the nodes' rises (node 2 only where
    ``second``: its gains are not both 0), the kernels' one formula."""
    if second:
        return y * (1.0 - s * rise - s2 * rise2) + e * rise + e2 * rise2
    return y * (1.0 - s * rise) + e * rise


@njit(cache=True, inline="always")
def _tabulated_step(rise, x_prev, x_now, gain, decay):
    """One node's rise one sample on, its input going from ``x_prev`` to ``x_now``, with the
    step's tabulated coefficients (:func:`lowpass_table`): every kernel's one formula."""
    return x_now - (x_now - x_prev) * gain + decay * (rise - x_prev)


@njit(cache=True, inline="always")
def _thermal_lane(rise, rise2, x_prev, x_now, gain1, decay1, gain2, decay2, y, s, e, s2, e2):
    """One sample of one parameter set of :func:`_thermal_kernel` (both nodes, tabulated
    coefficients): ``(rise, rise2, output)``, the kernel's operations in its order."""
    previous = rise
    rise = _tabulated_step(rise, x_prev, x_now, gain1, decay1)
    rise2 = _tabulated_step(rise2, previous, rise, gain2, decay2)
    return rise, rise2, _thermal_output(y, s, e, s2, e2, rise, rise2, True)


@njit(cache=True)
def _lane_tables(w0, steps, p, column):
    """``(decay, gain)``, each ``(4, n_steps)``: the tabulated coefficients of the node whose
    time constant is ``p[w, column]``, for the four sets ``w0 .. w0 + 3``."""
    decay = np.empty((4, steps.shape[0]))
    gain = np.empty((4, steps.shape[0]))
    for lane in range(4):
        lowpass_table(steps, p[w0 + lane, column], decay[lane], gain[lane])
    return decay, gain


@njit(cache=True)
def _first_outputs(w0, p, displacement, out, second):
    """The four sets' outputs at the first sample, from their start rises."""
    for w in range(w0, w0 + 4):
        out[w, 0] = _thermal_output(displacement[w, 0], p[w, 1], p[w, 2], p[w, 4], p[w, 5], p[w, 6], p[w, 7], second)


@njit(cache=True)
def _thermal_four(w0, index, steps, heating, p, displacement, out):
    """Parameter sets ``w0 .. w0 + 3`` of :func:`_thermal_kernel` in lockstep (both nodes,
    tabulated): four independent recursions interleaved, so one's latency hides behind the
    others'; each set's operations are those of :func:`_thermal_one`, bit for bit."""
    n_samples = displacement.shape[1]
    a1, g1 = _lane_tables(w0, steps, p, 0)
    a2, g2 = _lane_tables(w0, steps, p, 3)
    w1, w2, w3 = w0 + 1, w0 + 2, w0 + 3
    s0, s1, s2, s3 = p[w0, 1], p[w1, 1], p[w2, 1], p[w3, 1]
    e0, e1, e2, e3 = p[w0, 2], p[w1, 2], p[w2, 2], p[w3, 2]
    t0, t1, t2, t3 = p[w0, 4], p[w1, 4], p[w2, 4], p[w3, 4]
    f0, f1, f2, f3 = p[w0, 5], p[w1, 5], p[w2, 5], p[w3, 5]
    _first_outputs(w0, p, displacement, out, True)
    r0, r1, r2, r3 = p[w0, 6], p[w1, 6], p[w2, 6], p[w3, 6]
    q0, q1, q2, q3 = p[w0, 7], p[w1, 7], p[w2, 7], p[w3, 7]
    for k in range(1, n_samples):
        m = index[k]
        x_prev = heating[k - 1]
        x_now = heating[k]
        r0, q0, y0 = _thermal_lane(
            r0, q0, x_prev, x_now, g1[0, m], a1[0, m], g2[0, m], a2[0, m], displacement[w0, k], s0, e0, t0, f0
        )
        r1, q1, y1 = _thermal_lane(
            r1, q1, x_prev, x_now, g1[1, m], a1[1, m], g2[1, m], a2[1, m], displacement[w1, k], s1, e1, t1, f1
        )
        r2, q2, y2 = _thermal_lane(
            r2, q2, x_prev, x_now, g1[2, m], a1[2, m], g2[2, m], a2[2, m], displacement[w2, k], s2, e2, t2, f2
        )
        r3, q3, y3 = _thermal_lane(
            r3, q3, x_prev, x_now, g1[3, m], a1[3, m], g2[3, m], a2[3, m], displacement[w3, k], s3, e3, t3, f3
        )
        out[w0, k] = y0
        out[w1, k] = y1
        out[w2, k] = y2
        out[w3, k] = y3


@njit(cache=True)
def _thermal_four_first(w0, index, steps, heating, p, displacement, out):
    """:func:`_thermal_four` for four sets whose node 2 is off (both its gains 0: the study's
    usual case, the core node pinned off): node 1 only, bit for bit :func:`_thermal_one`'s
    operations for each set."""
    n_samples = displacement.shape[1]
    a1, g1 = _lane_tables(w0, steps, p, 0)
    w1, w2, w3 = w0 + 1, w0 + 2, w0 + 3
    s0, s1, s2, s3 = p[w0, 1], p[w1, 1], p[w2, 1], p[w3, 1]
    e0, e1, e2, e3 = p[w0, 2], p[w1, 2], p[w2, 2], p[w3, 2]
    r0, r1, r2, r3 = p[w0, 6], p[w1, 6], p[w2, 6], p[w3, 6]
    _first_outputs(w0, p, displacement, out, False)
    for k in range(1, n_samples):
        m = index[k]
        x_prev = heating[k - 1]
        x_now = heating[k]
        r0 = _tabulated_step(r0, x_prev, x_now, g1[0, m], a1[0, m])
        r1 = _tabulated_step(r1, x_prev, x_now, g1[1, m], a1[1, m])
        r2 = _tabulated_step(r2, x_prev, x_now, g1[2, m], a1[2, m])
        r3 = _tabulated_step(r3, x_prev, x_now, g1[3, m], a1[3, m])
        out[w0, k] = _thermal_output(displacement[w0, k], s0, e0, 0.0, 0.0, r0, 0.0, False)
        out[w1, k] = _thermal_output(displacement[w1, k], s1, e1, 0.0, 0.0, r1, 0.0, False)
        out[w2, k] = _thermal_output(displacement[w2, k], s2, e2, 0.0, 0.0, r2, 0.0, False)
        out[w3, k] = _thermal_output(displacement[w3, k], s3, e3, 0.0, 0.0, r3, 0.0, False)


@njit(cache=True)
def _thermal_one(w, time, steps, index, heating, p, displacement, out):
    """Parameter set ``w`` of :func:`_thermal_kernel`, alone (any case)."""
    n_samples = displacement.shape[1]
    n_steps = steps.shape[0]
    tabulated = n_steps > 0
    second = p[w, 4] != 0.0 or p[w, 5] != 0.0
    table1 = tabulated and p[w, 0] > 0.0
    table2 = tabulated and p[w, 3] > 0.0
    decay1 = np.empty(n_steps)
    gain1 = np.empty(n_steps)
    decay2 = np.empty(n_steps)
    gain2 = np.empty(n_steps)
    if table1:
        lowpass_table(steps, p[w, 0], decay1, gain1)
    if table2 and second:
        lowpass_table(steps, p[w, 3], decay2, gain2)
    rise = p[w, 6]
    rise2 = p[w, 7]
    out[w, 0] = _thermal_output(displacement[w, 0], p[w, 1], p[w, 2], p[w, 4], p[w, 5], rise, rise2, second)
    for k in range(1, n_samples):
        previous = rise
        x_prev = heating[k - 1]
        x_now = heating[k]
        if table1:
            m = index[k]
            rise = _tabulated_step(rise, x_prev, x_now, gain1[m], decay1[m])
        else:
            rise = lowpass_step(rise, x_prev, x_now, time[k] - time[k - 1], p[w, 0])
        if second:
            if table2:
                m = index[k]
                rise2 = _tabulated_step(rise2, previous, rise, gain2[m], decay2[m])
            else:
                rise2 = lowpass_step(rise2, previous, rise, time[k] - time[k - 1], p[w, 3])
        out[w, k] = _thermal_output(displacement[w, k], p[w, 1], p[w, 2], p[w, 4], p[w, 5], rise, rise2, second)


@njit(parallel=True, cache=True, nogil=True)
def _thermal_kernel(time, heating, p, displacement, out):
    """Two-node thermal network: ``rise`` (node 1) low-passes ``heating``, ``rise2`` (node 2)
    low-passes ``rise`` (from the start rises); ``out = displacement (1 - S rise - S2 rise2) + E
    rise + E2 rise2``. ``p``: shape ``(W, 8)``, per parameter set ``tau, S, E, tau2, S2, E2``
    and the two start rises (:class:`Thermal`'s parameter order).
    Node 2 is skipped (exactly the one-node form) where both of its gains are 0.

    With at most :data:`MAX_DISTINCT_STEPS` distinct sample steps (uniform sampling has a
    handful, differing in the last bits) each node's filter coefficients are computed
    once per distinct step and parameter set (:func:`distinct_steps`) instead of one
    ``exp`` per sample, bit-identical to :func:`lowpass_step` at every sample. Groups of
    four parameter sets with both nodes on and tabulated run in lockstep
    (:func:`_thermal_four`: the recursion is latency-bound), so do four with node 2 off
    (:func:`_thermal_four_first`), the rest one by one
    (:func:`_thermal_one`); the values are the same either way."""
    n_sets = displacement.shape[0]
    steps, index = distinct_steps(time, MAX_DISTINCT_STEPS)
    tabulated = steps.shape[0] > 0
    n_groups = (n_sets + 3) // 4
    for g in prange(n_groups):
        w0 = 4 * g
        w_end = min(w0 + 4, n_sets)
        both = first = tabulated and w_end - w0 == 4
        for w in range(w0, w_end):
            second = p[w, 4] != 0.0 or p[w, 5] != 0.0
            both = both and p[w, 0] > 0.0 and p[w, 3] > 0.0 and second
            first = first and p[w, 0] > 0.0 and not second
        if both:
            _thermal_four(w0, index, steps, heating, p, displacement, out)
        elif first:
            _thermal_four_first(w0, index, steps, heating, p, displacement, out)
        else:
            for w in range(w0, w_end):
                _thermal_one(w, time, steps, index, heating, p, displacement, out)


def thermal_rise(time, current, tau):
    r"""Normalised temperature rise :math:`\vartheta`: :math:`\tau \dot\vartheta = (i/i_\mathrm{ref})^2 - \vartheta`,
    :math:`\vartheta(t_0) = 0`.

    Parameters
    ----------
    time : array_like, shape (T,)
        [s].
    current : array_like, shape (T,)
        Coil current [A]; the Joule heating :math:`i^2 R` is normalised by
        :data:`REFERENCE_CURRENT` and taken as linear between samples.
    tau : float or array_like, shape (W,)
        Thermal time constant [s].

    Returns
    -------
    ndarray, shape (W, T)
        :math:`\vartheta`, dimensionless; 1 is the steady rise under a constant 5 A.
    """
    heating = (np.asarray(current, dtype=float) / REFERENCE_CURRENT) ** 2
    return first_order_lowpass(time, heating, tau, initial=0.0)


class Thermal(Effect):
    r"""Joule heating of the coils changing the strain response over the run: a two-node thermal network.

    The coils dissipate :math:`i^2 R`; the coil (node 1) warms through its own time
    constant, and the sample with the core (node 2) warms from the coil through theirs:

    .. math::

        \tau_T \dot\vartheta_1 = \Big(\frac{i}{i_\mathrm{ref}}\Big)^2 - \vartheta_1, \quad
        \tau_2 \dot\vartheta_2 = \vartheta_1 - \vartheta_2, \quad
        \vartheta_1(t_0) = \vartheta_{1,0}, \quad \vartheta_2(t_0) = \vartheta_{2,0},

        y = y_g\,(1 - S\,\vartheta_1 - S_2\,\vartheta_2) + E\,\vartheta_1 + E_2\,\vartheta_2

    with :math:`i_\mathrm{ref}` = :data:`REFERENCE_CURRENT` = 5 A (the paper's excitation),
    so :math:`\vartheta = 1` is a node's steady rise under a constant 5 A. :math:`S, S_2`
    are the relative losses of field-induced strain per unit rise of each node (the
    magnetocrystalline anisotropy, hence the MSM strain, falls as the alloy warms toward
    its transformation temperatures; e.g. Heczko and Straka, J. Appl. Phys. 2003; the
    sample sits in the core, node 2, but a fast node is also what a thin sample close to
    the coil sees), :math:`E, E_2` [um] the thermal expansion seen by the sensor (coil
    former and frame follow the coil, rod and core follow node 2). The rises at the record's
    start, :math:`\vartheta_{1,0}, \vartheta_{2,0}`, are the heat earlier runs left (run
    parameters: each record of a transducer has its own); at 0 (off, the default) the network
    starts cold and the quiet start is untouched, otherwise the quiet start shows the nodes
    cooling. Any linear two-node
    network (coil and sample/core, each with a heat capacity, coupled to each other and to
    the ambient) has a response of this two-pole form with two gains per output term;
    :math:`S_2 = E_2 = 0` is the one-pole form (exactly: node 2 is not computed), and a
    one-pole heating through either time constant is a special case.

    Discretised exactly for the heating linear between samples (node 1) and with node 1
    taken as linear between samples in node 2's step (error of order
    :math:`(h/\tau)^2` of a step, below 1e-6 of the rise for :math:`\tau \ge 1` s at 100 Hz).

    Symmetry: the network's output depends on the two time constants only through the
    pair :math:`\{\tau_T, \tau_2\}`: by partial fractions :math:`\vartheta_2 =
    (\tau_T \vartheta_1 - \tau_2 \vartheta_1')/(\tau_T - \tau_2)` with
    :math:`\vartheta_1'` the one-pole rise through :math:`\tau_2`, so swapping the time
    constants and mapping each gain pair :math:`(G_1, G_2) \to (G_1 \tau_2/\tau_T,\;
    G_2 + G_1 (1 - \tau_2/\tau_T))` (for :math:`G = S` and :math:`G = E`) gives the same
    output exactly (:meth:`swap_nodes`; the start's rises map as
    :math:`(\vartheta_{1,0}, \vartheta_{2,0}) \to ((\vartheta_{2,0} - c\,\vartheta_{1,0})/c',\;
    \vartheta_{2,0})`, :math:`c = \tau_T/(\tau_T - \tau_2)`, :math:`c' = \tau_2/(\tau_2 - \tau_T)`,
    which matches both free decays). The canonical labelling, the physical one, has
    the coil faster than the core, :math:`\tau_T \le \tau_2`; the least squares maps
    its result there and the posterior's support is that half (when all six parameters
    vary), so the posterior has one mode, not two mirror images.

    Trade-offs: the gains of a node trade off with its time constant where the record is
    much shorter than it (a rise that is still linear in time fixes only the product
    gain/tau); when node 2's gains are 0 its time constant does nothing, and a one-pole
    heating is then also node 2 behind a fast node 1 without gains (the study pins the
    core node off where the record does not support it: :attr:`terms`); the sensitivities
    scale the GPI's output, but with a rise that changes over the record, so they are not
    a reparametrisation of its gain (``rho``). Measured Jacobian rank with the GPI on the
    paper's input: ``docs/effects.md``.

    Parameters: ``thermal_tau`` [s] (1-2000), ``thermal_sensitivity`` (-0.5-0.5),
    ``thermal_expansion`` [um] (-50-50) for node 1 (the coil); ``thermal_tau_core`` [s]
    (1-5000), ``thermal_sensitivity_core`` (-0.5-0.5), ``thermal_expansion_core`` [um]
    (-50-50) for node 2 (sample and core); ``thermal_initial``, ``thermal_initial_core``
    (0-2, run parameters) the nodes' normalised rises at the record's start, pinned at 0 (a cold
    start: on a record that starts cold a free start is a flat direction that only slows a fit)
    unless freed (``model.parameters.replace("thermal_initial", vary=True)``; optional terms
    ``warm_start``, ``warm_start_core``: a study with them free pins them off where the record
    starts cold; the joint diagnosis of several records frees them, :meth:`earlier_run_parameters`).
    Off: every sensitivity and expansion 0.
    """

    name = "thermal"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter(
                "thermal_tau", 30.0, 1.0, 2000.0, unit="s", description="thermal time constant of the coil (node 1)"
            ),
            Parameter(
                "thermal_sensitivity",
                0.0,
                -0.5,
                0.5,
                unit="",
                description="relative strain loss per unit normalised temperature rise of node 1",
            ),
            Parameter(
                "thermal_expansion",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="displacement from thermal expansion at unit normalised rise of node 1",
            ),
            Parameter(
                "thermal_tau_core",
                300.0,
                1.0,
                5000.0,
                unit="s",
                description="thermal time constant of sample and core (node 2, heated by node 1)",
            ),
            Parameter(
                "thermal_sensitivity_core",
                0.0,
                -0.5,
                0.5,
                unit="",
                description="relative strain loss per unit normalised temperature rise of node 2",
            ),
            Parameter(
                "thermal_expansion_core",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="displacement from thermal expansion at unit normalised rise of node 2",
            ),
            Parameter(
                "thermal_initial",
                0.0,
                0.0,
                2.0,
                unit="",
                description="normalised rise of node 1 at the record's start (heat left by earlier runs)",
                per_record=True,
                vary=False,
            ),
            Parameter(
                "thermal_initial_core",
                0.0,
                0.0,
                2.0,
                unit="",
                description="normalised rise of node 2 at the record's start (heat left by earlier runs)",
                per_record=True,
                vary=False,
            ),
        ]
    )
    summary = (
        "Joule heating through coil and core: tau th1' = (i/5 A)^2 - th1, tau2 th2' = th1 - th2, y = y_g (1 - "
        "S th1 - S2 th2) + E th1 + E2 th2"
    )
    signature = (
        "follows the drive's power, not the strain: builds up while current flows and decays with its time "
        "constants once the drive stops (a record that ends with the drive off for a few time constants shows it)"
    )
    terms = {
        "core": ("thermal_tau_core", "thermal_sensitivity_core", "thermal_expansion_core"),
        "warm_start": ("thermal_initial",),
        "warm_start_core": ("thermal_initial_core",),
    }
    labelling_keeps_off = ("thermal_initial", "thermal_initial_core")
    earlier_run_terms = ("warm_start", "warm_start_core")

    @classmethod
    def earlier_run_parameters(cls, parameters):
        """Both nodes' starts (the heat left after any pause: the coil cools faster than the
        core, so their ratio is the run's), node 2's only where its parameters vary (pinned off,
        node 2 is not computed and its start does nothing)."""
        core_on = all(parameters[name].vary for name in cls.terms["core"])
        return ("thermal_initial", "thermal_initial_core") if core_on else ("thermal_initial",)

    @staticmethod
    def swap_nodes(values: dict[str, float]) -> dict[str, float]:
        """The other labelling of the same output: time constants swapped, gains and the start's
        rises mapped (class docstring, "Symmetry"). Its own inverse; needs distinct time constants."""
        tau1, tau2 = values["thermal_tau"], values["thermal_tau_core"]
        ratio = tau2 / tau1
        out = dict(values)
        out["thermal_tau"], out["thermal_tau_core"] = tau2, tau1
        for g1, g2 in (
            ("thermal_sensitivity", "thermal_sensitivity_core"),
            ("thermal_expansion", "thermal_expansion_core"),
        ):
            out[g1] = values[g1] * ratio
            out[g2] = values[g2] + values[g1] * (1.0 - ratio)
        if "thermal_initial" in values:
            a, b = values["thermal_initial"], values.get("thermal_initial_core", 0.0)
            out["thermal_initial"] = (b - a * tau1 / (tau1 - tau2)) * (tau2 - tau1) / tau2
            out["thermal_initial_core"] = b
        return out

    @classmethod
    def canonical(cls, values):
        """Node 1 (the coil) the faster: :meth:`swap_nodes` when ``thermal_tau > thermal_tau_core``."""
        return cls.swap_nodes(values) if values["thermal_tau"] > values["thermal_tau_core"] else values

    @classmethod
    def in_canonical_domain(cls, params):
        p = cls.values(np.atleast_2d(params))
        return p.tau <= p.tau_core

    @classmethod
    def reduced_starts(cls, values, term):
        """The one-node form from a two-node fit: node 2 off, and also node 1 taking node 2's
        time constant and gains. A one-pole heating is fitted equally well by node 1 alone and
        by a fast node 1 without gains feeding node 2, so a two-node fit may have put it on
        either node."""
        starts = super().reduced_starts(values, term)
        if term != "core":
            return starts
        moved = {
            "thermal_tau": values["thermal_tau_core"],
            "thermal_sensitivity": values["thermal_sensitivity_core"],
            "thermal_expansion": values["thermal_expansion_core"],
        }
        if "thermal_initial_core" in values:
            moved["thermal_initial"] = values["thermal_initial_core"]
        return starts + [{**starts[0], **moved}]  # the caller clips a start to the model's bounds

    @classmethod
    def term_reductions(cls, term):
        """The core: node 2 off, or node 1 without gains at its fastest (1 s): a one-pole heating
        fitted on node 2 behind a fast node 1, the second labelling of the one-node form (up to
        node 1's residual lag of 1 s). A warm start: the node's start rise 0."""
        if term != "core":
            return super().term_reductions(term)
        fastest = cls.parameters["thermal_tau"].lower
        return super().term_reductions(term) + [
            {"thermal_tau": fastest, "thermal_sensitivity": 0.0, "thermal_expansion": 0.0}
        ]

    @classmethod
    def get_test_parameters(cls):
        return {
            "thermal_tau": 20.0,
            "thermal_sensitivity": 0.08,
            "thermal_expansion": 3.0,
            "thermal_tau_core": 300.0,
            "thermal_sensitivity_core": 0.0,
            "thermal_expansion_core": 0.0,
            "thermal_initial": 0.0,
            "thermal_initial_core": 0.0,
        }

    def output(self, params, time, current, displacement):
        """Displacement with the heating's effect, shape ``(W, T)`` [um]."""
        time = np.ascontiguousarray(time, dtype=float)
        heating = np.ascontiguousarray((np.asarray(current, dtype=float) / REFERENCE_CURRENT) ** 2)
        displacement = np.ascontiguousarray(np.atleast_2d(displacement), dtype=float)
        out = np.empty_like(displacement)
        p = self.values(params)
        network = np.ascontiguousarray(np.column_stack(tuple(p)), dtype=float)  # (W, 8), the parameter order
        _thermal_kernel(kernel_array(time), heating, network, kernel_array(displacement), out)
        return out
