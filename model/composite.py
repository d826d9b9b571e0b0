"""The GPI model plus any subset of physical effects, as one vectorised forward model: :class:`Model`.

The effect protocol (:class:`Effect`, its three stages, the parameter declaration) and the
registry (:data:`EFFECTS`, :func:`register_effect`, :func:`get_effect`, :data:`STAGES`)
live in :mod:`model.effects.base` and are importable from here too; the library of effects
is :mod:`model.effects`.

A :class:`Model` applies its effects in the library's canonical order (input stage,
then state, then output, each in registration order), so ``thermal,creep`` and
``creep,thermal`` are the same model. Models compose with ``+``::

    Model() + "lag" + "thermal"      # == Model(["lag", "thermal"])

Every stage acts row by row (a parameter set's result depends on its own parameters and
its own input only): :meth:`Model.evaluate` relies on it to run each stage once per
distinct input of a batch (the rows of a finite-difference Jacobian differ in one
parameter each), which is exact (tested for the whole library).

Every effect has parameter values (:attr:`Effect.off`) at which the model equals the
plain GPI exactly, and :meth:`Effect.get_test_parameters` giving a typical "on"
setting, so the test suite can iterate over the whole library.
"""

from __future__ import annotations

import copy

import numpy as np

from .effects.base import EFFECTS, STAGES, Effect, get_effect, register_effect
from .gpi import GPI_PARAMETERS, READINGS, THETA_NAMES, distinct_rows, gpi_grouped
from .parameters import ParameterSet

__all__ = ["Effect", "Model", "EFFECTS", "register_effect", "get_effect", "STAGES"]


