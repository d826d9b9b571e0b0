r"""The GPI's parametrisation: the exact scaling degeneracy and its normalisation.

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

The weak directions at a fit are measured in :mod:`identify.fitting.identifiability`.
"""

from __future__ import annotations

import numpy as np

from model import GPI_PARAMETERS, THETA_NAMES, Model, ParameterSet

__all__ = [
    "SCALING_PARAMETERS",
    "SCALING_POWERS",
    "NORMALISATION",
    "SIGN_CONSTRAINTS",
    "gpi_scaling",
    "scaling_direction",
    "to_normalisation",
    "normalised_model",
    "with_threshold_sign",
    "pin_gpi_parameters",
    "parameter_scales",
    "in_record_units",
    "with_parameters",
    "record_unit_factors",
    "prefix_factor",
    "PAPER_INPUT_PEAK",
    "PAPER_OUTPUT_SPAN",
]

#: The parameters moved by the exact degeneracy, and the power of ``k`` each scales with.
SCALING_PARAMETERS = ("rho", "alpha", "tau", "a0", "a3", "b0", "b3")
SCALING_POWERS = (-1, 1, -1, 1, 1, 1, 1)
#: The normalisation: parameter name -> the value it is pinned at (Table 1's alpha).
NORMALISATION = {"alpha": float(GPI_PARAMETERS["alpha"].value)}
#: Lower bounds that remove the Omega envelopes' sign symmetry: parameter -> lower bound.
SIGN_CONSTRAINTS = {"c1": 1e-3, "d1": 1e-3}


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
    return model.with_gpi_parameters(gpi_params)


def normalised_model(model: Model, alpha=None) -> Model:
    """``model`` with the normalisation applied: alpha pinned (default Table 1's -0.1993)
    and the sign constraints ``c1, d1 >= 1e-3`` (:data:`SIGN_CONSTRAINTS`)."""
    target = NORMALISATION["alpha"] if alpha is None else float(alpha)
    gpi_params = ParameterSet(model.parameters[: len(THETA_NAMES)])
    gpi_params = gpi_params.replace("alpha", value=target, vary=False)
    for name, lower in SIGN_CONSTRAINTS.items():
        p = gpi_params[name]
        gpi_params = gpi_params.replace(name, lower=max(p.lower, lower), value=max(p.value, lower))
    return model.with_gpi_parameters(gpi_params)


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
    return model.with_gpi_parameters(gpi_params)


def parameter_scales(theta) -> np.ndarray:
    """``max(|theta_j|, 0.01)``: the scale of relative parameter changes, shape (P,)."""
    return np.maximum(np.abs(np.asarray(theta, dtype=float)), 0.01)


#: The paper's drive peak [A] and output span [um] (Table 1 on the paper's input): the
#: scale the default bounds are sized for.
PAPER_INPUT_PEAK = 5.0
PAPER_OUTPUT_SPAN = 300.0
#: GPI parameters per input unit (slopes), and per output unit, under the normalisation.
_PER_INPUT = ("a1", "b1", "c1", "d1")
_OUTPUT = ("rho", "c0", "c3", "d0", "d3")
#: With alpha free the thresholds are in the input unit too (see identify.fitting.lsq.parameter_units).
_INPUT_IF_FREE = ("alpha", "a0", "a3", "b0", "b3")
_PER_INPUT_IF_FREE = ("tau",)
#: Effect parameter units -> (power of the input factor, power of the output factor).
_UNIT_POWERS = {"um": (0, 1), "A": (1, 0), "1/A": (-1, 0), "um/A": (-1, 1)}


def prefix_factor(ratio) -> float:
    """``ratio`` rounded to a whole SI prefix step: ``10**(3 round(log10(ratio) / 3))``
    (1 for ratios within about 0.03-30, 1000 for a record in mA or nm instead of A or um)."""
    ratio = float(ratio)
    if not (np.isfinite(ratio) and ratio > 0):
        return 1.0
    return float(10.0 ** (3 * round(np.log10(ratio) / 3)))


def record_unit_factors(record) -> tuple[float, float]:
    """``(f_in, f_out)``: how many of the record's input and output units make the paper's
    scale (:data:`PAPER_INPUT_PEAK` A, :data:`PAPER_OUTPUT_SPAN` um), rounded to whole SI
    prefix steps (:func:`prefix_factor`)."""
    peak = float(np.max(np.abs(record.current)))
    span = float(np.ptp(record.displacement))
    return prefix_factor(peak / PAPER_INPUT_PEAK), prefix_factor(span / PAPER_OUTPUT_SPAN)


def in_record_units(model: Model, record) -> Model:
    """``model`` with the default bounds of its parameters widened, and their default
    values rescaled, to the record's units.

    The default bounds are sized for a drive in A (peak 5 A) and an output in um (span
    300 um) and span three or more decades, so records in V or mm within a factor ~30 of
    that scale keep them (:func:`record_unit_factors` is 1). A record in other unit
    prefixes (mA, nm, ...) gets each default value multiplied, and each default bound
    range extended to include the multiplied range (never narrowed, so nothing the
    defaults allowed is excluded), by the input factor ``f_in`` and the output factor
    ``f_out`` as the parameter's dimension says: under the normalisation
    (alpha pinned, thresholds in fixed units) the slopes ``a1, b1, c1, d1`` are per
    input unit and ``rho, c0, c3, d0, d3`` in output units; with alpha free also
    ``alpha, a0, a3, b0, b3`` in input units and ``tau`` per input unit; effect
    parameters by their declared unit (um, A, 1/A). Only bounds still at their declared
    defaults are changed (a priors file's bounds are the user's), so the function is
    idempotent, and with both factors 1 it returns ``model`` itself.
    """
    f_in, f_out = record_unit_factors(record)
    if f_in == 1.0 and f_out == 1.0:
        return model
    defaults = Model(list(model.effect_names), model.n_operators, model.reading).parameters
    normalised = normalised_model(Model(list(model.effect_names), model.n_operators, model.reading)).parameters
    alpha_free = bool(model.parameters["alpha"].vary)
    parameters = model.parameters
    for p in model.parameters:
        declared = {
            (defaults[p.name].lower, defaults[p.name].upper),
            (normalised[p.name].lower, normalised[p.name].upper),
        }
        if (p.lower, p.upper) not in declared:
            continue
        if p.name in THETA_NAMES:
            power_in = -1 if p.name in _PER_INPUT else 0
            power_out = 1 if p.name in _OUTPUT else 0
            if alpha_free:
                power_in += (
                    1 if p.name in _INPUT_IF_FREE else (-1 if p.name in _PER_INPUT_IF_FREE or p.name == "rho" else 0)
                )
        else:
            power_in, power_out = _UNIT_POWERS.get(p.unit, (0, 0))
        factor = f_in**power_in * f_out**power_out
        if factor != 1.0:
            lower, upper = min(p.lower, p.lower * factor), max(p.upper, p.upper * factor)
            parameters = parameters.replace(p.name, lower=lower, upper=upper, value=p.value * factor)
    return with_parameters(model, parameters)


def with_parameters(model: Model, parameters: ParameterSet) -> Model:
    """A shallow copy of ``model`` with other parameter bounds/values (:meth:`model.Model.with_parameters`)."""
    return model.with_parameters(parameters)
