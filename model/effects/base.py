"""The effect protocol: :class:`Effect`, its parameter declaration, and the registry :data:`EFFECTS`.

An :class:`Effect` is a small piece of the signal chain with named parameters. It acts
at one of three stages (:data:`STAGES`):

``"input"``
    transforms the drive current before the hysteresis (e.g. ``lag``):
    :meth:`Effect.drive` returns the per-parameter-set drive, shape ``(W, T)``.
``"state"``
    sets the operators' initial memory (e.g. ``initial_state``):
    :meth:`Effect.initial_memory` returns shape ``(W,)``, and optionally
    :meth:`Effect.initial_excursion` the last reversal before the record, shape ``(W,)``,
    and :meth:`Effect.initial_held` a memory held beyond the bounds, shape ``(W, N)``.
``"output"``
    transforms the displacement after the hysteresis (e.g. ``creep``, ``thermal``,
    ``sensor_drift``): :meth:`Effect.output` returns shape ``(W, T)``.

An input- or state-stage effect whose physics also acts on the strain sets
:attr:`Effect.acts_on_output` and implements :meth:`Effect.output` too (``training``: the
virgin material's strain amplitude); its output part runs before the output-stage effects.
An input-stage effect may also change the play width over the record
(:meth:`Effect.threshold_scale`: ``training``'s virgin width).

Every stage acts row by row: a parameter set's result depends on its own parameters and
its own input only. :meth:`model.composite.Model.evaluate` relies on it to run each stage
once per distinct input of a batch (the rows of a finite-difference Jacobian differ in one
parameter each), which is exact (tested for the whole library).

**Parameter declaration.** An effect declares its parameters (:attr:`Effect.parameters`)
named ``<effect>_<what>``, each at its **off** value: :attr:`Effect.off`, the values at
which the model is exactly the plain GPI, is derived from the declarations (a gain declared
at 0, a time constant at any value in its bounds, which then does nothing). The stage
methods receive the parameters as a ``(W, k)`` array and read them by name through
:meth:`Effect.values` (``p = self.values(params)``; ``p.tau`` is the column of
``lag_tau``), never by position.

Effects register themselves by name in :data:`EFFECTS` (:func:`register_effect`; the
library's modules in :mod:`model.effects` do so on import, in the canonical order).
Every effect has :meth:`Effect.get_test_parameters`, a typical "on" setting, so the test
suite can iterate over the whole library.
"""

from __future__ import annotations

from collections import namedtuple
from typing import ClassVar

import numpy as np

from ..parameters import ParameterSet

__all__ = ["Effect", "EFFECTS", "register_effect", "get_effect", "STAGES"]

STAGES = ("input", "state", "output")