class Model:
    """The GPI of :mod:`model.gpi` plus physical effects.

    Parameters
    ----------
    effects : sequence of str or Effect, default ()
        Effects to add, by name (see :data:`EFFECTS`). Order does not matter.
    n_operators : int, default 12
        Number of play operators.
    reading : {"swapped", "literal"}, default "swapped"
        Reading of the paper's eqs. (5)-(7); see :mod:`model.gpi`.
    gpi_parameters : ParameterSet, optional
        Override the GPI parameters' defaults/bounds (e.g. pinned by a normalisation).

    The full parameter vector is the 19 GPI parameters (Table 1 order) followed by
    each effect's parameters in canonical order: :attr:`names`.
    """

    def __init__(self, effects=(), n_operators=12, reading="swapped", gpi_parameters=None):
        if reading not in READINGS:
            raise ValueError(f"reading must be one of {sorted(READINGS)}, got {reading!r}")
        if isinstance(effects, (str, Effect)):
            effects = [effects]
        instances = {}
        for e in effects:
            inst = get_effect(e)
            if inst.name in instances:
                raise ValueError(f"effect {inst.name!r} is given twice")
            instances[inst.name] = inst
        order = list(EFFECTS)
        stage_rank = {s: i for i, s in enumerate(STAGES)}
        self.effects = tuple(
            sorted(
                instances.values(), key=lambda e: (stage_rank[e.stage], order.index(e.name) if e.name in order else 0)
            )
        )
        self.n_operators = int(n_operators)
        self.reading = reading
        gpi_params = GPI_PARAMETERS if gpi_parameters is None else ParameterSet(gpi_parameters)
        if gpi_params.names != THETA_NAMES:
            raise ValueError("gpi_parameters must hold the 19 GPI parameters in Table 1 order")
        # ParameterSet refuses clashing names between effects.
        self.parameters = ParameterSet(list(gpi_params) + [p for e in self.effects for p in e.parameters])
        self._slices = {}
        start = len(THETA_NAMES)
        for e in self.effects:
            self._slices[e.name] = slice(start, start + len(e.parameters))
            start += len(e.parameters)

    # -- description -------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return self.parameters.names

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    @property
    def n_parameters(self) -> int:
        return len(self.parameters)

    def __repr__(self):
        return f"Model(effects={list(self.effect_names)}, n_operators={self.n_operators}, reading={self.reading!r})"

    def __eq__(self, other):
        return (
            isinstance(other, Model)
            and self.effect_names == other.effect_names
            and self.n_operators == other.n_operators
            and self.reading == other.reading
            and self.parameters == other.parameters
        )

    def __add__(self, effect):
        if isinstance(effect, (list, tuple)):
            extra = list(effect)
        else:
            extra = [effect]
        return self._with_effects(list(self.effects) + extra)

    def without(self, effect: str) -> Model:
        """The model less ``effect``, every other parameter keeping its settings (pins, bounds):
        ``m.without(e) + e == m``. An effect not in the model is a KeyError naming the model's."""
        self.effect_slice(effect)  # the KeyError that names the model's effects
        return self._with_effects([e for e in self.effects if e.name != effect])

    def _with_effects(self, effects) -> Model:
        """A model of ``effects`` with this one's operators, reading and GPI settings, where every
        parameter it shares with this one keeps its settings (pins, bounds); a new effect's are its own."""
        out = Model(effects, self.n_operators, self.reading, self.parameters[: len(THETA_NAMES)])
        kept = {p.name: p for p in self.parameters}
        return out.with_parameters(ParameterSet(kept.get(p.name, p) for p in out.parameters))

    def with_parameters(self, parameters) -> Model:
        """A copy with other parameter settings (values, bounds, pins): ``parameters`` must
        hold this model's parameters, in its order. The effects and the GPI settings are shared
        (the forward model does not read the settings)."""
        parameters = ParameterSet(parameters)
        if parameters.names != self.names:
            raise ValueError(f"parameters {list(parameters.names)} are not those of {self!r}: {list(self.names)}")
        out = copy.copy(self)
        out.parameters = parameters
        return out

    def with_gpi_parameters(self, gpi_parameters) -> Model:
        """A copy whose 19 GPI parameters have the settings ``gpi_parameters`` (Table 1 order);
        the effects' parameters keep theirs."""
        gpi_parameters = ParameterSet(gpi_parameters)
        return self.with_parameters(list(gpi_parameters) + list(self.parameters[len(THETA_NAMES) :]))

    def to_dict(self) -> dict:
        """JSON-ready description (effects, operators, reading)."""
        return {"effects": list(self.effect_names), "n_operators": self.n_operators, "reading": self.reading}

    @classmethod
    def from_dict(cls, d) -> Model:
        return cls(d.get("effects", ()), d.get("n_operators", 12), d.get("reading", "swapped"))

    # -- parameter vectors ----------------------------------------------------------
    def default_theta(self, gpi_theta=None) -> np.ndarray:
        """Full vector: ``gpi_theta`` (Table 1 by default) with every effect off."""
        theta = self.parameters.values.copy()
        if gpi_theta is not None:
            theta[: len(THETA_NAMES)] = np.asarray(gpi_theta, dtype=float)
        for e in self.effects:
            theta[self._slices[e.name]] = [e.off[n] for n in e.parameters.names]
        return theta

    def effect_slice(self, name: str) -> slice:
        """Columns of the full vector that hold effect ``name``'s parameters."""
        try:
            return self._slices[name]
        except KeyError:
            raise KeyError(f"effect {name!r} is not in this model ({list(self.effect_names)})") from None

    def theta_dict(self, theta) -> dict[str, float]:
        """``{name: value}`` for a 1-D full vector."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_parameters,):
            raise ValueError(f"theta must have shape ({self.n_parameters},), got {theta.shape}")
        return dict(zip(self.names, map(float, theta)))

    def theta_from_dict(self, values: dict) -> np.ndarray:
        """Full vector from ``{name: value}``; missing GPI values from Table 1, missing effect values off."""
        theta = self.default_theta()
        unknown = set(values) - set(self.names)
        if unknown:
            raise ValueError(f"unknown parameter names {sorted(unknown)} for {self!r}")
        for k, v in values.items():
            theta[self.parameters.index(k)] = float(v)
        return theta

    def _symmetric_effects(self):
        """The effects whose parameters all vary (or are pinned at an off value the symmetry
        keeps, :attr:`Effect.labelling_keeps_off`) and whose form has a labelling symmetry (their
        own :meth:`Effect.in_canonical_domain`): only there does the labelling matter."""

        def free(e, n):
            p = self.parameters[n]
            return p.vary or (n in type(e).labelling_keeps_off and p.value == type(e).off[n])

        return [
            e
            for e in self.effects
            if type(e).in_canonical_domain.__func__ is not Effect.in_canonical_domain.__func__
            and all(free(e, n) for n in e.parameters.names)
        ]

    @property
    def has_canonical_domain(self) -> bool:
        """Whether :meth:`in_canonical_domain` can exclude anything (a fully free effect with a
        labelling symmetry): a sampler asks once instead of at every evaluation."""
        return bool(self._symmetric_effects())

    def canonical_theta(self, theta) -> np.ndarray:
        """``theta`` (shape ``(P,)``) with every fully free effect mapped to its canonical
        labelling (:meth:`Effect.canonical`): the same output, and kept only when the mapped
        values are within the bounds."""
        theta = np.array(theta, dtype=float)
        for e in self._symmetric_effects():
            sl = self._slices[e.name]
            canonical = e.canonical(dict(zip(e.parameters.names, theta[sl])))
            mapped = np.array([canonical[n] for n in e.parameters.names], dtype=float)
            lower, upper = self.parameters.lower[sl], self.parameters.upper[sl]
            if np.all((mapped >= lower) & (mapped <= upper)):
                theta[sl] = mapped
        return theta

    def in_canonical_domain(self, theta) -> np.ndarray:
        """Boolean ``(W,)``: every fully free effect in its canonical domain (:meth:`Effect.in_canonical_domain`)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        ok = np.ones(theta.shape[0], dtype=bool)
        for e in self._symmetric_effects():
            ok &= e.in_canonical_domain(theta[:, self._slices[e.name]])
        return ok

    def in_bounds(self, theta) -> np.ndarray:
        """Boolean ``(W,)``: every parameter finite and within its bounds."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        return (
            np.isfinite(theta).all(axis=1)
            & (theta >= self.parameters.lower).all(axis=1)
            & (theta <= self.parameters.upper).all(axis=1)
        )

    # -- evaluation -----------------------------------------------------------------
    def _check(self, theta, time, current):
        theta = np.asarray(theta, dtype=float)
        if theta.ndim not in (1, 2) or theta.shape[-1] != self.n_parameters:
            raise ValueError(
                f"theta must have shape ({self.n_parameters},) or (W, {self.n_parameters}) for {self!r}, got "
                f"{theta.shape}"
            )
        time = np.asarray(time, dtype=float)
        current = np.asarray(current, dtype=float)
        if time.ndim != 1 or current.shape != time.shape:
            raise ValueError(f"time and current must both have shape (T,), got {time.shape} and {current.shape}")
        if time.size >= 2 and not (np.diff(time) > 0).all():
            raise ValueError("time must be strictly increasing")
        if not np.isfinite(time).all():
            raise ValueError("time has a non-finite value")
        return theta, time, current

    def evaluate(self, theta, time, current):
        """Batch evaluation with a validity mask (for log-posteriors).

        Parameters
        ----------
        theta : array_like, shape (P,) or (W, P)
            Full parameter vectors (:attr:`names` order).
        time : array_like, shape (T,)
            Sample times [s], strictly increasing.
        current : array_like, shape (T,)
            Drive current [A].

        Returns
        -------
        y : ndarray, shape (W, T)
            Displacement [um]. Rows with ``valid = False`` are meaningless.
        valid : ndarray of bool, shape (W,)
            False where a parameter set produced a non-finite output (e.g. an effect that
            overflows far out in its bounds). The GPI itself is defined for every finite
            parameter set (:mod:`model.gpi`, "The whole domain").
        """
        theta, time, current = self._check(theta, time, current)
        theta2 = np.atleast_2d(theta)
        n_sets = theta2.shape[0]
        # Each stage runs once per distinct input: ``group[w]`` is the row of ``drive`` (and
        # of ``width``) set ``w`` sees, and an input effect runs on the first set of each
        # distinct (group, parameters). In a finite-difference Jacobian most rows differ
        # from the first in one parameter, so most stages run on one or two rows; the
        # output is the one of running every set (each stage acts row by row).
        group = np.zeros(n_sets, dtype=np.int64)
        drive = None  # the record's current, shared by every set, until an input effect
        width = None
        z0 = 0.0
        excursion = 0.0
        held = 0.0
        for e in self.effects:
            params = theta2[:, self._slices[e.name]]
            if e.stage == "input":
                first, new_group = distinct_rows(group, params)
                seen = current if drive is None else drive[group[first]]
                sub = params[first]
                scale = e.threshold_scale(sub, time, seen)
                new_drive = np.atleast_2d(np.asarray(e.drive(sub, time, seen), dtype=float))
                if new_drive.shape[0] not in (1, first.size):
                    raise ValueError(
                        f"an input-stage effect returned {new_drive.shape[0]} rows for {first.size} parameter sets"
                    )
                if scale is not None:
                    scale = np.broadcast_to(np.atleast_2d(np.asarray(scale, dtype=float)), (first.size, time.size))
                    width = scale if width is None else width[group[first]] * scale
                elif width is not None:
                    width = width[group[first]]
                drive = np.ascontiguousarray(np.broadcast_to(new_drive, (first.size, time.size)))
                group = new_group
            elif e.stage == "state":
                z0 = np.asarray(e.initial_memory(params), dtype=float)
                reversal = e.initial_excursion(params)
                if reversal is not None:
                    excursion = np.asarray(reversal, dtype=float)
                kept = e.initial_held(params, self.n_operators)
                if kept is not None:
                    held = np.asarray(kept, dtype=float)
        if drive is None:
            drive = current[None, :]
        elif not np.isfinite(drive).all():
            raise ValueError("an input-stage effect produced a non-finite drive")
        y, y_of = gpi_grouped(
            theta2[:, : len(THETA_NAMES)], drive, group, self.n_operators, self.reading, z0, width, excursion, held
        )
        for e in self.effects:
            if e.stage == "output" or e.acts_on_output:
                params = theta2[:, self._slices[e.name]]
                first, new_y_of = distinct_rows(y_of, params)
                y = np.atleast_2d(e.output(params[first], time, current, y[y_of[first]]))
                y_of = new_y_of
        if y.shape[0] != n_sets:
            y = y[y_of]
        valid = np.isfinite(y).all(axis=1)
        return y, valid

    def __call__(self, theta, time, current):
        """Displacement [um], shape ``(T,)`` for a 1-D ``theta`` else ``(W, T)``.

        Raises :class:`ValueError` for a parameter set whose output is not finite.
        """
        theta = np.asarray(theta, dtype=float)
        y, valid = self.evaluate(theta, time, current)
        if not valid.all():
            rows = np.flatnonzero(~valid)[:10].tolist()
            raise ValueError(f"parameter set(s) {rows} give a non-finite output on this input (an effect overflowed)")
        return y[0] if theta.ndim == 1 else y
