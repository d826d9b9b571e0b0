"""``incomplete_reset`` (output stage): the paper's first-cycle strain, extra on the virgin loading, partly kept.

Holds :class:`IncompleteReset`, :func:`incomplete_reset_strain` (its extra strain) and the
kernel that keeps the virgin levels not yet reset.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..gpi import kernel_array
from ..parameters import Parameter, ParameterSet
from .base import Effect

__all__ = ["IncompleteReset", "incomplete_reset_strain"]


@njit(parallel=True, cache=True)
def _incomplete_reset_kernel(current, excursion, strain, retained, fade, out_extra):
    """Extra strain of :class:`IncompleteReset` per row (see its docstring), shape ``(W, T)``:
    ``excursion[w]`` is row ``w``'s strain excursion from its first value, ``current`` the
    drive whose travel fades the retained part.

    The excursion levels set on a virgin loading and not reset since are kept as a stack of
    disjoint intervals ``[low, high]`` (ascending); an unloading to ``e`` resets every set
    level above ``e`` (it pops or cuts the top intervals), a new largest excursion sets the
    levels between the previous largest and it. Each level is pushed and popped at most
    once per new excursion, so the cost is linear in the samples."""
    n_sets = out_extra.shape[0]
    n_samples = out_extra.shape[1]
    row_step = 0 if excursion.shape[0] == 1 else 1
    for w in prange(n_sets):
        row = w * row_step
        scale = 0.0
        for k in range(n_samples):
            scale = max(scale, excursion[row, k])
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
            if kept != 0.0 and fade[w] > 0.0:
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


class IncompleteReset(Effect):
    r"""First-cycle strain: extra strain on the virgin loading, partly kept after unloading.

    With :math:`e_k = |y_{g,k} - y_{g,0}|` the strain's excursion from its first value (the
    GPI's output: the reorientation the field has done), :math:`E = \max_k e_k` the
    record's largest, :math:`M_k = \max_{m \le k} e_m` the largest so far, and
    :math:`S_k` the excursion levels set by the virgin loading and not reset since,
    updated at every sample (:math:`|\cdot|` the total length of a set of levels):

    .. math::

        \text{new excursion } (e_k > M_{k-1}):\quad
            S \leftarrow S \cup (M_{k-1}, e_k]

        \text{unloading } (e_k < e_{k-1}):\quad
            \delta = \frac{|S \cap (e_k, \infty)|}{E},\quad S \leftarrow S \cap [0, e_k],\quad
            q \leftarrow q + R\,\delta

        q \leftarrow q\, e^{-\lambda |i_k - i_{k-1}|}, \qquad
        y = y_g + A\,\Big(\frac{|S|}{E} + q\Big)

    (:math:`S` empty, :math:`q = 0` at the start). So the virgin loading adds the extra
    strain :math:`A` (at the record's largest excursion, in proportion to the strain
    before it: the extra reorientation goes with the reorientation) to the GPI's response.
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

    What the GPI cannot do: its first branch is tied to the later ones, and its rest
    level after the first cycle is set by the same operators. A raised level after the
    first cycle is partly within the GPI's reach (its initial memory already makes the
    virgin curve differ from later ones; :class:`InitialState` is an exact
    reparametrisation of it), so :math:`A R` trades off with the GPI's rest level
    (the Omega offsets c3, d3 and the envelope offsets) where the first cycle starts from
    rest; the transient part :math:`A (1 - R)` on the first loading does not. Within the
    effect, :math:`A` and :math:`R` are separated by the first loading (only :math:`A`
    acts there); :math:`\lambda` trades off with :math:`R` when the retained strain fades
    fast (a retained part that fades within a cycle looks like a smaller :math:`R`).
    Measured Jacobian rank with the GPI on the paper's input: ``docs/effects.md``.

    Parameters: ``incomplete_reset_strain`` :math:`A` [um] (-50-50), the extra strain of
    the virgin loading at the record's largest excursion; ``incomplete_reset_retained``
    :math:`R` (0-1), the fraction of it the unloading does not reset;
    ``incomplete_reset_fade`` :math:`\lambda` [1/A] (0-2), how fast the retained strain
    fades with the drive's travel (0: fixed). Off: :math:`A = 0`.
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
        ]
    )
    summary = (
        "first-cycle strain: extra strain A on the virgin loading, fraction R kept after unloading (fading with travel)"
    )
    signature = (
        "the first loading reaches further than the later ones and part of it stays after unloading; the "
        "later cycles ride on that raised level"
    )

    @classmethod
    def get_test_parameters(cls):
        return {"incomplete_reset_strain": 6.0, "incomplete_reset_retained": 0.5, "incomplete_reset_fade": 0.0}

    def output(self, params, time, current, displacement):
        """Displacement plus the first-cycle extra strain, shape ``(W, T)`` [um]."""
        p = self.values(params)
        displacement = np.atleast_2d(np.asarray(displacement, dtype=float))
        if not p.strain.any():  # off: the displacement itself, bit for bit
            return displacement
        extra = incomplete_reset_strain(current, displacement, p.strain, p.retained, p.fade)
        return displacement + extra


def incomplete_reset_strain(current, displacement, strain, retained, fade):
    """The extra strain :math:`A (n + q)` of :class:`IncompleteReset`, shape ``(W, T)`` [um].

    Parameters
    ----------
    current : array_like, shape (T,)
        Drive [A] (its travel fades the retained part).
    displacement : array_like, shape (T,) or (W, T)
        The strain the effect acts on [um] (the GPI's output): its excursion from its first
        value is the reorientation that adds the virgin extra strain.
    strain, retained, fade : array_like, shape (W,)
        :math:`A` [um], :math:`R`, :math:`\\lambda` [1/A].
    """
    current = np.ascontiguousarray(current, dtype=float)
    strain = np.ascontiguousarray(np.atleast_1d(strain), dtype=float)
    retained = np.broadcast_to(np.asarray(retained, dtype=float), strain.shape)  # the kernel call makes them
    fade = np.broadcast_to(np.asarray(fade, dtype=float), strain.shape)  # contiguous and writeable
    y = np.atleast_2d(np.asarray(displacement, dtype=float))
    if y.shape[0] not in (1, strain.size) or y.shape[1] != current.size:
        raise ValueError(
            f"incomplete_reset: the displacement has shape {y.shape} for {strain.size} parameter sets and "
            f"{current.size} samples"
        )
    excursion = np.ascontiguousarray(np.abs(y - y[:, :1]))
    out = np.zeros((strain.size, current.size))
    if current.size:
        _incomplete_reset_kernel(
            kernel_array(current), excursion, kernel_array(strain), kernel_array(retained), kernel_array(fade), out
        )
    return out
