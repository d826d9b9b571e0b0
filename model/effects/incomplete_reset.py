"""``incomplete_reset`` (output stage): the paper's first-cycle strain, extra on the virgin loading, partly kept.

Holds :class:`IncompleteReset`, :func:`incomplete_reset_strain` (its extra strain),
:func:`loading_levels` (the virgin loading's variable and shape) and the kernel that keeps
the virgin levels not yet reset.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..gpi_kernels import kernel_array
from ..parameters import Parameter, ParameterSet
from .base import Effect

__all__ = ["IncompleteReset", "incomplete_reset_strain", "loading_levels"]


@njit(parallel=True, cache=True, nogil=True)
def _incomplete_reset_kernel(current, excursion, strain, retained, fade, narrowing, strain_excursion, out_extra):
    """Extra strain of :class:`IncompleteReset` per row (see its docstring), shape ``(W, T)``:
    ``excursion[w]`` is row ``w``'s loading variable (the strain's excursion from its first
    value, or its level :func:`loading_levels`; measured in units of its largest),
    ``current`` the drive whose travel fades the retained part.

    The excursion levels set on a virgin loading and not reset since are kept as a stack of
    disjoint intervals ``[low, high]`` (ascending); an unloading to ``e`` resets every set
    level above ``e`` (it pops or cuts the top intervals), a new largest excursion sets the
    levels between the previous largest and it. Each level is pushed and popped at most
    once per new excursion, so the cost is linear in the samples. ``narrowing[w]`` is
    :math:`A b`: where it is not 0, the retained part :math:`q` is taken off again in
    proportion to the strain's excursion ``strain_excursion[w]`` (shape ``(1 or W, T)``) over
    its largest, the narrowing of the later strokes."""
    n_sets = out_extra.shape[0]
    n_samples = out_extra.shape[1]
    row_step = 0 if excursion.shape[0] == 1 else 1
    strain_row_step = 0 if strain_excursion.shape[0] == 1 else 1
    for w in prange(n_sets):
        row = w * row_step
        strain_row = w * strain_row_step
        scale = 0.0
        for k in range(n_samples):
            scale = max(scale, excursion[row, k])
        largest = 0.0
        if narrowing[w] != 0.0:
            for k in range(n_samples):
                largest = max(largest, strain_excursion[strain_row, k])
        out_extra[w, 0] = 0.0
        if not scale > 0.0:
            for k in range(1, n_samples):
                out_extra[w, k] = 0.0
            continue
        low = np.empty(n_samples)
        high = np.empty(n_samples)
        count = 0
        reached = 0.0  # largest excursion so far (the virgin territory)
        unreset = 0.0  # measure of the set levels the spring has not reset yet
        kept = 0.0  # retained part (normalised)
        previous = excursion[row, 0]
        for k in range(1, n_samples):
            e = excursion[row, k]
            if kept != 0.0 and fade[w] > 0.0 and current[k] != current[k - 1]:
                kept *= math.exp(-fade[w] * abs(current[k] - current[k - 1]))
            if e > reached:
                if count > 0 and high[count - 1] == reached:
                    high[count - 1] = e
                else:
                    low[count] = reached
                    high[count] = e
                    count += 1
                unreset += e - reached
                reached = e
            elif e < previous:
                while count > 0 and high[count - 1] > e:
                    if low[count - 1] >= e:
                        moved = high[count - 1] - low[count - 1]
                        count -= 1
                    else:
                        moved = high[count - 1] - e
                        high[count - 1] = e
                    unreset -= moved
                    kept += retained[w] * moved / scale
            previous = e
            out_extra[w, k] = strain[w] * (max(unreset, 0.0) / scale + kept)
            if largest > 0.0:
                out_extra[w, k] -= narrowing[w] * kept * (strain_excursion[strain_row, k] / largest)


@njit(parallel=True, cache=True, nogil=True)
def _levels_kernel(drive_part, excursion, drive, shape, onset, sharpness, general, levels):
    """The rows ``general`` of ``levels`` (shape ``(W, T)``) as :func:`loading_levels` defines
    them, the others the strain's excursion itself; ``drive_part`` is the drive's excursion over
    its largest (shape ``(T,)``), ``excursion`` the strain's (shape ``(1 or W, T)``)."""
    n_sets = levels.shape[0]
    n_samples = levels.shape[1]
    row_step = 0 if excursion.shape[0] == 1 else 1
    for w in prange(n_sets):
        row = w * row_step
        if not general[w]:
            for k in range(n_samples):
                levels[w, k] = excursion[row, k]
            continue
        largest = 0.0
        for k in range(n_samples):
            largest = max(largest, excursion[row, k])
        share = drive[w]
        top = 0.0
        for k in range(n_samples):
            strain_part = excursion[row, k] / largest if largest > 0.0 else 0.0
            mixed = (1.0 - share) * strain_part + share * drive_part[k]
            levels[w, k] = mixed
            top = max(top, mixed)
        k_step, c = sharpness[w], onset[w]
        low = math.tanh(k_step * c)
        span = math.tanh(k_step * (1.0 - c)) + low
        power = shape[w]
        last_in, last_out = -1.0, 0.0  # a level repeated (a hold, the drive off) is not recomputed
        for k in range(n_samples):
            level = levels[w, k] / top if top > 0.0 else 0.0
            if level == last_in:
                levels[w, k] = last_out
                continue
            last_in = level
            if power != 1.0:  # x ** 1 is x: the power function only where it changes the level
                level = level**power
            if k_step != 0.0:
                level = (math.tanh(k_step * (level - c)) + low) / span
            levels[w, k] = level
            last_out = level


