"""``initial_state`` (state stage): the memory the record starts from, left by the sample's history.

Holds :class:`InitialState` (a level, a prior excursion, a memory held beyond the bounds);
the play law that carries them is :func:`model.gpi.gpi`'s.
"""

from __future__ import annotations

import numpy as np

from ..parameters import Parameter, ParameterSet
from .base import Effect

__all__ = ["InitialState"]


class InitialState(Effect):
    r"""First-cycle state: the memory the record starts from, left by the sample's history.

    Before the record the sample was driven (a previous test, the mounting, a magnet
    nearby): its operators start with the memory that history left. A PI model's memory is
    a staircase of the past extremes the later motion has not wiped out; the record's own
    first large excursion wipes the narrow operators, so what can outlast it is the *last
    reversal before the record*; a history outside the drive can leave more. This effect
    is that history in three parts:

    * a **level** :math:`z^0` every operator's memory is clamped from (the state before
      any excursion):

      .. math::  z_j^c = \max\big(\gamma_\uparrow(v_0) - r_j,\ \min(\gamma_\downarrow(v_0) + r_j,\ z^0)\big);

    * a **prior excursion** :math:`e`: the drive went from :math:`v_0` to :math:`v_0 + e`
      and back before :math:`t_0`, and the play law carried the memory along (for
      :math:`e > 0`):

      .. math::  z_j(t_0) = \min\big(\gamma_\downarrow(v_0) + r_j,\ \max(z_j^c,\ \gamma_\uparrow(v_0 + e) - r_j)\big),

      and the mirror image for :math:`e < 0` (:func:`model.gpi.gpi`'s
      ``initial_memory`` and ``initial_excursion``). The narrow operators end on the
      return branch, the middle ones keep the excursion's peak, the widest keep the level:
      a memory profile over the widths that no level alone gives.

    * a **held memory** :math:`h_j = h + s\, j/N` added after the clamp and the excursion,
      not clamped (:func:`model.gpi.gpi`'s ``initial_held``). A history outside the drive (a
      pre-strain when the sample was mounted, a test at another pre-stress or temperature,
      a magnet nearby) can leave the lattice in a state the drive cannot leave at
      :math:`v_0`: a memory beyond its bounds. The play law moves a memory only when a bound
      passes it, so a memory above its upper bound is kept through the first loading and
      cut at the first unloading (below its lower bound: the mirror). The first loading then
      rides on extra strain that the first unloading gives back. The level :math:`h` and the
      slope :math:`s` over the operators' widths (the wide operators keeping more, or less,
      of that history) are the first two terms of any held profile.

    The paper: the pre-tensioned return spring "is not sufficiently large to provide
    crystal lattice reorientation ... thus that after first cycle maximum strain is
    reduced", i.e. the first loading of a sample differs from later ones; what the first
    cycle starts from is the history before it. :math:`z^0 \to -\infty`, :math:`e = 0`,
    :math:`h = s = 0` resets every operator to its lower bound (fully virgin); all 0 is the
    paper's state.

    **Identifiability.** The level alone is *not identifiable next to a GPI with free
    offsets* (any input, any size): shifting both envelope offsets (``a3``, ``b3``) by
    :math:`s` shifts every bound and memory by :math:`s`; lowering both :math:`\Omega`
    offsets (``c3``, ``d3``) by :math:`s \sum_j p_j` restores the output; with
    :math:`s = -z^0` (clipped to the bounds' range) the plain GPI's level 0 gives exactly
    the same output (:data:`identify.diagnosis.diagnose.GPI_EQUIVALENTS`; measured: z0 = -20,
    293 noise sigmas against the plain GPI at the same parameters, is fitted by a plain GPI
    to ~1e-13 sigma). So ``initial_state_memory`` is **pinned by default**
    (``vary=False``); free it (``Model.with_parameters``) only where those offsets are
    pinned or carry another parametrisation (e.g. a peer's fit, whose operators start above
    their upper bounds). The excursion is not such a shift (it moves some operators and not
    others); it trades off with the thresholds' scale (which operators the excursion
    reaches) and, at small sizes, with the first cycle's shape (``training``,
    ``incomplete_reset``), and it saturates where the envelopes do (beyond the record's
    drive range larger :math:`|e|` changes nothing). The held level :math:`h` **is** the
    pinned level wherever every memory stays inside its bounds (Table 1 at 0 A: all twelve
    operators start inside; ``benchmarks/effects_identifiability.py``: 6.8e-11, round-off):
    only its part beyond an operator's bound is information, carried by the operators that
    start clamped and by sizes that take memories past their bounds (measured: a uniform
    :math:`h = 0.3` on the paper's input with two GPIs whose wide operators start clamped,
    5.7 noise sigmas visible, leaves 5.6 and 1.05 sigmas after a plain GPI refit). The
    slope is not a shift (1e-2). :math:`h` and :math:`s` trade off with each other and with the excursion
    (all three move the first loading), and with ``incomplete_reset`` and ``training``;
    a record with one first loading tells them apart only by the shape of that loading
    and of the first unloading. The paper's training effect, a maximum
    strain reduced *after* the first cycle, is a ratchet on the largest excursion so far,
    which no initial memory represents.

    Parameters: ``initial_state_memory`` [A, envelope units], ``-20 <= z0 <= 20``, pinned;
    ``initial_state_excursion`` [A, drive units], ``-20 <= e <= 20``;
    ``initial_state_held`` and ``initial_state_held_slope`` [A, envelope units],
    ``-10 <= h, s <= 10``; off: all 0.
    """

    name = "initial_state"
    stage = "state"
    first_cycle = True
    parameters = ParameterSet(
        [
            Parameter(
                "initial_state_memory",
                0.0,
                -20.0,
                20.0,
                unit="A",
                vary=False,
                description="level the operators' initial memory is clamped from (0: paper; very negative: virgin); "
                "pinned: an exact reparametrisation next to free GPI offsets",
            ),
            Parameter(
                "initial_state_excursion",
                0.0,
                -20.0,
                20.0,
                unit="A",
                description="the last reversal before the record: the drive went to v0 + e and back (0: none)",
            ),
            Parameter(
                "initial_state_held",
                0.0,
                -10.0,
                10.0,
                unit="A",
                description="memory held beyond the bounds at the start, every operator (0: none); "
                "kept until the first motion against it",
            ),
            Parameter(
                "initial_state_held_slope",
                0.0,
                -10.0,
                10.0,
                unit="A",
                description="the held memory's growth from the narrowest to the widest operator: h_j = h + s j/N",
            ),
        ]
    )
    summary = (
        "first-cycle state: initial operator memory from a level z0, a prior excursion to v0 + e and a memory "
        "held beyond the bounds h + s j/N (all 0 = paper)"
    )
    signature = "only the first cycles differ from the later ones, as if the sample had been driven before the record"

    @classmethod
    def get_test_parameters(cls):
        return {"initial_state_memory": -0.5}

    def initial_memory(self, params):
        """The level :math:`z^0`, shape ``(W,)`` [A]."""
        return self.values(params).memory

    def initial_excursion(self, params):
        """The prior excursion :math:`e`, shape ``(W,)`` [A]."""
        return self.values(params).excursion

    def initial_held(self, params, n_operators):
        r"""The held memory :math:`h_j = h + s\, j/N`, shape ``(W, N)`` [A]."""
        width = np.arange(1, n_operators + 1) / n_operators
        p = self.values(params)
        return p.held[:, None] + p.held_slope[:, None] * width[None, :]
