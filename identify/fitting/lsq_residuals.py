"""The least squares' objective: the whitened residuals of a record as a function of the free
parameters (:class:`WhitenedResiduals`), with their batched forward- and central-difference
Jacobians and the compiled difference layout (:func:`difference_columns`).

The method (whitening, the penalty outside the domain, the steps) is stated in
:mod:`identify.fitting.lsq`'s docstring, "Objective" and "Jacobian".
"""

from __future__ import annotations

import copy

import numpy as np
from numba import njit

from model import Model

from .noise import NoiseModel, whiten_rows
from .threads import use_idle_cores

__all__ = ["WhitenedResiduals", "difference_columns", "DOMAIN_PENALTY", "CENTRAL_STEP_POWER"]

#: Whitened residual per sample returned for a parameter set whose model output is not finite.
DOMAIN_PENALTY = 1e5
#: Central-difference step ``eps**CENTRAL_STEP_POWER * max(|theta|, 0.01)``. Smaller than the
#: textbook ``eps**(1/3)`` on purpose: the play operators' clamps make the output only
#: piecewise smooth, and a step that straddles a kink at some sample mixes the two
#: branches' slopes differently for each parameter; with 0.45 (steps ~1e-7 relative) the
#: GPI's exact scaling degeneracy shows as an eigenvalue ~1e-17 of the largest (1e-10 with 1/3).
CENTRAL_STEP_POWER = 0.45


@njit(cache=True, nogil=True)
def difference_columns(rows, base, steps, columns, out, first=1):
    """Forward differences laid out as a Jacobian: ``out[k, j] = (rows[j + first, k] - base[k]) / steps[j]``
    for each ``j`` in ``columns`` (``rows`` of shape ``(P + first, T)``, ``out`` ``(T, P)``; other
    columns untouched).

    The same two operations per value as numpy's ``((rows[1:] - base) / steps[:, None]).T``,
    so the same bits, written in blocks of samples: numpy's transposed copy of the
    ``(P, T)`` differences strides through memory and costs about ten times as much at
    70001 samples."""
    n_samples = base.shape[0]
    block = 64
    for k0 in range(0, n_samples, block):
        k1 = min(k0 + block, n_samples)
        for j in columns:
            step = steps[j]
            for k in range(k0, k1):
                out[k, j] = (rows[j + first, k] - base[k]) / step


