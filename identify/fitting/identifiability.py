r"""Identifiability of the GPI: the exact scaling degeneracy, its normalisation, weak directions.

The exact degeneracy
--------------------
For any ``k > 0`` the GPI output is unchanged by

.. math::  (\rho, \alpha, \tau, a_0, a_3, b_0, b_3) \to
           (\rho/k,\ k\alpha,\ \tau/k,\ k a_0,\ k a_3,\ k b_0,\ k b_3) :

the envelopes (6), (7) and the thresholds :math:`r_j = \alpha j` all scale by ``k``, so
every operator's memory scales by ``k`` (the initial memory :math:`z^0 = 0` is
scale-free), while the weights :math:`p_j = \rho e^{-\tau r_j}` scale by ``1/k``
(:math:`\tau r_j` is unchanged). So the likelihood is flat along a curve and a
posterior with flat priors is improper. :func:`gpi_scaling` applies the map;
``tests/test_identifiability.py`` checks the invariance numerically.

The Omega terms (13) have a discrete exact symmetry as well:
:math:`c_0 \tanh(c_1 v + c_2) = (-c_0) \tanh(-c_1 v - c_2)`, and the same for ``d``;
the model's default bounds let ``c1`` and ``d1`` take either sign, so the posterior
has mirror modes (a least-squares start can land in either). (The envelopes' ``a`` and
``b`` flips are already removed by the model's positive bounds on ``a0, a1, b0, b1``.)

Normalisation
-------------
:data:`NORMALISATION` pins ``alpha`` at its start value, Table 1's -0.1993 (the curve
crosses every ``alpha < 0`` exactly once, so this picks one representative per
equivalence class), and :data:`SIGN_CONSTRAINTS` bounds ``c1, d1 >= 1e-3`` (positive
Omega slopes, as in Table 1), which picks one of the mirror modes. :func:`normalised_model` returns the model with
``Parameter.vary = False`` for alpha; :func:`to_normalisation` maps any parameter
vector to the equivalent one with that alpha, e.g. to compare an identified vector
with a true one. An effect that acts on the drive (``input`` stage) or on the output
does not break the symmetry, which lives entirely inside the GPI.

Weak directions
---------------
At the least-squares optimum, with ``J`` the Jacobian of the whitened residuals with
respect to the *relative* parameter changes ``d theta_j / s_j``,
``s_j = max(|theta_j|, 0.01)`` (:func:`parameter_scales`), the Fisher information is
``F = J^T J``. Its eigenvalues ``lambda`` give the posterior standard deviation
``1 / sqrt(lambda)`` of the relative change along each eigenvector (Laplace
approximation). Directions are classified as

* **exact**: ``lambda / lambda_max < EXACT_RATIO`` (1e-13: zero up to the round-off of
  the central-difference Jacobian, which puts the GPI scaling at ~1e-16; an effect that
  is practically switched off can reach 1e-10 without being an exact symmetry);
* **near**: otherwise, when the relative standard deviation ``1/sqrt(lambda)`` exceeds
  :data:`NEAR_RELATIVE_STD` (0.05: the combination is known to worse than 5 %) or
  ``lambda / lambda_max < NEAR_RATIO`` (1e-8);

and each is written as a named combination of its largest loadings
(:class:`Direction`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from model import GPI_PARAMETERS, THETA_NAMES, Model, ParameterSet

__all__ = [
    "SCALING_PARAMETERS",
    "SCALING_POWERS",
    "NORMALISATION",
    "SIGN_CONSTRAINTS",
    "EXACT_RATIO",
    "NEAR_RATIO",
    "NEAR_RELATIVE_STD",
    "Direction",
    "IdentifiabilityResult",
    "gpi_scaling",
    "scaling_direction",
    "to_normalisation",
    "normalised_model",
    "with_threshold_sign",
    "pin_gpi_parameters",
    "parameter_scales",
    "analyse_identifiability",
    "analyse_fit",
]

#: The parameters moved by the exact degeneracy, and the power of ``k`` each scales with.
SCALING_PARAMETERS = ("rho", "alpha", "tau", "a0", "a3", "b0", "b3")
SCALING_POWERS = (-1, 1, -1, 1, 1, 1, 1)
#: The normalisation: parameter name -> the value it is pinned at (Table 1's alpha).
NORMALISATION = {"alpha": float(GPI_PARAMETERS["alpha"].value)}
#: Lower bounds that remove the Omega envelopes' sign symmetry: parameter -> lower bound.
SIGN_CONSTRAINTS = {"c1": 1e-3, "d1": 1e-3}
EXACT_RATIO = 1e-13
NEAR_RATIO = 1e-8
NEAR_RELATIVE_STD = 0.05


def gpi_scaling(theta, k) -> np.ndarray:
    """Apply the exact degeneracy: ``theta`` with the 7 scaling parameters times ``k**power``.

    Parameters
    ----------
    theta : array_like, shape (..., P)
        Vectors whose first 19 entries are the GPI parameters (Table 1 order).
    k : float or array_like broadcastable to ``theta.shape[:-1]``
        Scale, > 0.
    """
    theta = np.array(theta, dtype=float)
    k = np.asarray(k, dtype=float)
    if not (np.isfinite(k).all() and (k > 0).all()):
        raise ValueError(f"the scaling k must be finite and > 0, got {k!r}")
    for name, power in zip(SCALING_PARAMETERS, SCALING_POWERS):
        i = THETA_NAMES.index(name)
        theta[..., i] = theta[..., i] * k**power
    return theta


def scaling_direction(theta, names) -> np.ndarray:
    """Unit tangent of the degeneracy curve at ``theta``, in relative coordinates.

    ``d(theta_j) / dk`` at ``k = 1`` is ``power_j * theta_j``; divided by the scales of
    :func:`parameter_scales` and normalised to unit length. Entries for parameters not
    in ``names`` are dropped.

    Parameters
    ----------
    theta : array_like, shape (P,)
        Full vector (``names`` are its free subset's names, or all of them).
    names : sequence of str
        Names of the coordinates to return, each a name in the GPI or an effect.
    """
    theta = np.asarray(theta, dtype=float)
    values = dict(zip(THETA_NAMES, theta[: len(THETA_NAMES)]))
    vec = np.zeros(len(names))
    for idx, name in enumerate(names):
        if name in SCALING_PARAMETERS:
            power = SCALING_POWERS[SCALING_PARAMETERS.index(name)]
            vec[idx] = power * values[name] / max(abs(values[name]), 0.01)
    norm = np.linalg.norm(vec)
    return vec / norm if norm > 0 else vec


def to_normalisation(theta, alpha=None) -> np.ndarray:
    """The equivalent vector(s) with ``alpha`` at the normalisation value.

    Parameters
    ----------
    theta : array_like, shape (..., P)
    alpha : float, optional
        Target alpha (< 0); default :data:`NORMALISATION` ``["alpha"]``.
    """
    theta = np.asarray(theta, dtype=float)
    target = NORMALISATION["alpha"] if alpha is None else float(alpha)
    current = theta[..., THETA_NAMES.index("alpha")]
    if not (target != 0 and (np.sign(current) == np.sign(target)).all()):
        raise ValueError(
            "alpha and the target alpha must be non-zero and of the same sign to normalise "
            "(the scaling k = target / alpha must be > 0; the sign of the thresholds is a model choice)"
        )
    return gpi_scaling(theta, target / current)


def pin_gpi_parameters(model: Model, values: dict) -> Model:
    """A copy of ``model`` with GPI parameters pinned (``vary=False``) at the given values.

    Parameters
    ----------
    model : model.Model
    values : dict
        ``{name: value}`` for GPI parameters (Table 1 names). An empty dict gives an
        equal model with every GPI parameter free.

    Raises
    ------
    ValueError
        A name that is not a GPI parameter (effects' parameters cannot be pinned here).
    """
    gpi_params = GPI_PARAMETERS
    unknown = set(values) - set(THETA_NAMES)
    if unknown:
        raise ValueError(f"only GPI parameters can be pinned; not GPI parameters: {sorted(unknown)}")
    for name, value in values.items():
        gpi_params = gpi_params.replace(name, value=float(value), vary=False)
    return Model(list(model.effect_names), model.n_operators, model.reading, gpi_parameters=gpi_params)


def normalised_model(model: Model, alpha=None) -> Model:
    """``model`` with the normalisation applied: alpha pinned (default Table 1's -0.1993)
    and the sign constraints ``c1, d1 >= 1e-3`` (:data:`SIGN_CONSTRAINTS`)."""
    target = NORMALISATION["alpha"] if alpha is None else float(alpha)
    gpi_params = ParameterSet(model.parameters[: len(THETA_NAMES)])
    gpi_params = gpi_params.replace("alpha", value=target, vary=False)
    for name, lower in SIGN_CONSTRAINTS.items():
        p = gpi_params[name]
        gpi_params = gpi_params.replace(name, lower=max(p.lower, lower), value=max(p.value, lower))
    return Model(list(model.effect_names), model.n_operators, model.reading, gpi_parameters=gpi_params)


def with_threshold_sign(model: Model, sign: int) -> Model:
    """``model`` with its pinned ``alpha`` given the sign ``sign`` (+1 or -1), magnitude kept.

    The exact scaling degeneracy (k > 0) fixes ``|alpha|`` but not its sign: ``alpha < 0``
    is the paper's Table 1 (the envelopes' gap makes the loop), ``alpha > 0`` the classical
    PI's positive thresholds (near-identical envelopes, thin loop tips). The two are
    different models; :func:`identify.fitting.lsq.fit_least_squares` fits both and keeps the better.
    """
    if sign not in (-1, 1):
        raise ValueError(f"sign must be +1 or -1, got {sign!r}")
    alpha = model.parameters["alpha"]
    if alpha.vary:
        raise ValueError("alpha is free in this model: apply the normalisation first (normalised_model)")
    gpi_params = ParameterSet(model.parameters[: len(THETA_NAMES)]).replace("alpha", value=sign * abs(alpha.value))
    return Model(list(model.effect_names), model.n_operators, model.reading, gpi_parameters=gpi_params)


def parameter_scales(theta) -> np.ndarray:
    """``max(|theta_j|, 0.01)``: the scale of relative parameter changes, shape (P,)."""
    return np.maximum(np.abs(np.asarray(theta, dtype=float)), 0.01)


@dataclass(frozen=True)
class Direction:
    """One eigen-direction of the scaled Fisher information.

    Parameters
    ----------
    eigenvalue : float
        ``lambda`` (scaled Fisher information along the direction).
    ratio : float
        ``lambda / lambda_max``.
    relative_std : float
        ``1 / sqrt(lambda)``: posterior std of the relative change along the direction
        (``inf`` for ``lambda <= 0``).
    combination : dict
        ``{name: loading}`` for the largest loadings (``|loading| >= 0.1``, at most
        :attr:`IdentifiabilityResult.max_terms`), sign-fixed so the largest is positive.
    vector : ndarray, shape (P_free,)
        The whole unit eigenvector.
    """

    eigenvalue: float
    ratio: float
    relative_std: float
    combination: dict
    vector: np.ndarray = field(repr=False)

    def describe(self) -> str:
        """E.g. ``"+0.41 rho -0.41 alpha ... (lambda = 3.2e-12, rel. std inf)"``."""
        terms = " ".join(f"{w:+.2f} {n}" for n, w in self.combination.items())
        return f"{terms}  (lambda = {self.eigenvalue:.3g}, lambda/lambda_max = {self.ratio:.2g}, rel. std {self.relative_std:.3g})"

    def to_dict(self) -> dict:
        return {
            "eigenvalue": float(self.eigenvalue),
            "ratio": float(self.ratio),
            "relative_std": float(self.relative_std) if math.isfinite(self.relative_std) else None,
            "combination": {k: float(v) for k, v in self.combination.items()},
        }


@dataclass(frozen=True)
class IdentifiabilityResult:
    """Eigen-analysis of the scaled Fisher information at an optimum.

    Parameters
    ----------
    names : tuple of str
        The free parameters, in the order of the Fisher matrix.
    scales : ndarray, shape (P_free,)
        Parameter scales (:func:`parameter_scales`).
    eigenvalues : ndarray, shape (P_free,)
        Ascending.
    eigenvectors : ndarray, shape (P_free, P_free)
        Columns match ``eigenvalues``.
    condition_number : float
        ``lambda_max / lambda_min`` (``inf`` when ``lambda_min <= 0``).
    exact, near : list of Direction
        Classified as in the module docstring, weakest first.
    normalisation : dict
        ``{name: value}`` of the pinned parameters.
    """

    names: tuple
    scales: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    condition_number: float
    exact: list
    near: list
    normalisation: dict
    max_terms: int = 8

    def to_dict(self) -> dict:
        """The ``identifiability`` block of ``summary.json`` (plus eigenvalues and condition number)."""
        return {
            "normalisation": {k: float(v) for k, v in self.normalisation.items()},
            "sign_constraints": {k: f">= {v:g}" for k, v in SIGN_CONSTRAINTS.items()},
            "exact": [d.to_dict() for d in self.exact],
            "near": [d.to_dict() for d in self.near],
            "eigenvalues": [float(v) for v in self.eigenvalues],
            "condition_number": float(self.condition_number) if math.isfinite(self.condition_number) else None,
            "names": list(self.names),
        }

    def describe(self) -> str:
        """Plain-text lines for the screen."""
        lines = [f"condition number of the scaled Fisher information: {self.condition_number:.3g}"]
        if self.normalisation:
            lines.append("normalisation (pinned): " + ", ".join(f"{k} = {v:g}" for k, v in self.normalisation.items()))
        for d in self.exact:
            lines.append("EXACT degeneracy: " + d.describe())
        for d in self.near:
            lines.append("near-degenerate: " + d.describe())
        if not self.exact and not self.near:
            lines.append("no exact or near-degenerate directions")
        return "\n".join(lines)


def _direction(value, lam_max, vector, names, max_terms) -> Direction:
    order = np.argsort(-np.abs(vector))
    if vector[order[0]] < 0:
        vector = -vector
    combination = {}
    for i in order[:max_terms]:
        if abs(vector[i]) >= 0.1:
            combination[names[i]] = float(vector[i])
    ratio = value / lam_max if lam_max > 0 else 0.0
    rel_std = 1.0 / math.sqrt(value) if value > 0 else math.inf
    return Direction(float(value), float(ratio), float(rel_std), combination, vector.copy())


def analyse_identifiability(
    jacobian, theta, names, *, normalisation=None, max_terms=8, max_near=6
) -> IdentifiabilityResult:
    """Eigen-analysis of the Fisher information of whitened residuals.

    Parameters
    ----------
    jacobian : ndarray, shape (T, P_free)
        d(whitened residual) / d(free parameter) at the optimum (e.g.
        :meth:`identify.fitting.lsq.WhitenedResiduals.central_jacobian`).
    theta : array_like, shape (P_free,)
        The free parameters' values (for the scales).
    names : sequence of str, length P_free
    normalisation : dict, optional
        Pinned ``{name: value}``, recorded in the result.
    max_terms : int, default 8
        Loadings shown per direction.
    max_near : int, default 6
        Most near-degenerate directions reported.
    """
    jac = np.asarray(jacobian, dtype=float)
    theta = np.asarray(theta, dtype=float)
    names = tuple(names)
    if jac.ndim != 2 or jac.shape[1] != len(names) or theta.shape != (len(names),):
        raise ValueError(f"jacobian (T, P) and theta (P,) must match {len(names)} names; got {jac.shape}, {theta.shape}")
    scales = parameter_scales(theta)
    scaled = jac * scales[None, :]
    fisher = scaled.T @ scaled
    eigenvalues, eigenvectors = np.linalg.eigh(fisher)
    lam_max = float(eigenvalues[-1])
    lam_min = float(eigenvalues[0])
    condition = lam_max / lam_min if lam_min > 0 else math.inf
    exact, near = [], []
    for idx, value in enumerate(eigenvalues):
        ratio = value / lam_max if lam_max > 0 else 0.0
        direction = _direction(float(value), lam_max, eigenvectors[:, idx], names, max_terms)
        if ratio < EXACT_RATIO:
            exact.append(direction)
        elif (ratio < NEAR_RATIO or direction.relative_std > NEAR_RELATIVE_STD) and len(near) < max_near:
            near.append(direction)
    return IdentifiabilityResult(
        names=names,
        scales=scales,
        eigenvalues=eigenvalues,
        eigenvectors=eigenvectors,
        condition_number=float(condition),
        exact=exact,
        near=near,
        normalisation=dict(normalisation or {}),
        max_terms=max_terms,
    )


def analyse_fit(fit, record, **kwargs) -> IdentifiabilityResult:
    """Identifiability at a least-squares optimum, exact directions detected automatically.

    Two Fisher analyses at ``fit.theta`` (central-difference Jacobians of the whitened
    residuals): with the normalisation released (every GPI parameter free), whose
    numerically-zero eigenvalues are the **exact** degeneracies (the scaling of
    :func:`gpi_scaling` is expected); and with the fitted model's pins, whose weak
    directions are the **near**-degenerate ones that remain. Eigenvalues and the
    condition number are those of the normalised (fitted) problem.

    Parameters
    ----------
    fit : identify.fitting.lsq.FitResult
    record : Record
    **kwargs
        Passed to :func:`analyse_identifiability`.
    """
    from .lsq import WhitenedResiduals, _single_threaded_blas

    model = fit.model
    pins = {n: float(v) for n, v, free in zip(model.names, fit.theta, fit.vary) if not free}
    normalisation = {n: v for n, v in pins.items() if n in NORMALISATION}
    with _single_threaded_blas():
        fitted = WhitenedResiduals(record, model, fit.noise)
        jac = fitted.central_jacobian(fit.theta[fitted.free])
        names = [model.names[i] for i in fitted.free]
        result = analyse_identifiability(jac, fit.theta[fitted.free], names, normalisation=normalisation, **kwargs)
        released_params = ParameterSet(model.parameters[: len(THETA_NAMES)])
        for name in NORMALISATION:
            released_params = released_params.replace(name, vary=True)
        released = Model(list(model.effect_names), model.n_operators, model.reading, gpi_parameters=released_params)
        released_res = WhitenedResiduals(record, released, fit.noise)
        theta_released = released_res.template.copy()
        theta_released[:] = fit.theta
        jac_released = released_res.central_jacobian(theta_released[released_res.free])
        names_released = [released.names[i] for i in released_res.free]
        exact = analyse_identifiability(
            jac_released, theta_released[released_res.free], names_released, **kwargs
        ).exact
    return IdentifiabilityResult(
        names=result.names,
        scales=result.scales,
        eigenvalues=result.eigenvalues,
        eigenvectors=result.eigenvectors,
        condition_number=result.condition_number,
        exact=exact,
        near=result.near,
        normalisation=normalisation,
        max_terms=result.max_terms,
    )
