"""Named model parameters: value, bounds, unit and whether they vary (lmfit style)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["Parameter", "ParameterSet"]


@dataclass(frozen=True)
class Parameter:
    """One scalar model parameter.

    Parameters
    ----------
    name : str
        Unique name, used everywhere (CLI, JSON, reports), e.g. ``"lag_tau"``.
    value : float
        Default / starting value.
    lower, upper : float
        Hard bounds (the prior's support). ``lower < upper``; ``value`` lies within.
    unit : str
        Physical unit, for labels (``""`` for dimensionless).
    vary : bool
        False pins the parameter at ``value`` during identification.
    description : str
        One line saying what the parameter is.
    per_record : bool
        True when the parameter belongs to the run rather than the transducer (a sensor's
        drift, the state a run starts from): several records of one transducer each get their
        own value; False (default): one value shared by every record.
    """

    name: str
    value: float
    lower: float = -np.inf
    upper: float = np.inf
    unit: str = ""
    vary: bool = True
    description: str = ""
    per_record: bool = False

    def __post_init__(self):
        if not self.name.isidentifier():
            raise ValueError(f"parameter name {self.name!r} is not a valid identifier")
        if not (self.lower < self.upper):
            raise ValueError(f"parameter {self.name!r}: lower bound {self.lower} is not below upper bound {self.upper}")
        if not np.isfinite(self.value) or not (self.lower <= self.value <= self.upper):
            raise ValueError(
                f"parameter {self.name!r}: value {self.value} is not finite or lies outside [{self.lower}, "
                f"{self.upper}]"
            )

    def with_(self, **changes) -> Parameter:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


class ParameterSet(tuple):
    """An ordered, name-unique tuple of :class:`Parameter` with array views."""

    def __new__(cls, parameters):
        parameters = tuple(parameters)
        seen = set()
        for p in parameters:
            if not isinstance(p, Parameter):
                raise TypeError(f"expected Parameter, got {type(p).__name__}")
            if p.name in seen:
                raise ValueError(f"parameter name {p.name!r} appears twice")
            seen.add(p.name)
        return super().__new__(cls, parameters)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self)

    @property
    def values(self) -> np.ndarray:
        return np.array([p.value for p in self], dtype=float)

    @property
    def lower(self) -> np.ndarray:
        return np.array([p.lower for p in self], dtype=float)

    @property
    def upper(self) -> np.ndarray:
        return np.array([p.upper for p in self], dtype=float)

    @property
    def vary(self) -> np.ndarray:
        return np.array([p.vary for p in self], dtype=bool)

    def index(self, name: str) -> int:  # type: ignore[override]
        for i, p in enumerate(self):
            if p.name == name:
                return i
        raise KeyError(f"no parameter named {name!r}; known: {', '.join(self.names)}")

    def __getitem__(self, key):
        if isinstance(key, str):
            return tuple.__getitem__(self, self.index(key))
        return tuple.__getitem__(self, key)

    def replace(self, name: str, **changes) -> ParameterSet:
        """A copy with parameter ``name`` changed."""
        i = self.index(name)
        items = list(self)
        items[i] = items[i].with_(**changes)
        return ParameterSet(items)
