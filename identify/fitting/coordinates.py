r"""Sampler coordinates in which the GPI posterior is nearly Gaussian, and the emcee move that uses them.

Why
---
emcee's moves are affine-invariant: a *linear* change of coordinates cannot change how
fast they mix. The GPI posterior is not linearly but *curvedly* correlated: the output
is :math:`\Omega + \sum_j p_j z_j` with :math:`z_j` following the envelopes, so the
operator weights and the envelopes' amplitudes trade along products
(:math:`\rho\,a_0`, :math:`\rho\,a_3`, ...), and each tanh's slope and offset along a
ratio (its centre :math:`-k_2/k_1`). On such a ridge the ensemble's difference vectors
point the wrong way and the chain crawls. :class:`GPICoordinates` maps the parameters to
quantities the record pins almost linearly:

========================  =====================================================================
parameters                sampler coordinates
========================  =====================================================================
``rho, tau``              total weight :math:`S = \sum_j p_j` and threshold moment
                          :math:`R = \sum_j p_j r_j`, with :math:`p_j = \rho e^{-\tau r_j}`
``a0, a1, a2, a3``        :math:`E(v_1), E(v_m), E(v_2)` with :math:`E(v) = S\,\gamma_a(v)`
                          (the envelope's contribution to the output at three input values)
                          and :math:`\log a_0`; the same for ``b``
``c1, c2`` (``d1, d2``)   :math:`\log c_1` and the centre :math:`-c_2/c_1` (amplitude and
                          offset unchanged)
thermal node (tau, S, E)  :math:`\log\tau`, :math:`S g`, :math:`E g` with ``g`` the node's
                          rise at the record's end under a constant heating
                          (:math:`1 - e^{-T/\tau_T}`; node 2: times :math:`1 - e^{-T/\tau_2}`)
everything else           unchanged (other effects, the noise scale)
========================  =====================================================================

with :math:`v_1, v_m, v_2` at 10 %, 50 % and 90 % of the record's input range.

Why three values and the amplitude, not two values, the slope and the centre: a record sees
an envelope only over its input range. When the tanh's centre lies outside it (or its slope
is small), the record sees a tail (or a near-straight piece) of the tanh, which a larger
amplitude with a shifted centre (or a smaller slope) draws as well; the record pins the
envelope's values, and what it leaves free is how far the tanh is from that limit, along
which amplitude, slope and centre all move together, curvedly. Three values pin the shape
the record sees in every regime (centred, tail, straight), nearly linearly, and the
amplitude's logarithm is left for the direction the record leaves open. Values carry a
tanh's slope and centre only where it still varies, so an envelope that has flattened at one
of the three inputs at the reference point (the least-squares solution: a step sharper than
the inputs' spacing, an envelope constant over the record; :data:`SENSITIVE_SLOPE`) keeps
two values (at 10 % and 90 %), its slope and its centre :math:`-a_2/a_1`. How Gaussian a
study's chain is in either choice (the fraction of each whitened coordinate explained by
quadratic terms of the others, 0 for a Gaussian): ``benchmarks/coordinate_curvature.py``,
with its measured figures in ``docs/benchmarks.md``.

A block is used only when all its parameters are free (``alpha`` pinned for the weights),
and a coordinate is a logarithm only of a parameter with a positive lower bound (``c1``,
``d1``; ``a0``, ``b0`` with ``a1``, ``b1`` positive too: an increasing envelope); otherwise
the block's parameters stay as they are. The map is a bijection on its domain, with an
explicit inverse (the weight block solves the one-dimensional, monotone equation for
``tau``, each envelope the one-dimensional equation of equal argument steps between its
three values, :func:`identify.fitting._coordinate_kernels.equal_steps`, both by safeguarded
Newton steps to machine precision) and the log-determinant of its Jacobian in closed form
(block-triangular: ``log |det du/dx|`` is a sum over the blocks).

How the chain stays in the parameters
-------------------------------------
:class:`CoordinateMove` wraps an emcee move: it maps the walkers to the sampler
coordinates, lets the wrapped move propose there, maps the proposal back and adds the
Jacobian ratio :math:`\log|\det \partial u/\partial x|(x) - \log|\det \partial u/\partial
x|(x')` to the acceptance. That is the Metropolis-Hastings rule for a proposal made in
``u``, so the target stays the posterior *of the parameters*: the log-posterior, the
priors and the stored chain (``chain.h5``) are in the parameters the user sees, and
resuming needs nothing new. A proposal outside the map's range (e.g. a negative total
weight) is rejected.

Registry
--------
:data:`COORDINATES`: ``"gpi"`` (:class:`GPICoordinates`, the default of
:func:`identify.posterior.sample_posterior`) and ``"identity"`` (the parameters
themselves); or any callable ``f(log_post)`` returning an object with ``forward``,
``inverse`` and ``log_det``.
"""

