"""Priors from a TOML file: ``study --priors FILE`` and the ``priors`` key of a batch config.

One representation: a parameter's **bounds** are its :class:`model.parameters.Parameter`
``lower``/``upper`` (the prior's support, also the least squares' box), and its
**distribution** is the entry for its name in :class:`identify.fitting.posterior.LogPosterior`'s
``priors`` (a name of :data:`identify.fitting.posterior.PRIORS` or a :class:`Prior`). A priors
file changes both for the parameters it names (:func:`apply_priors`); every other
parameter keeps its default (:func:`identify.fitting.posterior.default_priors` on the model's
bounds). The priors used, defaults included, go to ``summary.json`` (``priors``) and the
report (:func:`prior_table`).

File format (values in the record's units; the parameter names are the model's, as in
``summary.json``)::

    # priors.toml
    [c0]
    distribution = "normal"            # uniform | log_uniform | normal | truncated_normal
    mu = 1.6
    sigma = 0.1                        # normal: bounds optional (default: the model's)

    [thermal_tau]
    distribution = "truncated_normal"
    mu = 120.0
    sigma = 15.0
    lower = 60.0
    upper = 240.0

    [rho]
    distribution = "log_uniform"
    lower = 0.5
    upper = 50.0

Densities on ``[lower, upper]`` (``-inf`` outside, as for every prior): uniform
``1/(u-l)``; log-uniform ``1/(x log(u/l))`` (needs ``l > 0``); normal and truncated
normal ``N(mu, sigma^2)`` renormalised to the bounds (a ``normal`` is truncated at the
model's default bounds; give ``lower``/``upper`` to change them).

Any problem is a :class:`PriorsError` (exit code 2) naming the file, the parameter and
what is wrong: unreadable file or TOML, an unknown parameter (the known ones are listed),
a pinned parameter, an unknown distribution or key, a missing or non-numeric value,
``sigma <= 0``, ``lower >= upper``, and bounds that exclude the parameter's starting
value (the model's default, Table 1 for the GPI).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import log_ndtr

from ..data.fileio import toml_module
from .parametrisation import with_parameters

__all__ = ["Prior", "PriorsError", "DISTRIBUTIONS", "read_priors_file", "apply_priors", "prior_table"]


class PriorsError(ValueError):
    """A priors file that cannot be used; the message names the file, the parameter and the problem."""


#: distribution name -> keys it needs (beside ``distribution``); ``lower``/``upper`` are optional for ``normal``.
DISTRIBUTIONS = {
    "uniform": ("lower", "upper"),
    "log_uniform": ("lower", "upper"),
    "normal": ("mu", "sigma"),
    "truncated_normal": ("mu", "sigma", "lower", "upper"),
}
_KEYS = {"distribution", "lower", "upper", "mu", "sigma"}


@dataclass(frozen=True)
class Prior:
    """One parameter's prior distribution (its bounds are the parameter's, see the module docstring).

    Parameters
    ----------
    distribution : str
        A key of :data:`DISTRIBUTIONS`.
    mu, sigma : float, optional
        Mean and standard deviation of a (truncated) normal, in the parameter's unit.
    source : str, default ""
        The file it came from (``summary.json`` says so).

    Called as ``prior(x, lower, upper)`` it returns the log-density of ``x`` (shape (W,))
    on ``[lower, upper]``, the signature :class:`identify.fitting.posterior.LogPosterior` calls.
    """

    distribution: str
    mu: float | None = None
    sigma: float | None = None
    source: str = ""

    @property
    def __name__(self) -> str:  # LogPosterior names a callable prior by its __name__
        return self.distribution

    def __call__(self, x, lower, upper) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self.distribution == "uniform":
            return np.full(x.shape, -math.log(upper - lower))
        if self.distribution == "log_uniform":
            return -np.log(x) - math.log(math.log(upper / lower))
        # normal renormalised to [lower, upper]: log phi(z) - log sigma - log(Phi(b) - Phi(a))
        z = (x - self.mu) / self.sigma
        a, b = (lower - self.mu) / self.sigma, (upper - self.mu) / self.sigma
        log_mass = log_ndtr(b) + np.log1p(-np.exp(min(0.0, log_ndtr(a) - log_ndtr(b)))) if b > a else -np.inf
        return -0.5 * z * z - 0.5 * math.log(2 * math.pi) - math.log(self.sigma) - log_mass

    def to_dict(self) -> dict:
        out = {"distribution": self.distribution}
        if self.mu is not None:
            out.update(mu=self.mu, sigma=self.sigma)
        return out


def _number(path, name, key, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise PriorsError(f"{path}: parameter {name!r}: {key} must be a finite number, got {value!r}")
    return float(value)


def read_priors_file(path) -> dict[str, dict]:
    """The raw tables of a priors file, checked for form: ``{name: {key: value}}``.

    Raises
    ------
    PriorsError
        Unreadable file, invalid TOML (with its line), a value that is not a table, an
        unknown distribution or key, a missing or non-numeric value, ``sigma <= 0`` or
        ``lower >= upper``.
    """
    tomllib = toml_module()
    path = Path(path)
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise PriorsError(f"{path}: no such priors file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PriorsError(f"{path}: cannot read the priors file ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise PriorsError(f"{path}: not valid TOML: {exc}") from None
    if not data:
        raise PriorsError(f"{path}: no priors in the file (expected tables such as [rho] with distribution = ...)")
    tables = {}
    for name, table in data.items():
        if not isinstance(table, dict):
            raise PriorsError(f"{path}: {name!r} must be a table ([{name}] with distribution = ...), got {table!r}")
        kind = table.get("distribution")
        if kind not in DISTRIBUTIONS:
            raise PriorsError(
                f"{path}: parameter {name!r}: unknown distribution {kind!r}; known: {', '.join(DISTRIBUTIONS)}"
            )
        unknown = sorted(set(table) - _KEYS)
        if unknown:
            raise PriorsError(
                f"{path}: parameter {name!r}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(_KEYS))}"
            )
        missing = [k for k in DISTRIBUTIONS[kind] if k not in table]
        if missing:
            raise PriorsError(f"{path}: parameter {name!r}: a {kind} prior needs {', '.join(missing)}")
        if kind in ("uniform", "log_uniform") and ({"mu", "sigma"} & set(table)):
            raise PriorsError(f"{path}: parameter {name!r}: a {kind} prior takes no mu or sigma")
        values = {k: _number(path, name, k, v) for k, v in table.items() if k != "distribution"}
        if "sigma" in values and not values["sigma"] > 0:
            raise PriorsError(f"{path}: parameter {name!r}: sigma must be > 0, got {values['sigma']!r}")
        if ("lower" in values) != ("upper" in values):
            raise PriorsError(f"{path}: parameter {name!r}: give both lower and upper, or neither")
        if "lower" in values and not values["lower"] < values["upper"]:
            raise PriorsError(
                f"{path}: parameter {name!r}: lower {values['lower']!r} must be below upper {values['upper']!r}"
            )
        if kind == "log_uniform" and not values["lower"] > 0:
            raise PriorsError(
                f"{path}: parameter {name!r}: a log_uniform prior needs lower > 0, got {values['lower']!r}"
            )
        tables[name] = {"distribution": kind, **values}
    return tables


def apply_priors(model, path, start=None, start_name="starting value"):
    """The model with the file's bounds, and the ``priors`` mapping for
    :class:`identify.fitting.posterior.LogPosterior`.

    Parameters
    ----------
    model : model.Model
        The model to be identified (pinned parameters stay pinned).
    path : path-like
        The priors file (module docstring).
    start : array_like, shape (P,), optional
        Where the sampler starts (the least-squares estimate, in ``model.names`` order);
        default the parameters' default values. Bounds must include it.
    start_name : str
        What ``start`` is, for the error message.

    Returns
    -------
    model : model.Model
        A copy whose named parameters have the file's ``lower``/``upper`` (when given);
        for the posterior only: the least squares keeps the model's default bounds.
    priors : dict
        ``{name: Prior}`` for the named parameters.

    Raises
    ------
    PriorsError
        As :func:`read_priors_file`, and: a name that is no parameter of the model (the
        known ones are listed), a pinned parameter, bounds that exclude the parameter's
        starting value, or a mean outside the bounds.
    """
    tables = read_priors_file(path)
    names = list(model.names)
    parameters = model.parameters
    priors = {}
    for name, table in tables.items():
        if name not in names:
            raise PriorsError(f"{path}: {name!r} is not a parameter of {model!r}; its parameters: {', '.join(names)}")
        p = parameters[name]
        if not p.vary:
            raise PriorsError(
                f"{path}: parameter {name!r} is pinned at {p.value:g} (the normalisation); it takes no prior"
            )
        lower, upper = table.get("lower", p.lower), table.get("upper", p.upper)
        value = p.value if start is None else float(start[names.index(name)])
        if not lower <= value <= upper:
            raise PriorsError(
                f"{path}: parameter {name!r}: bounds [{lower:g}, {upper:g}] exclude its {start_name} {value:g} "
                f"({'the model default' if start is None else 'where the sampler starts'}); widen them to include it"
            )
        if "mu" in table and not lower <= table["mu"] <= upper:
            raise PriorsError(
                f"{path}: parameter {name!r}: mu {table['mu']:g} lies outside the bounds [{lower:g}, {upper:g}]"
            )
        parameters = parameters.replace(name, lower=lower, upper=upper)
        priors[name] = Prior(table["distribution"], table.get("mu"), table.get("sigma"), source=str(path))
    return with_parameters(model, parameters), priors


def prior_table(log_post) -> list[dict]:
    """The priors a :class:`identify.fitting.posterior.LogPosterior` uses, one dict per sampled
    coordinate: ``name``, ``distribution``, ``lower``, ``upper`` (and ``mu``, ``sigma``), and
    ``source`` (the priors file, or ``"default"``); for ``summary.json`` and the report."""
    rows = []
    for j, name in enumerate(log_post.names):
        prior = log_post.priors_used.get(name)
        row = {"name": name}
        if isinstance(prior, Prior):
            row.update(prior.to_dict())
            row["source"] = prior.source or "given"
        else:
            row["distribution"] = log_post.prior_names[name]
            row["source"] = "default"
        row["lower"], row["upper"] = float(log_post.lower[j]), float(log_post.upper[j])
        rows.append(row)
    return rows
