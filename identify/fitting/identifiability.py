r"""Identifiability at a fit: the weak directions of the GPI (+ effects) parameters.

The exact scaling degeneracy and the normalisation that removes it are in
:mod:`identify.fitting.parametrisation`.

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
  is practically switched off can reach 1e-10 without being an exact symmetry); at a
  fit (:func:`analyse_fit`) the GPI scaling is listed from a finite check of the output's
  invariance instead, since kinks of the output can lift its eigenvalue far above that;
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

from model import THETA_NAMES, ParameterSet

from .lsq import WhitenedResiduals
from .parametrisation import NORMALISATION, SIGN_CONSTRAINTS, gpi_scaling, parameter_scales, scaling_direction
from .threads import single_threaded_blas

__all__ = [
    "EXACT_RATIO",
    "NEAR_RATIO",
    "NEAR_RELATIVE_STD",
    "Direction",
    "IdentifiabilityResult",
    "analyse_identifiability",
    "analyse_fit",
    "exact_directions",
    "invariant_under_scaling",
]

EXACT_RATIO = 1e-13
NEAR_RATIO = 1e-8
NEAR_RELATIVE_STD = 0.05


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
        return (
            f"{terms}  (lambda = {self.eigenvalue:.3g}, lambda/lambda_max = {self.ratio:.2g}, rel. std "
            f"{self.relative_std:.3g})"
        )

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


def _scaled_fisher(jacobian, theta) -> tuple[np.ndarray, np.ndarray]:
    """``(scales, F)``: :func:`parameter_scales` of ``theta`` ``(P,)`` and the Fisher information
    ``F = J_s^T J_s`` ``(P, P)`` of the Jacobian ``(T, P)`` in relative parameter changes."""
    scales = parameter_scales(theta)
    scaled = np.asarray(jacobian, dtype=float) * scales[None, :]
    return scales, scaled.T @ scaled


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
        raise ValueError(
            f"jacobian (T, P) and theta (P,) must match {len(names)} names; got {jac.shape}, {theta.shape}"
        )
    scales, fisher = _scaled_fisher(jac, theta)
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


#: Relative scale of the finite check that the output is invariant under :func:`gpi_scaling`.
SCALING_CHECK = 0.01
#: Largest change of a whitened residual (in noise sigmas) under that scaling for the output to count as invariant.
SCALING_TOLERANCE = 1e-6


def invariant_under_scaling(residuals: WhitenedResiduals, theta) -> bool:
    """Whether the output at full vector ``theta`` is unchanged by :func:`gpi_scaling` with
    ``k = 1 + SCALING_CHECK`` (a finite check: exact symmetries hold for any ``k``)."""
    free = residuals.free
    before = residuals(theta[free])
    after = residuals(gpi_scaling(theta, 1.0 + SCALING_CHECK)[free])
    return bool(np.all(np.isfinite(before)) and np.max(np.abs(after - before)) <= SCALING_TOLERANCE)


def exact_directions(residuals: WhitenedResiduals, theta, jacobian, names, max_terms) -> list:
    """The exact degeneracies of the released problem (every GPI parameter free) at full vector ``theta``.

    The GPI scaling (:func:`gpi_scaling`) is exact by construction; it is listed when a finite
    check confirms it for this model and record (:func:`invariant_under_scaling`), with
    eigenvalue 0, and the search for further numerically-zero eigenvalues runs in the
    complement of its direction. Why not from the eigenvalues alone: where operator bounds
    cross, the output has kinks in the parameters, and a central difference that straddles one
    at some sample puts the scaling's eigenvalue at ~1e-9 of the largest (a 5 Hz record, bounds
    crossing by 0.05 A), far above the round-off that :data:`EXACT_RATIO` allows.
    """
    _, fisher = _scaled_fisher(jacobian, theta[residuals.free])
    lam_max = float(np.linalg.eigvalsh(fisher)[-1])
    exact, basis = [], np.eye(len(names))
    direction = scaling_direction(theta, names)
    if np.linalg.norm(direction) > 0 and invariant_under_scaling(residuals, theta):
        exact.append(_direction(0.0, lam_max, direction, names, max_terms))
        basis = np.linalg.svd(np.eye(len(names)) - np.outer(direction, direction))[0][:, : len(names) - 1]
    values, vectors = np.linalg.eigh(basis.T @ fisher @ basis)
    for value, vector in zip(values, vectors.T):
        if lam_max > 0 and value / lam_max < EXACT_RATIO:
            exact.append(_direction(float(value), lam_max, basis @ vector, names, max_terms))
    return exact


def analyse_fit(fit, record, **kwargs) -> IdentifiabilityResult:
    """Identifiability at a least-squares optimum, exact directions detected automatically.

    Two Fisher analyses at ``fit.theta`` (central-difference Jacobians of the whitened
    residuals): with the normalisation released (every GPI parameter free), for the
    **exact** degeneracies (the scaling of :func:`gpi_scaling`, confirmed by a finite check,
    and any further numerically-zero eigenvalue: :func:`exact_directions`); and with the
    fitted model's pins, whose weak directions are the **near**-degenerate ones that remain.
    Eigenvalues and the condition number are those of the normalised (fitted) problem.

    Parameters
    ----------
    fit : identify.fitting.lsq.FitResult
    record : Record
    **kwargs
        Passed to :func:`analyse_identifiability`.
    """
    model = fit.model
    pins = {n: float(v) for n, v, free in zip(model.names, fit.theta, fit.vary) if not free}
    normalisation = {n: v for n, v in pins.items() if n in NORMALISATION}
    with single_threaded_blas():
        fitted = WhitenedResiduals(record, model, fit.noise)
        jac = fitted.central_jacobian(fit.theta[fitted.free])
        names = [model.names[i] for i in fitted.free]
        result = analyse_identifiability(jac, fit.theta[fitted.free], names, normalisation=normalisation, **kwargs)
        released_params = ParameterSet(model.parameters[: len(THETA_NAMES)])
        for name in NORMALISATION:
            released_params = released_params.replace(name, vary=True)
        released = model.with_gpi_parameters(released_params)
        released_res = WhitenedResiduals(record, released, fit.noise)
        theta_released = released_res.template.copy()
        theta_released[:] = fit.theta
        jac_released = released_res.central_jacobian(theta_released[released_res.free])
        names_released = [released.names[i] for i in released_res.free]
        exact = exact_directions(released_res, theta_released, jac_released, names_released, result.max_terms)
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