from __future__ import annotations

import emcee
import numpy as np

from model import TABLE1, THETA_NAMES

from . import _coordinate_kernels as kernels

__all__ = [
    "GPICoordinates",
    "IdentityCoordinates",
    "CoordinateMove",
    "COORDINATES",
    "coordinates_for",
    "POINT_FRACTIONS",
    "SENSITIVE_SLOPE",
]

#: Fractions of the record's input range where the envelopes' values are coordinates (two
#: values: the outer two).
POINT_FRACTIONS = (0.1, 0.5, 0.9)
#: An envelope's values carry its tanh's slope and centre only where the tanh still varies:
#: it takes three values (and its amplitude) as coordinates when, at the reference point, its
#: slope ``1 - tanh^2`` at each of the three inputs is at least this share of the maximum
#: (``|a1 v + a2| <= 4.1``). Where it has flattened at an input (a step sharper than the
#: points' spacing, an envelope constant over the record) the values no longer tell the slope
#: and centre apart, and those stay coordinates themselves.
SENSITIVE_SLOPE = 1e-3
#: Thermal nodes (:class:`model.effects.Thermal`): block name -> (time constant, gains).
_THERMAL_NODES = {
    "thermal": ("thermal_tau", "thermal_sensitivity", "thermal_expansion"),
    "thermal_core": ("thermal_tau_core", "thermal_sensitivity_core", "thermal_expansion_core"),
}
_THERMAL = tuple(n for names in _THERMAL_NODES.values() for n in names)
#: Most safeguarded Newton steps for ``tau`` in the inverse map (typically 4-6 are used).
MAX_NEWTON_STEPS = 100


class IdentityCoordinates:
    """The parameters themselves (``forward`` and ``inverse`` copy, ``log_det`` is 0)."""

    blocks: tuple = ()

    def forward(self, x):
        return np.array(x, dtype=float)

    def inverse(self, u):
        return np.array(u, dtype=float)

    def log_det(self, x):
        return np.zeros(np.atleast_2d(x).shape[0])