class IncompleteReset(Effect):
    r"""First-cycle strain: extra strain on the virgin loading, partly kept after unloading.

    The virgin loading's variable is the excursion from the first sample of the strain
    (the GPI's output: the reorientation the field has done) and of the drive current,
    mixed by :math:`m` and each normalised by the record's largest,

    .. math::

        e_k = (1 - m)\,\frac{|y_{g,k} - y_{g,0}|}{E_y} + m\,\frac{|i_k - i_0|}{E_i}, \qquad
        l_k = \varphi(e_k / E), \quad \varphi(x) = x^p, \quad E = \max_k e_k,

    and the extra strain follows the level :math:`l \in [0, 1]` (1 at the record's largest
    excursion). With :math:`M_k = \max_{m \le k} l_m` the largest level so far and
    :math:`S_k` the levels set by the virgin loading and not reset since, updated at every
    sample (:math:`|\cdot|` the total length of a set of levels):

    .. math::

        \text{new excursion } (l_k > M_{k-1}):\quad
            S \leftarrow S \cup (M_{k-1}, l_k]

        \text{unloading } (l_k < l_{k-1}):\quad
            \delta = |S \cap (l_k, \infty)|,\quad S \leftarrow S \cap [0, l_k],\quad
            q \leftarrow q + R\,\delta

        q \leftarrow q\, e^{-\lambda |i_k - i_{k-1}|}, \qquad
        y = y_g + A\,\big(|S| + q\big)

    (:math:`S` empty, :math:`q = 0` at the start), and with the optional stroke term
    :math:`b` the retained strain also narrows the later strokes (below):

    .. math::  y = y_g + A\,\big(|S| + q\,(1 - b\,x)\big), \qquad
        x_k = \frac{|y_{g,k} - y_{g,0}|}{E_y}.

    :math:`m = 0, p = 1` is the strain's own
    excursion, :math:`l = e / E` (the form before the general one; computed on
    :math:`|y_g - y_{g,0}|` itself there, bit for bit that form). Then the virgin loading
    adds the extra strain :math:`A` (at the record's largest excursion, in proportion to
    the strain before it: the extra reorientation goes with the reorientation) to the
    GPI's response.
    Each level of it is reset when the strain comes back below that level (the spring
    pushes the lattice back that far), except the fraction :math:`R`, which stays
    (:math:`q`); a level is reset once. The extra strain is thus a function of the
    strain's state (how far it went, how low it has come back since), not of its travel:
    later cycles within the range already reached add no extra strain and ride on the
    retained :math:`R A` (plus the virgin levels below the lowest strain since, which no
    unloading has reached), fixed (:math:`\lambda = 0`) or fading with the drive's further
    travel (:math:`\lambda > 0` per unit of drive: cycling and the spring progressively
    reset the lattice). Only an excursion beyond the largest so far (virgin territory)
    adds extra strain again.

    Physics, the paper's first-cycle effect (sec. "Magnetic shape memory materials"): in
    the spring-returned mode the pretensioned spring must reorient the variants after
    the field is removed, but its "compressive force is not sufficiently large to provide
    crystal lattice reorientation which was deformed in magnetic field thus that after
    first cycle maximum strain is reduced". On the virgin loading the field reorients
    more of the crystal than on later cycles (the as-received sample starts fully
    compressed, :math:`R = 0` of the variants left over); the spring resets only part
    of it when the field goes, so the strain stays raised by the retained fraction and
    later cycles span a reduced range on top of it. This lives on the strain side (an
    incomplete reset of the lattice), unlike :class:`Training`, which changes the drive
    the virgin material needs.

    **The virgin loading's shape** (:math:`m`, :math:`p`): the extra reorientation of the
    virgin loading need not scale with the strain's own excursion. It can be set by the
    field, the drive's excursion (:math:`m = 1`; a mix of the two between), and it can be
    front-loaded, an overshoot early in the loading to which the rest of the loading adds
    little (:math:`p < 1`), or come late in it (:math:`p > 1`). The bookkeeping of the set
    and reset levels depends only on their order, so running it on :math:`l =
    \varphi(e/E)` measures every level by :math:`\varphi`: the virgin loading adds
    :math:`A\,\varphi(e/E)`, and an unloading resets (and retains the fraction :math:`R`
    of) the :math:`\varphi`-measure of the levels it comes back through, so the first
    unloading gives back the shape the first loading took. Both are optional terms
    (:attr:`Effect.terms` ``drive`` and ``shape``): while :math:`A = 0` they do nothing,
    and a record of the strain-proportional form is not charged for them. The virgin
    material may also switch around a level of its loading variable, spread over a range
    of it (its switching field, when the drive sets it): the optional term ``step`` takes
    the level through :math:`S(u) = (\tanh(k(u - c)) + \tanh(kc)) / (\tanh(k(1 - c)) +
    \tanh(kc))` (:func:`loading_levels`; :math:`k = 0` is no step, bit for bit).

    **The stroke the retained strain takes** (:math:`b`, the optional term ``stroke``): the
    variants the spring did not reset are the ones the field reorients, so the retained
    strain raises the rest level more than the top of the later strokes, which the crystal's
    full reorientation bounds. The retained :math:`A q` then shrinks with the strain's
    excursion :math:`x` (its fraction of the record's largest): :math:`b = 0` raises every
    level alike (the form above), :math:`b = 1` leaves the top of the stroke where it was
    (a later stroke narrower by the retained strain), :math:`b > 1` lowers it (the paper's
    "maximum strain is reduced"; 3 at most, a later stroke that keeps a third of its
    range with everything retained). It acts only where some strain is retained and
    fades with it.

    What the GPI cannot do: its first branch is tied to the later ones, and its rest
    level after the first cycle is set by the same operators. A raised level after the
    first cycle is partly within the GPI's reach (its initial memory already makes the
    virgin curve differ from later ones; :class:`InitialState` is an exact
    reparametrisation of it), so :math:`A R` trades off with the GPI's rest level
    (the Omega offsets c3, d3 and the envelope offsets) where the first cycle starts from
    rest; the transient part :math:`A (1 - R)` on the first loading does not. Within the
    effect, :math:`A` and :math:`R` are separated by the first loading (only :math:`A`
    acts there); :math:`\lambda` trades off with :math:`R` when the retained strain fades
    fast (a retained part that fades within a cycle looks like a smaller :math:`R`). The
    loading's shape (:math:`m`, :math:`p`) trades off with :class:`Training`, whose fading
    virgin differences also reshape the first loading; the later cycles (training changes
    every branch as it fades, this effect adds to them only a level) and the first unloading
    (which gives back the shape the loading took) tell them apart. A held initial memory
    (:class:`InitialState`) hardly takes it over. Measured Jacobian ranks with the GPI and
    with each of the two on the paper's input: ``docs/effects.md``.

    Parameters: ``incomplete_reset_strain`` :math:`A` [um] (-50-50), the extra strain of
    the virgin loading at the record's largest excursion; ``incomplete_reset_retained``
    :math:`R` (0-1), the fraction of it the unloading does not reset;
    ``incomplete_reset_fade`` :math:`\lambda` [1/A] (0-2), how fast the retained strain
    fades with the drive's travel (0: fixed); ``incomplete_reset_drive`` :math:`m` (0-1),
    the drive's share of the loading variable; ``incomplete_reset_shape`` :math:`p`
    (0.2-5, symmetric about 1 on a log scale), the exponent of the loading's shape;
    ``incomplete_reset_stroke`` :math:`b` (0-3), how much of the retained strain the top of
    the later strokes does not keep. Off: :math:`A = 0` (whatever the others); :math:`m = 0,
    p = 1, b = 0` is the strain-proportional form.
    """

    name = "incomplete_reset"
    stage = "output"
    first_cycle = True
    parameters = ParameterSet(
        [
            Parameter(
                "incomplete_reset_strain",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="extra strain of the virgin loading at the record's largest excursion",
                per_record=True,
            ),
            Parameter(
                "incomplete_reset_retained",
                0.5,
                0.0,
                1.0,
                unit="",
                description="fraction of the virgin extra strain that the unloading does not reset",
            ),
            Parameter(
                "incomplete_reset_fade",
                0.0,
                0.0,
                2.0,
                unit="1/A",
                description="fading of the retained strain per unit of drive travel (0: fixed)",
            ),
            Parameter(
                "incomplete_reset_drive",
                0.0,
                0.0,
                1.0,
                unit="",
                description="share of the drive's excursion in the virgin loading's variable (0: the strain's own)",
            ),
            Parameter(
                "incomplete_reset_shape",
                1.0,
                0.2,
                5.0,
                unit="",
                description="exponent p of the extra strain along the virgin loading, (e/E)^p "
                "(< 1: front-loaded, an early overshoot; 1: proportional)",
            ),
            Parameter(
                "incomplete_reset_onset",
                0.5,
                0.02,
                0.98,
                unit="",
                description="level c (of the loading variable's largest) around which the virgin reorientation "
                "sets in, with a step",
            ),
            Parameter(
                "incomplete_reset_sharpness",
                0.0,
                0.0,
                40.0,
                unit="",
                description="steepness k of that step, tanh(k (u - c)) (0: no step, the level itself)",
            ),
            Parameter(
                "incomplete_reset_stroke",
                0.0,
                0.0,
                3.0,
                unit="",
                description="share b of the retained strain the top of the later strokes does not keep "
                "(0: every level raised alike; 1: the top where it was)",
            ),
        ]
    )
    terms = {
        "drive": ("incomplete_reset_drive",),
        "shape": ("incomplete_reset_shape",),
        "step": ("incomplete_reset_onset", "incomplete_reset_sharpness"),
        "stroke": ("incomplete_reset_stroke",),
    }
    summary = (
        "first-cycle strain: extra strain A S((e/E)^p) on the virgin loading (e the strain's excursion, or part the "
        "drive's; S a tanh step at c of sharpness k, none at k = 0), fraction R kept after unloading (fading with "
        "travel), narrowing the later strokes by b"
    )
    signature = (
        "the first loading reaches further than the later ones and part of it stays after unloading; the "
        "later cycles ride on that raised level"
    )

    @classmethod
    def get_test_parameters(cls):
        """The strain-proportional form (the drive's share 0, the shape 1)."""
        return {
            "incomplete_reset_strain": 6.0,
            "incomplete_reset_retained": 0.5,
            "incomplete_reset_fade": 0.0,
            "incomplete_reset_drive": 0.0,
            "incomplete_reset_shape": 1.0,
            "incomplete_reset_onset": 0.5,
            "incomplete_reset_sharpness": 0.0,
            "incomplete_reset_stroke": 0.0,
        }

    def output(self, params, time, current, displacement):
        """Displacement plus the first-cycle extra strain, shape ``(W, T)`` [um]."""
        p = self.values(params)
        displacement = np.atleast_2d(np.asarray(displacement, dtype=float))
        if not p.strain.any():  # off: the displacement itself, bit for bit
            return displacement
        extra = incomplete_reset_strain(
            current, displacement, p.strain, p.retained, p.fade, p.drive, p.shape, p.onset, p.sharpness, p.stroke
        )
        return displacement + extra


