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
``a0, a1, a2, a3``        :math:`E(v_1), E(v_2)` with :math:`E(v) = S\,\gamma_a(v)` (the
                          envelope's contribution to the output at two input values), slope
                          ``a1`` and centre :math:`-a_2/a_1`; the same for ``b``
``c1, c2`` (``d1, d2``)   :math:`\log c_1` and the centre :math:`-c_2/c_1` (amplitude and
                          offset unchanged)
thermal node (tau, S, E)  :math:`\log\tau`, :math:`S g`, :math:`E g` with ``g`` the node's
                          rise at the record's end under a constant heating
                          (:math:`1 - e^{-T/\tau_T}`; node 2: times :math:`1 - e^{-T/\tau_2}`)
everything else           unchanged (other effects, the noise scale)
========================  =====================================================================

with :math:`v_1, v_2` at 10 % and 90 % of the record's input range. Measured on a
converged clean-record chain (50 Hz, 18 parameters): the fraction of each whitened
coordinate explained by quadratic terms of the others (0 for a Gaussian) fell from 0.53
(worst) / 0.17 (mean) to 0.10 / 0.05.

A block is used only when all its parameters are free (``alpha`` pinned for the weights,
a positive lower bound on ``c1``/``d1`` for their logarithm); otherwise its parameters
stay as they are. The map is a bijection on its domain, with an explicit inverse (the
weight block solves the one-dimensional, monotone equation for ``tau`` by safeguarded
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

import math

import emcee
import numpy as np
from numba import njit

from model import TABLE1, THETA_NAMES

__all__ = ["GPICoordinates", "IdentityCoordinates", "CoordinateMove", "COORDINATES", "coordinates_for"]

#: Fractions of the record's input range where the envelopes' values are coordinates.
POINT_FRACTIONS = (0.1, 0.9)
#: Thermal nodes (:class:`model.effects.Thermal`): block name -> (time constant, gains).
_THERMAL_NODES = {
    "thermal": ("thermal_tau", "thermal_sensitivity", "thermal_expansion"),
    "thermal_core": ("thermal_tau_core", "thermal_sensitivity_core", "thermal_expansion_core"),
}
_THERMAL = tuple(n for names in _THERMAL_NODES.values() for n in names)
#: Most safeguarded Newton steps for ``tau`` in the inverse map (typically 4-6 are used).
MAX_NEWTON_STEPS = 100


@njit(cache=True, error_model="numpy")
def _moment_rows(rho, tau, r, out):
    """Per row ``w``: ``out[:, w] = (S, R, central second moment, s0)`` of the weights
    ``p_j = rho e^{-tau r_j}`` (``s0 = sum_j e^{-tau r_j}``), one pass over the thresholds."""
    for w in range(rho.shape[0]):
        s0 = s1 = s2 = 0.0
        for j in range(r.shape[0]):
            e = math.exp(-tau[w] * r[j])
            s0 += e
            s1 += e * r[j]
            s2 += e * r[j] * r[j]
        out[0, w] = rho[w] * s0
        out[1, w] = rho[w] * s1
        out[2, w] = rho[w] * (s2 - s1 * s1 / s0)
        out[3, w] = s0


@njit(cache=True, error_model="numpy")
def _mean_and_var(t, r, r2):
    """Mean and variance of the thresholds ``r`` under the weights ``e^{-t r}``; the
    exponent's maximum is at the first or the last threshold (``-t r_j`` is monotone in
    ``j``), so the weights are scaled by it (no overflow)."""
    top = max(-t * r[0], -t * r[-1])
    s0 = s1 = s2 = 0.0
    for j in range(r.shape[0]):
        e = math.exp(-t * r[j] - top)
        s0 += e
        s1 += e * r[j]
        s2 += e * r2[j]
    m = s1 / s0
    return m, s2 / s0 - m * m


@njit(cache=True, error_model="numpy")
def _solve_tau_rows(mean, r, r2, lower, upper, mean_lo, mean_hi, m0, v0, max_steps, out):
    """Per row: the ``tau`` in ``[lower, upper]`` whose weighted mean threshold is ``mean``
    (safeguarded Newton from the linearisation at ``tau = 0``, a bisection step whenever
    Newton leaves the bracket, until a step moves ``tau`` by at most ``1e-13 (1 + |tau|)``);
    NaN where ``mean`` is not finite or outside ``[mean_hi, mean_lo]`` (the means at the
    bounds)."""
    for w in range(mean.shape[0]):
        target = mean[w]
        if not (target <= mean_lo and target >= mean_hi and math.isfinite(target)):
            out[w] = math.nan
            continue
        lo, hi = lower, upper
        t = min(max((m0 - target) / v0, lo), hi)
        for _ in range(max_steps):
            m, var = _mean_and_var(t, r, r2)
            f = m - target  # > 0: the root lies at larger tau
            if f > 0:
                lo = t
            else:
                hi = t
            newton = t + f / var
            t_new = newton if lo <= newton <= hi else 0.5 * (lo + hi)
            done = abs(t_new - t) <= 1e-13 * (1.0 + abs(t))
            t = t_new
            if done:
                break
        out[w] = t


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
    """

    def __init__(self, names, template, n_operators, input_range, lower, tau_bounds, duration=None, pinned=None):
        self.names = tuple(names)
        idx = {n: i for i, n in enumerate(self.names)}
        template = np.asarray(template, dtype=float)
        self.alpha = float(template[THETA_NAMES.index("alpha")])
        self.r = self.alpha * np.arange(1, int(n_operators) + 1)
        self._r2 = self.r**2
        self._at_bounds = None  # (mean at the tau bounds, mean and variance at tau = 0): _solve_tau
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
        for p in "ab":
            if {p + "0", p + "1", p + "2", p + "3"} <= idx.keys() and lower[idx[p + "1"]] > 0:
                blocks.append("envelope_" + p)
        for p in "cd":
            if {p + "1", p + "2"} <= idx.keys() and lower[idx[p + "1"]] > 0:
                blocks.append("omega_" + p)
        if self.duration is not None and self.duration > 0:
            for node, (tau_name, *gains) in _THERMAL_NODES.items():
                if {tau_name, *gains} <= idx.keys() and lower[idx[tau_name]] > 0:
                    blocks.append(node)
        self.blocks = tuple(blocks)
        #: The thermal blocks in use: (index into ``_thermal_scales``, time constant, gains).
        self._thermal = [
            (k, tau_name, gains)
            for k, (node, (tau_name, *gains)) in enumerate(_THERMAL_NODES.items())
            if node in self.blocks
        ]

    @classmethod
    def for_model(cls, model, time, current, names=None, lower=None):
        """The coordinates of ``model``'s free parameters on a record.

        Parameters
        ----------
        model : model.Model
        time, current : array_like, shape (T,)
            The record's times [s] and input: its input range and duration.
        names, lower : sequence, optional
            The coordinates and their lower bounds, when they are not the model's free
            parameters (e.g. a log-posterior's, with a noise coordinate).

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
        )

    @classmethod
    def from_log_posterior(cls, log_post):
        """The coordinates for a :class:`identify.posterior.LogPosterior` (its names,
        model, bounds and record input); :class:`IdentityCoordinates` for a log-posterior
        without a GPI model (e.g. a test density)."""
        model = getattr(log_post, "model", None)
        if model is None:
            return IdentityCoordinates()
        return cls.for_model(model, log_post.time, log_post.current, log_post.names, log_post.lower)

    # -- the weight block ------------------------------------------------------------
    def _moments(self, rho, tau):
        """``S = sum p_j``, ``R = sum p_j r_j``, the centred second moment and ``sum e^{-tau r_j}`` (W,)."""
        out = np.empty((4, np.size(rho)))
        _moment_rows(np.ascontiguousarray(rho, dtype=float), np.ascontiguousarray(tau, dtype=float), self.r, out)
        return out[0], out[1], out[2], out[3]

    def _gpi(self, x, name):
        if name in self.idx:
            return x[:, self.idx[name]]
        return np.full(x.shape[0], self._pinned[name])

    def _thermal_scales(self, x):
        """``(g1, g2)`` (W,): a node's rise at the end of the record under a constant unit
        heating, ``g(tau) = 1 - exp(-duration / tau)``, node 2 (heated through node 1)
        ``g(tau_1) g(tau_2)``; the gains' coordinates are the gains times these (what the
        record pins when a time constant is longer than the record is gain / tau)."""
        g1 = -np.expm1(-self.duration / self._gpi(x, "thermal_tau"))
        return g1, g1 * -np.expm1(-self.duration / self._gpi(x, "thermal_tau_core"))

    def _total_weight(self, x):
        rho, tau = self._gpi(x, "rho"), self._gpi(x, "tau")
        return self._moments(rho, tau)[0]

    def _mean_and_var(self, t):
        """Mean and variance of the thresholds under the weights ``e^{-t r}`` (W,)."""
        m, var = np.empty(np.size(t)), np.empty(np.size(t))
        for w, tw in enumerate(np.atleast_1d(np.asarray(t, dtype=float))):
            m[w], var[w] = _mean_and_var(tw, self.r, self._r2)
        return m, var

    def _solve_tau(self, mean):
        """``tau`` with weighted mean threshold ``sum r e^{-tau r} / sum e^{-tau r} = mean``;
        NaN where ``mean`` is outside the range ``tau_bounds`` gives.

        The mean decreases in tau with slope ``-var`` (the weights' variance of the
        thresholds), so Newton's method, kept inside a shrinking bracket (a bisection step
        whenever Newton would leave it), converges to machine precision in a few steps
        (:func:`_solve_tau_rows`, row by row).
        """
        if self._at_bounds is None:  # the same for every row: computed once
            mean_lo, _ = _mean_and_var(self.tau_bounds[0], self.r, self._r2)
            mean_hi, _ = _mean_and_var(self.tau_bounds[1], self.r, self._r2)
            m0, v0 = _mean_and_var(0.0, self.r, self._r2)
            self._at_bounds = (mean_lo, mean_hi, m0, v0)
        out = np.empty(np.size(mean))
        _solve_tau_rows(
            np.ascontiguousarray(mean, dtype=float),
            self.r,
            self._r2,
            self.tau_bounds[0],
            self.tau_bounds[1],
            *self._at_bounds,
            MAX_NEWTON_STEPS,
            out,
        )
        return out

    # -- the map ---------------------------------------------------------------------
    def forward(self, x) -> np.ndarray:
        """Sampler coordinates ``u`` ``(W, D)`` of parameters ``x`` ``(W, D)``."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = x.copy()
        i = self.idx
        S, R, _, _ = self._moments(self._gpi(x, "rho"), self._gpi(x, "tau"))
        if "weights" in self.blocks:
            u[:, i["rho"]], u[:, i["tau"]] = S, R
        for p in "ab":
            if "envelope_" + p in self.blocks:
                k0, k1, k2, k3 = (x[:, i[p + str(n)]] for n in range(4))
                t1, t2 = (np.tanh(k1 * v + k2) for v in self.points)
                u[:, i[p + "0"]] = S * (k0 * t1 + k3)
                u[:, i[p + "3"]] = S * (k0 * t2 + k3)
                u[:, i[p + "2"]] = -k2 / k1
        for p in "cd":
            if "omega_" + p in self.blocks:
                k1, k2 = x[:, i[p + "1"]], x[:, i[p + "2"]]
                with np.errstate(invalid="ignore", divide="ignore"):
                    u[:, i[p + "1"]] = np.log(k1)
                u[:, i[p + "2"]] = -k2 / k1
        if self._thermal:
            with np.errstate(invalid="ignore", divide="ignore"):
                scales = self._thermal_scales(x)
                for k, tau_name, gains in self._thermal:
                    u[:, i[tau_name]] = np.log(x[:, i[tau_name]])
                    for name in gains:
                        u[:, i[name]] = x[:, i[name]] * scales[k]
        return u

    def inverse(self, u) -> np.ndarray:
        """Parameters ``x`` ``(W, D)`` of sampler coordinates ``u``; rows outside the map's
        range (a total weight <= 0, a threshold moment no ``tau`` in its bounds gives, a
        zero slope) are NaN."""
        u = np.atleast_2d(np.asarray(u, dtype=float))
        x = u.copy()
        i = self.idx
        bad = np.zeros(u.shape[0], dtype=bool)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            if "weights" in self.blocks:
                S, R = u[:, i["rho"]], u[:, i["tau"]]
                tau = self._solve_tau(R / np.where(S > 0, S, np.nan))
                e = np.exp(-tau[:, None] * self.r[None, :]).sum(axis=1)
                x[:, i["rho"]], x[:, i["tau"]] = S / e, tau
                bad |= ~(S > 0) | ~np.isfinite(tau)
            S = self._total_weight(x)
            for p in "cd":
                if "omega_" + p in self.blocks:
                    k1 = np.exp(u[:, i[p + "1"]])
                    x[:, i[p + "1"]], x[:, i[p + "2"]] = k1, -u[:, i[p + "2"]] * k1
            for p in "ab":
                if "envelope_" + p in self.blocks:
                    k1 = u[:, i[p + "1"]]
                    k2 = -u[:, i[p + "2"]] * k1
                    t1, t2 = (np.tanh(k1 * v + k2) for v in self.points)
                    e1, e2 = u[:, i[p + "0"]] / S, u[:, i[p + "3"]] / S
                    k0 = (e1 - e2) / (t1 - t2)
                    x[:, i[p + "0"]], x[:, i[p + "2"]], x[:, i[p + "3"]] = k0, k2, e1 - k0 * t1
                    bad |= ~(k1 != 0) | ~(t1 != t2)
            if self._thermal:
                for _k, tau_name, _gains in self._thermal:  # both time constants before the scales
                    x[:, i[tau_name]] = np.exp(u[:, i[tau_name]])
                scales = self._thermal_scales(x)
                for k, _tau, gains in self._thermal:
                    for name in gains:
                        x[:, i[name]] = u[:, i[name]] / scales[k]
                    bad |= ~(scales[k] > 0)
        bad |= ~np.isfinite(x).all(axis=1)
        x[bad] = np.nan
        return x

    def log_det(self, x) -> np.ndarray:
        r"""``log |det du/dx|`` ``(W,)`` at parameters ``x`` ``(W, D)`` (closed form).

        Block-triangular (the weights first, then the slopes and centres, then the
        envelope values), so the determinant is the product of the blocks':

        * weights: :math:`|\partial(S,R)/\partial(\rho,\tau)| = \rho\,(s_0 s_2 - s_1^2)`
          with :math:`s_k = \sum_j r_j^k e^{-\tau r_j}`;
        * envelope ``a`` (``b``): :math:`S^2 |t_1 - t_2| / |a_1|` with
          :math:`t_k = \tanh(a_1 v_k + a_2)`;
        * Omega ``c`` (``d``): :math:`1 / c_1^2`;
        * a thermal node: :math:`g^2 / \tau` (two gains scaled by ``g``, the log of the
          time constant); node 2's ``g`` depends on node 1's time constant, which comes
          before it, so the blocks stay triangular.
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        i = self.idx
        out = np.zeros(x.shape[0])
        with np.errstate(invalid="ignore", divide="ignore"):
            rho, tau = self._gpi(x, "rho"), self._gpi(x, "tau")
            S, _, central, s0 = self._moments(rho, tau)
            if "weights" in self.blocks:
                # d(S, R)/d(rho, tau) = [[s0, -rho s1], [s1, -rho s2]]: |det| = rho (s0 s2 - s1^2) = s0 central
                out += np.log(np.abs(s0)) + np.log(np.abs(central))
            for p in "ab":
                if "envelope_" + p in self.blocks:
                    k1, k2 = x[:, i[p + "1"]], x[:, i[p + "2"]]
                    t1, t2 = (np.tanh(k1 * v + k2) for v in self.points)
                    out += 2 * np.log(np.abs(S)) + np.log(np.abs(t1 - t2)) - np.log(np.abs(k1))
            for p in "cd":
                if "omega_" + p in self.blocks:
                    out -= 2 * np.log(np.abs(x[:, i[p + "1"]]))
            if self._thermal:
                scales = self._thermal_scales(x)
                for k, tau_name, gains in self._thermal:
                    out += len(gains) * np.log(np.abs(scales[k])) - np.log(np.abs(x[:, i[tau_name]]))
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


def _identity(log_post):
    return IdentityCoordinates()


#: name -> factory ``f(log_post)`` of sampler coordinates.
COORDINATES = {"gpi": GPICoordinates.from_log_posterior, "identity": _identity}


def coordinates_for(spec, log_post):
    """Sampler coordinates from a :data:`COORDINATES` name or a callable ``f(log_post)``."""
    if callable(spec):
        return spec(log_post)
    if spec not in COORDINATES:
        raise ValueError(f"unknown sampler coordinates {spec!r}; known: {', '.join(COORDINATES)}")
    return COORDINATES[spec](log_post)


def _log_probabilities(model, q):
    """emcee's ``compute_log_prob`` of the proposals ``q``: ``(log_prob (n,), blobs)``. A
    log-probability function that declares ``vectorised_log_probability`` (e.g.
    :class:`identify.fitting.posterior.LogPosterior`: one call for all rows, a float array,
    never NaN, no blobs) is called directly, without emcee's per-row conversion and checks
    (the same numbers); any other goes through emcee."""
    wrapper = model.log_prob_fn
    fn = getattr(wrapper, "f", None)
    if getattr(fn, "vectorised_log_probability", False) and not wrapper.args and not wrapper.kwargs:
        return np.asarray(fn(q), dtype=float), None
    return model.compute_log_prob_fn(q)


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
        cs = self.coordinates
        q = cs.inverse(q_u)
        ok = np.isfinite(q).all(axis=1)
        factors = np.array(factors, dtype=float)
        log_det_q = np.full(q.shape[0], np.nan)
        with np.errstate(invalid="ignore"):
            log_det_q[ok] = cs.log_det(q[ok])
            factors[ok] += log_det_s[ok] - log_det_q[ok]
        ok &= np.isfinite(factors)
        q[~ok] = s[~ok]  # emcee refuses non-finite positions: stay, and reject below
        factors[~ok] = -np.inf
        return q, factors, log_det_q

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
        all_inds = np.arange(nwalkers)
        inds = all_inds % self.nsplits
        if self.randomize_split:
            model.random.shuffle(inds)
        for split in range(self.nsplits):
            S1 = inds == split
            s = state.coords[S1]
            c_u = [u[inds == j] for j in range(self.nsplits) if j != split]
            q_u, factors = self.move.get_proposal(u[S1], c_u, model.random)
            q, factors, log_det_q = self._back(s, q_u, factors, log_det[S1])
            new_log_probs, new_blobs = _log_probabilities(model, q)
            members = all_inds[S1]
            draws = model.random.rand(members.size)  # the draws of emcee's per-walker loop, in its order
            take = factors + new_log_probs - state.log_prob[members] > np.log(draws)
            accepted[members[take]] = True
            new_state = emcee.State(q, log_prob=new_log_probs, blobs=new_blobs)
            state = self.update(state, new_state, accepted, S1)
            moved = members[take]
            if moved.size:
                u[moved] = self.coordinates.forward(q[take])
                log_det[moved] = log_det_q[take]
        self._x = np.array(state.coords, dtype=float)
        return state, accepted