class GPICoordinates:
    """The map between the sampled parameters ``x`` and near-Gaussian coordinates ``u``.

    Parameters
    ----------
    names : sequence of str, length D
        Names of the sampled coordinates (``LogPosterior.names``).
    template : array_like, shape (P,)
        The model's full parameter vector; pinned values (``alpha``, and anything not in
        ``names``) are read from it.
    n_operators : int
        Number of play operators ``N`` (thresholds ``r_j = alpha j``, ``j = 1..N``).
    input_range : (float, float)
        Smallest and largest input of the record [input unit]; the envelope values are
        taken at :data:`POINT_FRACTIONS` of it.
    lower : array_like, shape (D,)
        Lower bounds of the sampled coordinates (a log is used for ``c1``/``d1`` only
        when theirs is positive).
    tau_bounds : (float, float)
        Bracket for ``tau`` in the inverse map (the parameter's bounds).
    duration : float, optional
        The record's duration [s]; needed for the thermal blocks (none without it).
    pinned : dict, optional
        Values of pinned thermal time constants ``{name: value}`` [s] (a free node-2 block
        with node 1's time constant pinned reads it here).
    reference : array_like, shape (D,), optional
        A point of the sampled coordinates near the posterior (a study passes the
        least-squares solution): an envelope whose tanh has flattened at one of the three
        inputs there (:data:`SENSITIVE_SLOPE`) keeps two values, its slope and its centre as
        coordinates. Without one every envelope takes three values.

    Attributes
    ----------
    three_values : tuple of str
        The envelope blocks (``"envelope_a"``, ``"envelope_b"``) whose coordinates are three
        values and the amplitude's logarithm.
    """

    def __init__(
        self, names, template, n_operators, input_range, lower, tau_bounds, duration=None, pinned=None, reference=None
    ):
        self.names = tuple(names)
        idx = {n: i for i, n in enumerate(self.names)}
        template = np.asarray(template, dtype=float)
        self.alpha = float(template[THETA_NAMES.index("alpha")])
        self.r = self.alpha * np.arange(1, int(n_operators) + 1)
        self._pinned = {n: float(template[THETA_NAMES.index(n)]) for n in ("rho", "tau")}
        self.tau_bounds = (float(tau_bounds[0]), float(tau_bounds[1]))
        lo, hi = float(input_range[0]), float(input_range[1])
        if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
            raise ValueError(f"input_range must be finite and increasing, got {input_range!r}")
        self.points = tuple(lo + f * (hi - lo) for f in POINT_FRACTIONS)
        self.duration = None if duration is None else float(duration)
        self._pinned.update(pinned or {})
        self.idx = idx
        lower = np.asarray(lower, dtype=float)
        blocks = []
        if "alpha" not in idx and self.alpha != 0 and {"rho", "tau"} <= idx.keys():
            blocks.append("weights")
        three = []
        for p in "ab":
            if {p + "0", p + "1", p + "2", p + "3"} <= idx.keys() and lower[idx[p + "1"]] > 0:
                blocks.append("envelope_" + p)
                if lower[idx[p + "0"]] > 0 and self._varies_at_the_points(reference, idx, p):
                    three.append("envelope_" + p)
        self.three_values = tuple(three)
        for p in "cd":
            if {p + "1", p + "2"} <= idx.keys() and lower[idx[p + "1"]] > 0:
                blocks.append("omega_" + p)
        if self.duration is not None and self.duration > 0:
            for node, (tau_name, *gains) in _THERMAL_NODES.items():
                if {tau_name, *gains} <= idx.keys() and lower[idx[tau_name]] > 0:
                    blocks.append(node)
        self.blocks = tuple(blocks)
        self._tau_bounds = np.array(self.tau_bounds)
        column = idx.get
        self.layout = kernels.Layout(
            np.array([b in self.blocks for b in kernels.BLOCKS]),
            np.array([column("rho", -1), column("tau", -1)]),
            np.array([[column(p + str(n), -1) for n in range(4)] for p in "ab"]),
            np.array([[column(p + str(n), -1) for n in (1, 2)] for p in "cd"]),
            np.array([[column(n, -1) for n in names] for names in _THERMAL_NODES.values()]),
            np.array([self._pinned.get(n, np.nan) for n in ("rho", "tau", "thermal_tau", "thermal_tau_core")]),
            np.array(["envelope_" + p in self.three_values for p in "ab"]),
            np.array(self.points, dtype=float),
            self.r,
            np.nan if self.duration is None else self.duration,
        )

    def _varies_at_the_points(self, reference, idx, p) -> bool:
        """Whether envelope ``p``'s tanh at ``reference`` has a slope of at least
        :data:`SENSITIVE_SLOPE` of its maximum at each of the three inputs (True without one)."""
        if reference is None:
            return True
        reference = np.asarray(reference, dtype=float)
        slope, offset = reference[idx[p + "1"]], reference[idx[p + "2"]]
        arguments = slope * np.asarray(self.points) + offset
        return bool(np.all(1.0 - np.tanh(arguments) ** 2 >= SENSITIVE_SLOPE))

    @classmethod
    def for_model(cls, model, time, current, names=None, lower=None, reference=None):
        """The coordinates of ``model``'s free parameters on a record.

        Parameters
        ----------
        model : model.Model
        time, current : array_like, shape (T,)
            The record's times [s] and input: its input range and duration.
        names, lower : sequence, optional
            The coordinates and their lower bounds, when they are not the model's free
            parameters (e.g. a log-posterior's, with a noise coordinate).
        reference : array_like, shape (D,), optional
            A point near the posterior (see the class).

        Returns
        -------
        GPICoordinates, or IdentityCoordinates for a model without the GPI's weights.
        """
        if model is None or not {"alpha", "tau"} <= set(getattr(model, "names", ())):
            return IdentityCoordinates()
        free = model.parameters.vary
        names = [n for n, v in zip(model.names, free) if v] if names is None else names
        lower = model.parameters.lower[free] if lower is None else lower
        tau = model.parameters["tau"]
        return cls(
            names,
            model.parameters.values,
            model.n_operators,
            (float(np.min(current)), float(np.max(current))),
            lower,
            (tau.lower, tau.upper),
            duration=float(np.ptp(time)) if np.size(time) > 1 else None,
            pinned={n: float(model.parameters[n].value) for n in _THERMAL if n in model.names},
            reference=reference,
        )

    @classmethod
    def from_log_posterior(cls, log_post, reference=None):
        """The coordinates for a :class:`identify.posterior.LogPosterior` (its names,
        model, bounds and record input; ``reference`` as for the class);
        :class:`IdentityCoordinates` for a log-posterior without a GPI model (e.g. a test
        density)."""
        model = getattr(log_post, "model", None)
        if model is None:
            return IdentityCoordinates()
        return cls.for_model(model, log_post.time, log_post.current, log_post.names, log_post.lower, reference)

    # -- the map (compiled loops, row by row: :mod:`identify.fitting._coordinate_kernels`) --
    def _rows(self, a):
        return np.ascontiguousarray(np.atleast_2d(np.asarray(a, dtype=float)))

    def forward(self, x) -> np.ndarray:
        """Sampler coordinates ``u`` ``(W, D)`` of parameters ``x`` ``(W, D)``."""
        x = self._rows(x)
        u = np.empty_like(x)
        kernels.forward_rows(x, *self.layout, u)
        return u

    def inverse(self, u) -> np.ndarray:
        """Parameters ``x`` ``(W, D)`` of sampler coordinates ``u``; rows outside the map's
        range (a total weight <= 0, a threshold moment no ``tau`` in its bounds gives, a
        set of envelope values no increasing tanh of that amplitude passes through) are NaN."""
        u = self._rows(u)
        x = np.empty_like(u)
        kernels.inverse_rows(u, *self.layout, self._tau_bounds, MAX_NEWTON_STEPS, u, False, x)
        return x

    def back(self, s, q_u, factors, log_det_s):
        """:meth:`CoordinateMove._back` in one compiled pass: the proposals ``q_u`` ``(W, D)`` in the
        parameters, their log factors ``(W,)`` with the Jacobian ratio added (``log_det_s``: the
        walkers' ``s`` log-determinants) and their log-determinants; a row outside the map's
        range or with a non-finite factor stays at ``s`` with factor ``-inf``."""
        if type(self).inverse is not GPICoordinates.inverse or type(self).log_det is not GPICoordinates.log_det:
            return back_in_steps(self, s, q_u, factors, log_det_s)  # a subclass's own map
        q_u = self._rows(q_u)
        q = np.empty_like(q_u)
        out_factors = np.empty(q_u.shape[0])
        log_det_q = np.empty(q_u.shape[0])
        kernels.back_rows(
            self._rows(s),
            q_u,
            np.ascontiguousarray(factors, dtype=float),
            np.ascontiguousarray(log_det_s, dtype=float),
            *self.layout,
            self._tau_bounds,
            MAX_NEWTON_STEPS,
            q,
            out_factors,
            log_det_q,
        )
        return q, out_factors, log_det_q

    def log_det(self, x) -> np.ndarray:
        r"""``log |det du/dx|`` ``(W,)`` at parameters ``x`` ``(W, D)`` (closed form).

        Block-triangular (the weights first; each envelope's and Omega's coordinates
        depend on the weights and on their own parameters only), so the determinant is the
        product of the blocks':

        * weights: :math:`|\partial(S,R)/\partial(\rho,\tau)| = \rho\,(s_0 s_2 - s_1^2)`
          with :math:`s_k = \sum_j r_j^k e^{-\tau r_j}`;
        * envelope ``a`` (``b``): :math:`S^3 a_0 |\det N|`, the rows of the 3 x 3 matrix
          :math:`N` being :math:`(s_k v_k, s_k, 1)` with
          :math:`s_k = 1 - \tanh^2(a_1 v_k + a_2)` at the three inputs;
        * Omega ``c`` (``d``): :math:`1 / c_1^2`;
        * a thermal node: :math:`g^2 / \tau` (two gains scaled by ``g``, the log of the
          time constant); node 2's ``g`` depends on node 1's time constant, which comes
          before it, so the blocks stay triangular.
        """
        x = self._rows(x)
        out = np.empty(x.shape[0])
        kernels.log_det_rows(x, *self.layout, out)
        return out

    @staticmethod
    def get_test_parameters():
        """A small setting for the tests: the 18 free GPI parameters of the normalised
        model at Table 1 (alpha pinned), 12 operators, input 0-5 A."""
        names = [n for n in THETA_NAMES if n != "alpha"]
        lower = np.full(len(names), -np.inf)
        for n in ("a1", "b1", "c1", "d1", "rho", "a0", "b0"):
            lower[names.index(n)] = 1e-3
        x = np.array([TABLE1[THETA_NAMES.index(n)] for n in names])
        return dict(
            names=names, template=TABLE1, n_operators=12, input_range=(0.0, 5.0), lower=lower, tau_bounds=(-5.0, 5.0)
        ), x