def incomplete_reset_strain(
    current, displacement, strain, retained, fade, drive=0.0, shape=1.0, onset=0.5, sharpness=0.0, stroke=0.0
):
    r"""The extra strain :math:`A (|S| + q (1 - b x))` of :class:`IncompleteReset`, shape ``(W, T)`` [um].

    Parameters
    ----------
    current : array_like, shape (T,)
        Drive [A] (its travel fades the retained part; its excursion is the drive's share of
        the loading variable).
    displacement : array_like, shape (T,) or (W, T)
        The strain the effect acts on [um] (the GPI's output): its excursion from its first
        value is the reorientation that adds the virgin extra strain.
    strain, retained, fade : array_like, shape (W,)
        :math:`A` [um], :math:`R`, :math:`\lambda` [1/A].
    drive, shape : array_like, shape (W,), default 0 and 1
        :math:`m` and :math:`p` (> 0), the virgin loading's variable and shape
        (:func:`loading_levels`); the defaults are the strain's own excursion.
    onset, sharpness : array_like, shape (W,), default 0.5 and 0
        :math:`c` in (0, 1) and :math:`k \ge 0` of the step the reorientation sets in with
        (:func:`loading_levels`); ``k = 0``: no step.
    stroke : array_like, shape (W,), default 0
        :math:`b`, the share of the retained strain the top of the later strokes does not keep
        (0: the retained strain raises every level alike, bit for bit the form without it).
    """
    current = np.ascontiguousarray(current, dtype=float)
    strain = np.ascontiguousarray(np.atleast_1d(strain), dtype=float)
    retained = np.broadcast_to(np.asarray(retained, dtype=float), strain.shape)  # the kernel call makes them
    fade = np.broadcast_to(np.asarray(fade, dtype=float), strain.shape)  # contiguous and writeable
    drive = np.broadcast_to(np.asarray(drive, dtype=float), strain.shape)
    shape = np.broadcast_to(np.asarray(shape, dtype=float), strain.shape)
    onset = np.broadcast_to(np.asarray(onset, dtype=float), strain.shape)
    sharpness = np.broadcast_to(np.asarray(sharpness, dtype=float), strain.shape)
    stroke = np.broadcast_to(np.asarray(stroke, dtype=float), strain.shape)
    y = np.atleast_2d(np.asarray(displacement, dtype=float))
    if y.shape[0] not in (1, strain.size) or y.shape[1] != current.size:
        raise ValueError(
            f"incomplete_reset: the displacement has shape {y.shape} for {strain.size} parameter sets and "
            f"{current.size} samples"
        )
    bad = ~(np.isfinite(drive) & np.isfinite(shape) & (shape > 0.0))
    bad |= ~(np.isfinite(sharpness) & (sharpness >= 0.0) & np.isfinite(onset) & (onset > 0.0) & (onset < 1.0))
    bad |= ~np.isfinite(stroke)
    if bad.any():
        raise ValueError(
            "incomplete_reset: incomplete_reset_drive must be finite, incomplete_reset_shape finite and > 0, "
            "incomplete_reset_sharpness finite and >= 0, incomplete_reset_onset within (0, 1) and "
            "incomplete_reset_stroke finite; "
            f"parameter set(s) {np.flatnonzero(bad)[:5].tolist()} are not"
        )
    excursion = np.ascontiguousarray(np.abs(y - y[:, :1]))
    out = np.zeros((strain.size, current.size))
    if current.size:
        levels = excursion
        if _general_rows(drive, shape, sharpness).any():
            levels = loading_levels(current, excursion, drive, shape, onset, sharpness)
        _incomplete_reset_kernel(
            kernel_array(current),
            levels,
            kernel_array(strain),
            kernel_array(retained),
            kernel_array(fade),
            kernel_array(strain * stroke),
            excursion,
            out,
        )
    return out