#: name -> Effect subclass, in registration (canonical) order.
EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls):
    """Class decorator: add an :class:`Effect` subclass to :data:`EFFECTS` under ``cls.name``."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise TypeError("register_effect expects an Effect subclass")
    if cls.name in EFFECTS and EFFECTS[cls.name] is not cls:
        raise ValueError(f"an effect named {cls.name!r} is already registered")
    if cls.stage not in STAGES:
        raise ValueError(f"effect {cls.name!r}: stage must be one of {STAGES}, got {cls.stage!r}")
    prefix = cls.name + "_"
    for p in cls.parameters:
        if not p.name.startswith(prefix):
            raise ValueError(f"effect {cls.name!r}: parameter {p.name!r} must start with {prefix!r}")
    missing = set(cls.parameters.names) ^ set(cls.off)
    if missing:
        raise ValueError(
            f"effect {cls.name!r}: 'off' must give exactly one value per parameter (mismatch: {sorted(missing)})"
        )
    in_terms = [n for names in cls.terms.values() for n in names]
    if not set(in_terms) <= set(cls.parameters.names) or len(in_terms) != len(set(in_terms)):
        raise ValueError(f"effect {cls.name!r}: 'terms' must name its own parameters, each in one term at most")
    if not set(cls.forms) <= set(cls.terms) or len(cls.forms) == 1:
        raise ValueError(f"effect {cls.name!r}: 'forms' must name two or more of its terms (got {list(cls.forms)})")
    if cls.terms and len(in_terms) == len(cls.parameters) and not cls.forms:
        raise ValueError(
            f"effect {cls.name!r}: 'terms' must leave part of the effect outside every optional term, "
            "or name its alternative general forms ('forms'), of which a fit keeps one"
        )
    EFFECTS[cls.name] = cls
    return cls


def get_effect(name: str) -> Effect:
    """An instance of the registered effect ``name`` (clear error listing the known names)."""
    if isinstance(name, Effect):
        return name
    try:
        return EFFECTS[name]()
    except KeyError:
        raise ValueError(f"unknown effect {name!r}; the library has: {', '.join(EFFECTS) or '(none loaded)'}") from None


class Effect:
    """Base class of a physical effect; see the module docstring for the protocol.

    Subclasses set the class attributes and implement the method of their stage.
    ``params`` arguments are arrays of shape ``(W, k)`` with the effect's ``k``
    parameters as columns, in :attr:`parameters` order; read them by name with
    :meth:`values`.
    """

    name: ClassVar[str] = ""
    stage: ClassVar[str] = ""
    #: the effect's parameters; names start with ``name + "_"``, each declared at its off value
    parameters: ClassVar[ParameterSet] = ParameterSet(())
    #: parameter values at which the model is exactly the plain GPI: the declared values of
    #: :attr:`parameters` (set for every subclass by :meth:`__init_subclass__`, unless the
    #: class gives its own)
    off: ClassVar[dict[str, float]] = {}
    #: one line: what physics this represents, with its equation
    summary: ClassVar[str] = ""
    #: what tells this effect apart from the others in a record (completes "it ..."): shown
    #: when the diagnosis cannot choose between two effects that fit a record equally well
    signature: ClassVar[str] = ""
    #: optional parts of the physics, ``{term: parameter names}``: a term is off when its
    #: parameters are at :attr:`off`, and while its gains are 0 its other parameters (a time
    #: constant, an onset) have no effect at all, so a record without that part leaves them
    #: unidentified. A fit may pin such a term off where the record does not support it
    #: (``identify.fitting.terms``). Every effect keeps a part that is never pinned off: a
    #: parameter outside every term, or one of its :attr:`forms`.
    terms: ClassVar[dict[str, tuple[str, ...]]] = {}
    #: terms that are alternative general forms of the effect, each a complete physics of it
    #: (e.g. saturating and logarithmic creep): a record of one form must not pay for the
    #: other, so each is optional, but a fit keeps at least one (:meth:`keeps_a_form`). An
    #: effect whose every parameter lies in a term names two or more.
    forms: ClassVar[tuple[str, ...]] = ()
    #: an input- or state-stage effect that also transforms the displacement after the
    #: hysteresis (:meth:`output`, applied before the output-stage effects)
    acts_on_output: ClassVar[bool] = False
    #: physics of the first cycle: the material's first loading differs from the later ones
    #: (a virgin material that trains, a prior state, a strain the first cycle leaves). A
    #: record with one first loading can hold such parts without telling them apart.
    first_cycle: ClassVar[bool] = False
    #: parameters a labelling symmetry (:meth:`canonical`) maps to themselves while they are at
    #: their :attr:`off` value: pinned there, they leave the symmetry in force
    labelling_keeps_off: ClassVar[tuple[str, ...]] = ()
    #: terms of :attr:`terms` that hold the state earlier runs left a record in (run
    #: parameters, pinned off by default: one record that starts at rest cannot tell them from
    #: the rest of the effect, so a free start only slows its fit). Records of one transducer
    #: are taken one after another, and each starts where the earlier runs left it (a coil
    #: still warm), so a joint fit of several frees them (:meth:`earlier_run_parameters`).
    earlier_run_terms: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "off" not in cls.__dict__:
            cls.off = {p.name: p.value for p in cls.parameters}

    @classmethod
    def values(cls, params):
        """The parameter columns of ``params`` (shape ``(W, k)``) by name, without the effect's
        prefix: ``p = Lag.values(params)`` has ``p.tau`` and ``p.delay``, each a contiguous
        float array of shape ``(W,)`` (``p.tau[:, None]`` broadcasts over the samples)."""
        params = np.asarray(params, dtype=float)
        if params.ndim != 2 or params.shape[1] != len(cls.parameters):
            raise ValueError(
                f"effect {cls.name!r}: parameters must have shape (W, {len(cls.parameters)}), got {params.shape}"
            )
        view = cls.__dict__.get("_values_type")
        if view is None:
            prefix = cls.name + "_"
            fields = [n[len(prefix) :] if n.startswith(prefix) else n for n in cls.parameters.names]
            view = namedtuple(f"{cls.__name__}Values", fields)
            cls._values_type = view
        return view(*(np.ascontiguousarray(params[:, i]) for i in range(params.shape[1])))

    @classmethod
    def earlier_run_parameters(cls, parameters) -> tuple[str, ...]:
        """The parameters of :attr:`earlier_run_terms` a joint fit frees, given a model's
        ``parameters`` (a :class:`~model.parameters.ParameterSet` holding this effect's): by
        default every one of them."""
        return tuple(name for term in cls.earlier_run_terms for name in cls.terms[term])

    @classmethod
    def n_varying(cls) -> int:
        """How many of the effect's parameters vary by default: what adding it costs in a
        parameter count (one pinned by default, e.g. the state a run starts in, is not charged)."""
        return sum(1 for p in cls.parameters if p.vary)

    def drive(self, params, time, current):  # pragma: no cover - protocol
        """Stage ``"input"``: drive seen by the hysteresis, shape ``(W, T)`` [A]."""
        raise NotImplementedError

    def threshold_scale(self, params, time, drive):
        """Stage ``"input"``, optional: a factor on every play threshold at each sample, shape
        ``(W, T)``, or None (the default: the thresholds of the GPI). ``drive`` is the drive
        this effect receives (after the input effects before it)."""
        return None

    def initial_memory(self, params):  # pragma: no cover - protocol
        """Stage ``"state"``: the operators' initial memory level, shape ``(W,)``."""
        raise NotImplementedError

    def initial_excursion(self, params):
        """Stage ``"state"``, optional: the last reversal before the record, shape ``(W,)`` [A]
        (:func:`model.gpi.gpi`'s ``initial_excursion``), or None (the default: none)."""
        return None

    def initial_held(self, params, n_operators):
        """Stage ``"state"``, optional: memory held beyond the bounds at the record's start,
        shape ``(W, N)`` [A] (:func:`model.gpi.gpi`'s ``initial_held``), or None (the
        default: none)."""
        return None

    def output(self, params, time, current, displacement):  # pragma: no cover - protocol
        """Stage ``"output"``: displacement after the effect, shape ``(W, T)`` [um]."""
        raise NotImplementedError

    @classmethod
    def get_test_parameters(cls) -> dict[str, float]:
        """A typical "on" setting, within bounds, that visibly changes the output."""
        raise NotImplementedError(f"effect {cls.name!r} must define get_test_parameters()")

    @classmethod
    def canonical(cls, values: dict[str, float]) -> dict[str, float]:
        """The representative of ``values`` (the effect's parameters by name) in the effect's
        canonical domain: an effect whose form has an exact discrete symmetry (two labellings
        that give the same output) maps the other labelling here. Default: ``values``."""
        return values

    @classmethod
    def in_canonical_domain(cls, params) -> np.ndarray:
        """Boolean ``(W,)`` of parameter rows ``(W, k)``: in the canonical domain (default: all)."""
        return np.ones(np.atleast_2d(params).shape[0], dtype=bool)

    @classmethod
    def reduced_starts(cls, values: dict[str, float], term: str) -> list[dict[str, float]]:
        """Starting values of this effect's parameters with ``term`` off, from ``values`` of
        a fit with every term free: by default ``values`` with the term's parameters at
        :attr:`off`. An effect whose other terms can take over what ``term`` did (e.g. two
        thermal nodes that can exchange roles) adds a start for that."""
        return [{**values, **{name: cls.off[name] for name in cls.terms[term]}}]

    @classmethod
    def keeps_a_form(cls, off_terms) -> bool:
        """Does the effect keep one of its :attr:`forms` with the terms ``off_terms`` (names)
        switched off? True for an effect without forms (its core is never a term)."""
        return not cls.forms or not set(cls.forms) <= set(off_terms)

    @classmethod
    def term_reductions(cls, term: str) -> list[dict[str, float]]:
        """The ways of switching ``term`` off, each ``{parameter: value}`` (the other parameters
        free): by default the term's parameters at :attr:`off`. An effect whose simpler form
        has a second labelling (one thermal node standing for the other) adds it; the
        parameters set are the ones the simpler form does not have."""
        return [{name: cls.off[name] for name in cls.terms[term]}]

    def __repr__(self):
        return f"{type(self).__name__}()"