def _identity(log_post, reference=None):
    return IdentityCoordinates()


#: name -> factory ``f(log_post, reference=None)`` of sampler coordinates.
COORDINATES = {"gpi": GPICoordinates.from_log_posterior, "identity": _identity}


def coordinates_for(spec, log_post, reference=None):
    """Sampler coordinates from a :data:`COORDINATES` name (given ``reference``, a point near the
    posterior, shape (D,), or None) or a callable ``f(log_post)``."""
    if callable(spec):
        return spec(log_post)
    if spec not in COORDINATES:
        raise ValueError(f"unknown sampler coordinates {spec!r}; known: {', '.join(COORDINATES)}")
    return COORDINATES[spec](log_post, reference)


def back_in_steps(coordinates, s, q_u, factors, log_det_s):
    """:meth:`CoordinateMove._back` with the map's ``inverse`` and ``log_det``: ``(q, factors,
    log_det_q)``; a row outside the map's range or with a non-finite factor stays at ``s`` with
    factor ``-inf`` (emcee refuses non-finite positions: the walker stays, and is rejected)."""
    q = coordinates.inverse(q_u)
    ok = np.isfinite(q).all(axis=1)
    factors = np.array(factors, dtype=float)
    log_det_q = np.full(q.shape[0], np.nan)
    with np.errstate(invalid="ignore"):
        log_det_q[ok] = coordinates.log_det(q[ok])
        factors[ok] += log_det_s[ok] - log_det_q[ok]
    ok &= np.isfinite(factors)
    q[~ok] = s[~ok]
    factors[~ok] = -np.inf
    return q, factors, log_det_q