def _general_rows(drive, shape, sharpness):
    """Which parameter sets take the general loading variable (:func:`loading_levels`) rather
    than the strain's own excursion: a drive share, a shape other than 1 or a step."""
    return (drive != 0.0) | (shape != 1.0) | (sharpness != 0.0)


def loading_levels(current, excursion, drive, shape, onset=None, sharpness=None):
    r"""The virgin loading's variable of :class:`IncompleteReset` per parameter set, shape ``(W, T)``.

    A row with :math:`m \ne 0`, :math:`p \ne 1` or :math:`k \ne 0` is the level
    :math:`l = \varphi(e/E)` of the mixed excursion :math:`e = (1 - m)\,|y_g - y_{g,0}|/E_y +
    m\,|i - i_0|/E_i` (each part 0 where its largest :math:`E_y`, :math:`E_i` is 0; :math:`l`
    is 0 where :math:`E` is), :math:`\varphi(x) = S(x^p)` with the step

    .. math::  S(u) = \frac{\tanh(k (u - c)) + \tanh(k c)}{\tanh(k (1 - c)) + \tanh(k c)}

    (:math:`S(0) = 0`, :math:`S(1) = 1`, increasing; :math:`S(u) = u` at :math:`k = 0`, its
    limit as :math:`k \to 0`); a row with :math:`m = 0, p = 1, k = 0` is the strain's excursion
    itself, as the form before the general one ran on it (the kernel measures the levels in
    units of the row's largest, so both give the same extra strain, the latter bit for bit
    that form).

    Parameters
    ----------
    current : ndarray, shape (T,)
        Drive [A], ``T >= 1``.
    excursion : ndarray, shape (1 or W, T)
        The strain's excursion :math:`|y_g - y_{g,0}|` [um].
    drive, shape : ndarray, shape (W,)
        :math:`m` and :math:`p > 0`.
    onset, sharpness : ndarray, shape (W,), optional
        :math:`c \in (0, 1)` and :math:`k \ge 0` (default 0.5 and 0: no step).
    """
    n_sets = drive.shape[0]
    drive = kernel_array(drive)
    shape = kernel_array(shape)
    onset = np.full(n_sets, 0.5) if onset is None else kernel_array(onset)
    sharpness = np.zeros(n_sets) if sharpness is None else kernel_array(sharpness)
    current = np.asarray(current, dtype=float)
    drive_excursion = np.abs(current - current[0])
    largest_drive = drive_excursion.max()
    drive_part = drive_excursion / largest_drive if largest_drive > 0.0 else np.zeros_like(drive_excursion)
    general = _general_rows(drive, shape, sharpness)
    levels = np.empty((n_sets, excursion.shape[1]))
    _levels_kernel(
        drive_part, np.ascontiguousarray(excursion, dtype=float), drive, shape, onset, sharpness, general, levels
    )
    return levels
