"""Library of physical effects that can be added to the GPI model (see model.composite).

Each effect registers itself with :func:`model.composite.register_effect`.
"""

from __future__ import annotations

from .composite import Effect, register_effect  # noqa: F401

__all__: list[str] = []