def _log_probabilities(model, q):
    """emcee's ``compute_log_prob`` of the proposals ``q``: ``(log_prob (n,), blobs)``. A
    log-probability function that declares ``vectorised_log_probability`` (e.g.
    :class:`identify.fitting.posterior.LogPosterior`: one call for all rows, a float array,
    never NaN, no blobs), given as it is (:class:`identify.fitting.ensemble.EnsembleLoop`) or in
    emcee's wrapper without arguments, is called directly, without emcee's per-row conversion
    and checks (the same numbers); any other goes through emcee."""
    fn = model.log_prob_fn
    if not getattr(fn, "vectorised_log_probability", False):
        inner = getattr(fn, "f", None)
        if not (getattr(inner, "vectorised_log_probability", False) and not fn.args and not fn.kwargs):
            return model.compute_log_prob_fn(q)
        fn = inner
    return np.asarray(fn(q), dtype=float), None


class CoordinateMove(emcee.moves.RedBlueMove):
    """An emcee red-blue move made in other coordinates (see the module docstring).

    Parameters
    ----------
    move : emcee.moves.RedBlueMove
        The move that proposes in the sampler coordinates (e.g. ``DEMove()``).
    coordinates : object
        ``forward(x) -> u``, ``inverse(u) -> x`` (NaN rows outside the range) and
        ``log_det(x) -> log|det du/dx|``, all ``(W, D)``.

    :meth:`propose` is emcee's :meth:`emcee.moves.RedBlueMove.propose` (emcee 3.1: the
    same random draws in the same order, the same acceptance rule) with two savings that
    change no number: the ensemble's sampler coordinates and log-determinants are kept
    from one call to the next (the map is computed for the accepted proposals only, not
    again for every walker in every split: both are row by row, so a row's value does
    not depend on the rows computed with it), and the acceptance test is one vectorised
    comparison with the uniform draws taken as one array (``rand(n)`` gives the numbers
    of ``n`` calls of ``rand()``). ``tests/test_coordinates.py`` checks the chain is
    emcee's stock one bit for bit.
    """

    def __init__(self, move, coordinates):
        super().__init__(
            nsplits=move.nsplits, randomize_split=move.randomize_split, live_dangerously=move.live_dangerously
        )
        self.move = move
        self.coordinates = coordinates
        self._x = self._u = self._log_det = None  # the ensemble, its coordinates and log-determinants

    def setup(self, coords):
        self.move.setup(self.coordinates.forward(coords))

    def get_proposal(self, s, c, random):
        cs = self.coordinates
        q_u, factors = self.move.get_proposal(cs.forward(s), [cs.forward(ci) for ci in c], random)
        return self._back(s, q_u, factors, cs.log_det(s))[:2]

    def _back(self, s, q_u, factors, log_det_s):
        """The proposals in the parameters, their log factors (Jacobian ratio added; -inf
        outside the map's range) and, where finite, the proposals' log-determinants."""
        back = getattr(self.coordinates, "back", None)
        if back is not None:  # the same in one compiled pass (GPICoordinates)
            return back(s, q_u, factors, log_det_s)
        return back_in_steps(self.coordinates, s, q_u, factors, log_det_s)

    def _ensemble(self, coords):
        """Sampler coordinates and log-determinants of the walkers ``coords``: kept from the
        previous call when the walkers are those it left, else computed."""
        if self._x is None or self._x.shape != coords.shape or not np.array_equal(self._x, coords):
            self._x = np.array(coords, dtype=float)
            self._u = self.coordinates.forward(self._x)
            self._log_det = self.coordinates.log_det(self._x)
        return self._u, self._log_det

    def propose(self, model, state):
        """emcee's red-blue update (see the class docstring): ``(state, accepted)``."""
        nwalkers, ndim = state.coords.shape
        if nwalkers < 2 * ndim and not self.live_dangerously:
            raise RuntimeError(
                "It is unadvisable to use a red-blue move with fewer walkers than twice the number of dimensions."
            )
        u, log_det = self._ensemble(state.coords)
        self.move.setup(u)
        accepted = np.zeros(nwalkers, dtype=bool)
        inds = np.arange(nwalkers) % self.nsplits
        if self.randomize_split:
            model.random.shuffle(inds)
        splits = [np.flatnonzero(inds == j) for j in range(self.nsplits)]  # each split's walkers, in order
        for split, members in enumerate(splits):
            c_u = [u[others] for j, others in enumerate(splits) if j != split]
            q_u, factors = self.move.get_proposal(u[members], c_u, model.random)
            q, factors, log_det_q = self._back(state.coords[members], q_u, factors, log_det[members])
            new_log_probs, new_blobs = _log_probabilities(model, q)
            draws = model.random.rand(members.size)  # the draws of emcee's per-walker loop, in its order
            take = factors + new_log_probs - state.log_prob[members] > np.log(draws)
            moved = members[take]
            accepted[moved] = True
            if new_blobs is None:  # emcee's update: the accepted walkers of this split take their proposals
                state.coords[moved] = q[take]
                state.log_prob[moved] = new_log_probs[take]
            else:
                new_state = emcee.State(q, log_prob=new_log_probs, blobs=new_blobs)
                state = self.update(state, new_state, accepted, inds == split)
            if moved.size:
                u[moved] = self.coordinates.forward(q[take])
                log_det[moved] = log_det_q[take]
        self._x = np.array(state.coords, dtype=float)
        return state, accepted