class WhitenedResiduals:
    """Whitened residuals of a record as a function of the free parameters.

    Parameters
    ----------
    record : Record
        Supplies ``time``, ``current``, ``displacement`` (shape (T,)).
    model : model.Model
    noise : NoiseModel
        A free sigma is treated as 1 here (the scale does not move the optimum).

    Attributes
    ----------
    free : ndarray of int, shape (P_free,)
        Columns of the full vector that vary.
    template : ndarray, shape (P,)
        The full vector's pinned values.
    n_evaluations : int
        Model rows evaluated so far.
    """

    def __init__(self, record, model: Model, noise: NoiseModel):
        self.time = np.asarray(record.time, dtype=float)
        self.current = np.asarray(record.current, dtype=float)
        self.data = np.asarray(record.displacement, dtype=float)
        self.model = model
        self.noise = noise
        # each step's correlation r_k when the grid's steps are not all the noise's one step
        # (a thinned record), else None (every step rho): computed once, whitened with at each call
        self._correlations = noise.step_correlations(self.time)
        self.sigma = 1.0 if noise.is_free else noise.sigma
        self.free = np.flatnonzero(model.parameters.vary)
        self.template = model.parameters.values.copy()
        self.lower = model.parameters.lower[self.free]
        self.upper = model.parameters.upper[self.free]
        self.n_evaluations = 0
        self._cache_x = None
        self._cache_r = None
        self._cache_valid = False

    def copy(self) -> WhitenedResiduals:
        """The same residuals with their own last-point cache and evaluation count (for a fit run
        beside another on this one's data: the arrays are shared, read only)."""
        twin = copy.copy(self)
        twin.n_evaluations = 0
        twin._cache_x = twin._cache_r = None
        twin._cache_valid = False
        return twin

    def full(self, x) -> np.ndarray:
        """Full vector(s) ``(…, P)`` from free values ``(…, P_free)``."""
        x = np.asarray(x, dtype=float)
        out = np.broadcast_to(self.template, x.shape[:-1] + self.template.shape).copy()
        out[..., self.free] = x
        return out

    def batch(self, x_rows) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals ``(B, T)`` and validity ``(B,)`` for free vectors ``(B, P_free)``."""
        thetas = self.full(np.atleast_2d(x_rows))
        use_idle_cores()
        y, valid = self.model.evaluate(thetas, self.time, self.current)
        self.n_evaluations += thetas.shape[0]
        w, finite = whiten_rows(self.data, y, self.noise, self.sigma, correlations=self._correlations)
        valid = valid & finite
        return w, valid

    def __call__(self, x) -> np.ndarray:
        """Residual vector ``(T,)``; :data:`DOMAIN_PENALTY` everywhere where the output is not finite."""
        x = np.asarray(x, dtype=float)
        if self._cache_x is not None and np.array_equal(x, self._cache_x):
            return self._cache_r
        w, valid = self.batch(x[None, :])
        r = w[0] if valid[0] else np.full(self.data.size, DOMAIN_PENALTY)
        self._cache_x, self._cache_r, self._cache_valid = x.copy(), r, bool(valid[0])
        return r

    def _steps(self, x, power):
        return np.finfo(float).eps ** power * np.maximum(np.abs(x), 0.01)

    def jacobian(self, x, columns=None) -> np.ndarray:
        """Forward-difference Jacobian ``(T, P_free)`` from one batch: a row per column and the
        point itself unless it is the last point evaluated (its residual is kept; a solver asks
        for the Jacobian where it has just evaluated the residual). With ``columns`` (indices
        into the free values), only those columns ``(T, len(columns))``."""
        x = np.asarray(x, dtype=float)
        columns = np.arange(x.size) if columns is None else np.asarray(columns, dtype=np.int64)
        if not columns.size:
            return np.empty((self.data.size, 0))
        steps = self._steps(x[columns], 0.5)
        steps = np.where(x[columns] + steps > self.upper[columns], -steps, steps)
        known = self._cache_x is not None and np.array_equal(x, self._cache_x)
        first = 0 if known else 1
        rows = np.repeat(x[None, :], columns.size + first, axis=0)
        rows[first:][np.arange(columns.size), columns] += steps
        w, valid = self.batch(rows)
        base_valid = self._cache_valid if known else bool(valid[0])
        base = self._cache_r if known else (w[0] if base_valid else self(x))
        jac = np.empty((self.data.size, columns.size))
        difference_columns(w, base, steps, np.arange(columns.size), jac, first)
        bad = [j for j in range(columns.size) if not valid[j + first]]
        jac[:, bad] = 0.0
        if bad and base_valid:
            # Non-finite output on the forward step: step backward instead, in one more batch.
            back = np.repeat(x[None, :], len(bad), axis=0)
            back[np.arange(len(bad)), columns[bad]] -= steps[bad]
            back = np.clip(back, self.lower, self.upper)
            wb, vb = self.batch(back)
            for k, j in enumerate(bad):
                delta = back[k, columns[j]] - x[columns[j]]
                if vb[k] and delta != 0:
                    jac[:, j] = (wb[k] - base) / delta
        return jac

    def central_jacobian(self, x) -> np.ndarray:
        """Central-difference Jacobian ``(T, P_free)`` from one ``(2 P_free + 1)``-row batch.

        Falls back to one-sided differences for a column whose up or down step leaves
        the bounds or gives a non-finite output.
        """
        x = np.asarray(x, dtype=float)
        n_free = x.size
        steps = self._steps(x, CENTRAL_STEP_POWER)
        up = np.repeat(x[None, :], n_free, axis=0)
        down = up.copy()
        idx = np.arange(n_free)
        up[idx, idx] = np.minimum(x + steps, self.upper)
        down[idx, idx] = np.maximum(x - steps, self.lower)
        w, valid = self.batch(np.vstack([x[None, :], up, down]))
        base, w_up, w_down = w[0], w[1 : n_free + 1], w[n_free + 1 :]
        v_up, v_down = valid[1 : n_free + 1], valid[n_free + 1 :]
        jac = np.zeros((self.data.size, n_free))
        for j in range(n_free):
            hu, hd = up[j, j] - x[j], x[j] - down[j, j]
            if v_up[j] and v_down[j] and hu > 0 and hd > 0:
                jac[:, j] = (w_up[j] - w_down[j]) / (hu + hd)
            elif v_up[j] and hu > 0:
                jac[:, j] = (w_up[j] - base) / hu
            elif v_down[j] and hd > 0:
                jac[:, j] = (base - w_down[j]) / hd
        return jac
