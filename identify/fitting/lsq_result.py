"""What a least-squares fit returns (:class:`FitResult`, one :class:`StartOutcome` per start),
its JSON form, and the units of its parameters in a record's units (:func:`parameter_units`).

The fit itself is :func:`identify.fitting.lsq.fit_least_squares` (method in
:mod:`identify.fitting.lsq`'s docstring); this module holds only the result's shape and its
JSON form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from model import Model

from .noise import NoiseModel

__all__ = ["FitResult", "StartOutcome", "StoredModelError", "parameter_units", "SLOPE_NAMES"]

#: The envelopes' slopes ``a1, b1, c1, d1``: per input unit (their unit and the data-scaled
#: start's input rescaling follow from that).
SLOPE_NAMES = ("a1", "b1", "c1", "d1")


class StoredModelError(ValueError):
    """A stored fit whose parameters are not those of its model in this version of the library
    (written by another version): the message names the parameters that differ."""


@dataclass(frozen=True)
class StartOutcome:
    """How one least-squares start ended.

    Parameters
    ----------
    label : str
        ``"user"``, ``"table1"``, ``"data_scaled"`` or ``"perturbed-k"``.
    chi2 : float
        Sum of squared whitened residuals at the end (``2 * cost``); ``inf`` when the
        start gave a non-finite model output.
    n_evaluations : int
        Residual evaluations used.
    success : bool
    message : str
    """

    label: str
    chi2: float
    n_evaluations: int
    success: bool
    message: str


@dataclass
class FitResult:
    """A least-squares fit (fields as in docs/CONTRACTS.md, plus start bookkeeping).

    Parameters
    ----------
    model : model.Model
        The model fitted, with any pinned parameters.
    theta : ndarray, shape (P,)
        Best parameter vector, full, in ``model.names`` order.
    stderr : ndarray, shape (P,)
        Jacobian-based standard errors; NaN for pinned parameters.
    covariance : ndarray, shape (P, P)
        Jacobian-based covariance; zero rows/columns for pinned parameters.
    vary : ndarray of bool, shape (P,)
        False = pinned.
    residual : ndarray, shape (T,)
        Data minus model [output unit].
    rms : float
        Residual RMS over the energised part [output unit].
    max_error_pct : float
        Largest ``|residual|`` over the energised part, in % of the measured
        displacement range (max - min).
    reduced_chi2 : float
        ``sum w^2 / (T - P_free)`` with ``w`` the whitened residuals (1 for a perfect
        noise model).
    noise : NoiseModel
        The noise model used (a free sigma replaced by its estimate).
    n_starts : int
        Starts run.
    success : bool
        The best start's solver reported convergence.
    message : str
        The best start's solver message.
    seconds : float
        Wall time of the whole fit [s].
    n_agree : int
        Starts within chi-square 1 of the best.
    starts : list of StartOutcome
    terms : list of dict
        The optional effect terms tested by :func:`identify.fitting.terms.select_terms`
        (effect, term, parameters, chi-square change, BIC penalty, whether pinned off);
        empty when none was tested.
    """

    model: Model
    theta: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    vary: np.ndarray
    residual: np.ndarray
    rms: float
    max_error_pct: float
    reduced_chi2: float
    noise: NoiseModel
    n_starts: int
    success: bool
    message: str
    seconds: float
    n_agree: int = 1
    starts: list[StartOutcome] = field(default_factory=list)
    terms: list[dict] = field(default_factory=list)

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.names

    @property
    def chi2(self) -> float:
        """Sum of squared whitened residuals at the optimum."""
        return float(self.reduced_chi2 * (self.residual.size - int(self.vary.sum())))

    def theta_dict(self) -> dict[str, float]:
        return self.model.theta_dict(self.theta)

    def to_dict(self) -> dict:
        """JSON-ready (NaN written as None): everything needed to rebuild the fit."""
        return {
            "names": list(self.names),
            "units": [p.unit for p in self.model.parameters],
            "model": self.model.to_dict(),
            "theta": _floats(self.theta),
            "stderr": _floats(self.stderr),
            "covariance": [_floats(row) for row in self.covariance],
            "vary": [bool(v) for v in self.vary],
            "lower": _floats(self.model.parameters.lower),
            "upper": _floats(self.model.parameters.upper),
            "residual": _floats(self.residual),
            "rms": float(self.rms),
            "max_error_pct": float(self.max_error_pct),
            "reduced_chi2": float(self.reduced_chi2),
            "noise": self.noise.to_dict(),
            "n_starts": int(self.n_starts),
            "n_agree": int(self.n_agree),
            "success": bool(self.success),
            "message": str(self.message),
            "seconds": float(self.seconds),
            "starts": [
                {
                    "label": s.label,
                    "chi2": _float(s.chi2),
                    "n_evaluations": s.n_evaluations,
                    "success": s.success,
                    "message": s.message,
                }
                for s in self.starts
            ],
            "terms": [dict(t) for t in self.terms],
        }

    @classmethod
    def from_dict(cls, d: dict) -> FitResult:
        """Inverse of :meth:`to_dict` (the model is rebuilt with the same pins)."""
        theta = _array(d["theta"])
        vary = np.asarray(d["vary"], dtype=bool)
        base = Model.from_dict(d["model"])
        if tuple(d["names"]) != base.names:
            lacks = [n for n in base.names if n not in d["names"]]
            unknown = [n for n in d["names"] if n not in base.names]
            differ = []
            if lacks:
                differ.append(f"it lacks {', '.join(lacks)}")
            if unknown:
                differ.append(f"it has {', '.join(unknown)}, which this version does not know")
            raise StoredModelError(
                f"the stored fit's parameters are not those of {base!r} in this version of the library "
                f"({'; '.join(differ) or 'in another order'}): written by another version; fit the record again"
            )
        lower = _array(d["lower"]) if "lower" in d else base.parameters.lower
        upper = _array(d["upper"]) if "upper" in d else base.parameters.upper
        settings = []  # every parameter's pin and bounds as stored (GPI and effects alike)
        for i, p in enumerate(base.parameters):
            value = float(theta[i]) if not vary[i] else min(max(p.value, lower[i]), upper[i])
            settings.append(p.with_(value=value, vary=bool(vary[i]), lower=float(lower[i]), upper=float(upper[i])))
        model = base.with_parameters(settings)
        starts = [
            StartOutcome(
                s["label"], _unfloat(s["chi2"], math.inf), int(s["n_evaluations"]), bool(s["success"]), s["message"]
            )
            for s in d.get("starts", [])
        ]
        return cls(
            model=model,
            theta=theta,
            stderr=_array(d["stderr"]),
            covariance=np.array([_array(r) for r in d["covariance"]]).reshape(theta.size, theta.size),
            vary=vary,
            residual=_array(d["residual"]),
            rms=float(d["rms"]),
            max_error_pct=float(d["max_error_pct"]),
            reduced_chi2=float(d["reduced_chi2"]),
            noise=NoiseModel.from_dict(d["noise"]),
            n_starts=int(d["n_starts"]),
            success=bool(d["success"]),
            message=str(d["message"]),
            seconds=float(d["seconds"]),
            n_agree=int(d.get("n_agree", 1)),
            starts=starts,
            terms=[dict(t) for t in d.get("terms", [])],
        )


def _float(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _floats(a):
    return [_float(x) for x in np.asarray(a, dtype=float).ravel()]


def _unfloat(x, missing=math.nan):
    return missing if x is None else float(x)


def _array(values):
    return np.array([_unfloat(v) for v in values], dtype=float)


def parameter_units(model: Model, record=None) -> list[str]:
    r"""Units of ``model.names``, with the record's input/output units substituted.

    The GPI's declared units assume a drive in A and an output in um. For a record in
    other units (e.g. V and um for a piezo) they are rewritten by dimensional analysis:
    the slopes ``a1, b1, c1, d1`` are per input unit; the envelopes
    :math:`\gamma(v) = a_0 \tanh(a_1 v + a_2) + a_3` are compared with the thresholds
    :math:`r_j = \alpha j`, and the paper gives both the input's unit, so ``alpha, a0,
    a3, b0, b3`` are in the input unit, ``tau`` per input unit and ``rho`` output per
    input unit; ``c0, c3, d0, d3`` are in the output unit.
    """
    in_unit = getattr(record, "input_unit", "A") if record is not None else "A"
    out_unit = getattr(record, "output_unit", "um") if record is not None else "um"
    units = []
    for p in model.parameters:
        unit = p.unit
        if p.name in SLOPE_NAMES or p.name == "tau":
            unit = f"1/{in_unit}"
        elif p.name in ("alpha", "a0", "a3", "b0", "b3"):
            unit = in_unit
        elif p.name in ("c0", "c3", "d0", "d3"):
            unit = out_unit
        elif p.name == "rho":
            unit = f"{out_unit}/{in_unit}"
        units.append(unit)
    return units
